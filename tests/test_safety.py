"""Everything that breaks a test drives the shaker output OFF, within 100 ms of emulated time.

Each test breaks something (an exception, an abort, a limit breach, a dropped link,
a signal, interpreter exit, a killed host, a silent host) and then asks the
emulated controller when its output went off.
"""
import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import serial

import drivers  # noqa: F401  (registers sim://)
from drivers.emulator import EmulatedRig, register
from drivers.errors import ArmingRefused, LinkLost
from drivers.interfaces import Block
from analysis.common.held_signals import signals_held
from drivers.safety import AbortLimits, LimitExceeded, OutputGuard, check_limits
from drivers.serve import EmulatorServer

from rig_double import RigDouble, bench, stream_start

ROOT = Path(__file__).resolve().parents[1]
LATENCY = 0.1
"""Longest the output may stay on after a fault (s of emulated time)."""
GUARDIAN_LATENCY = 1.0
"""Longest a bench generator's output may stay on after its host is killed (its guardian switches it off)."""

CHILD = """
import signal, sys, threading, time
# Ctrl-C as a user's shell delivers it: a test worker may have started this process with SIGINT ignored
signal.signal(signal.SIGINT, signal.default_int_handler)
from drivers import OutputGuard, open_daq, open_shaker
mode, shaker_url, daq_url, model = sys.argv[1:5]
shaker = open_shaker(shaker_url, **({"watchdog": 0.08 if mode == "kill" else 1.0} if model == "SC-1" else {}))
daq = open_daq(daq_url)
shaker.set_sine(10.0, 0.2)

def session():
    with OutputGuard(shaker) as guard:
        guard.arm()
        with daq.stream(50) as stream:
            for block in stream:
                guard.check(block)

if mode == "exit":
    threading.Thread(target=session, daemon=True).start()
    time.sleep(1.0)
else:
    session()
"""


def wait_for(condition, timeout=20.0):
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.005)


def last_off(rig):
    events = rig.output_events()
    assert events and events[-1].detail.startswith("off"), events
    return events[-1]


def test_arming_needs_a_guard_and_the_guard_starts_with_the_output_off():
    with bench() as (rig, shaker, daq):
        with pytest.raises(ArmingRefused):
            shaker.arm()
        assert not rig.shaker.output_on
        with rig.lock:
            rig.shaker.switch_on()  # as if left on by someone else
        with OutputGuard(shaker) as guard:
            assert not rig.shaker.output_on
            guard.arm()
            assert rig.shaker.output_on and shaker.armed
        assert not rig.shaker.output_on and not shaker.armed


@pytest.mark.parametrize("fault", ["exception", "abort"])
def test_exception_or_abort_mid_stream_switches_off(fault):
    with bench() as (rig, shaker, daq):
        daq.configure(frame_points=10)
        shaker.set_sine(10.0, 0.5)
        with pytest.raises(RuntimeError, match="analysis failed"):
            with OutputGuard(shaker) as guard:
                guard.arm()
                with daq.stream(20, buffered_blocks=1) as stream:
                    for count, block in enumerate(stream):
                        if count == 30:
                            fault_time = rig.time
                            if fault == "abort":
                                guard.trip("abort button")
                                assert not rig.shaker.output_on
                            raise RuntimeError("analysis failed")
        off = last_off(rig)
        assert off.detail == "off: command"
        assert 0.0 <= off.time - fault_time <= LATENCY
        assert guard.events[-1].kind == "end" and "RuntimeError: analysis failed" in guard.events[-1].detail
        assert any(e.kind == "trip" and e.detail == "abort button" for e in guard.events) == (fault == "abort")


def test_limit_breach_switches_off_within_100_ms_of_the_offending_sample():
    with bench() as (rig, shaker, daq):
        daq.configure(frame_points=10)
        shaker.set_sine(10.0, 0.5)  # 1.0 N at full amplitude, reached through the ramp
        with OutputGuard(shaker, limits=AbortLimits(max_force=0.8)) as guard:
            guard.arm()
            with pytest.raises(LimitExceeded) as info:
                with daq.stream(20, buffered_blocks=1) as stream:
                    for block in stream:
                        guard.check(block)
        breach = info.value.breach
        assert breach.channel == "force" and breach.peak > 0.8
        breach_time = (stream_start(rig) + breach.sample) / rig.sample_rate
        off = last_off(rig)
        assert off.detail == "off: command" and 0.0 <= off.time - breach_time <= LATENCY
        assert any(e.kind == "trip" and "limit" in e.detail for e in guard.events)


def test_dropped_shaker_link_is_reported_and_the_watchdog_switches_off():
    with EmulatedRig(RigDouble(), paced=True, name="droplink") as rig:
        register(rig)
        shaker = drivers.open_shaker("sim://droplink/shaker", watchdog=0.08)
        shaker.set_sine(10.0, 0.5)
        with OutputGuard(shaker) as guard:
            guard.arm()
            rig.inject("shaker", {"disconnect": 0})
            wait_for(lambda: shaker.fault is not None)
            with pytest.raises(LinkLost):
                guard.check()
            wait_for(lambda: not rig.shaker.output_on)
        off = last_off(rig)
        assert off.detail == "off: watchdog"
        assert off.time - rig.shaker.last_feed <= LATENCY
        assert any(e.kind == "fault" for e in guard.events)
        assert any(e.kind == "unconfirmed" for e in guard.events)
        shaker.close()


def test_a_silent_host_is_switched_off_by_the_instrument_watchdog():
    with EmulatedRig(RigDouble(), paced=True, name="silent") as rig:
        register(rig)
        port = serial.serial_for_url(f"sim://{rig.name}/shaker", timeout=1.0)
        port.write(b"SYST:WDOG 0.05;:VOLT 0.5;:OUTP ON;*OPC?\n")
        assert port.readline() == b"1\n"
        wait_for(lambda: not rig.shaker.output_on)
        off = last_off(rig)
        assert off.detail == "off: watchdog" and 0.05 < off.time - rig.shaker.last_feed <= 0.05 + LATENCY
        port.write(b"SYST:ERR?\n")
        assert port.readline() == b'201,"Watchdog expired; output switched off"\n'
        port.close()


def test_sigterm_in_process_switches_off_and_chains_to_the_previous_handler():
    calls = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: calls.append(signum))
    try:
        with bench() as (rig, shaker, daq):
            shaker.set_sine(10.0, 0.2)
            with OutputGuard(shaker) as guard:
                guard.arm()
                signal.raise_signal(signal.SIGTERM)
                assert calls == [signal.SIGTERM]
                wait_for(lambda: not rig.shaker.output_on)
                assert guard.tripped and any(e.kind == "emergency" and "sent" in e.detail for e in guard.events)
            assert last_off(rig).detail == "off: command"
        assert signal.getsignal(signal.SIGTERM) is not previous and calls == [signal.SIGTERM]
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_signal_in_a_held_block_switches_off_at_once_and_interrupts_at_the_block_end(ctrl_c):
    with bench() as (rig, shaker, daq):
        shaker.set_sine(10.0, 0.2)
        with OutputGuard(shaker) as guard:
            guard.arm()
            installed = signal.getsignal(signal.SIGINT)
            reached = []
            with pytest.raises(KeyboardInterrupt):
                with signals_held():
                    signal.raise_signal(signal.SIGINT)
                    wait_for(lambda: not rig.shaker.output_on)        # the output went off when the signal came
                    reached.append("end of block")
            assert reached == ["end of block"] and guard.tripped
            assert sum(e.kind == "emergency" for e in guard.events) == 1        # one stop for one signal
            assert signal.getsignal(signal.SIGINT) is installed


@pytest.mark.parametrize("guarded", [False, True])
def test_a_second_signal_in_a_held_block_interrupts_at_once_and_the_next_block_holds_again(ctrl_c, guarded):
    """Without a guard the block puts a holding handler in place; under a guard's handler it only counts."""
    with bench() as (rig, shaker, daq), (OutputGuard(shaker) if guarded else contextlib.nullcontext()):
        installed = signal.getsignal(signal.SIGINT)
        for _ in range(2):
            reached = []
            with pytest.raises(KeyboardInterrupt):
                with signals_held():
                    signal.raise_signal(signal.SIGINT)
                    reached.append("after the first")
                    signal.raise_signal(signal.SIGINT)
                    reached.append("after the second")
            assert reached == ["after the first"]
            assert signal.getsignal(signal.SIGINT) is installed
            with pytest.raises(KeyboardInterrupt):             # nothing left held from before
                with signals_held():
                    signal.raise_signal(signal.SIGINT)
                    reached.append("held")
            assert reached[-1] == "held"


@pytest.mark.parametrize("guarded", [False, True])
def test_a_signal_held_keeps_nothing_of_the_call_it_interrupted(ctrl_c, guarded):
    """A held signal that kept the frame it came in kept that call's locals alive to the block's end: a view of
    a buffer among them forbade the buffer's resize (the DAQ's stream decoder failed on its next frame)."""
    import weakref

    class Local:
        pass

    buffer, kept = bytearray(b"0123456789"), []

    def interrupted():
        view, local = memoryview(buffer)[2:6], Local()
        kept.append(weakref.ref(local))
        signal.raise_signal(signal.SIGINT)
        return bytes(view)

    seen = []
    with bench() as (rig, shaker, daq), (OutputGuard(shaker) if guarded else contextlib.nullcontext()):
        with pytest.raises(KeyboardInterrupt):
            with signals_held():
                seen.append(interrupted())
                seen.append(kept[0]())                          # the call's locals went with it
                del buffer[:4]                                  # no view of the buffer is left
    assert seen == [b"2345", None] and buffer == b"456789"


@pytest.mark.parametrize("guarded", [False, True])
def test_a_second_signal_acts_at_once_in_held_blocks_within_one_another(ctrl_c, guarded):
    """Held steps nest (a compile within a compile, a cache save within it): a second signal acts at once however
    deep, and the handlers are as they were after the outermost block."""
    with bench() as (rig, shaker, daq), (OutputGuard(shaker) if guarded else contextlib.nullcontext()):
        installed = signal.getsignal(signal.SIGINT)
        reached = []
        with pytest.raises(KeyboardInterrupt):
            with signals_held():
                with signals_held():
                    with signals_held():
                        signal.raise_signal(signal.SIGINT)
                        reached.append("after the first")
                        signal.raise_signal(signal.SIGINT)
                        reached.append("after the second")
        assert reached == ["after the first"] and signal.getsignal(signal.SIGINT) is installed
        with pytest.raises(KeyboardInterrupt):                 # the next block holds again
            with signals_held():
                with signals_held():
                    signal.raise_signal(signal.SIGINT)
                    reached.append("held")
        assert reached[-1] == "held"


def test_a_held_block_without_a_signal_or_outside_the_main_thread_leaves_the_handlers_as_they_were():
    import threading
    before = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]
    with signals_held():
        assert signal.getsignal(signal.SIGINT) not in before          # held within
    assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] == before
    seen = []

    def in_a_worker():
        with signals_held():                                           # signal.signal would raise here
            seen.append(signal.getsignal(signal.SIGINT))

    worker = threading.Thread(target=in_a_worker)
    worker.start()
    worker.join()
    assert seen == before[:1]


@pytest.mark.parametrize("model, mode, action, detail, returncodes", [
    ("SC-1", "stream", signal.SIGTERM, "off: command", {143}),
    ("SC-1", "stream", signal.SIGINT, "off: command", {-signal.SIGINT, 130, 1}),
    ("SC-1", "kill", signal.SIGKILL, "off: watchdog", {-signal.SIGKILL}),
    ("SC-1", "exit", None, "off: command", {0}),
    # a bench generator has no watchdog: its guardian process switches it off when the host is killed
    ("33500B", "stream", signal.SIGTERM, "off: command", {143}),
    ("33500B", "stream", signal.SIGINT, "off: command", {-signal.SIGINT, 130, 1}),
    ("33500B", "kill", signal.SIGKILL, "off: command", {-signal.SIGKILL}),
    ("33500B", "exit", None, "off: command", {0}),
])
@pytest.mark.slow
def test_a_guarded_session_in_another_process_always_ends_with_the_output_off(model, mode, action, detail,
                                                                              returncodes):
    with EmulatedRig(RigDouble(), paced=True, name=f"child-{mode}", shaker_model=model) as rig, \
            EmulatorServer(rig, "tcp") as server:
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        child = subprocess.Popen([sys.executable, "-c", CHILD, mode, server.urls["shaker"], server.urls["daq"], model],
                                 cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            wait_for(lambda: rig.shaker.output_on and rig.daq.acquiring or child.poll() is not None, timeout=60)
            assert child.poll() is None, child.communicate()[1].decode()
            fault_time = rig.time
            if action is not None:
                child.send_signal(action)
            child.wait(timeout=120)           # a guard for a loaded machine: the latency is checked below
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
        assert child.returncode in returncodes, child.stderr.read().decode()
        wait_for(lambda: not rig.shaker.output_on)
        off = last_off(rig)
        assert off.detail == detail
        if action is not None:
            assert off.time - fault_time <= (GUARDIAN_LATENCY if model != "SC-1" and mode == "kill" else LATENCY)


def test_limits_from_a_plan_table_and_the_check_function():
    limits = AbortLimits.from_table({"max_force": 5.0, "max_acceleration": 50.0})
    data = np.zeros((10, 3))
    data[7, 1] = -60.0
    block = Block(data, ("force", "acc:x1", "volts"), ("N", "m/s^2", "V"), 100.0, first_sample=1000)
    breach = check_limits(block, limits)
    assert (breach.channel, breach.peak, breach.limit, breach.sample) == ("acc:x1", 60.0, 50.0, 1007)
    data[7, 1] = 0.0
    data[:, 2] = 1e6  # a channel with no limit
    assert check_limits(block, limits) is None
    with pytest.raises(Exception, match=r"\[limits\].max_force"):
        AbortLimits.from_table({"max_force": -1.0}, "plan.toml")
    with pytest.raises(Exception, match="unknown key"):
        AbortLimits.from_table({"max_speed": 1.0})


def test_the_check_of_all_peaks_at_once_finds_what_the_search_channel_by_channel_finds():
    """check_limits first compares each column's peak with its limit; only a block beyond one is searched. On
    blocks with breaches in any column, at a limit exactly, NaNs, a force-only limit and none, it reports what
    the per-channel search alone reports."""
    rng = np.random.default_rng(5)
    channels, units = ("force", "acc:x1", "acc:x2", "volts"), ("N", "m/s^2", "m/s^2", "V")
    cases = [AbortLimits(5.0, 50.0), AbortLimits(max_force=5.0), AbortLimits()]

    def searched(block, limits):
        for column, unit in enumerate(block.units):
            limit = limits.max_force if unit == "N" else limits.max_acceleration if unit == "m/s^2" else None
            over = np.flatnonzero(np.abs(block.data[:, column]) > limit) if limit is not None else []
            if len(over):
                return (block.channels[column], float(np.abs(block.data[:, column]).max()), limit,
                        block.first_sample + int(over[0]))
        return None

    for trial in range(300):
        data = rng.normal(0.0, 1.0, (64, 4)) * [2.0, 20.0, 20.0, 1e6]
        if trial % 3 == 0:
            data[rng.integers(64), rng.integers(3)] = [5.0, 50.0, -50.0][trial % 3]   # at the limit: no breach
        if trial % 7 == 0:
            data[rng.integers(64), rng.integers(4)] = np.nan
        for limits in cases:
            block = Block(data, channels, units, 512.0, first_sample=trial)
            breach = check_limits(block, limits)
            found = None if breach is None else (breach.channel, breach.peak, breach.limit, breach.sample)
            assert repr(found) == repr(searched(block, limits))      # repr: a NaN peak equals a NaN peak


class FrozenWallClock:
    """Stands in for the ``time`` module of the emulated shaker: a wall clock that moves only when told."""

    def __init__(self):
        self.now = 1000.0

    def monotonic(self):
        return self.now


def test_a_fast_rig_running_ahead_of_real_time_does_not_trip_a_host_that_feeds_in_real_time(monkeypatch):
    """The watchdog needs the host silent by both clocks: 5 s of emulated time pass within no wall time (the
    rig far faster than real time) and the output stays on; once the wall clock says the host is gone, it goes
    off at the next frame, with error 201."""
    import drivers.emulator.shaker as shaker_firmware
    wall = FrozenWallClock()
    monkeypatch.setattr(shaker_firmware, "time", wall)
    with EmulatedRig(RigDouble(), paced=False, name="ahead") as rig:
        register(rig)
        port = serial.serial_for_url("sim://ahead/shaker", timeout=1.0)
        port.write(b"SYST:WDOG 1;:VOLT 0.5;:OUTP ON;*OPC?\n")
        assert port.readline() == b"1\n"
        daq = serial.serial_for_url("sim://ahead/daq", timeout=1.0)
        daq.write(b"INIT\n")
        frame = 20 + 4 * 20 * 3 + 4           # default frame: 20 samples of 3 channels
        daq.read(frame * 250)                  # 5 s of emulated time
        assert rig.time - rig.shaker.last_feed >= 5.0 and rig.shaker.output_on
        wall.now += shaker_firmware.FAST_HOST_SILENCE - 0.01
        daq.read(frame)
        assert rig.shaker.output_on        # silent, but not yet for FAST_HOST_SILENCE: slow, not gone
        wall.now += 0.02
        daq.read(frame)
        assert not rig.shaker.output_on
        off = last_off(rig)
        assert off.detail == "off: watchdog" and off.time - rig.shaker.last_feed <= 5.0 + 2 * LATENCY
        port.write(b"SYST:ERR?\n")
        assert port.readline() == b'201,"Watchdog expired; output switched off"\n'
        port.close()
        daq.close()
