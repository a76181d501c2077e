"""Firmware of the emulated DAQ (model DAQ-1).

Channels are the rig backend's channels. Each sample is quantised to integer
counts of the channel's LSB (physical units per count) and saturates at the
channel's range: ``range [V] / sensitivity [V per unit]``; a saturated sample sets
the frame's OVERLOAD flag. ``INITiate`` starts the binary stream of
:mod:`drivers.stream` frames, ``ABORt`` ends it with an END frame. Frames wait in
an output FIFO; in paced mode a FIFO that the host does not empty fast enough
overflows, the frame is lost (its sequence number is skipped), the next frame
carries the OVERRUN flag and error 301 is queued.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numba import types

from analysis.common.compiled import njit

from ..stream import FLAG_OVERLOAD, FLAG_OVERRUN, MAX_POINTS, encode_end, encode_frame, frame_size
from .firmware import Firmware
from .scpi_server import (Interrupted, ScpiError, action, block_data, expect_none, expect_one, format_channel_list,
                          format_number, limit_query, parse_channel_list, parse_number, reply_with)

if TYPE_CHECKING:
    from .core import EmulatedRig

DEFAULT_SENSITIVITY = 0.01
"""V per physical unit (10 mV/N, 10 mV/(m/s^2)) after *RST."""
DEFAULT_RANGE = 10.0
"""Input range after *RST (V peak)."""
SENSITIVITY_LIMITS = (1e-6, 100.0)
RANGE_LIMITS = (0.001, 50.0)
MAX_READ_POINTS = 1 << 20
"""Largest READ? block (samples per channel)."""
READ_PIECE = 4096
"""Fast mode: samples a READ? acquires between two checks for a device clear."""
FRAME_SECONDS = 0.02
"""Default frame duration: STReam:POINts after *RST is about this many seconds of samples."""
MIN_FIFO_BYTES = 1 << 16
INT32_MAX = (1 << 31) - 1


class BlockCapture:
    """Samples collected for one ``READ?`` in paced mode."""

    def __init__(self, points: int):
        self.points = points
        self.parts: list[np.ndarray] = []
        self.collected = 0

    def add(self, data: np.ndarray) -> None:
        take = min(self.points - self.collected, data.shape[0])
        self.parts.append(data[:take])
        self.collected += take

    @property
    def done(self) -> bool:
        return self.collected >= self.points


class DaqFirmware(Firmware):
    """The DAQ: channel setup, quantisation, framing, FIFO, block reads."""

    model = "DAQ-1"

    def __init__(self, rig: "EmulatedRig", fifo_seconds: float):
        super().__init__(rig, "daq")
        self.fifo_seconds = fifo_seconds
        self.n_channels = len(rig.channels)
        self.acquiring = False
        self.sequence = 0
        self.acquired = 0
        self.frames_overrun = 0
        self._overrun_pending = False
        self._unframed = np.zeros((0, 0), dtype=np.int32)
        self._unframed_over = np.zeros(0, dtype=bool)
        self._capture: BlockCapture | None = None
        self.fifo_bytes = MIN_FIFO_BYTES
        self._defaults()
        self._add_commands()

    def _defaults(self) -> None:
        if self.acquiring:
            self.stop_acquisition()
        self.scan = list(range(self.n_channels))
        self.sensitivity = np.full(self.n_channels, DEFAULT_SENSITIVITY)
        self.input_range = np.full(self.n_channels, DEFAULT_RANGE)
        self._scaled = None
        self.points = int(min(MAX_POINTS, max(16, round(FRAME_SECONDS * self.rig.sample_rate))))

    # ----- quantisation --------------------------------------------------------------------
    def _scaling(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scanned channels' indices, LSB and largest count within range; kept until a setting changes
        (quantise runs on every frame)."""
        if self._scaled is None:
            scan = np.asarray(self.scan, np.int64)
            lsb = self.rig.lsb[scan]
            limit = np.minimum(np.floor(self.input_range[scan] / self.sensitivity[scan] / lsb), INT32_MAX)
            self._scaled = (scan, lsb, limit)
        return self._scaled

    def quantise(self, data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Counts of the scanned channels, shape (n, len(scan)), and per-row saturation flags."""
        return counts_of(data, *self._scaling())

    # ----- physics side (rig lock held) -----------------------------------------------------
    def busy(self) -> bool:
        return self.acquiring

    def capture(self, data: np.ndarray) -> None:
        """Samples of all channels, shape (n, n_channels), just produced by the backend."""
        if self.acquiring:
            counts, saturated = self.quantise(data)
            if not self._unframed.size and counts.shape[0] == self.points:
                # a fast reader asks for one frame at a time: framed as it comes, without the buffer's copies
                self._emit(counts, saturated)
            else:
                self._frame_buffered(counts, saturated)
        if self._capture is not None and not self._capture.done:
            self._capture.add(data)

    def _frame_buffered(self, counts: np.ndarray, saturated: np.ndarray) -> None:
        """Append to the samples not yet framed and emit every whole frame they hold."""
        self._unframed = np.concatenate([self._unframed, counts]) if self._unframed.size else counts
        self._unframed_over = np.concatenate([self._unframed_over, saturated])
        while self._unframed.shape[0] >= self.points:
            self._emit(self._unframed[:self.points], self._unframed_over[:self.points])
            self._unframed = self._unframed[self.points:]
            self._unframed_over = self._unframed_over[self.points:]

    def _emit(self, counts: np.ndarray, saturated: np.ndarray) -> None:
        flags = (FLAG_OVERRUN if self._overrun_pending else 0) | (FLAG_OVERLOAD if saturated.any() else 0)
        frame = encode_frame(self.sequence, self.acquired, counts, flags)
        injector = self.injector
        lost = injector is not None and injector.lose_frame()
        if lost or not self.output.put(frame, limit=self.fifo_bytes):
            self.frames_overrun += 1
            if not self._overrun_pending:
                self.scpi.errors.push(ScpiError(301))
                self.rig.log("daq", "overrun", f"frame {self.sequence} lost")
            self._overrun_pending = True
        else:
            self._overrun_pending = False
        self.sequence += 1
        self.acquired += counts.shape[0]

    def produce(self) -> bool:
        with self.rig.idle_clock.working(), self.rig.lock:
            self.rig.hold_for_commands()   # the host's commands come first, then more physics
            if not self.acquiring:
                return False
            if not len(self.output):
                self.rig.advance(self.points - self._unframed.shape[0])
            return True

    def start_acquisition(self) -> None:
        if self.acquiring:
            raise ScpiError(-213, "acquisition already running")
        self.rig.recover()
        self.sequence = 0
        self.acquired = 0
        self.frames_overrun = 0
        self._overrun_pending = False
        self._scaled = None
        self._unframed = np.zeros((0, len(self.scan)), dtype=np.int32)
        self._unframed_over = np.zeros(0, dtype=bool)
        byte_rate = self.rig.sample_rate * frame_size(self.points, len(self.scan)) / self.points
        self.fifo_bytes = max(MIN_FIFO_BYTES, int(self.fifo_seconds * byte_rate))
        self.acquiring = True
        self.rig.log("daq", "stream", "start")
        self.output.wake()

    def stop_acquisition(self) -> None:
        if not self.acquiring:
            return
        if self._unframed.shape[0]:
            self._emit(self._unframed, self._unframed_over)
        self._unframed = self._unframed[:0]
        self._unframed_over = self._unframed_over[:0]
        flags = FLAG_OVERRUN if self._overrun_pending else 0
        self.output.put(encode_end(self.sequence, self.acquired, len(self.scan), flags))
        self.acquiring = False
        self.rig.log("daq", "stream", f"end after {self.acquired} samples")

    def read_block(self, points: int) -> bytes:
        """Acquire ``points`` samples now (paced: wait for the clock; fast: advance) as block data.

        A device clear (the host went away) abandons the read."""
        self.rig.recover()
        capture = BlockCapture(points)
        self._capture = capture
        generation = self.generation
        try:
            while not capture.done:
                if self.cleared_since(generation):
                    raise Interrupted
                if not self.rig.running or self.rig.failure is not None:
                    raise ScpiError(-200, "acquisition stopped")
                if self.rig.paced:
                    self.rig.changed.wait(0.1)
                else:   # in pieces, so that a device clear stops a long read
                    self.rig.advance(min(points - capture.collected, READ_PIECE))
        finally:
            self._capture = None
        counts, _ = self.quantise(np.concatenate(capture.parts))
        return block_data(counts.astype("<i4").tobytes())

    def clear_operations(self) -> None:
        self.stop_acquisition()

    # ----- commands ------------------------------------------------------------------------
    def _channel(self, number: int) -> int:
        if not 1 <= number <= self.n_channels:
            raise ScpiError(-114, f"channels are 1 to {self.n_channels}")
        return number - 1

    def _add_commands(self) -> None:
        add = self.scpi.add
        rig = self.rig
        add("SYSTem:CHANnel:COUNt", query=reply_with(lambda: str(self.n_channels)))
        add("SENSe:CHANnel#:NAME", query=self._channel_query(lambda i: rig.channels[i]))
        add("SENSe:CHANnel#:UNIT", query=self._channel_query(lambda i: rig.units[i]))
        add("SENSe:CHANnel#:LSB", query=self._channel_query(lambda i: format_number(rig.lsb[i])))
        add("SENSe:CHANnel#:SENSitivity", write=self._set_sensitivity,
            query=lambda a, n: format_number(limit_query(a, *SENSITIVITY_LIMITS,
                                                         self.sensitivity[self._channel(n)])))
        add("SENSe:CHANnel#:RANGe", write=self._set_range,
            query=lambda a, n: format_number(limit_query(a, *RANGE_LIMITS, self.input_range[self._channel(n)])))
        add("ROUTe:SCAN", write=self._set_scan, query=reply_with(lambda: format_channel_list(self.scan)))
        add("[SENSe:]SRATe", write=self._set_rate, query=reply_with(lambda: format_number(rig.sample_rate)))
        add("[SENSe:]SRATe:LIST", query=reply_with(lambda: format_number(rig.sample_rate)))
        add("STReam:POINts", write=self._set_points,
            query=lambda a: format_number(limit_query(a, 1, MAX_POINTS, self.points)))
        add("STReam:COUNt", query=reply_with(lambda: str(self.acquired)))
        add("INITiate[:IMMediate]", write=action(self.start_acquisition), while_busy=True)
        add("ABORt", write=action(self.stop_acquisition), while_busy=True)
        add("READ", query=self._read)

    def _channel_query(self, get):
        """Handler of a parameterless per-channel query answering ``get(channel index)``."""
        def handler(args: list[str], number: int) -> str:
            expect_none(args)
            return get(self._channel(number))
        return handler

    def _set_sensitivity(self, args: list[str], number: int) -> None:
        self.sensitivity[self._channel(number)] = parse_number(expect_one(args), *SENSITIVITY_LIMITS,
                                                               DEFAULT_SENSITIVITY)
        self._scaled = None

    def _set_range(self, args: list[str], number: int) -> None:
        self.input_range[self._channel(number)] = parse_number(expect_one(args), *RANGE_LIMITS, DEFAULT_RANGE)
        self._scaled = None

    def _set_scan(self, args: list[str]) -> None:
        self.scan = parse_channel_list(expect_one(args), self.n_channels)
        self._scaled = None

    def _set_rate(self, args: list[str]) -> None:
        rate = parse_number(expect_one(args), 0.0, float("inf"))
        if abs(rate - self.rig.sample_rate) > 1e-9 * self.rig.sample_rate:
            raise ScpiError(-222, f"this DAQ samples at {format_number(self.rig.sample_rate)} Hz only")

    def _set_points(self, args: list[str]) -> None:
        self.points = parse_number(expect_one(args), 1, MAX_POINTS, self.points, integer=True)

    def _read(self, args: list[str]) -> bytes:
        return self.read_block(parse_number(expect_one(args), 1, MAX_READ_POINTS, integer=True))


def compile_converter() -> None:
    """:func:`counts_of` compiled for the arrays a campaign passes, or loaded from the disk cache (compiled ahead
    by :mod:`app.compile_ahead` while a fresh checkout's demo starts)."""
    v = types.float64[::1]
    counts_of.compile((types.float64[:, ::1], types.int64[::1], v, v))


@njit(cache=True)
def counts_of(data, scan, lsb, limit):
    """The converter's counts ``rint(data[:, scan] / lsb)`` saturating at ``+-limit``, and which rows saturate. A
    sample that is not a number reads full scale, saturated (a count for it would be undefined).

    Parameters
    ----------
    data : (n, channels)
        Physical units.
    scan : (m,) int
        The scanned channels, in scan order.
    lsb, limit : (m,)
        Physical units per count; the largest count within range.

    Returns
    -------
    counts : (n, m) int32
    saturated : (n,) bool
    """
    n, m = data.shape[0], scan.shape[0]
    counts = np.empty((n, m), np.int32)
    saturated = np.zeros(n, np.bool_)
    for i in range(n):
        for c in range(m):
            code = np.rint(data[i, scan[c]] / lsb[c])
            if not abs(code) <= limit[c]:
                saturated[i] = True
                code = min(max(code, -limit[c]), limit[c]) if code == code else limit[c]
            counts[i, c] = np.int32(code)
    return counts, saturated
