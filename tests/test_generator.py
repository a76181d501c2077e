"""A bench function generator (emulated 33500B) as the shaker controller: dialect, driver ramp, campaign."""
from pathlib import Path

import numpy as np
import pytest
import serial

import drivers
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.session.writer import open_session
from drivers import ArmingRefused, GeneratorShaker, InstrumentError, OutputGuard, SerialShaker, WrongDevice
from drivers.emulator import EmulatedRig, register
from drivers.generator import RAMP_STEP, Family, generator_family
from drivers.interfaces import Identity
from drivers.serve import EmulatorServer
from drivers.settings import GENERATOR, SC1
from drivers.simulation.rig import load_rig

from rig_double import RigDouble
from test_campaign import assert_matches_receptance, plan

RIGS = Path(__file__).parent / "rigs"


def ask(port, line: bytes) -> bytes:
    port.write(line + b"\n")
    return port.readline()


def test_the_emulated_33500b_speaks_its_own_dialect_without_ramp_or_watchdog():
    with EmulatedRig(RigDouble(), paced=True, name="gen-dialect", shaker_model="33500B") as rig:
        register(rig)
        port = serial.serial_for_url("sim://gen-dialect/shaker", timeout=1.0)
        assert ask(port, b"*IDN?") == b"Keysight Technologies,33521B,gen-dialect,1.0\n"
        assert ask(port, b"VOLT? MIN;:VOLT? MAX;:FREQ? MAX") == b"0.002;20;450\n"
        # out of range: clipped to the limit, not rejected, with the 33500B's text
        assert ask(port, b"VOLT 25;:SYST:ERR?") == b'-222,"Data out of range;value clipped to upper limit"\n'
        assert ask(port, b"VOLT?") == b"20\n"
        assert ask(port, b"SYST:WDOG 1;:SYST:ERR?") == b'-113,"Undefined header;SYST:WDOG"\n'
        assert ask(port, b"VOLT:RAMP 1;:SYST:ERR?").startswith(b"-113,")
        # no ramp: the output comes on at the set amplitude
        assert ask(port, b"VOLT 1;:OUTP ON;*OPC?") == b"1\n"
        assert rig.shaker.level == 0.5 and rig.backend.output and rig.backend.sine[1] == 0.5
        ask(port, b"VOLT 2;*OPC?")
        assert rig.backend.sine[1] == 1.0
        # no watchdog: a host silent far longer than any SC-1 watchdog leaves the output on
        fed = rig.time
        while rig.time - fed < 0.5:
            rig.changed.acquire()
            rig.changed.wait(0.05)
            rig.changed.release()
        assert rig.shaker.output_on
        port.close()


def test_open_shaker_chooses_the_driver_by_the_identity_and_the_driver_ramps_in_steps():
    with EmulatedRig(RigDouble(), paced=False, name="gen-ramp", shaker_model="33500B") as rig:
        register(rig)
        shaker = drivers.open_shaker("sim://gen-ramp/shaker", ramp_rate=5.0)
        try:
            assert isinstance(shaker, GeneratorShaker) and shaker.family.name == "Keysight 33500B/33600A"
            assert shaker.amplitude_range == (0.0, 10.0) and shaker.frequency_range == (1e-6, 450.0)
            with pytest.raises(InstrumentError, match="outside 0 to 10"):
                shaker.set_sine(10.0, 12.0)        # the generator would clip it: refused before sending
            with pytest.raises(InstrumentError, match="outside"):
                shaker.set_sine(1000.0, 0.1)
            shaker.set_sine(10.0, 0.5)
            assert rig.shaker.peak == 0.001        # held at the minimum while off
            with OutputGuard(shaker) as guard:
                guard.arm()
                assert rig.shaker.output_on and shaker.output_level() == 0.5
                shaker.set_sine(12.0, 0.2)
            levels = [args[1] for _, call, args in rig.backend.calls if call == "set_sine"]
            on = levels.index(0.001)
            ramp = np.array(levels[on:])
            steps = np.abs(np.diff(ramp))
            assert ramp.max() == 0.5 and ramp[-1] == pytest.approx(0.2)
            assert steps.max() <= 5.0 * RAMP_STEP * (1 + 1e-9)   # up and down, no step beyond the rate
            assert not rig.shaker.output_on and rig.shaker.peak == 0.001
        finally:
            shaker.close()


def arms_and_disarms(rig, shaker):
    shaker.set_sine(10.0, 0.05)
    with OutputGuard(shaker) as guard:
        guard.arm()
        assert rig.shaker.output_on
    assert not rig.shaker.output_on


@pytest.mark.slow
def test_a_generator_without_its_guardian_is_not_armed_unless_unguarded():
    with EmulatedRig(RigDouble(), paced=False, name="gen-tcp", shaker_model="33500B") as rig, \
            EmulatorServer(rig, "tcp") as server:
        url = server.urls["shaker"]
        with drivers.open_shaker(url, guardian=False) as shaker:
            assert not shaker.protection.survives_kill
            with OutputGuard(shaker) as guard, pytest.raises(ArmingRefused, match="--unguarded"):
                guard.arm()
            assert not rig.shaker.output_on
        with drivers.open_shaker(url, guardian=False, unguarded=True) as shaker:
            arms_and_disarms(rig, shaker)


def test_families_by_identity_and_the_settings_table():
    assert generator_family(Identity("Agilent Technologies", "33220A", "MY1", "2.0")).name.startswith("Keysight 332")
    assert generator_family(Identity("RIGOL TECHNOLOGIES", "DG1062Z", "DG1", "00.01")).name == "Rigol DG"
    assert generator_family(Identity("contactid", "SC-1", "x", "1.0")) is None
    assert not Family("x", ("a",), ("B",), False).matches(Identity("a", "C1", "", ""))
    assert SC1.watchdog.short == "SYST:WDOG" and GENERATOR.voltage.short == "VOLT"
    assert GENERATOR.frequency.command(10) == "FREQ 10.0" and GENERATOR.output.command("ON") == "OUTP ON"
    with pytest.raises(ValueError, match="VOLT:RAMP"):
        SC1.ramp.command(5000.0)
    with pytest.raises(ValueError, match="VPP|VRMS"):
        GENERATOR.unit.command("DBM")
    assert GENERATOR.watchdog is None and GENERATOR.ramp is None


def test_an_sc1_is_still_opened_as_the_sc1_and_another_instrument_is_refused():
    with EmulatedRig(RigDouble(), paced=False, name="gen-sc1") as rig:
        register(rig)
        with drivers.open_shaker("sim://gen-sc1/shaker") as shaker:
            assert type(shaker) is SerialShaker
        with pytest.raises(WrongDevice, match="DAQ-1.*not a contactid shaker controller"):
            drivers.open_shaker("sim://gen-sc1/daq")


GENERATOR_PLAN = """
[[stepped_sine]]
force = 0.5
start = 5.0
stop = 9.0
step = 1.0
direction = "up"
[limits]
max_force = 5.0
max_acceleration = 150.0
"""


@pytest.mark.slow
def test_a_stepped_sine_campaign_on_the_generator_matches_the_analytic_receptance(tmp_path):
    rig = load_rig(RIGS / "linear-shaker.toml")
    path = tmp_path / "gen.h5"
    with emulated_instruments(rig, seed=1, shaker_model="33500B") as inst:
        assert isinstance(inst.shaker, GeneratorShaker)
        summary = run_plan(plan(GENERATOR_PLAN), inst, path)
        assert not inst.shaker.output_enabled()
        events = inst.emulator.output_events()
    assert not summary.aborted and summary.runs == {"sine_0.5N_up": "complete"}
    assert events[-1].detail == "off: command"
    with open_session(path) as s:
        assert_matches_receptance(rig, s.run("sine_0.5N_up"))


@pytest.mark.slow
def test_a_guardian_that_cannot_start_stops_the_open_unless_unguarded(monkeypatch):
    import drivers.generator as generator

    def no_guardian(url, baudrate=115200):
        raise OSError(f"the guardian of {url} did not start: no processes left")

    monkeypatch.setattr(generator.Guardian, "start", staticmethod(no_guardian))
    with EmulatedRig(RigDouble(), paced=False, name="gen-noguard", shaker_model="33500B") as rig, \
            EmulatorServer(rig, "tcp") as server:
        url = server.urls["shaker"]
        with pytest.raises(InstrumentError, match="no processes left.*--unguarded"):
            drivers.open_shaker(url)
        with drivers.open_shaker(url, unguarded=True) as shaker:
            assert shaker.guardian is None and not shaker.protection.survives_kill
            arms_and_disarms(rig, shaker)


@pytest.mark.slow
def test_the_guardian_switches_off_a_hung_host_and_the_driver_reports_it():
    from drivers import OutputTripped
    from drivers.generator import HEARTBEAT
    from drivers.guardian import HOST_SILENCE
    with EmulatedRig(RigDouble(), paced=True, name="gen-hung", shaker_model="33500B") as rig, \
            EmulatorServer(rig, "tcp") as server, drivers.open_shaker(server.urls["shaker"]) as shaker:
        assert shaker.protection.guardian and shaker.protection.survives_kill
        shaker.set_sine(10.0, 0.05)
        with OutputGuard(shaker) as guard:
            guard.arm()
            hook = shaker._link._idle_hook
            shaker._link.set_idle_hook(None, 1.0)          # the heartbeat stops: a hung host
            silent_since = rig.time
            deadline = silent_since + 20 * HOST_SILENCE
            while rig.shaker.output_on and rig.time < deadline:
                with rig.changed:
                    rig.changed.wait(0.05)
            assert not rig.shaker.output_on
            off = rig.output_events()[-1]
            # the silence began with the last heartbeat, up to a heartbeat interval (and a poll) before the hook
            # was removed; the upper bound is loose for a loaded machine (the guardian may wait for a CPU)
            silence = off.time - silent_since
            assert off.detail == "off: command" and HOST_SILENCE - 2 * HEARTBEAT <= silence <= HOST_SILENCE + 3.0
            shaker._link.set_idle_hook(hook, 0.25)         # the host wakes up and hears of it
            while shaker.fault is None and rig.time < deadline:
                with rig.changed:
                    rig.changed.wait(0.05)
            with pytest.raises(OutputTripped):
                guard.check()


@pytest.mark.slow
def test_contactid_acquire_runs_a_campaign_on_a_served_generator_through_its_guardian(tmp_path):
    """The whole path a lab takes: `emulate --shaker-model 33500B --tcp` (paced: real time, as a bench) in one
    process, `acquire` in another, the generator behind its guardian."""
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[1]
    server = subprocess.Popen([sys.executable, "-m", "app.cli", "emulate", str(RIGS / "linear-shaker.toml"), "--tcp",
                               "127.0.0.1:0", "--shaker-model", "33500B"], cwd=root, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        urls = dict(server.stdout.readline().strip().split(": ", 1) for _ in range(2))
        # the path under test is the processes, the guardian and the generator's commands, not the settling, and
        # a paced bench spends real time on every period: the transient-aware lines, above the rig's modes (the
        # first line's force loop waits 80 periods, 16 s at 5 Hz and 4 s at 20 Hz)
        (tmp_path / "plan.toml").write_text("[[stepped_sine]]\nforce = 0.5\nstart = 20.0\nstop = 21.0\nstep = 0.5\n"
                                            "refine = false\n[settle]\nmethod = \"transient\"\n"
                                            "[limits]\nmax_force = 5.0\nmax_acceleration = 150.0\n")
        done = subprocess.run([sys.executable, "-m", "app.cli", "acquire", str(tmp_path / "plan.toml"), "-o",
                               str(tmp_path / "g.h5"), "--shaker", urls["shaker"], "--daq", urls["daq"],
                               "--excitation", "x1", "--quiet"], cwd=root, capture_output=True, text=True,
                              timeout=600)
    finally:
        server.terminate()
        server.wait(10)
    assert done.returncode == 0, done.stderr
    with open_session(tmp_path / "g.h5") as s:
        run = s.run("sine_0.5N_up")
        assert len(run.frequency) == 3
        assert_matches_receptance(load_rig(RIGS / "linear-shaker.toml"), run, rtol=1e-2, dofs=("x1",))


def test_discovery_finds_a_generator_as_the_shaker_controller():
    from drivers.discovery import find_instruments
    with EmulatedRig(RigDouble(), paced=False, name="gen-find", shaker_model="33500B") as rig:
        register(rig)
        found, probes = find_instruments(["sim://gen-find/daq", "sim://gen-find/shaker"], timeout=0.5)
        assert found == {"shaker": "sim://gen-find/shaker", "daq": "sim://gen-find/daq"}
        assert probes[1].identity.model == "33521B"
