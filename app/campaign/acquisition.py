"""Records of contiguous samples from a running DAQ stream, checked on every block.

The campaign asks for records of a given length (whole periods of the excitation); :class:`RecordFeed` cuts
them out of the stream's blocks, runs the abort-limit and instrument checks on every block as it arrives, and
starts a record afresh after a gap (a lost or corrupted frame): a record never spans missing samples, and the
loss is reported once with its sample range.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from drivers.interfaces import Block
from drivers.stream import Gap


@dataclass
class Record:
    """``data`` (n, channels) in physical units; ``first_sample`` counted since the stream started."""

    data: np.ndarray
    first_sample: int
    sample_rate: float
    overload: bool


class RecordFeed:
    """Cut records out of a block stream.

    Parameters
    ----------
    stream : the running ``BlockStream``.
    check : called with every block before its samples are used (abort limits, instrument faults); raises to
        abort.
    on_gap : called with each ``drivers.stream.Gap`` (lost frames, with their sequence numbers and samples).
    on_block : called with every block (live display); may be None.
    read_timeout : s to wait for a block before the link counts as lost.
    """

    def __init__(self, stream, check: Callable[[Block], None], on_gap: Callable[[Gap], None],
                 on_block: Callable[[Block], None] | None = None, read_timeout: float = 5.0):
        self.stream = stream
        self.check = check
        self.on_gap = on_gap
        self.on_block = on_block
        self.read_timeout = read_timeout
        self._buffer: list[np.ndarray] = []
        self._buffered = 0
        self._start: int | None = None
        self._overload = False
        self.sample_rate: float | None = None

    def discard(self) -> None:
        """Drop what was collected (after the drive changed, the old samples describe another state)."""
        self._buffer, self._buffered, self._start, self._overload = [], 0, None, False

    def flush(self) -> None:
        """Drop every sample taken before now: what is collected and what waits in the stream's queue.

        Called after the generator changes: blocks already queued were sampled before the instrument acted on
        the command (still checked against the limits, as every block is)."""
        self.discard()
        for _ in range(self.stream.pending()):
            self._pull()
        self.discard()

    def skip(self, n: int) -> None:
        """Read and drop ``n`` samples (still checking every block)."""
        self.discard()
        while self._buffered < n:
            self._pull()
        self._keep_tail(self._buffered - n)

    def record(self, n: int) -> Record:
        """The next ``n`` contiguous samples."""
        while self._buffered < n:
            self._pull()
        data = np.concatenate(self._buffer, axis=0)
        rec = Record(data[:n], self._start, self.sample_rate, self._overload)
        rest = data[n:]
        self._buffer = [rest] if len(rest) else []
        self._buffered = len(rest)
        self._start = self._start + n if len(rest) else None
        self._overload = False
        return rec

    def _keep_tail(self, n: int) -> None:
        data = np.concatenate(self._buffer, axis=0) if self._buffer else np.zeros((0, 0))
        tail = data[len(data) - n:] if n else data[:0]
        start = None if not n else self._start + len(data) - n
        self._buffer, self._buffered, self._start = ([tail] if n else []), n, start

    def _pull(self) -> None:
        block = self.stream.read(timeout=self.read_timeout)
        self.sample_rate = block.sample_rate
        self.check(block)
        if self.on_block is not None:
            self.on_block(block)
        if block.gaps:
            for gap in block.gaps:
                self.on_gap(gap)
            self.discard()
        if self._start is None:
            self._start = block.first_sample
        self._buffer.append(block.data)
        self._buffered += len(block)
        self._overload |= block.overload
