"""The drivers against the emulated instruments: in process (sim://), over pseudo terminals and TCP."""
import contextlib
import signal
import threading
import time

import numpy as np
import pytest

from analysis.common.errors import InputError

import drivers  # noqa: F401  (registers sim://)
from drivers.daq import SerialDaq
from drivers.discovery import find_instruments
from drivers.emulator import EmulatedRig, register, set_backend_factory
from app.campaign.instruments import builtin_backend
from drivers.emulator.daq import counts_of
from drivers.emulator.registry import find_rig
from drivers.emulator.shaker import RAMP_STEP
from drivers.errors import DeviceError, LinkLost, LinkTimeout, WrongDevice
from drivers.faults import LinkFaults, parse_faults
from drivers.safety import OutputGuard
from drivers.serve import parse_tcp_address, serve_emulator
from drivers.shaker import SerialShaker
from rig_double import ACC_GAIN, FORCE_GAIN, RigDouble, bench, signature, stream_start


def assert_exact(rig, blocks, start):
    """Every delivered sample is the backend's sample at its index (the drive is off)."""
    lsb = rig.lsb
    for block in blocks:
        index = start + block.first_sample + np.arange(len(block))
        truth = np.column_stack([signature(index, k) * lsb[k] for k in range(3)])
        np.testing.assert_array_equal(block.data, truth)


def single_bin(x, cycles):
    """Complex amplitude of the component with ``cycles`` periods in ``x`` (sin convention: |.| = amplitude)."""
    n = len(x)
    return 2.0 / n * np.sum(x * np.exp(-2j * np.pi * cycles * np.arange(n) / n))


@pytest.mark.parametrize("transport", ["sim", "pty", "tcp"])
@pytest.mark.slow
def test_sine_reaches_the_daq_with_the_right_amplitude(transport):
    with bench(transport) as (rig, shaker, daq):
        shaker.set_sine(12.5, 0.5)
        with OutputGuard(shaker) as guard:
            guard.arm()
            with daq.stream(800) as stream:
                blocks = [stream.read() for _ in range(3)]
            assert rig.shaker.output_on
        assert not rig.shaker.output_on
        assert stream.stats.balanced and stream.stats.samples_lost == 0
        assert [b.first_sample for b in blocks] == [0, 800, 1600]
        settled = blocks[2]
        force = single_bin(settled.channel("force"), 10)
        assert abs(force) == pytest.approx(FORCE_GAIN * 0.5, abs=2e-3)
        for name, gain in zip(("acc:x1", "acc:x2"), ACC_GAIN):
            ratio = single_bin(settled.channel(name), 10) / force
            assert ratio.real == pytest.approx(gain / FORCE_GAIN, rel=2e-3) and abs(ratio.imag) < 2e-2


def test_amplitude_ramps_in_small_steps_and_switches_off_at_once():
    with bench() as (rig, shaker, daq):
        shaker.set_ramp_rate(4.0)
        shaker.set_sine(10.0, 1.0)
        with OutputGuard(shaker) as guard:
            guard.arm()
            with daq.stream(500, buffered_blocks=1) as stream:
                stream.read()
                shaker.set_sine(10.0, 0.2)
                for _ in range(4):  # more than the read-ahead plus the 0.2 s ramp down
                    stream.read()
            assert shaker.output_level() == pytest.approx(0.2)
        calls = rig.backend.calls
        on = next(i for i, c in enumerate(calls) if c[1:] == ("set_output", (True,)))
        off = next(i for i, c in enumerate(calls) if c[1:] == ("set_output", (False,)))
        amplitudes = [0.0] + [c[2][1] for c in calls[on + 1:off] if c[1] == "set_sine"]
        steps = np.abs(np.diff(amplitudes))
        assert steps.max() <= 4.0 * RAMP_STEP * (1 + 1e-9)
        assert max(amplitudes) == pytest.approx(1.0) and amplitudes[-1] == pytest.approx(0.2)
        assert rig.backend.output is False


def test_paced_mode_streams_contiguous_samples_and_block_reads():
    with bench(paced=True) as (rig, shaker, daq):
        with daq.stream(100) as stream:
            blocks = [stream.read() for _ in range(3)]
        assert stream.stats.balanced
        assert_exact(rig, blocks, stream_start(rig))
        before = rig.time
        block = daq.read(50)
        assert len(block) == 50 and rig.time >= before + 0.05


def test_noise_drives_the_backend_with_the_asked_rms_and_band():
    with bench() as (rig, shaker, daq):
        shaker.set_noise(0.1, (2.0, 50.0))
        with OutputGuard(shaker) as guard:
            guard.arm()
            with daq.stream(4000) as stream:
                stream.read()
                block = stream.read()
        rms, band = [c[2] for c in rig.backend.calls if c[1] == "set_noise"][-1]
        assert rms == pytest.approx(0.1) and band == (2.0, 50.0)
        assert rig.backend.sine[1] == 0.0  # the sine generator was silenced
        assert np.std(block.channel("force")) == pytest.approx(FORCE_GAIN * 0.1, rel=0.06)


def test_channel_selection_and_range_saturation():
    with bench() as (rig, shaker, daq):
        daq.configure(channels=["acc:x2", "force"], sensitivities={"force": 0.5}, ranges={"force": 0.1},
                      frame_points=50)
        assert daq.channels == ("acc:x2", "force") and daq.frame_points == 50
        shaker.set_sine(10.0, 0.5)
        with OutputGuard(shaker) as guard:
            guard.arm()
            with daq.stream(1000) as stream:
                stream.read()
                block = stream.read()
        assert block.overload
        assert np.abs(block.channel("force")).max() == pytest.approx(0.2)
        assert np.abs(block.channel("acc:x2")).max() > 5.0


@pytest.mark.parametrize("faults, reported", [
    ({"drop": 2e-3, "seed": 1}, "corrupt"),
    ({"flip": 2e-3, "seed": 2}, "corrupt"),
    ({"overrun": 0.05, "seed": 3}, "overrun"),
    ({"drop": 5e-4, "flip": 5e-4, "overrun": 0.02, "seed": 4}, "corrupt"),
    ({"stall": 2e-4, "stall_time": 0.02, "seed": 5}, None),
])
@pytest.mark.slow
def test_injected_stream_faults_are_reported_and_every_sample_accounted_for(faults, reported):
    with bench() as (rig, shaker, daq):
        injector = rig.inject("daq", faults)
        with daq.stream(200, buffered_blocks=2) as stream:
            blocks = [stream.read() for _ in range(25)]
        blocks += list(stream)
        stats = stream.stats
        assert stats.balanced
        assert sum(len(b) for b in blocks) == stats.samples_received
        assert_exact(rig, blocks, stream_start(rig))
        if reported == "corrupt":
            assert stats.corrupt_frames + stats.skipped_bytes > 0 and stats.samples_lost > 0
            assert injector.dropped_bytes + injector.flipped_bits > 0
        elif reported == "overrun":
            assert stats.overrun_frames > 0
            assert sum(g.frames for g in stats.gaps) == rig.daq.frames_overrun == injector.lost_frames > 0
            assert 301 in [e.code for e in daq.errors()]
        else:
            assert injector.stalls > 0 and stats.samples_lost == 0
        assert sum(g.samples for g in stats.gaps) == stats.samples_lost


def test_a_fast_port_is_read_no_further_ahead_than_its_consumer_asks():
    """An in-process fast emulator samples only as it is read: its driver reads a frame only when the consumer
    waits for a block, so the emulated time stands where the consumer stopped reading and a command the
    consumer sends next lands there, as on a real instrument whose driver holds what arrived meanwhile. A
    consumer that idles longer than the no-data timeout is no silence of the line."""
    with bench() as (rig, shaker, daq):
        with daq.stream(200, no_data_timeout=0.3) as stream:
            for _ in range(3):
                stream.read()
            assert stream.sync() and stream.pending() == 0
            assert rig.daq.acquired == 600
            time.sleep(0.6)                      # the consumer busy elsewhere
            assert rig.daq.acquired == 600
            blocks = [stream.read() for _ in range(2)]
            assert [b.first_sample for b in blocks] == [600, 800] and rig.daq.acquired == 1000
        assert stream.stats.balanced and stream.stats.samples_lost == 0


def test_a_fast_port_is_read_in_its_consumers_thread_and_a_failure_there_ends_the_stream():
    """The consumer of a fast port reads it itself (no frame goes from thread to thread): the physics runs in
    the consumer's thread, never in the port's owner thread. A failure while it reads ends the stream as one on
    the owner thread does: the error on every later read and at stop(), and the instrument's stream stopped."""
    with bench() as (rig, shaker, daq):
        advance, threads = rig.backend.advance, set()

        def recorded(n):
            threads.add(threading.current_thread())
            return advance(n)

        rig.backend.advance = recorded
        with daq.stream(200, no_data_timeout=0.3) as stream:
            consumer = threading.Thread(target=lambda: [stream.read() for _ in range(5)])
            consumer.start()
            consumer.join(10.0)
            assert not consumer.is_alive() and stream.sync() and rig.daq.acquired == 1000
        assert threads == {consumer} and stream.stats.balanced

        abandoned_in_a_stall(rig, daq, reads=2)


@pytest.mark.parametrize("guarded", [False, True])
def test_ctrl_c_while_a_fast_port_is_read_acts_once_its_block_is_in_and_the_clock_goes_on(ctrl_c, monkeypatch,
                                                                                         guarded):
    """The consumer of a fast port runs the instrument's physics in its read -- in the main thread, where Ctrl-C
    lands. A signal acts once the read has queued its block (kept for the next read), never between the
    instrument's idle clock counting the work and letting it go: the clock would stand still for good, and every
    deadline on it, the stream's stop among them. Under a guard's handler (a campaign) and without."""
    with bench() as (rig, shaker, daq), contextlib.ExitStack() as stack:
        if guarded:
            stack.enter_context(OutputGuard(shaker))
        clock, fired = rig.idle_clock, []
        begin = clock.begin

        def begin_then_ctrl_c():
            begin()
            if threading.current_thread() is threading.main_thread() and not fired:
                fired.append(True)
                signal.raise_signal(signal.SIGINT)      # just after the count, before the work

        monkeypatch.setattr(clock, "begin", begin_then_ctrl_c)
        stream = daq.stream(200, no_data_timeout=0.3)
        with pytest.raises(KeyboardInterrupt):
            stream.read()
        assert fired and stream.read().first_sample == 0        # the block read when the signal came
        still = clock()
        time.sleep(0.05)
        assert clock() > still                                  # the clock goes on
        stopping = threading.Thread(target=stream.stop, daemon=True)
        stopping.start()
        stopping.join(30.0)
        assert not stopping.is_alive() and stream.stats.balanced


def abandoned_in_a_stall(rig, daq, reads: int) -> None:
    """A stream whose DAQ stalls for 3 s: its ``reads`` reads and its stop fail for want of data, and the ABORt the
    failure sent stops the instrument's stream once its firmware thread acts."""
    rig.inject("daq", {"stall": 1.0, "stall_time": 3.0})
    stream = daq.stream(200, no_data_timeout=0.3)
    for _ in range(reads):
        with pytest.raises(LinkTimeout, match="no stream data"):
            stream.read()
    with pytest.raises(LinkTimeout, match="no stream data"):
        stream.stop()
    give_up = time.monotonic() + 10.0
    while rig.daq.acquiring and time.monotonic() < give_up:
        time.sleep(0.01)
    assert not rig.daq.acquiring


def test_a_stream_after_one_abandoned_in_a_stall_reads_its_own_samples():
    """A stream abandoned while the instrument stalled never saw the END its ABORt asked for: the END comes once
    the stall is over, and the next stream must not take it for its own end."""
    with bench() as (rig, shaker, daq):
        abandoned_in_a_stall(rig, daq, reads=1)
        rig.inject("daq", {"stall": 0.0})
        with daq.stream(200) as stream:
            blocks = [stream.read() for _ in range(3)]
        assert [b.first_sample for b in blocks] == [0, 200, 400] and stream.stats.balanced


def test_a_port_read_ahead_fills_the_queue():
    """Over a transport that does not sample on demand (TCP here) the driver reads ahead of its consumer up
    to its queue's depth, as it must on a real instrument whose FIFO would otherwise overrun."""
    with bench("tcp") as (rig, shaker, daq):
        with daq.stream(200, buffered_blocks=4) as stream:
            stream.read()
            assert stream.sync()
            assert stream.pending() >= 4 and rig.daq.acquired >= 1000


def test_a_long_stall_is_a_timeout():
    with bench() as (rig, shaker, daq):
        rig.inject("daq", {"stall": 1e-3, "stall_time": 3.0})
        stream = daq.stream(200, no_data_timeout=0.3)
        with pytest.raises(LinkTimeout, match="no stream data"):
            for _ in range(100):
                stream.read()


@pytest.mark.parametrize("transport", ["sim", "pty", "tcp"])
@pytest.mark.slow
def test_a_dropped_link_is_link_lost(transport):
    with bench(transport, faults={"daq": {"disconnect": 20000}}) as (rig, shaker, daq):
        with pytest.raises(LinkLost):
            with daq.stream(100) as stream:
                for _ in range(1000):
                    stream.read()
        with pytest.raises(LinkLost):
            daq.stream(100)


def test_scpi_error_injection_is_reported_by_the_driver():
    with EmulatedRig(RigDouble(), paced=False, name="scpierr") as rig:
        register(rig, "scpierr")
        with pytest.raises(DeviceError) as info:
            SerialShaker("sim://scpierr/shaker?scpi_error=1")
        assert info.value.codes == [-300] * 3 and "*RST" in str(info.value)  # *RST, *CLS, SYST:WDOG


def test_wrong_device_and_missing_port_are_clear_errors():
    with bench() as (rig, shaker, daq):
        shaker_url, daq_url = shaker.url, daq.url
        shaker.close()
        daq.close()
        with pytest.raises(WrongDevice, match="not a contactid DAQ"):
            SerialDaq(shaker_url)
        with pytest.raises(WrongDevice, match="not a contactid shaker controller"):
            SerialShaker(daq_url)
    with pytest.raises(LinkLost, match="cannot open port"):
        SerialShaker("/dev/no-such-port-here")


def test_an_instrument_that_goes_away_is_link_lost():
    with bench(paced=True) as (rig, shaker, daq):
        stream = daq.stream(100)
        stream.read()
        rig.close()
        with pytest.raises(LinkLost):
            for _ in range(100):
                stream.read()


@pytest.mark.parametrize("url, message", [
    ("sim://{name}/shaker?bogus=1", "unknown option"),
    ("sim://{name}/pump", "expected sim://"),
    ("sim://nowhere-{name}/daq", "no built-in rig has that name"),
    ("sim://{name}/daq?fast=0", "already running fast"),
    ("sim://{name}/daq?drop=2", "probability"),
    ("sim://{name}/shaker", "already open"),
])
@pytest.mark.slow
def test_bad_sim_urls_are_explained(url, message):
    with bench() as (rig, shaker, daq):
        with pytest.raises(LinkLost, match=message):
            SerialShaker(url.format(name=rig.name))


def test_a_backend_factory_builds_rigs_on_demand():
    set_backend_factory(lambda name, seed: (RigDouble(seed=seed or 0), {"daq": {"overrun": 0.5}}))
    try:
        shaker = SerialShaker("sim://ondemand/shaker?fast=1&seed=4")
        daq = SerialDaq("sim://ondemand/daq")
        rig = find_rig("ondemand")
        assert not rig.paced and shaker.identity.serial == "ondemand"
        with daq.stream(100) as stream:
            stream.read()
        assert stream.stats.overrun_frames > 0  # the factory's fault table applies
        shaker.close()
        assert find_rig("ondemand") is rig
        daq.close()
        assert find_rig("ondemand") is None and not rig.running
    finally:
        set_backend_factory(builtin_backend)


def test_discovery_classifies_ports():
    with bench() as (rig, shaker, daq):
        urls = [shaker.url, daq.url]
        shaker.close()
        daq.close()
        found, probes = find_instruments(urls + ["sim://nowhere/daq"], timeout=0.3)
        assert found == {"shaker": urls[0], "daq": urls[1]}
        assert probes[2].role is None and "no emulated rig named 'nowhere'" in probes[2].detail


class FailingRig(RigDouble):
    """Diverges after ``limit`` samples, as the simulator does when a softening element escapes."""

    def __init__(self, limit):
        super().__init__()
        self.limit = limit

    def advance(self, n):
        if self.samples + n > self.limit:
            raise FloatingPointError("the response diverged")
        return super().advance(n)


def test_a_physics_failure_switches_off_and_ends_the_stream_with_the_reason():
    with EmulatedRig(FailingRig(3000), paced=False, name="diverging") as rig:
        register(rig)
        shaker = SerialShaker("sim://diverging/shaker")
        daq = SerialDaq("sim://diverging/daq")
        shaker.set_sine(10.0, 0.5)
        with OutputGuard(shaker) as guard:
            guard.arm()
            stream = daq.stream(500)
            with pytest.raises(DeviceError, match="physics stopped: FloatingPointError") as info:
                for _ in range(100):
                    stream.read()
            assert info.value.codes == [-300]
            assert not rig.shaker.output_on and rig.output_events()[-1].detail == "off: physics failure"
        assert stream.stats.balanced and stream.stats.samples_sent == rig.daq.acquired
        shaker.close()
        daq.close()


def test_serve_emulator_announces_urls_and_serves_until_stopped():
    lines, stop = [], threading.Event()
    server = threading.Thread(target=serve_emulator, args=(RigDouble(),),
                              kwargs=dict(transport="tcp", fast=True, name="served", announce=lines.append,
                                          stop=stop))
    server.start()
    try:
        deadline = time.monotonic() + 10
        while len(lines) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        roles = dict(line.split(": ", 1) for line in lines)
        assert set(roles) == {"shaker", "daq"} and all(u.startswith("socket://127.0.0.1:") for u in roles.values())
        with SerialShaker(roles["shaker"]) as shaker, SerialDaq(roles["daq"]) as daq:
            assert shaker.identity.serial == "served" and daq.read(10).data.shape == (10, 3)
    finally:
        stop.set()
        server.join(10)
    assert not server.is_alive()
    assert parse_tcp_address("localhost:5025") == ("localhost", 5025)
    with pytest.raises(InputError, match="HOST:PORT"):
        parse_tcp_address("5025")


def test_fault_tables_are_checked_and_merged_per_link():
    faults = parse_faults({"seed": 3, "drop": 1e-4, "daq": {"overrun": 0.01}, "shaker": {"drop": 0.0}})
    assert faults["daq"] == LinkFaults(drop=1e-4, overrun=0.01, seed=3)
    assert faults["shaker"] == LinkFaults(seed=3)
    with pytest.raises(InputError, match=r"rig.toml: \[faults\].daq.flip: is a probability"):
        parse_faults({"daq": {"flip": 1.5}}, "rig.toml")
    with pytest.raises(InputError, match="unknown fault"):
        parse_faults({"jitter": 1.0})
    with pytest.raises(InputError, match="non-negative integer"):
        parse_faults({"disconnect": 2.5})


def test_built_in_rigs_are_reachable_by_name():
    with SerialShaker("sim://paper-2dof/shaker?fast=1") as shaker, SerialDaq("sim://paper-2dof/daq") as daq:
        assert shaker.identity.serial == "paper-2dof"
        assert daq.channels == ("force", "acc:x1", "acc:x2") and daq.units == ("N", "m/s^2", "m/s^2")
        shaker.set_sine(1.5, 0.5)
        with OutputGuard(shaker) as guard:
            guard.arm()
            with daq.stream(256) as stream:
                blocks = [stream.read() for _ in range(4)]
        assert stream.stats.balanced and np.abs(blocks[-1].channel("force")).max() > 0.01
    assert find_rig("paper-2dof") is None


def _quantised_with_clip(daq, data):
    """The DAQ's counts and saturation flags by clipping every sample in NumPy: the reference for the compiled
    converter (``counts_of``)."""
    lsb = daq.rig.lsb[daq.scan]
    limit = np.minimum(np.floor(daq.input_range[daq.scan] / daq.sensitivity[daq.scan] / lsb), (1 << 31) - 1)
    counts = np.rint(data[:, daq.scan] / lsb)
    saturated = np.abs(counts) > limit
    return np.clip(counts, -limit, limit).astype(np.int32), saturated.any(axis=1)


def test_the_converter_saturates_at_its_limits_and_reads_a_sample_that_is_not_a_number_full_scale():
    data = np.array([[0.26, -7.0, np.inf], [np.nan, 0.0, -np.inf], [1.0, 2.0, 3.0]])
    counts, saturated = counts_of(data, np.array([2, 0, 1]), np.array([0.5, 0.1, 1.0]), np.array([4.0, 2.0, 5.0]))
    assert counts.dtype == np.int32 and counts.tolist() == [[4, 2, -5], [-4, 2, 0], [4, 2, 2]]
    assert saturated.tolist() == [True, True, True]
    counts, saturated = counts_of(data[2:], np.array([0, 1]), np.ones(2), np.full(2, 3.0))
    assert counts.tolist() == [[1, 2]] and saturated.tolist() == [False]


def test_the_daq_frames_a_frame_asked_for_alone_as_it_frames_a_buffered_one():
    """Fast mode asks the physics for one frame at a time, and such a frame is framed without the buffer of
    unframed samples. Frames of a few samples, whole frames and larger chunks, within and beyond a range, give
    the same counts, flags and bytes either way, and the counts and flags the NumPy reference gives."""
    frames = {}
    for direct in (True, False):
        rig = EmulatedRig(RigDouble(), paced=False, name=f"frames{direct}")
        daq = rig.daq
        daq.points = 16
        daq.input_range[0] = 1e-3            # force saturates at 0.1 N (sensitivity 0.01 V/N)
        if not direct:                       # every chunk through the buffer, as before the direct path
            daq.capture = lambda data, daq=daq: daq._frame_buffered(*daq.quantise(data)) if daq.acquiring else None
        daq.start_acquisition()
        rng = np.random.default_rng(3)
        for k, size in enumerate((16, 3, 13, 16, 40, 16, 1, 15, 16, 16)):
            data = rng.normal(0.0, [0.02, 1.0, 1.0], (size, 3))
            if k % 2:
                data[size // 2, 0] *= 20.0   # past the force range
            counts, flags = daq.quantise(data)
            reference = _quantised_with_clip(daq, data)
            assert np.array_equal(counts, reference[0]) and np.array_equal(flags, reference[1])
            daq.capture(data)
        daq.stop_acquisition()
        frames[direct] = daq.output.take(1 << 20)
    assert frames[True] == frames[False] and len(frames[True]) > 0
