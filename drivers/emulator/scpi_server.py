"""The instrument side of SCPI: header matching, parameters, error queue.

Headers are declared in the usual notation: upper-case letters are the short
form, the whole word the long form, ``[...]`` marks an optional node and ``#`` a
numeric suffix (``SENSe:CHANnel#:RANGe`` matches ``sens:chan2:rang``). Matching is
case-insensitive. Program messages may hold several units separated by ``;``; each
unit's header is resolved from the root (a leading ``:`` is accepted), and the
replies of the queries in one message come back in one line joined by ``;``.
"""
from __future__ import annotations

import math
import re
import threading
from collections import deque
from dataclasses import dataclass
from typing import Callable

from ..errors import ScpiErrorEntry

ERROR_MESSAGES = {
    0: "No error",
    -102: "Syntax error",
    -104: "Data type error",
    -108: "Parameter not allowed",
    -109: "Missing parameter",
    -113: "Undefined header",
    -114: "Header suffix out of range",
    -131: "Invalid suffix",
    -200: "Execution error",
    -213: "Init ignored",
    -221: "Settings conflict",
    -222: "Data out of range",
    -224: "Illegal parameter value",
    -300: "Device-specific error",
    -350: "Queue overflow",
    -363: "Input buffer overrun",
    201: "Watchdog expired; output switched off",
    301: "Acquisition FIFO overrun; frames lost",
}
"""Every error code the emulated instruments report (docs/protocol.md lists when)."""

ERROR_QUEUE_LENGTH = 20
_NUMBER = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$")
_NUMBER_WITH_SUFFIX = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*[A-Za-z]+$")
_CHANNEL_LIST = re.compile(r"^\(\s*@\s*([0-9:,\s]+)\)$")


class ScpiError(Exception):
    """A command failed with SCPI error ``code``; ``detail`` is appended to the standard message."""

    def __init__(self, code: int, detail: str | None = None):
        self.code = code
        self.detail = detail
        super().__init__(self.entry().message)

    def entry(self) -> ScpiErrorEntry:
        message = ERROR_MESSAGES[self.code]
        return ScpiErrorEntry(self.code, f"{message};{self.detail}" if self.detail else message)


class Interrupted(Exception):
    """The program message was abandoned by a device clear: the rest of it is not executed, nothing queued."""


class ErrorQueue:
    """The instrument's error queue: oldest first; when full the newest entry becomes -350."""

    def __init__(self, capacity: int = ERROR_QUEUE_LENGTH):
        self._entries: deque[ScpiErrorEntry] = deque()
        self._capacity = capacity
        self._lock = threading.Lock()

    def push(self, error: ScpiError) -> None:
        with self._lock:
            if len(self._entries) >= self._capacity:
                self._entries[-1] = ScpiError(-350).entry()
            else:
                self._entries.append(error.entry())

    def pop(self) -> ScpiErrorEntry:
        with self._lock:
            return self._entries.popleft() if self._entries else ScpiErrorEntry(0, ERROR_MESSAGES[0])

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)


def keyword_regex(word: str) -> str:
    """Regex alternative for a mnemonic such as ``FREQuency`` (FREQ or FREQUENCY)."""
    short = "".join(ch for ch in word if ch.isupper() or ch.isdigit() or ch in "*")
    full = word.upper()
    return re.escape(short) if short == full else f"(?:{re.escape(short)}|{re.escape(full)})"


def compile_header(pattern: str) -> re.Pattern:
    """Compile a header pattern (see module docstring) to an anchored upper-case regex."""
    parts = []
    for token in re.findall(r"\[|\]|:|\*?[A-Za-z]+#?", pattern):
        if token == "[":
            parts.append("(?:")
        elif token == "]":
            parts.append(")?")
        elif token == ":":
            parts.append(":")
        elif token.endswith("#"):
            parts.append(keyword_regex(token[:-1]) + r"(\d*)")
        else:
            parts.append(keyword_regex(token))
    return re.compile("^:?" + "".join(parts) + "$")


def split_outside(text: str, separator: str) -> list[str]:
    """Split on ``separator`` outside double quotes and parentheses."""
    pieces, depth, quoted, start = [], 0, False, 0
    for i, ch in enumerate(text):
        if ch == '"':
            quoted = not quoted
        elif not quoted and ch == "(":
            depth += 1
        elif not quoted and ch == ")":
            depth = max(0, depth - 1)
        elif not quoted and depth == 0 and ch == separator:
            pieces.append(text[start:i])
            start = i + 1
    pieces.append(text[start:])
    return pieces


# ----- parameter parsing ------------------------------------------------------------------------
def expect_none(args: list[str]) -> None:
    if args:
        raise ScpiError(-108)


def reply_with(value: Callable[[], str]) -> Callable[[list[str]], str]:
    """Handler of a query without parameters that answers ``value()``."""
    def handler(args: list[str]) -> str:
        expect_none(args)
        return value()
    return handler


def action(do: Callable[[], None]) -> Callable[[list[str]], None]:
    """Handler of a command without parameters that calls ``do()``."""
    def handler(args: list[str]) -> None:
        expect_none(args)
        do()
    return handler


def expect_one(args: list[str]) -> str:
    if not args or not args[0]:
        raise ScpiError(-109)
    if len(args) > 1:
        raise ScpiError(-108)
    return args[0]


def match_keyword(text: str, choices: dict[str, str]) -> str | None:
    """The value of the mnemonic in ``choices`` (e.g. ``{"SINusoid": "SIN"}``) that ``text`` spells."""
    for word, value in choices.items():
        if re.fullmatch(keyword_regex(word), text.upper()):
            return value
    return None


def parse_choice(text: str, choices: dict[str, str]) -> str:
    value = match_keyword(text, choices)
    if value is None:
        raise ScpiError(-224, f"expected {'|'.join(choices)}")
    return value


def parse_bool(text: str) -> bool:
    value = match_keyword(text, {"ON": "1", "OFF": "0", "1": "1", "0": "0"})
    if value is None:
        raise ScpiError(-224, "expected ON|OFF|1|0")
    return value == "1"


def parse_number(text: str, low: float, high: float, default: float | None = None,
                 integer: bool = False) -> float:
    """A numeric parameter in [low, high]; MINimum, MAXimum and DEFault are accepted."""
    keyword = match_keyword(text, {"MINimum": "MIN", "MAXimum": "MAX", "DEFault": "DEF"})
    if keyword == "MIN":
        return low
    if keyword == "MAX":
        return high
    if keyword == "DEF" and default is not None:
        return default
    text = text.strip()
    if _NUMBER.match(text):
        value = float(text)
    elif _NUMBER_WITH_SUFFIX.match(text):
        raise ScpiError(-131, "values are in SI base units without suffix")
    else:
        raise ScpiError(-104, f"expected a number, got {text[:20]!r}")
    if integer and value != int(value):
        raise ScpiError(-104, "expected an integer")
    if not low <= value <= high:
        raise ScpiError(-222, f"valid range {format_number(low)} to {format_number(high)}")
    return int(value) if integer else value


def limit_query(args: list[str], low: float, high: float, current: float) -> float:
    """Value for ``X?``, ``X? MIN`` or ``X? MAX``."""
    if not args:
        return current
    keyword = match_keyword(expect_one(args), {"MINimum": "MIN", "MAXimum": "MAX"})
    if keyword is None:
        raise ScpiError(-224, "expected MIN|MAX")
    return low if keyword == "MIN" else high


def parse_channel_list(text: str, count: int) -> list[int]:
    """``(@1,3:4)`` to zero-based indices [0, 2, 3]; each channel in 1..count, no repeats."""
    match = _CHANNEL_LIST.match(text.strip())
    if match is None:
        raise ScpiError(-104, "expected a channel list such as (@1,2:4)")
    indices: list[int] = []
    for item in match.group(1).split(","):
        bounds = [b.strip() for b in item.split(":")]
        if len(bounds) > 2 or not all(b.isdigit() for b in bounds):
            raise ScpiError(-104, f"bad channel range {item.strip()!r}")
        first, last = int(bounds[0]), int(bounds[-1])
        if not 1 <= first <= last <= count:
            raise ScpiError(-222, f"channels are 1 to {count}")
        indices.extend(range(first - 1, last))
    if len(set(indices)) != len(indices):
        raise ScpiError(-224, "channel listed twice")
    return indices


def format_channel_list(indices: list[int]) -> str:
    return "(@" + ",".join(str(i + 1) for i in indices) + ")"


def format_number(value: float) -> str:
    """Shortest text that reads back as the same float (an NRf number; integers without a point)."""
    value = float(value)
    if math.isfinite(value) and value == int(value) and abs(value) < 1e16:
        return str(int(value))
    return repr(value)


def block_data(payload: bytes) -> bytes:
    """IEEE 488.2 definite-length block: ``#<digits of length><length><payload>``."""
    length = str(len(payload)).encode()
    return b"#" + str(len(length)).encode() + length + payload


# ----- commands ------------------------------------------------------------------------------
Handler = Callable[..., "str | bytes | None"]


@dataclass
class CommandSpec:
    """One header with its set (write) and query handlers.

    Handlers take the parameter list and, for a pattern with ``#``, the suffix
    number (1 when omitted). ``while_busy`` marks commands the instrument still
    accepts while it streams.
    """

    pattern: str
    regex: re.Pattern
    write: Handler | None
    query: Handler | None
    while_busy: bool = False


class ScpiServer:
    """Parse and execute program messages against a table of commands."""

    def __init__(self) -> None:
        self.commands: list[CommandSpec] = []
        self.errors = ErrorQueue()

    def add(self, pattern: str, *, write: Handler | None = None, query: Handler | None = None,
            while_busy: bool = False) -> None:
        self.commands.append(CommandSpec(pattern, compile_header(pattern), write, query, while_busy))

    def lookup(self, header: str) -> tuple[CommandSpec, list[int]]:
        upper = header.upper()
        for spec in self.commands:
            match = spec.regex.match(upper)
            if match:
                return spec, [int(g) if g else 1 for g in match.groups()]
        raise ScpiError(-113, header[:40])

    def execute(self, message: str, *, busy: bool = False,
                reject: Callable[[], bool] | None = None) -> bytes | None:
        """Execute one program message; the reply line (with LF) or None.

        Parameters
        ----------
        message : str
            The message without its terminator.
        busy : bool
            The instrument is streaming: only ``while_busy`` commands run, the rest
            are rejected with -221.
        reject : callable, optional
            Asked before each command (not query); True rejects it with -300
            (fault injection).
        """
        replies: list[bytes] = []
        for unit in split_outside(message, ";"):
            unit = unit.strip()
            if not unit:
                continue
            try:
                reply = self._execute_unit(unit, busy, reject)
            except Interrupted:
                return None
            except ScpiError as exc:
                self.errors.push(exc)
                continue
            except Exception as exc:  # a failure behind the command (e.g. the physics) must not stop the parser
                self.errors.push(ScpiError(-300, f"{type(exc).__name__}: {exc}"[:200]))
                continue
            if reply is not None:
                replies.append(reply if isinstance(reply, bytes) else reply.encode("ascii"))
        return b";".join(replies) + b"\n" if replies else None

    def _execute_unit(self, unit: str, busy: bool, reject: Callable[[], bool] | None) -> str | bytes | None:
        header, _, rest = unit.partition(" ")
        if not header or not re.fullmatch(r":?[*A-Za-z][A-Za-z0-9:]*\??", header):
            raise ScpiError(-102, unit[:40])
        is_query = header.endswith("?")
        spec, suffixes = self.lookup(header[:-1] if is_query else header)
        handler = spec.query if is_query else spec.write
        if handler is None:
            raise ScpiError(-113, f"{header} is {'not a query' if is_query else 'query only'}")
        if busy and not spec.while_busy:
            raise ScpiError(-221, "acquisition running; send ABORt first")
        if not is_query and reject is not None and reject():
            raise ScpiError(-300, "command not executed")
        args = [a.strip() for a in split_outside(rest, ",")] if rest.strip() else []
        return handler(args, *suffixes)
