"""A campaign never reports success on bad data: repeated acquisitions over TCP, runs that miss their force,
the first line's approach, unresolved sensors, exit codes and progress output."""
import io
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

import drivers
from app.campaign.engine import _added, stored_frf
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import ProgressBar, run_plan
from app.campaign.plan import parse_plan
from app.session.writer import open_session
from drivers.interfaces import Block
from drivers.simulation.rig import load_rig
from served_rig import FIVE_LINES, ForcePeaks, fixed_count_acquisition, served_paper_2dof

RIGS = Path(__file__).parent / "rigs"
ROOT = Path(__file__).resolve().parents[1]
# one DOF on an ideal force source of 0.1 N/V: at most 1 N from the generator's 10 V
WEAK_SOURCE = """
name = "weak-source"
[structure]
type = "lumped"
dofs = ["x"]
mass = [[1.0]]
stiffness = [[4000.0]]
rayleigh = [2.0, 0.0]
[excitation]
dof = "x"
gain = 0.1
[sensors]
dofs = ["x"]
[daq]
sample_rate = 256.0
"""


def plan(text: str):
    import tomllib
    return parse_plan(tomllib.loads(text), text, "plan.toml")


def cli(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "app.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


@pytest.fixture
def tcp_emulator():
    """paper-2dof served over TCP (fast) from a thread of this process: {"shaker": url, "daq": url}."""
    with served_paper_2dof() as urls:
        yield urls


@pytest.mark.slow
def test_a_repeated_acquisition_holds_its_force_like_the_first(tmp_path, tcp_emulator):
    """issue 13 §1: the second of two identical acquisitions on one emulator held 0.05 N instead of 0.8 N,
    stored FRF x2 = 0 and still said "complete" with exit 0. Both must now be complete at 0.8 N."""
    (tmp_path / "plan.toml").write_text(FIVE_LINES)
    for name in ("A.h5", "B.h5"):
        done = cli("acquire", tmp_path / "plan.toml", "-o", tmp_path / name, "--shaker", tcp_emulator["shaker"],
                   "--daq", tcp_emulator["daq"], "--excitation", "x2")
        assert done.returncode == 0, done.stderr
        assert "force within 1 % of target at every line" in done.stdout
        with open_session(tmp_path / name) as s:
            run = s.run("sine_0.8N_up")
            assert run.status == "complete" and len(run.frequency) == 5
            np.testing.assert_allclose(run.arrays["force_amplitude"], 0.8, rtol=0.01)
            assert run.arrays["force_on_target"].all() and run.arrays["steady"].all()
            assert np.all(run.frf["x2"] != 0)


def test_a_reconnection_starts_from_the_reset_state(tcp_emulator):
    """What a previous client leaves behind -- settings, replies it never read, half a command -- is gone
    when the driver opens the instrument."""
    host, port = tcp_emulator["shaker"].removeprefix("socket://").split(":")
    with socket.create_connection((host, int(port))) as raw:
        raw.sendall(b"FREQ 3;:VOLT:UNIT VPP;:VOLT 4;:VOLT:RAMP 0.01\n*IDN?\nFREQ?\nFREQ 1")
        threading.Event().wait(0.3)
    with drivers.open_shaker(tcp_emulator["shaker"]) as shaker:
        assert shaker._scpi.query("VOLT?") == "0.1"            # *RST: 0.05 V peak
        assert float(shaker._scpi.query("FREQ?")) == 10.0       # neither 3 nor 15 ("FREQ 1" + "5")
        assert shaker.ramp_rate == 2.0 and not shaker.output_enabled()
        assert shaker.errors() == []


@pytest.mark.slow
def test_a_run_that_cannot_reach_its_force_fails_and_exits_3(tmp_path):
    (tmp_path / "weak.toml").write_text(WEAK_SOURCE)
    (tmp_path / "plan.toml").write_text("[[stepped_sine]]\nforce = 2.0\nstart = 8.0\nstop = 9.0\nstep = 0.5\nrefine = false\n"
                                        "[limits]\nmax_force = 5.0\nmax_acceleration = 500.0\n")
    done = cli("simulate", tmp_path / "weak.toml", tmp_path / "plan.toml", "-o", tmp_path / "w.h5")
    assert done.returncode == 3, done.stderr
    assert "force OFF TARGET at 3 of 3 line(s)" in done.stdout and "INCOMPLETE" in done.stdout
    assert "sine_2N_up: force missed its 2 N target by more than 5 % at 3 of 3 line(s)" in done.stderr
    with open_session(tmp_path / "w.h5") as s:
        run = s.run("sine_2N_up")
        assert run.status == "failed" and "force missed" in run.attrs["end_reason"]
        assert not run.arrays["force_on_target"].any()
        np.testing.assert_allclose(run.arrays["drive"], 10.0)        # it tried: the generator's largest
        assert any("target 2 N (-50.00 %, tolerance 1 %)" in e["message"] for e in s.events())


@pytest.mark.slow
def test_a_run_whose_lines_sit_at_the_settling_limit_fails():
    rig = load_rig(RIGS / "linear-shaker.toml")
    text = "[[stepped_sine]]\nforce = 0.5\nstart = 6.0\nstop = 7.0\nstep = 0.5\nrefine = false\n" \
           "[settle]\ntolerance = 1e-9\nmax_periods = 30\n[limits]\nmax_force = 5.0\nmax_acceleration = 150.0\n"
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan(text), inst, Path(inst.emulator.name + ".h5"))
    Path(inst.emulator.name + ".h5").unlink()
    assert summary.runs == {"sine_0.5N_up": "failed"} and not summary.complete
    assert "3 of 3 line(s) hit the settling limit" in summary.failed["sine_0.5N_up"]


def _on_the_shaker_rig(tmp_path, text: str) -> tuple[dict, dict]:
    """``text`` run on the voltage-driven rig, complete: each run's peak force and its arrays, by run name."""
    peaks = ForcePeaks()
    with emulated_instruments(load_rig(RIGS / "linear-shaker.toml")) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "o.h5", listener=peaks)
    assert summary.complete, summary.text()
    with open_session(tmp_path / "o.h5") as s:
        return peaks.peak, {name: s.run(name).arrays for name in s.run_names()}


@pytest.mark.slow
def test_the_first_line_approaches_its_force_from_below(tmp_path):
    """A gain learnt at the structure's resonance (an electrodynamic shaker gives little force there) would
    drive the next run, at the drive point's anti-resonance (more than twice the N/V), far over its abort limit; the
    first line starts low and approaches its target instead."""
    peak, runs = _on_the_shaker_rig(tmp_path, "[[stepped_sine]]\nforce = 0.1\nstart = 7.0\nstop = 7.2\nstep = 0.1\n"
                                    "refine = false\n[[stepped_sine]]\nforce = 0.5\nstart = 10.0\nstop = 10.2\n"
                                    "step = 0.1\nrefine = false\n[limits]\nmax_force = 1.0\nmax_acceleration = 150.0\n")
    assert peak["sine_0.5N_up"] < 0.5 * 1.1
    first, second = runs["sine_0.1N_up"], runs["sine_0.5N_up"]
    gain = (first["force_amplitude"][-1] / first["drive"][-1], second["force_amplitude"][0] / second["drive"][0])
    assert 0.5 * gain[1] / gain[0] > 1.0    # the old start, target / last gain, breached the 1 N limit


@pytest.mark.slow
def test_a_run_that_starts_where_another_held_its_level_starts_at_half_that_drive(tmp_path):
    """Up then down: the down run's first line is the up run's last, at the same force, so the drive that held it
    says what it needs. It starts at half that drive (one correction) instead of approaching from 0.05 V; the up
    run, with nothing measured at its first line, still approaches from below."""
    peak, runs = _on_the_shaker_rig(tmp_path, "[[stepped_sine]]\nforce = 0.5\nstart = 12.0\nstop = 12.2\nstep = 0.1\n"
                                    "direction = \"both\"\nrefine = false\n[limits]\nmax_force = 2.0\n"
                                    "max_acceleration = 150.0\n")
    assert peak["sine_0.5N_down"] < 0.5 * 1.1
    up, down = runs["sine_0.5N_up"], runs["sine_0.5N_down"]
    assert up["control_steps"][0] >= 3                     # 0.05 V doubled towards the 0.5 N it needs
    assert down["control_steps"][0] <= 1
    np.testing.assert_allclose(down["drive"][0], up["drive"][-1], rtol=0.05)


@pytest.mark.slow
def test_a_sensor_that_saw_nothing_is_stored_as_nan_not_zero(tmp_path):
    assert np.isnan(stored_frf({"a": 0j, "b": 1 + 2j})["a"]) and stored_frf({"b": 1 + 2j})["b"] == 1 + 2j
    # paper-2dof: at 0.05 N the friction on x2 (0.1 N) holds it: the accelerometers read exactly 0
    text = "[[stepped_sine]]\nforce = 0.05\nstart = 2.0\nstop = 2.5\nstep = 0.5\nrefine = false\n" \
           "[settle]\nmax_periods = 60\n[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n"
    with emulated_instruments(load_rig("paper-2dof")) as inst:
        run_plan(plan(text), inst, tmp_path / "n.h5")
    with h5py.File(tmp_path / "n.h5", "r") as f:
        x2 = f["runs/sine_0.05N_up/frf/x2"][:]
        x1 = f["runs/sine_0.05N_up/frf/x1"][:]            # x2 held, x1 (driven through it) too
        assert np.all(np.isnan(x2)) and np.all(np.isnan(x1))
        assert np.all(np.isnan(f["runs/sine_0.05N_up/frf_std/x2"][:]))
        messages = [m.decode() for m in f["events"]["message"]]
    assert sum("no signal on acc:x2" in m for m in messages) == 2


@pytest.mark.slow
def test_exit_codes_name_the_failing_instrument(tmp_path):
    (tmp_path / "plan.toml").write_text(FIVE_LINES)
    with socket.socket() as probe, socket.socket() as other:      # ports nobody listens on
        probe.bind(("127.0.0.1", 0))
        other.bind(("127.0.0.1", 0))
        port, daq_port = probe.getsockname()[1], other.getsockname()[1]
    done = cli("acquire", tmp_path / "plan.toml", "-o", tmp_path / "x.h5", "--shaker", f"socket://127.0.0.1:{port}",
               "--daq", f"socket://127.0.0.1:{daq_port}", "--excitation", "x2")
    assert done.returncode == 4
    assert done.stderr.startswith(f"contactid: instrument failure: shaker at socket://127.0.0.1:{port}: cannot open")
    assert not (tmp_path / "x.h5").exists()
    done = cli("acquire", tmp_path / "missing.toml", "-o", tmp_path / "x.h5", "--shaker", "socket://127.0.0.1:1",
               "--daq", "socket://127.0.0.1:2", "--excitation", "x2")
    assert done.returncode == 2 and "missing.toml" in done.stderr
    assert "4 link or instrument failure" in " ".join(cli("acquire", "--help").stdout.split())


def test_progress_counts_planned_plus_added_lines_and_writes_plain_lines_to_a_log():
    planned = [1.0, 2.0, 3.0]
    assert _added(planned, 1.0, 1.0, 1) == 0 and _added(planned, 1.5, 1.0, 3) == 2
    assert _added(planned, 2.0, -1.0, 4) == 2          # down: 3 and 2 passed, 4 measured
    log = io.StringIO()
    bar = ProgressBar(stream=log)
    bar.run_started("sine_1N_up", type("Spec", (), {"force": 1.0})())
    for done in range(1, 31):              # refinement adds a line every third line, 10 in all
        added = min(done // 3, 10)
        if added:
            bar.lines_added(20, added)
        bar.progress(done, 20 + added, 1.0, "sine_1N_up")
    bar.run_ended("sine_1N_up", "complete")
    text = log.getvalue()
    assert "\r" not in text and len(text.splitlines()) <= 12
    assert "sine_1N_up: complete (30/20+10 lines)" in text
    counts = re.findall(r"(\d+)/(\d+)(?:\+(\d+))? lines", text)
    assert len(counts) > 5 and all(int(d) <= int(p) + int(a or 0) for d, p, a in counts)


@pytest.mark.slow
def test_a_link_lost_mid_run_names_the_instrument_and_is_an_instrument_failure(tmp_path):
    rig = load_rig(RIGS / "linear-shaker.toml")
    text = "[[stepped_sine]]\nforce = 0.5\nstart = 6.0\nstop = 9.0\nstep = 0.5\n[limits]\nmax_force = 5.0\n" \
           "max_acceleration = 150.0\n"
    with emulated_instruments(rig, faults={"daq": {"disconnect": 300_000}}) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "l.h5")
        assert not inst.shaker.output_enabled()
    assert summary.aborted_by_instrument and not summary.complete
    assert summary.aborted.startswith(f"DAQ at {inst.daq.url}: ")
    with open_session(tmp_path / "l.h5") as s:
        run = s.run("sine_0.5N_up")
        assert run.status == "aborted" and run.attrs["end_reason"].startswith("DAQ at ")


def test_the_demo_stops_with_3_on_an_incomplete_campaign(monkeypatch, tmp_path, capsys):
    import app.demo
    from app.campaign.engine import CampaignSummary
    from app.cli import main

    summary = CampaignSummary(runs={"sine_1N_up": "failed"}, failed={"sine_1N_up": "force missed"})

    def run_plan_failing(*args, **kwargs):
        return summary

    monkeypatch.setattr(app.demo, "run_plan", run_plan_failing)
    assert main(["demo", "--quick", "--out", str(tmp_path / "demo")]) == 3
    assert "the campaign is incomplete, nothing is identified from it: force missed" in capsys.readouterr().err


@pytest.mark.slow
def test_fixed_count_settling_over_a_fast_tcp_emulator_holds_every_line_and_never_overshoots(tmp_path, tcp_emulator):
    """`[settle] fixed_periods = 10` on paper-2dof served by `emulate --fast` over TCP once failed or aborted in 5
    of 24 acquisitions, and drove the force past its 0.8 N target in 24 of 24 (1.6 to 4.8 N). Three acquisitions
    in a row on one served rig: every one complete, every line within the control tolerance, the force never
    above its target (the approach from 0.05 V doubles to exactly 0.8 V). The force peak caught every such run
    measured: three runs miss a loop that overshoots with probability below 0.01 if each escapes with 1/5 (the
    95 % bound of 0 in 24 is 0.12). The failure rate over many acquisitions is benchmarks/fixed_count_settling.py's
    (docs/performance.md)."""
    for attempt in range(3):
        assert fixed_count_acquisition(tcp_emulator, tmp_path / f"f{attempt}.h5") == [], f"acquisition {attempt}"


class LaggingBench:
    """An ideal force source (1 N/V, amplitude ramped at 2 V/s) and one accelerometer (receptance
    ``RECEPTANCE``), read through a transport that holds ``backlog`` samples: a generator command lands that
    many samples after the last one the host has read, as on a fast emulator behind full socket buffers. It is
    the shaker and the stream of a :class:`LineMeter` at once."""

    fs = 256.0
    ramp_rate = 2.0
    amplitude_range = (0.0, 10.0)
    RECEPTANCE = 2e-3 * np.exp(-0.3j)     # m/N, the same at every frequency

    def __init__(self, backlog: int, frequency: float, drive: float):
        self.backlog = backlog
        self.read_to = 0
        self.changes = [(0, frequency, drive)]          # (sample where it lands, Hz, V peak)
        self.phase = self.level = 0.0
        self.frequency, self.target = frequency, drive
        self.peak = 0.0                                 # largest amplitude the source ever gave, N

    def set_sine(self, frequency, amplitude):
        self.changes.append((self.read_to + self.backlog, frequency, amplitude))

    def pending(self):
        return 0

    def sync(self, timeout=5.0):
        return True

    def read(self, timeout=None):
        data = np.empty((64, 2))
        i = 0
        while i < 64:
            k = self.read_to + i
            while self.changes and self.changes[0][0] <= k:
                _, self.frequency, self.target = self.changes.pop(0)
            n = min(64, self.changes[0][0] - self.read_to) - i if self.changes else 64 - i
            ramp = self.level + np.sign(self.target - self.level) * self.ramp_rate / self.fs * np.arange(1, n + 1)
            level = np.minimum(ramp, self.target) if self.target >= self.level else np.maximum(ramp, self.target)
            phase = self.phase + 2 * np.pi * self.frequency / self.fs * np.arange(n)
            h = self.RECEPTANCE * -(2 * np.pi * self.frequency) ** 2          # accelerance, (m/s^2)/N
            data[i:i + n] = np.column_stack([level * np.sin(phase), abs(h) * level * np.sin(phase + np.angle(h))])
            self.level, self.phase = level[-1], phase[-1] + 2 * np.pi * self.frequency / self.fs
            self.peak = max(self.peak, level.max())
            i += n
        block = Block(data, ("force", "acc:x"), ("N", "m/s^2"), self.fs, self.read_to)
        self.read_to += 64
        return block


@pytest.mark.parametrize("fixed_periods", [10, 0])
def test_the_line_meter_measures_only_data_that_show_the_last_generator_change(fixed_periods):
    """issue 13: behind a transport holding 47 s of stream (a fast emulator over TCP) every change shows in the
    data long after the 10 s the meter used to wait; fixed-count settling then took the stale records as
    settled, corrected the force on them and doubled the drive past its target (5.2 N at a 5 N limit). Each
    line must be measured on data after its last change: the approach from below never passes the target,
    and the next line holds its force with no correction at all."""
    from app.campaign.acquisition import RecordFeed
    from app.campaign.plan import SettleSpec
    from app.campaign.stepped_sine import LineMeter

    bench = LaggingBench(backlog=47 * 256, frequency=1.0, drive=0.05)
    feed = RecordFeed(bench, check=lambda block: None, on_gap=lambda gap: None)
    meter = LineMeter(bench, feed, ["force", "acc:x"], ["x"], bench.fs, SettleSpec(fixed_periods=fixed_periods),
                      control_tolerance=0.01)
    first = meter.measure(1.0, 0.8, 0.05)
    second = meter.measure(1.5, 0.8, first.drive)
    assert bench.peak <= 0.8 + 1e-12                     # doublings from 0.05 V: 0.1, 0.2, 0.4, 0.8
    assert first.control_steps == 4 and second.control_steps == 0
    for m in (first, second):
        assert m.on_target and abs(abs(m.force) - 0.8) < 1e-3
        np.testing.assert_allclose(m.frf["x"], bench.RECEPTANCE, rtol=1e-3)
    assert meter.latency >= 47 * 256 - 64 * 14           # the wait learnt the transport's backlog


def test_a_change_shows_only_in_the_direction_of_the_drive_and_the_wait_needs_both_clocks():
    from app.campaign.stepped_sine import MAX_LATENCY_S, ChangeWait, LineMeter
    assert LineMeter._moved(0.1, 0.15, 2.0) and LineMeter._moved(0.2, 0.1, 0.5) and LineMeter._moved(0.0, 0.1, 2.0)
    assert not LineMeter._moved(0.1, 0.05, 2.0)          # a stale record reading low is no larger drive
    assert not LineMeter._moved(0.2, 0.4, 0.5) and not LineMeter._moved(0.1, 0.12, 2.0)
    now = time.monotonic()
    stream = int(256 * MAX_LATENCY_S)
    assert ChangeWait(256.0, stream, now - MAX_LATENCY_S - 1).expired()
    assert not ChangeWait(256.0, 100 * stream, now).expired()          # a fast transport: lots of stream at once
    assert not ChangeWait(256.0, stream - 1, now - 100 * MAX_LATENCY_S).expired()   # a slow host
