"""SCPI over a pyserial port: one owner thread per port, a deadline on every read.

The port is opened with :func:`serial.serial_for_url`, so a device name
(``/dev/ttyUSB0``, ``COM4``), ``socket://host:port``, ``rfc2217://...`` and the
in-process emulator's ``sim://rig/instrument`` all work the same way.

Only the owner thread of a :class:`SerialLink` touches its port. Other threads hand
it work (:meth:`SerialLink.call`), so replies can never interleave. Reads poll the
port in short slices (:data:`POLL` s) until a deadline, so a silent instrument
raises :class:`~drivers.errors.LinkTimeout` instead of hanging, and a vanished port
raises :class:`~drivers.errors.LinkLost`. Between slices the owner thread services
emergency writes (output off from a signal handler) ahead of everything queued.

Messages are ASCII lines terminated by LF; replies to several queries in one line
come back joined by ``;``. Binary replies use IEEE 488.2 definite-length block data
``#<d><length><bytes>`` followed by LF.
"""
from __future__ import annotations

import collections
import logging
import queue
import re
import threading
import time
from typing import Any, Callable

import serial

from .errors import (DeviceError, InstrumentError, LinkLost, LinkTimeout, ProtocolError, ScpiErrorEntry,
                     WrongDevice)
from .interfaces import Identity

log = logging.getLogger("contactid.drivers")

POLL = 0.02
"""Slice of a blocking read (s): the longest an emergency write waits for the owner thread."""
MAX_LINE = 1 << 16
"""Longest reply line accepted (bytes); anything longer is a protocol error."""
MAX_ERRORS_DRAINED = 64
"""Error-queue entries read after a failed command before giving up draining."""
CLEAR_QUIET = 0.1
"""Device clear on a byte link: the line must stay silent this long (s) before the first command..."""
CLEAR_LIMIT = 10.0
"""...waiting at most this long (s) for a previous client's late replies or stream to end."""
LATE_REPLIES = 1
"""Replies to a query that may miss their deadline once: waited for one more timeout (logged) before the
request fails. A loaded host can delay one reply past a real instrument's 1 s; two in a row is a failure."""
_ERROR_REPLY = re.compile(r'^\s*([+-]?\d+)\s*,\s*"(.*)"\s*$')


def open_port(url: str, *, baudrate: int, write_timeout: float) -> serial.SerialBase:
    """Open ``url`` with pyserial; LinkLost with the reason if it cannot be opened."""
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=POLL, write_timeout=write_timeout)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkLost(url, f"cannot open port: {exc}") from None


def parse_error_entry(url: str, reply: str) -> ScpiErrorEntry:
    """Parse a ``SYSTem:ERRor?`` reply such as ``-222,"Data out of range"``."""
    match = _ERROR_REPLY.match(reply)
    if match is None:
        raise ProtocolError(url, f"SYST:ERR? answered {reply!r}, expected <code>,\"<message>\"")
    return ScpiErrorEntry(int(match.group(1)), match.group(2))


class PortIO:
    """Buffered reads with deadlines on one open port (used only by its owner thread).

    Parameters
    ----------
    port : serial.SerialBase
        The open port.
    url : str
        Its URL, for messages.
    service : callable
        Called after every read slice (the owner's emergency-write check).
    """

    def __init__(self, port: serial.SerialBase, url: str, service: Callable[[], None]):
        self.port = port
        self.url = url
        self.rx = bytearray()
        self.last_activity = time.monotonic()
        self.desynced = False
        # what reply deadlines count: the wall clock, or for an in-process emulator its idle time
        self.clock: Callable[[], float] = getattr(port, "deadline_clock", time.monotonic)
        # whether the instrument samples only as it is read (an in-process emulator in fast mode: drivers/daq.py)
        self.samples_on_demand: bool = bool(getattr(port, "samples_on_demand", False))
        self._service = service
        self._timeout = port.timeout

    def _receive(self, size: int, timeout: float) -> bytes:
        if timeout != self._timeout:
            self.port.timeout = timeout
            self._timeout = timeout
        try:
            data = self.port.read(size)
        except (serial.SerialException, OSError) as exc:
            raise LinkLost(self.url, f"port lost while reading: {exc}") from None
        if data:
            self.last_activity = time.monotonic()
        self._service()
        return data

    def write(self, data: bytes) -> None:
        """Write all of ``data``; LinkTimeout if the port does not take it in time."""
        try:
            self.port.write(data)
        except serial.SerialTimeoutException:
            raise LinkTimeout(self.url, f"port did not accept {len(data)} bytes in time") from None
        except (serial.SerialException, OSError) as exc:
            raise LinkLost(self.url, f"port lost while writing: {exc}") from None
        self.last_activity = time.monotonic()

    def _fill(self, deadline: "Deadline", what: str) -> None:
        """Append at least one byte to ``rx`` or raise LinkTimeout at the deadline."""
        chunk = self._receive(MAX_LINE, 0)
        while not chunk:
            left = deadline.left()
            if left <= 0:
                self.desynced = True
                raise LinkTimeout(self.url, f"no complete reply to {what}{deadline.extended()}")
            chunk = self._receive(1, min(POLL, left))
        self.rx += chunk

    def read_line(self, deadline: "Deadline", what: str) -> bytes:
        """The next LF-terminated line (terminator and a trailing CR removed)."""
        while True:
            end = self.rx.find(b"\n")
            if end >= 0:
                line = bytes(self.rx[:end])
                del self.rx[:end + 1]
                return line[:-1] if line.endswith(b"\r") else line
            if len(self.rx) > MAX_LINE:
                self.rx.clear()
                self.desynced = True
                raise ProtocolError(self.url, f"reply to {what} exceeds {MAX_LINE} bytes without a line end")
            self._fill(deadline, what)

    def read_exact(self, count: int, deadline: "Deadline", what: str) -> bytes:
        """Exactly ``count`` bytes, or LinkTimeout at the deadline."""
        while len(self.rx) < count:
            left = deadline.left()
            if left <= 0:
                self.desynced = True
                raise LinkTimeout(self.url, f"reply to {what} incomplete: {len(self.rx)} of {count} bytes"
                                            f"{deadline.extended()}")
            self.rx += self._receive(count - len(self.rx), min(POLL, left))
        data = bytes(self.rx[:count])
        del self.rx[:count]
        return data

    def read_some(self, size: int, timeout: float) -> bytes:
        """Whatever arrives within ``timeout`` (buffered bytes first), at most about ``size`` bytes."""
        if self.rx:
            data = bytes(self.rx)
            self.rx.clear()
            return data
        return self._receive(size, timeout)

    def unread(self, data: bytes) -> None:
        """Put bytes back in front of the receive buffer."""
        self.rx[:0] = data

    def discard_input(self) -> None:
        """Drop everything received and not yet read (after a timeout left the link out of step)."""
        self.rx.clear()
        try:
            self.port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise LinkLost(self.url, f"port lost: {exc}") from None
        self.desynced = False

    def drain(self, quiet: float, limit: float) -> None:
        """Discard input until nothing arrives for ``quiet`` s (at most ``limit`` s)."""
        self.rx.clear()
        start = last = time.monotonic()
        while True:
            now = time.monotonic()
            if now - last >= quiet or now - start >= limit:
                return
            if self._receive(MAX_LINE, min(POLL, quiet)):
                last = time.monotonic()


class Deadline:
    """When a reply is due, on the port's clock (:attr:`PortIO.clock`).

    ``late_replies`` = 1 gives a reply that misses the deadline one more timeout before the read fails: a busy
    host (or a busy instrument) can make one reply late without losing the run; the extension is logged."""

    def __init__(self, io: PortIO, timeout: float, what: str, late_replies: int = 0):
        self.io = io
        self.timeout = timeout
        self.what = what
        self.at = io.clock() + timeout
        self._late_left = late_replies
        self.extensions = 0

    def left(self) -> float:
        """Seconds left (<= 0: expired, after any extension)."""
        left = self.at - self.io.clock()
        if left <= 0 and self._late_left > 0:
            self._late_left -= 1
            self.extensions += 1
            log.warning("%s: reply to %s is late; waiting %.3g s more before giving up", self.io.url, self.what,
                        self.timeout)
            self.at = self.io.clock() + self.timeout
            left = self.timeout
        return left

    def extended(self) -> str:
        """A message's note of the extension: `` (and again 1 s after it was late)``."""
        return f" (and {self.timeout:.3g} s more after it was late)" if self.extensions else ""


class _Request:
    __slots__ = ("fn", "done", "result", "error")

    def __init__(self, fn: Callable[[PortIO], Any]):
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None

    def wait(self, url: str, timeout: float, clock: Callable[[], float] = time.monotonic) -> Any:
        """The request's result, waiting at most ``timeout`` s on ``clock`` (the port's)."""
        deadline = clock() + timeout
        while not self.done.wait(min(POLL * 5, max(deadline - clock(), 0.0))):
            if clock() >= deadline:
                raise LinkTimeout(url, f"port owner did not finish the request within {timeout:.3g} s")
        if self.error is not None:
            raise self.error
        return self.result


class SerialLink:
    """A pyserial port with its owner thread.

    Parameters
    ----------
    url : str
        Port name or pyserial URL.
    name : str
        Short role name (``"shaker"``, ``"daq"``) for the thread name.
    baudrate : int
        Line rate for real serial ports (ignored by socket and sim transports).
    write_timeout : float
        Longest a write may block (s).
    port : serial.SerialBase, optional
        An already open port to own instead of opening ``url`` (tests use scripted ports).
    """

    def __init__(self, url: str, *, name: str, baudrate: int = 115200, write_timeout: float = 1.0,
                 port: serial.SerialBase | None = None):
        self.url = url
        self.port = port if port is not None else open_port(url, baudrate=baudrate,
                                                            write_timeout=write_timeout)
        self.port.timeout = POLL
        self.io = PortIO(self.port, url, self._service_emergencies)
        self.failure: LinkLost | None = None
        self._requests: queue.Queue[_Request | None] = queue.Queue()
        self._emergencies: collections.deque[tuple[bytes, threading.Event]] = collections.deque()
        self._idle_hook: Callable[[PortIO], None] | None = None
        self._idle_interval = 0.0
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"{name} port {url}", daemon=True)
        self._thread.start()

    # ----- owner thread -------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while True:
                self._service_emergencies()
                try:
                    request = self._requests.get(timeout=POLL)
                except queue.Empty:
                    self._idle()
                    continue
                if request is None:
                    break
                self._execute(request)
        finally:
            self._service_emergencies()
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass  # the port is gone already; closing it is all that was left to do

    def _execute(self, request: _Request) -> None:
        try:
            request.result = request.fn(self.io)
        except LinkLost as exc:
            self.failure = exc
            request.error = exc
        except BaseException as exc:  # handed to the calling thread, which re-raises it
            request.error = exc
        finally:
            request.done.set()

    def _idle(self) -> None:
        hook = self._idle_hook
        if hook is None or self.failure is not None:
            return
        if time.monotonic() - self.io.last_activity < self._idle_interval:
            return
        try:
            hook(self.io)
        except LinkLost as exc:
            self.failure = exc
        except InstrumentError:
            pass  # the hook records instrument faults itself; the link stays usable

    def _service_emergencies(self) -> None:
        while self._emergencies:
            data, sent = self._emergencies.popleft()
            if self.failure is None:
                try:
                    self.io.write(data)
                except LinkLost as exc:
                    self.failure = exc
                except LinkTimeout:
                    continue
                else:
                    sent.set()

    # ----- any thread ---------------------------------------------------------------------
    def _check_usable(self) -> None:
        if self.failure is not None:
            raise LinkLost(self.url, f"link is down ({self.failure.message})")
        if self._closed:
            raise LinkLost(self.url, "port is closed")

    def submit(self, fn: Callable[[PortIO], Any]) -> _Request:
        """Queue ``fn(io)`` for the owner thread; wait on the returned request yourself."""
        self._check_usable()
        request = _Request(fn)
        self._requests.put(request)
        return request

    def call(self, fn: Callable[[PortIO], Any], timeout: float) -> Any:
        """Run ``fn(io)`` on the owner thread and return its result (or raise its exception).

        Called on the owner thread itself (from a fault listener, say), ``fn`` runs at once.
        """
        if threading.current_thread() is self._thread:
            self._check_usable()
            return fn(self.io)
        return self.submit(fn).wait(self.url, timeout, self.io.clock)

    def set_idle_hook(self, hook: Callable[[PortIO], None] | None, interval: float) -> None:
        """Run ``hook(io)`` on the owner thread whenever the port was silent ``interval`` s."""
        self._idle_interval = interval
        self._idle_hook = hook

    def emergency_write(self, data: bytes, timeout: float) -> bool:
        """Write ``data`` before anything queued; True once written.

        Safe in a signal handler: it takes no lock the interrupted thread could hold
        (a deque append and a fresh Event).
        """
        if self.failure is not None or self._closed:
            return False
        sent = threading.Event()
        self._emergencies.append((data, sent))
        return sent.wait(timeout)

    def close(self, timeout: float = 2.0) -> None:
        """Stop the owner thread after the queued requests and close the port."""
        if self._closed:
            return
        self._closed = True
        self._requests.put(None)
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self.failure is None and not self._closed


class ScpiInstrument:
    """SCPI request/reply helpers over a :class:`SerialLink`.

    Parameters
    ----------
    link : SerialLink
        The owned port.
    timeout : float
        Deadline for one reply (s).
    """

    def __init__(self, link: SerialLink, timeout: float):
        self.link = link
        self.url = link.url
        self.timeout = timeout

    def _deadline(self, io: PortIO, timeout: float | None, what: str, late_replies: int = 0) -> Deadline:
        return Deadline(io, self.timeout if timeout is None else timeout, what, late_replies)

    def _wait(self, timeout: float | None) -> float:
        return self.reply_wait(1, timeout)

    def reply_wait(self, replies: int, timeout: float | None = None) -> float:
        """How long a caller waits for the owner thread to get ``replies`` replies: each one's deadline and
        its extension when it is late (LATE_REPLIES), plus a second."""
        return replies * (LATE_REPLIES + 1) * (self.timeout if timeout is None else timeout) + 1.0

    # ----- functions that run on the owner thread -------------------------------------------
    def send(self, io: PortIO, command: str) -> None:
        io.write(command.encode("ascii") + b"\n")

    def resync(self, io: PortIO, timeout: float | None = None) -> None:
        """Get back in step after a timeout or a garbled reply.

        Dropping what has arrived is not enough: the reply to the request that timed out may still be on its
        way and would be taken for the answer to the next query. So ``*IDN?`` is sent and lines are read
        until its reply -- four comma-separated fields, unlike any other reply of the protocol -- comes back;
        everything before it was late.
        """
        io.discard_input()
        self.send(io, "*IDN?")
        deadline = self._deadline(io, timeout, "'*IDN?' (resynchronising)")
        while True:
            line = io.read_line(deadline, deadline.what)
            if line.count(b",") == 3:
                return

    def ask(self, io: PortIO, command: str, timeout: float | None = None) -> str:
        """Send a query and read its reply line."""
        if io.desynced:
            self.resync(io, timeout)
        self.send(io, command)
        what = self._what(command, timeout)
        line = io.read_line(self._deadline(io, timeout, what, LATE_REPLIES), what)
        return line.decode("ascii", errors="replace")

    def _what(self, command: str, timeout: float | None) -> str:
        """A request as error messages name it: ``'OUTP?' within 1 s``."""
        return f"{command!r} within {self.timeout if timeout is None else timeout:.3g} s"

    def ask_block(self, io: PortIO, command: str, timeout: float | None = None) -> bytes:
        """Send a query whose reply is IEEE 488.2 definite-length block data; its payload."""
        if io.desynced:
            self.resync(io, timeout)
        self.send(io, command)
        what = self._what(command, timeout)
        deadline = self._deadline(io, timeout, what, LATE_REPLIES)
        head = io.read_exact(2, deadline, what)
        if head[:1] != b"#" or not head[1:2].isdigit() or head[1:2] == b"0":
            io.desynced = True
            raise ProtocolError(self.url, f"reply to {what} is not definite-length block data: {head!r}")
        digits = io.read_exact(int(head[1:2]), deadline, what)
        if not digits.isdigit():
            io.desynced = True
            raise ProtocolError(self.url, f"block length of the reply to {what} is not a number: {digits!r}")
        payload = io.read_exact(int(digits), deadline, what)
        if io.read_line(deadline, what):
            io.desynced = True
            raise ProtocolError(self.url, f"extra bytes after the block data of {what}")
        return payload

    def clear(self, io: PortIO) -> None:
        """Device clear over a byte link (a serial line or a socket has no IEEE 488.1 DCL).

        An instrument keeps its state from one connection to the next: a half-written command of the previous
        client, replies it never read, a stream it left running. A line end completes (and so discards, as an
        error the caller clears with ``*CLS``) any half-written command, and every byte still arriving is
        dropped until the line has been silent for CLEAR_QUIET s. The caller then resets the instrument
        (``*RST;*CLS``) and reads back what matters (:meth:`expect`)."""
        self.send(io, "")
        io.drain(quiet=CLEAR_QUIET, limit=CLEAR_LIMIT)
        io.desynced = False

    def expect(self, io: PortIO, checks: dict[str, Callable[[str], bool]], after: str) -> None:
        """Ask the queries of ``checks`` in one message and raise InstrumentError naming the first whose reply
        fails its test (after ``after``, e.g. ``"*RST"``: the instrument is not in the state it promises)."""
        queries = list(checks)
        reply = self.ask(io, ";:".join(queries))
        replies = reply.split(";")
        if len(replies) != len(queries):
            raise ProtocolError(self.url, f"{';:'.join(queries)} answered {reply!r}")
        for query, answer in zip(queries, replies):
            if not checks[query](answer.strip()):
                raise InstrumentError(self.url, f"{query} answered {answer.strip()!r} after {after}: the "
                                                f"instrument is not in its reset state")

    def drain_errors(self, io: PortIO) -> list[ScpiErrorEntry]:
        """Read the error queue until it reports 0 (at most MAX_ERRORS_DRAINED entries)."""
        errors = []
        for _ in range(MAX_ERRORS_DRAINED):
            entry = parse_error_entry(self.url, self.ask(io, "SYST:ERR?"))
            if entry.code == 0:
                break
            errors.append(entry)
        return errors

    def execute(self, io: PortIO, command: str) -> None:
        """Send a command and check the error queue in the same round trip; DeviceError if not 0."""
        first = parse_error_entry(self.url, self.ask(io, f"{command};:SYST:ERR?"))
        if first.code != 0:
            raise DeviceError(self.url, [first] + self.drain_errors(io), command)

    # ----- the same from any thread ----------------------------------------------------------
    def write(self, command: str) -> None:
        """Send a command that has no reply."""
        self.link.call(lambda io: self.send(io, command), self._wait(None))

    def query(self, command: str, timeout: float | None = None) -> str:
        """Send a query and return its reply line."""
        return self.link.call(lambda io: self.ask(io, command, timeout), self._wait(timeout))

    def query_block(self, command: str, timeout: float | None = None) -> bytes:
        """Send a query and return its block-data payload."""
        return self.link.call(lambda io: self.ask_block(io, command, timeout), self._wait(timeout))

    def command(self, command: str, timeout: float | None = None) -> None:
        """Send a command and raise DeviceError if the instrument reports an error for it."""
        self.link.call(lambda io: self.execute(io, command), self._wait(timeout))

    def errors(self) -> list[ScpiErrorEntry]:
        """Empty the instrument's error queue; its entries, oldest first."""
        return self.link.call(self.drain_errors, self.reply_wait(4))

    def query_float(self, command: str) -> float:
        reply = self.query(command)
        try:
            return float(reply)
        except ValueError:
            raise ProtocolError(self.url, f"{command} answered {reply!r}, expected a number") from None

    def identify(self, io: PortIO, manufacturer: str, models: tuple[str, ...], role: str,
                 timeout: float) -> Identity:
        """Ask ``*IDN?`` and check the instrument is one of ``models`` by ``manufacturer``."""
        if io.desynced:
            self.resync(io, timeout)
        self.send(io, "*IDN?")
        deadline = self._deadline(io, timeout, "'*IDN?'")
        reply = None
        while True:      # a late reply to a previous client's query may come first: skip non-identities
            try:
                line = io.read_line(deadline, "'*IDN?'").decode("ascii", errors="replace")
            except LinkTimeout:
                if reply is not None:
                    break
                raise LinkTimeout(self.url, f"no reply to *IDN? within {timeout:.3g} s: is this the {role} and "
                                            "is the baud rate right?") from None
            reply = line
            identity = Identity.parse(line)
            if identity is not None:
                break
        if identity is None:
            raise WrongDevice(self.url, f"*IDN? answered {reply!r}, which is not an IEEE 488.2 identity: "
                                        f"not a {role}")
        if identity.manufacturer.lower() != manufacturer.lower() or identity.model not in models:
            raise WrongDevice(self.url, f"*IDN? answered {reply!r}: not a {role} "
                                        f"(expected {manufacturer} model {' or '.join(models)})")
        return identity
