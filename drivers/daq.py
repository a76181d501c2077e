"""The DAQ driver: SCPI configuration and the binary stream over any pyserial URL.

While a stream runs, the port's owner thread reads the frames, checks them
(:class:`drivers.stream.FrameDecoder`), converts counts to physical units and cuts
them into blocks of contiguous samples, which wait in a bounded queue for the
consumer. A block ends early where samples were lost, and the next block lists
the loss (:class:`drivers.stream.Gap`), so no block ever bridges a gap. When the
queue is full the owner thread stops reading: a real-time instrument then overruns its
FIFO and the loss is reported. A port whose instrument samples only when it is read
(an in-process emulator in fast mode: the port's ``samples_on_demand``) is read one
frame at a time, when the consumer asks for a block and none is queued: reading ahead
would advance the emulated time by the queue's depth past the consumer, and every
command the consumer then sends would act that much later than on a real instrument,
whose driver holds only what arrived while the consumer worked. The consumer reads such
a port itself, in its own thread, with the same checks, decoding and assembly, while the
owner thread, which starts and stops the stream, waits: handing every frame from one
thread to the other and back cost more CPU than decoding it.

Stopping sends ``ABORt``, reads on to the END frame and then knows how many
samples the instrument sent; if the END frame was lost it asks ``STReam:COUNt?``.
Either way ``stats.samples_received + stats.samples_lost == stats.samples_sent``.
"""
from __future__ import annotations

import collections
import re
import threading
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np
import serial

from analysis.common.held_signals import signals_held

from .errors import DeviceError, InstrumentError, LinkLost, LinkTimeout, ProtocolError
from .interfaces import Block, Identity
from .scpi import POLL, PortIO, ScpiInstrument, SerialLink
from .stream import FLAG_OVERLOAD, FLAG_OVERRUN, MAX_POINTS, Frame, FrameDecoder, Gap, StreamFormatError, frame_size

MANUFACTURER = "contactid"
DAQ_MODELS = ("DAQ-1",)
END_QUIET = 0.5
"""After ABORt, give up waiting for the END frame when the line is silent this long (s)."""
END_LIMIT = 10.0
"""After ABORt, give up waiting for the END frame after this long in any case (s)."""
COUNT_ATTEMPTS = 5
"""Attempts at reading the instrument's sample count when the END frame was lost."""
_SCAN = re.compile(r"^\(@([0-9,]+)\)$")


@dataclass
class StreamStats:
    """What a stream delivered and lost (samples are per channel).

    ``samples_sent`` is known once the stream has stopped; then
    ``samples_received + samples_lost == samples_sent``.
    """

    samples_received: int = 0
    samples_lost: int = 0
    samples_sent: int | None = None
    gaps: list[Gap] = field(default_factory=list)
    corrupt_frames: int = 0
    skipped_bytes: int = 0
    overrun_frames: int = 0
    end_frame_received: bool = False

    @property
    def balanced(self) -> bool:
        """Whether every sent sample is either received or reported lost."""
        return self.samples_sent is not None and self.samples_received + self.samples_lost == self.samples_sent


class BlockAssembler:
    """Cut checked frames into blocks of contiguous samples in physical units.

    Parameters
    ----------
    block_size : int
        Samples per channel in a full block.
    lsb : ndarray, shape (c,)
        Physical units per count of each channel.
    channels, units : tuple of str
        Column names and units.
    sample_rate : float
        Hz.
    """

    def __init__(self, block_size: int, lsb: np.ndarray, channels: tuple[str, ...], units: tuple[str, ...],
                 sample_rate: float):
        if block_size < 1:
            raise ValueError(f"block_size must be >= 1, got {block_size}")
        self.block_size = block_size
        self.lsb = np.asarray(lsb, dtype=float)
        self.channels = channels
        self.units = units
        self.sample_rate = sample_rate
        self._parts: list[np.ndarray] = []
        self._count = 0
        self._first = 0
        self._gaps: list[Gap] = []
        self._overload = False

    def add(self, frame: Frame) -> list[Block]:
        """The blocks completed by ``frame`` (a gap before it closes the block in progress)."""
        blocks = []
        if frame.gap is not None:
            if self._count:
                blocks.append(self._emit())
            self._gaps.append(frame.gap)
        counts = frame.counts
        offset = 0
        while offset < counts.shape[0]:
            if self._count == 0:
                self._first = frame.first_sample + offset
            take = min(self.block_size - self._count, counts.shape[0] - offset)
            self._parts.append(counts[offset:offset + take])
            self._count += take
            self._overload |= bool(frame.flags & FLAG_OVERLOAD)
            offset += take
            if self._count == self.block_size:
                blocks.append(self._emit())
        return blocks

    def flush(self) -> Block | None:
        """The last, short block at the end of the stream (None if empty)."""
        return self._emit() if self._count else None

    def _emit(self) -> Block:
        data = np.concatenate(self._parts).astype(float) * self.lsb
        block = Block(data, self.channels, self.units, self.sample_rate, self._first, tuple(self._gaps),
                      self._overload)
        self._parts = []
        self._count = 0
        self._gaps = []
        self._overload = False
        return block


class _BlockQueue:
    """Blocks from the reader to the consumer; bounded while the stream runs."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self._blocks: collections.deque[Block] = collections.deque()
        self._ready = threading.Condition()
        self.finished = False
        self.error: BaseException | None = None

    def put(self, block: Block, unbounded: threading.Event, caught_up: threading.Event) -> None:
        with self._ready:
            while len(self._blocks) >= self.capacity and not unbounded.is_set():
                caught_up.set()
                self._ready.wait(POLL)
            self._blocks.append(block)
            self._ready.notify_all()

    def finish(self, error: BaseException | None) -> None:
        with self._ready:
            self.finished = True
            self.error = error
            self._ready.notify_all()

    def __len__(self) -> int:
        return len(self._blocks)

    def get(self, timeout: float, url: str, clock: Callable[[], float]) -> Block | None:
        """The next block; None when the stream has ended and nothing is left. ``timeout`` counts on
        ``clock`` (the port's: an in-process emulator's idle time)."""
        deadline = clock() + timeout
        with self._ready:
            while not self._blocks:
                if self.finished:
                    if self.error is not None:
                        raise self.error
                    return None
                left = deadline - clock()
                if left <= 0:
                    raise LinkTimeout(url, f"no block from the DAQ stream within {timeout:.3g} s")
                self._ready.wait(min(left, POLL * 5))
            block = self._blocks.popleft()
            if len(self._blocks) == self.capacity - 1:
                self._ready.notify_all()      # a reader may wait in put() for the room just made
            return block


class DaqStream:
    """A running acquisition (see module docstring); use as a context manager and iterator.

    Parameters
    ----------
    daq : SerialDaq
        The instrument.
    block_size : int
        Samples per channel per block.
    buffered_blocks : int
        Blocks the driver reads ahead of the consumer.
    timeout : float, optional
        Longest :meth:`read` waits for a block (s); default ``max(2, 2 x block duration)``.
    no_data_timeout : float
        The stream fails with LinkTimeout after this long without a byte (s).
    """

    def __init__(self, daq: "SerialDaq", block_size: int, buffered_blocks: int, timeout: float | None,
                 no_data_timeout: float):
        self.daq = daq
        self.url = daq.url
        self.stats = StreamStats()
        self.timeout = timeout if timeout is not None else max(2.0, 2.0 * block_size / daq.sample_rate)
        self._no_data_timeout = no_data_timeout
        self._assembler = BlockAssembler(block_size, daq.lsb, daq.channels, daq.units, daq.sample_rate)
        self._decoder = FrameDecoder(len(daq.channels), daq.frame_points)
        self._queue = _BlockQueue(max(1, buffered_blocks))
        self._stopping = threading.Event()
        self._caught_up = threading.Event()
        self._on_demand = daq._link.io.samples_on_demand
        self._chunk = frame_size(daq.frame_points, len(daq.channels)) * (1 if self._on_demand else 4)
        # who reads the port: the owner thread, or (on demand) the consumer in read() while the owner waits
        self._port = threading.Lock()
        self._started = threading.Event()
        # the consumer of an on-demand port only reads with the queue empty, and must never wait for itself
        self._unbounded = self._stopping
        if self._on_demand:
            self._unbounded = threading.Event()
            self._unbounded.set()
        self._request = daq._link.submit(self._run)

    # ----- owner thread --------------------------------------------------------------------
    def _run(self, io: PortIO) -> None:
        try:
            with self._port:
                failed = self._attempt(io, self._start)
        finally:
            self._started.set()
        if not failed:
            if self._on_demand:
                self._stopping.wait()     # the consumer reads (read()) until stop() or a failure there
            with self._port:
                if not self._queue.finished and not self._attempt(io, self._finish if self._on_demand
                                                                  else self._read_ahead):
                    self._end(None)
        if isinstance(self._queue.error, LinkLost):
            raise self._queue.error  # marks the port dead for every later call

    def _attempt(self, io: PortIO, step: Callable[[PortIO], None]) -> bool:
        """Run ``step(io)`` on the owner thread; whether it failed (then the stream has ended with the error)."""
        try:
            step(io)
        except BaseException as exc:  # handed to the consumer through the queue
            self._fail(io, exc)
            return True
        return False

    def _start(self, io: PortIO) -> None:
        if io.desynced:
            self.daq._scpi.resync(io)         # what a stream abandoned before may still send comes first
        elif io.rx:
            io.discard_input()
        self.daq._scpi.send(io, "INIT")

    def _read_ahead(self, io: PortIO) -> None:
        """Read as the instrument sends, until stopped, then stop the instrument's stream."""
        last = io.clock()
        while not self._stopping.is_set():
            last = self._read_frame(io, last)
        self._finish(io)

    def _read_frame(self, io: PortIO, last: float) -> float:
        """Read what the port has (at most a chunk) into the queue; the time of the port's last data
        (LinkTimeout after ``no_data_timeout`` of silence since ``last``)."""
        data = io.read_some(self._chunk, POLL)
        if len(data) < self._chunk:
            self._caught_up.set()   # the instrument had nothing more to send
        if data:
            self._deliver(data)
            if self._decoder.ended:
                self._ended_by_instrument(io)
            return io.clock()
        if io.clock() - last > self._no_data_timeout:
            raise LinkTimeout(self.url, f"no stream data for {self._no_data_timeout:.3g} s")
        return last

    def _fail(self, io: PortIO, exc: BaseException) -> None:
        """End the stream with ``exc``: stop the instrument's stream where the link still works, and hand the
        error to the consumer."""
        error = ProtocolError(self.url, f"stream: {exc}") if isinstance(exc, StreamFormatError) else exc
        if not isinstance(error, LinkLost):
            self._abandon(io)
        self._end(error)

    def _end(self, error: BaseException | None) -> None:
        self._queue.finish(error)
        self._caught_up.set()
        self._stopping.set()      # (an owner waiting while the consumer reads goes on)

    def _deliver(self, data: bytes) -> None:
        stats = self.stats
        for frame in self._decoder.feed(data):
            if frame.gap is not None:
                stats.gaps.append(frame.gap)
                stats.samples_lost += frame.gap.samples
            stats.corrupt_frames += frame.corrupt_frames
            stats.skipped_bytes += frame.skipped_bytes
            stats.overrun_frames += bool(frame.flags & FLAG_OVERRUN)
            if frame.is_end:
                stats.samples_sent = frame.first_sample
                stats.end_frame_received = True
            stats.samples_received += frame.points
            for block in self._assembler.add(frame):
                self._queue.put(block, self._unbounded, self._caught_up)

    def _finish(self, io: PortIO) -> None:
        self.daq._scpi.send(io, "ABOR")
        start = last = io.clock()
        while not self._decoder.ended:
            data = io.read_some(self._chunk, POLL)
            now = io.clock()
            if data:
                self._deliver(data)
                last = now
            elif now - last > END_QUIET or now - start > END_LIMIT:
                break
        if self._decoder.ended:
            io.unread(self._decoder.remainder())
        else:
            io.discard_input()
            sent = self._instrument_count(io)
            gap = self._decoder.finish(sent)
            if gap is not None:
                self.stats.gaps.append(gap)
                self.stats.samples_lost += gap.samples
            self.stats.samples_sent = sent
            self.stats.skipped_bytes = self._decoder.stats.skipped_bytes
            self.stats.corrupt_frames = self._decoder.stats.corrupt_frames
        tail = self._assembler.flush()
        if tail is not None:
            self._queue.put(tail, self._unbounded, self._caught_up)

    def _ended_by_instrument(self, io: PortIO) -> None:
        """The DAQ sent END unasked: keep the samples, then raise what its error queue says."""
        io.unread(self._decoder.remainder())
        tail = self._assembler.flush()
        if tail is not None:
            self._queue.put(tail, self._unbounded, self._caught_up)
        errors = self.daq._scpi.drain_errors(io)
        if errors:
            raise DeviceError(self.url, errors, "INIT (the instrument ended the stream)")
        raise ProtocolError(self.url, "the DAQ ended the stream without ABORt")

    def _instrument_count(self, io: PortIO) -> int:
        """``STReam:COUNt?``, asked until two answers agree (a noisy line can garble one)."""
        previous = None
        for _ in range(COUNT_ATTEMPTS):
            try:
                reply = self.daq._scpi.ask(io, "STR:COUN?").strip()
            except LinkTimeout:
                continue
            if reply.isdigit():
                if reply == previous:
                    return int(reply)
                previous = reply
        raise ProtocolError(self.url, f"STR:COUN? gave no two equal answers in {COUNT_ATTEMPTS} attempts")

    def _abandon(self, io: PortIO) -> None:
        """After a failure: stop the instrument streaming so the port is usable again. The link is left out of
        step: an instrument that stalled sends the END its ABORt asks for once it acts, after any quiet wait here,
        and the next request or stream must read past it (:meth:`drivers.scpi.ScpiInstrument.resync`) rather than
        take it for its own reply or end."""
        try:
            self.daq._scpi.send(io, "ABOR")
            io.drain(quiet=0.1, limit=END_LIMIT)
        except InstrumentError:
            pass  # the original failure is what the consumer needs to see
        io.desynced = True

    # ----- consumer ------------------------------------------------------------------------
    def read(self, timeout: float | None = None) -> Block:
        """The next block.

        Raises
        ------
        LinkTimeout
            No block within ``timeout`` (default: the stream's timeout).
        EOFError
            The stream has stopped and every block was read.
        InstrumentError
            The stream failed (link lost, protocol error); raised on every later read too.
        """
        timeout = self.timeout if timeout is None else timeout
        clock = self.daq._link.io.clock
        if self._on_demand:
            deadline = clock() + timeout
            self._read_on_demand(deadline)
            timeout = max(deadline - clock(), 0.0)
        block = self._queue.get(timeout, self.url, clock)
        if block is None:
            raise EOFError(f"{self.url}: stream stopped")
        return block

    def _read_on_demand(self, deadline: float) -> None:
        """Read an on-demand port in this thread until a block is queued, the stream stops or ``deadline`` (on the
        port's clock) passes; a failure ends the stream as on the owner thread."""
        io = self.daq._link.io
        while not self._started.wait(POLL):
            if io.clock() >= deadline:
                return
        # one step, a signal acting once it is done: the read runs the instrument's physics and moves counts
        # its threads share (its idle clock's work, counted and let go), which a Ctrl-C between the two would
        # leave standing for good -- and the clock with them, every deadline on it never reached
        with signals_held(), self._port:
            last = io.clock()
            try:
                while not len(self._queue) and not self._stopping.is_set() and io.clock() < deadline:
                    last = self._read_frame(io, last)
            except Exception as exc:  # (a Ctrl-C leaves the stream running, as it does a consumer waiting)
                self._fail(io, exc)

    def pending(self) -> int:
        """Blocks already received and waiting to be read (samples the instrument sent before now)."""
        with self._queue._ready:
            return len(self._queue._blocks)

    def __iter__(self) -> Iterator[Block]:
        return self

    def __next__(self) -> Block:
        try:
            return self.read()
        except EOFError:
            raise StopIteration from None

    def sync(self, timeout: float = 5.0) -> bool:
        """Wait until the driver has read what the instrument had to send, or its queue is full (it waits for
        the consumer); whether that came within ``timeout`` s.

        Call it before changing what the instrument measures (the generator): then the samples taken before
        the change are all received or queued, however the threads were scheduled. Against an emulator that
        samples only as fast as it is read, this makes a run the same on any machine; such a port is read only by
        the consumer's :meth:`read`, and holds nothing unread once no read is under way."""
        if self._on_demand:
            if not self._port.acquire(timeout=timeout):
                return False
            self._port.release()
            return True
        self._caught_up.clear()
        if self._queue.finished:   # (the reader sets the event after it finishes)
            return True
        clock = self.daq._link.io.clock    # an in-process emulator's idle time: a busy machine is no reason
        deadline = clock() + timeout
        while not self._caught_up.wait(POLL * 5):
            if clock() >= deadline:
                return False
        return True

    def stop(self, timeout: float = END_LIMIT + 5.0) -> StreamStats:
        """End the acquisition and wait until the instrument confirmed it; the final stats.

        Blocks still queued stay readable; reading past them raises EOFError.
        A stream that failed raises its error here.
        """
        self.sync()
        self._stopping.set()
        self._request.wait(self.url, timeout, self.daq._link.io.clock)
        if self._queue.error is not None:
            raise self._queue.error
        return self.stats

    @property
    def running(self) -> bool:
        return not self._queue.finished

    def __enter__(self) -> "DaqStream":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.stop()
        except InstrumentError:
            if exc_type is None:
                raise
        finally:
            self.daq._stream = None


class SerialDaq:
    """A :class:`~drivers.interfaces.Daq` on a serial link.

    Parameters
    ----------
    url : str
        Port name or pyserial URL.
    baudrate : int
        Line rate of a real serial port.
    timeout : float
        Deadline for each reply (s).
    models : tuple of str
        ``*IDN?`` model fields accepted.
    port : serial.SerialBase, optional
        An open port to use instead of opening ``url``.
    """

    def __init__(self, url: str, *, baudrate: int = 2_000_000, timeout: float = 1.0,
                 models: tuple[str, ...] = DAQ_MODELS, port: serial.SerialBase | None = None):
        self.url = url
        self._link = SerialLink(url, name="daq", baudrate=baudrate, port=port)
        self._scpi = ScpiInstrument(self._link, timeout)
        self._stream: DaqStream | None = None
        try:
            self.identity: Identity = self._link.call(lambda io: self._connect(io, models), 4 * timeout + END_LIMIT)
        except BaseException:
            self._link.close()
            raise

    def _connect(self, io: PortIO, models: tuple[str, ...]) -> Identity:
        scpi = self._scpi
        scpi.send(io, "")
        scpi.send(io, "ABOR")  # a stream left running by an earlier session must not garble the replies
        scpi.clear(io)
        identity = scpi.identify(io, MANUFACTURER, models, "contactid DAQ", 2 * scpi.timeout)
        scpi.execute(io, "*RST;*CLS")
        scpi.expect(io, {"SYST:ERR:COUN?": lambda r: r == "0"}, "*RST;*CLS")
        self._read_setup(io)
        return identity

    def _read_setup(self, io: PortIO) -> None:
        scpi = self._scpi
        count = self._ask_int(io, "SYST:CHAN:COUN?")
        names, units, lsb = [], [], []
        for n in range(1, count + 1):
            names.append(scpi.ask(io, f"SENS:CHAN{n}:NAME?"))
            units.append(scpi.ask(io, f"SENS:CHAN{n}:UNIT?"))
            lsb.append(self._ask_float(io, f"SENS:CHAN{n}:LSB?"))
        scan_reply = scpi.ask(io, "ROUT:SCAN?").replace(" ", "")
        match = _SCAN.match(scan_reply)
        if match is None:
            raise ProtocolError(self.url, f"ROUT:SCAN? answered {scan_reply!r}")
        scan = [int(x) - 1 for x in match.group(1).split(",")]
        if not all(0 <= i < count for i in scan):
            raise ProtocolError(self.url, f"ROUT:SCAN? names channels outside 1..{count}: {scan_reply!r}")
        self.all_channels = tuple(names)
        self.channels = tuple(names[i] for i in scan)
        self.units = tuple(units[i] for i in scan)
        self.lsb = np.array([lsb[i] for i in scan])
        self.sample_rate = self._ask_float(io, "SRAT?")
        self.frame_points = self._ask_int(io, "STR:POIN?")

    def _ask_float(self, io: PortIO, command: str) -> float:
        reply = self._scpi.ask(io, command)
        try:
            return float(reply)
        except ValueError:
            raise ProtocolError(self.url, f"{command} answered {reply!r}, expected a number") from None

    def _ask_int(self, io: PortIO, command: str) -> int:
        reply = self._scpi.ask(io, command)
        if not reply.strip().isdigit():
            raise ProtocolError(self.url, f"{command} answered {reply!r}, expected a count")
        return int(reply)

    def _idle(self) -> None:
        if self._stream is not None and self._stream.running:
            raise InstrumentError(self.url, "a stream is running: stop it first")

    def configure(self, *, channels: Sequence[str] | None = None, sensitivities: dict[str, float] | None = None,
                  ranges: dict[str, float] | None = None, frame_points: int | None = None) -> None:
        """Select and set up channels (names as in ``all_channels``).

        Parameters
        ----------
        channels : sequence of str, optional
            Channels to acquire, in column order.
        sensitivities : dict, optional
            Sensor sensitivity per channel name (V per physical unit).
        ranges : dict, optional
            Input range per channel name (V peak).
        frame_points : int, optional
            Samples per channel per stream frame (1..4096).
        """
        self._idle()
        commands = []
        if channels is not None:
            commands.append("ROUT:SCAN (@" + ",".join(str(self._number(c)) for c in channels) + ")")
        for name, value in (sensitivities or {}).items():
            commands.append(f"SENS:CHAN{self._number(name)}:SENS {float(value)!r}")
        for name, value in (ranges or {}).items():
            commands.append(f"SENS:CHAN{self._number(name)}:RANG {float(value)!r}")
        if frame_points is not None:
            if not 1 <= frame_points <= MAX_POINTS:
                raise ValueError(f"frame_points must be 1..{MAX_POINTS}, got {frame_points}")
            commands.append(f"STR:POIN {int(frame_points)}")

        def apply(io: PortIO) -> None:
            for command in commands:
                self._scpi.execute(io, command)
            self._read_setup(io)

        self._link.call(apply, self._scpi.reply_wait(len(commands) + 10))

    def _number(self, name: str) -> int:
        try:
            return self.all_channels.index(name) + 1
        except ValueError:
            raise KeyError(f"{self.url}: no channel {name!r}; channels are {', '.join(self.all_channels)}") from None

    def stream(self, block_size: int, *, buffered_blocks: int = 4, timeout: float | None = None,
               no_data_timeout: float = 2.0) -> DaqStream:
        """Start streaming (see :class:`DaqStream`)."""
        self._idle()
        if self._link.failure is not None:
            raise self._link.failure
        self._stream = DaqStream(self, block_size, buffered_blocks, timeout, no_data_timeout)
        return self._stream

    def read(self, points: int) -> Block:
        """Acquire ``points`` samples per channel now (IEEE 488.2 block read); first_sample is 0."""
        self._idle()
        wait = points / self.sample_rate + self._scpi.timeout
        payload = self._scpi.query_block(f"READ? {int(points)}", timeout=wait)
        width = len(self.channels)
        if len(payload) != 4 * width * points:
            raise ProtocolError(self.url, f"READ? {points} returned {len(payload)} bytes, "
                                          f"expected {4 * width * points}")
        counts = np.frombuffer(payload, dtype="<i4").reshape(points, width)
        return Block(counts * self.lsb, self.channels, self.units, self.sample_rate, 0)

    def errors(self) -> list:
        """Empty the instrument's error queue (entries oldest first)."""
        self._idle()
        return self._scpi.errors()

    def close(self) -> None:
        """Stop a running stream and release the port."""
        try:
            if self._stream is not None and self._stream.running:
                self._stream.stop()
        finally:
            self._link.close()

    def __enter__(self) -> "SerialDaq":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
