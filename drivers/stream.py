"""The DAQ's binary stream: frame format, CRC, encoder and a resynchronising decoder.

A frame (all integers little-endian; docs/protocol.md has the full description)::

    offset  size      field
    0       4         sync word A5 5A C3 3C
    4       4         sequence number (u32), 0 for the first frame after INIT, +1 per frame
    8       8         index of the frame's first sample (u64), counted per channel since INIT
    16      2         points n: samples per channel in this frame (u16); 0 only in the END frame
    18      1         channels c (u8)
    19      1         flags (u8): 1 OVERRUN, 2 OVERLOAD, 4 END
    20      4 n c     samples, int32 counts, sample-major: s0c0 s0c1 ... s1c0 ...
    20+4nc  4         CRC-32 (u32) of bytes 0 .. 20+4nc-1

The CRC is CRC-32/ISO-HDLC (the zlib/Ethernet CRC: polynomial 0x04C11DB7 reflected,
initial value and final xor 0xFFFFFFFF; check value of ``b"123456789"`` is
0xCBF43926). A physical value is ``counts * lsb`` of its channel.

The decoder accepts bytes in arbitrary chunks, skips anything that is not a valid
frame (garbage, truncated or corrupted frames) by searching for the next sync word,
and reports every loss: each good frame carries the gap of sequence numbers and
samples since the previous good frame, plus the number of bytes and corrupted frames
skipped to reach it. It never returns a sample from a frame whose CRC failed and
never invents one, so ``samples delivered + samples in gaps == samples sent``.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

SYNC = b"\xa5\x5a\xc3\x3c"
HEADER = struct.Struct("<4sIQHBB")
CRC = struct.Struct("<I")
FLAG_OVERRUN = 0x01
FLAG_OVERLOAD = 0x02
FLAG_END = 0x04
KNOWN_FLAGS = FLAG_OVERRUN | FLAG_OVERLOAD | FLAG_END
MAX_POINTS = 4096
SEQUENCE_MODULUS = 1 << 32
SAMPLE_BYTES = 4


def crc32(data: bytes | bytearray | memoryview) -> int:
    """CRC-32/ISO-HDLC of ``data`` (the frame check), as an unsigned 32-bit integer."""
    return zlib.crc32(data) & 0xFFFFFFFF


def frame_size(points: int, channels: int) -> int:
    """Bytes in a frame of ``points`` samples per channel over ``channels`` channels."""
    return HEADER.size + SAMPLE_BYTES * points * channels + CRC.size


def encode_frame(sequence: int, first_sample: int, counts: np.ndarray, flags: int = 0) -> bytes:
    """One data frame.

    Parameters
    ----------
    sequence : int
        Frame sequence number (taken modulo 2**32).
    first_sample : int
        Per-channel index of the first sample since INIT.
    counts : ndarray, shape (n, c)
        Integer ADC counts, 1 <= n <= MAX_POINTS.
    flags : int
        OR of FLAG_OVERRUN / FLAG_OVERLOAD.
    """
    counts = np.ascontiguousarray(counts, dtype="<i4")
    n, c = counts.shape
    header = HEADER.pack(SYNC, sequence % SEQUENCE_MODULUS, first_sample, n, c, flags)
    body = header + counts.tobytes()
    return body + CRC.pack(crc32(body))


def encode_end(sequence: int, samples_sent: int, channels: int, flags: int = 0) -> bytes:
    """The END frame closing a stream: no samples; ``samples_sent`` per channel were acquired."""
    body = HEADER.pack(SYNC, sequence % SEQUENCE_MODULUS, samples_sent, 0, channels, flags | FLAG_END)
    return body + CRC.pack(crc32(body))


class StreamFormatError(ValueError):
    """The stream contradicts itself (a good frame that goes back in time)."""


@dataclass(frozen=True)
class Gap:
    """Frames that never arrived intact, between two good frames.

    Attributes
    ----------
    first_sequence : int
        Sequence number of the first missing frame.
    frames : int
        Number of missing frames (by sequence number).
    first_sample : int
        Per-channel index of the first missing sample.
    samples : int
        Missing samples per channel.
    """

    first_sequence: int
    frames: int
    first_sample: int
    samples: int

    def __str__(self) -> str:
        last = (self.first_sequence + self.frames - 1) % SEQUENCE_MODULUS
        return (f"frames {self.first_sequence}..{last} lost "
                f"(samples {self.first_sample}..{self.first_sample + self.samples - 1})")


@dataclass(frozen=True)
class Frame:
    """A frame whose CRC checked, with what was lost just before it.

    Attributes
    ----------
    sequence, first_sample, flags : int
        Header fields.
    counts : ndarray, shape (n, c), int32
        The samples in ADC counts (n = 0 for the END frame).
    gap : Gap or None
        Frames missing between the previous good frame and this one.
    skipped_bytes : int
        Bytes discarded (garbage, corrupted or truncated frames) since the previous good frame.
    corrupt_frames : int
        Candidate frames whose CRC failed since the previous good frame.
    """

    sequence: int
    first_sample: int
    flags: int
    counts: np.ndarray
    gap: Gap | None = None
    skipped_bytes: int = 0
    corrupt_frames: int = 0

    @property
    def points(self) -> int:
        return self.counts.shape[0]

    @property
    def is_end(self) -> bool:
        return bool(self.flags & FLAG_END)


@dataclass
class DecoderStats:
    """Running totals of a :class:`FrameDecoder` (per channel for samples)."""

    frames: int = 0
    samples: int = 0
    lost_samples: int = 0
    lost_frames: int = 0
    corrupt_frames: int = 0
    skipped_bytes: int = 0
    gaps: list[Gap] = field(default_factory=list)


class FrameDecoder:
    """Turn a byte stream into checked frames, resynchronising on the sync word.

    Parameters
    ----------
    channels : int
        Channels per frame the instrument was configured for; a header naming
        another count is not a frame.
    max_points : int
        Largest points per frame the instrument was configured for.

    Notes
    -----
    Feed bytes as they arrive with :meth:`feed`. Decoding stops at the END frame;
    any bytes after it (replies to later commands) are left in :meth:`remainder`.
    If the END frame itself is lost, call :meth:`finish` with the sample count the
    instrument reports, so the trailing loss is accounted for too.
    """

    def __init__(self, channels: int, max_points: int = MAX_POINTS):
        if not 1 <= channels <= 255:
            raise ValueError(f"channels must be 1..255, got {channels}")
        if not 1 <= max_points <= 0xFFFF:
            raise ValueError(f"max_points must be 1..65535, got {max_points}")
        self.channels = channels
        self.max_points = max_points
        self.stats = DecoderStats()
        self.ended = False
        self._buffer = bytearray()
        self._consumed = 0           # stream position of _buffer[0]
        self._last_good_end = 0      # stream position just after the last good frame
        self._corrupt_since_good = 0
        self._next_sequence = 0
        self._next_sample = 0

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Add bytes; return the good frames completed by them, in stream order."""
        self._append(data)
        if self.ended:
            return []
        frames: list[Frame] = []
        buf = self._buffer
        pos = 0
        header_size = HEADER.size
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # keep a tail that may be the beginning of a sync word
                pos = max(pos, len(buf) - (len(SYNC) - 1))
                break
            if len(buf) - start < header_size:
                pos = start
                break
            _, sequence, first_sample, points, channels, flags = HEADER.unpack_from(buf, start)
            if not self._plausible(points, channels, flags):
                pos = start + 1
                continue
            end = start + header_size + SAMPLE_BYTES * points * channels
            if len(buf) - end < CRC.size:
                pos = start
                break
            (check,) = CRC.unpack_from(buf, end)
            if crc32(memoryview(buf)[start:end]) != check:
                self._corrupt_since_good += 1
                pos = start + 1
                continue
            counts = np.frombuffer(buf, dtype="<i4", count=points * channels,
                                   offset=start + header_size).reshape(points, channels).copy()
            frames.append(self._accept(sequence, first_sample, flags, counts, self._consumed + start))
            self._last_good_end = self._consumed + end + CRC.size
            pos = end + CRC.size
            if self.ended:
                break
        self._drop(pos)
        self._consumed += pos
        return frames

    # A view of the buffer can outlive the call that took it (in a frame a traceback keeps), and a bytearray with a
    # view cannot be resized: the buffer is then replaced by a copy, which costs a copy only then (appending in
    # place keeps a frame fed in small reads linear in its size).
    def _append(self, data) -> None:
        try:
            self._buffer += data
        except BufferError:
            self._buffer = self._buffer + data

    def _drop(self, count: int) -> None:
        try:
            del self._buffer[:count]
        except BufferError:
            self._buffer = self._buffer[count:]

    def _plausible(self, points: int, channels: int, flags: int) -> bool:
        if channels != self.channels or flags & ~KNOWN_FLAGS:
            return False
        if flags & FLAG_END:
            return points == 0
        return 1 <= points <= self.max_points

    def _accept(self, sequence: int, first_sample: int, flags: int, counts: np.ndarray,
                position: int) -> Frame:
        missing_frames = (sequence - self._next_sequence) % SEQUENCE_MODULUS
        missing_samples = first_sample - self._next_sample
        if missing_samples < 0 or (missing_samples == 0) != (missing_frames == 0):
            raise StreamFormatError(
                f"frame {sequence} (first sample {first_sample}) does not follow frame "
                f"{self._next_sequence - 1} (next sample {self._next_sample})")
        gap = None
        if missing_samples:
            gap = Gap(self._next_sequence, missing_frames, self._next_sample, missing_samples)
            self._record_gap(gap)
        skipped = position - self._last_good_end
        frame = Frame(sequence, first_sample, flags, counts, gap, skipped, self._corrupt_since_good)
        stats = self.stats
        stats.skipped_bytes += skipped
        stats.corrupt_frames += self._corrupt_since_good
        self._corrupt_since_good = 0
        points = counts.shape[0]
        if flags & FLAG_END:
            self.ended = True
        else:
            stats.frames += 1
            stats.samples += points
            self._next_sequence = (sequence + 1) % SEQUENCE_MODULUS
            self._next_sample = first_sample + points
        return frame

    def _record_gap(self, gap: Gap) -> None:
        self.stats.gaps.append(gap)
        self.stats.lost_frames += gap.frames
        self.stats.lost_samples += gap.samples

    def finish(self, samples_sent: int) -> Gap | None:
        """Close the stream when its END frame was not received intact.

        Parameters
        ----------
        samples_sent : int
            Samples per channel the instrument acquired (its ``STReam:COUNt?``).

        Returns
        -------
        Gap or None
            The trailing loss (its frame count is unknown and reported as 0), if any.
        """
        if samples_sent < self._next_sample:
            raise StreamFormatError(
                f"instrument reports {samples_sent} samples sent, but {self._next_sample} were received")
        self.stats.skipped_bytes += self._consumed + len(self._buffer) - self._last_good_end
        self.stats.corrupt_frames += self._corrupt_since_good
        self._corrupt_since_good = 0
        self._buffer = bytearray()
        self.ended = True
        if samples_sent == self._next_sample:
            return None
        gap = Gap(self._next_sequence, 0, self._next_sample, samples_sent - self._next_sample)
        self._record_gap(gap)
        self._next_sample = samples_sent
        return gap

    def remainder(self) -> bytes:
        """Bytes received after the END frame (replies to later commands); empties the buffer."""
        data, self._buffer = bytes(self._buffer), bytearray()
        return data
