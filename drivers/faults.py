"""Fault injection for the emulated instrument links.

Faults are configured by a table, from a rig file's ``[faults]`` table, a
``sim://`` URL query or the command line. Keys at the top level apply to both
links; a ``shaker`` or ``daq`` sub-table overrides them for one link::

    [faults]
    seed = 3
    [faults.daq]
    drop = 1e-4          # probability that a byte sent by the instrument is lost
    flip = 1e-5          # probability that a byte sent by the instrument has one bit inverted
    stall = 1e-6         # probability per byte that the link stalls before sending it ...
    stall_time = 0.5     # ... for this long (s)
    disconnect = 200000  # the link drops for good after this many more bytes from the instrument
    overrun = 1e-3       # probability that a DAQ frame is lost to an acquisition FIFO overrun
    [faults.shaker]
    scpi_error = 0.01    # probability that a command is rejected with -300,"Device-specific error"

Byte faults act on the instrument-to-host direction, at byte positions drawn from
geometric distributions, so where they strike does not depend on how the host
chunks its reads: the same seed gives the same corrupted stream.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

import numpy as np

from analysis.common.errors import InputError

ROLES = ("shaker", "daq")


@dataclass(frozen=True)
class LinkFaults:
    """The faults injected on one instrument link (all off by default).

    Attributes
    ----------
    drop, flip, stall : float
        Per-byte probabilities (instrument to host) of losing the byte, inverting one of
        its bits, and stalling the link before it.
    stall_time : float
        Length of one stall (s).
    disconnect : int or None
        Bytes sent by the instrument after which the link drops for good.
    scpi_error : float
        Probability that a command (not a query) is rejected with error -300.
    overrun : float
        Probability that a DAQ frame is lost to an acquisition FIFO overrun.
    seed : int
        Seed of the link's random generator.
    """

    drop: float = 0.0
    flip: float = 0.0
    stall: float = 0.0
    stall_time: float = 0.5
    disconnect: int | None = None
    scpi_error: float = 0.0
    overrun: float = 0.0
    seed: int = 0

    @property
    def active(self) -> bool:
        return bool(self.drop or self.flip or self.stall or self.scpi_error or self.overrun
                    or self.disconnect is not None)

    def updated(self, values: Mapping[str, Any], source: str | None = None, where: str = "") -> "LinkFaults":
        """A copy with ``values`` (checked, InputError naming ``source`` and ``where``) applied."""
        changes = {}
        for key, value in values.items():
            changes[key] = _check(key, value, source, where)
        return replace(self, **changes)


_PROBABILITIES = {"drop", "flip", "stall", "scpi_error", "overrun"}
FAULT_KEYS = tuple(f.name for f in fields(LinkFaults))


def _check(key: str, value: Any, source: str | None, where: str) -> Any:
    field_name = f"{where}.{key}" if where else key
    if key not in FAULT_KEYS:
        raise InputError(f"unknown fault (known: {', '.join(FAULT_KEYS)})", source, field_name)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"must be a number, got {value!r}", source, field_name)
    if not math.isfinite(value):
        raise InputError(f"must be finite, got {value!r}", source, field_name)
    if key in _PROBABILITIES:
        if not 0.0 <= value <= 1.0:
            raise InputError(f"is a probability and must be in [0, 1], got {value!r}", source, field_name)
        return float(value)
    if key == "stall_time":
        if value <= 0:
            raise InputError(f"must be > 0 s, got {value!r}", source, field_name)
        return float(value)
    if value != int(value) or value < 0:
        raise InputError(f"must be a non-negative integer, got {value!r}", source, field_name)
    return int(value)


def parse_faults(table: Mapping[str, Any] | None, source: str | None = None,
                 where: str = "[faults]") -> dict[str, LinkFaults]:
    """The faults of each link from a ``[faults]`` table.

    Parameters
    ----------
    table : mapping or None
        Top-level keys apply to both links; ``shaker`` / ``daq`` sub-tables override.
    source : str, optional
        File name for error messages.
    where : str
        Table name for error messages.

    Returns
    -------
    dict
        ``{"shaker": LinkFaults, "daq": LinkFaults}``.
    """
    table = dict(table or {})
    common = {k: v for k, v in table.items() if k not in ROLES}
    base = LinkFaults().updated(common, source, where)
    result = {}
    for role in ROLES:
        sub = table.get(role, {})
        if not isinstance(sub, Mapping):
            raise InputError("must be a table", source, f"{where}.{role}")
        result[role] = base.updated(sub, source, f"{where}.{role}")
    return result


def parse_query_value(key: str, text: str) -> float:
    """A fault value from URL text (InputError naming the option if it is not a number)."""
    try:
        return float(text) if key in _PROBABILITIES or key == "stall_time" else int(text)
    except ValueError:
        raise InputError(f"must be a number, got {text!r}", "URL", key) from None


def _next_event(rng: np.random.Generator, p: float, after: int) -> float:
    """Position of the next byte hit by an event of per-byte probability ``p`` at or after ``after``."""
    if p <= 0.0:
        return math.inf
    return after + int(rng.geometric(p)) - 1


class FaultInjector:
    """Runtime state of one link's faults: byte position, random generator, counters.

    Parameters
    ----------
    faults : LinkFaults
        What to inject.
    stream : int
        Distinguishes links that share a seed (0 shaker, 1 DAQ).
    start : int
        Bytes the link carried before these faults took effect.
    """

    def __init__(self, faults: LinkFaults, stream: int, start: int = 0):
        self.faults = faults
        self.rng = np.random.default_rng([faults.seed, stream])
        self.position = start
        self.dropped_bytes = 0
        self.flipped_bits = 0
        self.stalls = 0
        self.rejected_commands = 0
        self.lost_frames = 0
        self.disconnected = False
        self.stalled_until = 0.0
        self._next_drop = _next_event(self.rng, faults.drop, start)
        self._next_flip = _next_event(self.rng, faults.flip, start)
        self._next_stall = _next_event(self.rng, faults.stall, start)
        self._disconnect_at = math.inf if faults.disconnect is None else start + faults.disconnect

    def allowance(self, size: int) -> int:
        """How many bytes may pass now, up to the next stall or the disconnect point."""
        limit = min(self._next_stall, self._disconnect_at) - self.position
        return int(min(size, limit))

    def strike(self) -> None:
        """Trigger the event at the current position (allowance was 0): stall or disconnect."""
        if self.position >= self._disconnect_at:
            self.disconnected = True
            return
        self.stalls += 1
        self.stalled_until = time.monotonic() + self.faults.stall_time
        self._next_stall = _next_event(self.rng, self.faults.stall, self.position + 1)

    def corrupt(self, data: bytes) -> bytes:
        """Apply bit flips and byte drops to the next ``len(data)`` bytes of the stream."""
        start = self.position
        end = start + len(data)
        self.position = end
        if self._next_flip >= end and self._next_drop >= end:
            return data
        out = np.frombuffer(data, dtype=np.uint8).copy()
        while self._next_flip < end:
            out[self._next_flip - start] ^= np.uint8(1 << int(self.rng.integers(8)))
            self.flipped_bits += 1
            self._next_flip = _next_event(self.rng, self.faults.flip, self._next_flip + 1)
        drops = []
        while self._next_drop < end:
            drops.append(self._next_drop - start)
            self._next_drop = _next_event(self.rng, self.faults.drop, self._next_drop + 1)
        if drops:
            self.dropped_bytes += len(drops)
            out = np.delete(out, drops)
        return out.tobytes()

    def reject_command(self) -> bool:
        """Whether to reject the next command (counts it)."""
        if self.faults.scpi_error and self.rng.random() < self.faults.scpi_error:
            self.rejected_commands += 1
            return True
        return False

    def lose_frame(self) -> bool:
        """Whether the next DAQ frame is lost to an overrun (counts it)."""
        if self.faults.overrun and self.rng.random() < self.faults.overrun:
            self.lost_frames += 1
            return True
        return False
