"""Stream decoding speed against the line rate, and a loss-free paced stream over a pty.

Part 1 times the driver's receive path (frame decoder + block assembler) on a
recorded stream and compares its throughput with the line rate of a 2 Mbaud
serial link (8N1: 10 bits per byte, 200 000 bytes/s), for 4 channels at the
sample rate that fills that line. Part 2 serves an emulated DAQ at that rate in
real time over a pseudo terminal and streams it through the real driver for
``--seconds`` of emulated time, counting every lost or corrupted frame.

Run: ``python benchmarks/stream_decode.py [--seconds 60]``
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.daq import BlockAssembler, SerialDaq
from drivers.emulator import EmulatedRig
from drivers.faults import FaultInjector, LinkFaults
from drivers.serve import EmulatorServer
from drivers.stream import FrameDecoder, encode_frame, frame_size

BAUD = 2_000_000
LINE_RATE = BAUD / 10            # bytes/s on an 8N1 line
CHANNELS = 4
SAMPLE_RATE = 12_000.0           # Hz: 4 channels of int32 at this rate fill 97 % of the line
FRAME_POINTS = 240               # 20 ms frames, the DAQ's default size at this rate
BLOCK = 4096


class SineSource:
    """Four channels of sines with the rig backend's interface (no physics: the benchmark
    measures the link, not the simulator)."""

    sample_rate = SAMPLE_RATE
    channels = ["force", "acc:a", "acc:b", "acc:c"]
    units = ["N", "m/s^2", "m/s^2", "m/s^2"]
    lsb = np.array([1e-6, 1e-5, 1e-5, 1e-5])

    def __init__(self) -> None:
        self.samples = 0
        self.frequency = 37.0

    @property
    def time(self) -> float:
        return self.samples / self.sample_rate

    def set_sine(self, frequency_hz: float, amplitude_volts: float) -> None:
        self.frequency = frequency_hz

    def set_noise(self, rms_volts: float, band_hz: tuple[float, float]) -> None:
        """Noise is not used here."""

    def set_output(self, on: bool) -> None:
        """The source runs regardless: only the data rate matters here."""

    def advance(self, n: int) -> np.ndarray:
        t = (self.samples + np.arange(n)) / self.sample_rate
        self.samples += n
        phases = 2 * np.pi * self.frequency * t[:, None] + np.arange(CHANNELS)
        return np.round(np.sin(phases) / self.lsb) * self.lsb


def recorded_stream(seconds: float) -> bytes:
    """What the DAQ sends for ``seconds`` of streaming (frames of FRAME_POINTS samples)."""
    rng = np.random.default_rng(0)
    frames = int(seconds * SAMPLE_RATE / FRAME_POINTS)
    counts = rng.integers(-2**23, 2**23, size=(frames, FRAME_POINTS, CHANNELS)).astype(np.int32)
    return b"".join(encode_frame(k, k * FRAME_POINTS, counts[k]) for k in range(frames))


def decode(stream: bytes, chunk: int) -> tuple[float, FrameDecoder]:
    """Seconds of CPU the receive path needs for ``stream``, fed in ``chunk``-byte reads."""
    decoder = FrameDecoder(CHANNELS, FRAME_POINTS)
    assembler = BlockAssembler(BLOCK, SineSource.lsb, tuple(SineSource.channels), tuple(SineSource.units),
                               SAMPLE_RATE)
    start = time.process_time()
    for offset in range(0, len(stream), chunk):
        for frame in decoder.feed(stream[offset:offset + chunk]):
            assembler.add(frame)
    assembler.flush()
    return time.process_time() - start, decoder


def decode_benchmark() -> None:
    seconds = 120.0
    stream = recorded_stream(seconds)
    data_rate = len(stream) / seconds
    chunk = 4 * frame_size(FRAME_POINTS, CHANNELS)   # what the driver asks the port for
    print(f"stream: {CHANNELS} channels x {SAMPLE_RATE:g} Hz, {FRAME_POINTS}-point frames: "
          f"{data_rate:,.0f} B/s = {100 * data_rate / LINE_RATE:.1f} % of a {BAUD / 1e6:g} Mbaud line")
    clean_cpu, _ = decode(stream, chunk)
    damaged = FaultInjector(LinkFaults(drop=1e-4, flip=1e-4, seed=1), 1).corrupt(stream)
    damaged_cpu, decoder = decode(damaged, chunk)
    for label, cpu, size in (("clean", clean_cpu, len(stream)), ("1e-4 drops + 1e-4 flips", damaged_cpu,
                                                                 len(damaged))):
        throughput = size / cpu
        print(f"  {label:26s} {throughput / 1e6:8.1f} MB/s = {throughput / LINE_RATE:7.0f} x line rate; "
              f"CPU share at line rate {100 * LINE_RATE / throughput:.2f} % of one core")
    stats = decoder.stats
    print(f"  damaged stream: {stats.frames} frames good, {stats.lost_frames} lost in {len(stats.gaps)} gaps, "
          f"{stats.corrupt_frames} failed the CRC, {stats.skipped_bytes} bytes skipped")


def pty_benchmark(seconds: float) -> None:
    wall_start, cpu_start = time.monotonic(), time.process_time()
    with EmulatedRig(SineSource(), paced=True, name="bench") as rig, EmulatorServer(rig, "pty") as server:
        daq = SerialDaq(server.urls["daq"], baudrate=BAUD)
        daq.configure(frame_points=FRAME_POINTS)
        wanted = int(seconds * SAMPLE_RATE)
        received = 0
        stream_wall = time.monotonic()
        with daq.stream(BLOCK, buffered_blocks=16) as stream:
            while received < wanted:
                received += len(stream.read())
        stream_wall = time.monotonic() - stream_wall
        stats = stream.stats
        daq.close()
    wall, cpu = time.monotonic() - wall_start, time.process_time() - cpu_start
    print(f"pty, paced, {seconds:g} s of emulated streaming ({stream_wall:.1f} s wall): "
          f"{stats.samples_sent:,} samples/channel sent, {stats.samples_received:,} received, "
          f"{stats.samples_lost} lost, {stats.corrupt_frames} corrupt frames, {stats.overrun_frames} overruns")
    print(f"  CPU of emulator + pty + driver + decoder: {100 * cpu / wall:.1f} % of one core over {wall:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="emulated seconds over the pty (default 60)")
    args = parser.parse_args()
    decode_benchmark()
    pty_benchmark(args.seconds)


if __name__ == "__main__":
    main()
