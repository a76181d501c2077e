"""Campaigns through the real drivers and the in-process emulator, against analytic truth."""
import threading
from pathlib import Path

import numpy as np
import pytest

from analysis import InputError
from app.campaign.engine import CampaignListener
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from app.session.writer import SessionWriteError, SessionWriter, open_session
from drivers.simulation.rig import load_rig

RIGS = Path(__file__).parent / "rigs"


def plan(text: str):
    import tomllib
    return parse_plan(tomllib.loads(text), text, "plan.toml")


def output_events(inst):
    return [e for e in inst.emulator.output_events()]


LINEAR_PLAN = """
[random]
force_rms = 0.2
band = [2.0, 40.0]
duration = 64.0
[[stepped_sine]]
force = 0.5
start = 5.0
stop = 17.0
step = 0.5
direction = "up"
[limits]
max_force = 5.0
max_acceleration = 150.0
"""


@pytest.fixture(scope="module")
def linear_session(tmp_path_factory):
    rig = load_rig(RIGS / "linear-shaker.toml")
    path = tmp_path_factory.mktemp("campaign") / "linear.h5"
    with emulated_instruments(rig, seed=1) as inst:
        summary = run_plan(plan(LINEAR_PLAN), inst, path)
        assert not inst.shaker.output_enabled()
    return rig, path, summary


def assert_matches_receptance(rig, run, rtol=5e-3, dofs=("x1", "x2")):
    """The run's FRF at each DOF against the rig structure's analytic receptance driven at x1."""
    f = run.arrays["measured_frequency"]
    H = rig.structure.frf(2 * np.pi * f, columns=["x1"])[:, :, 0]
    for p, dof in enumerate(dofs):
        np.testing.assert_allclose(run.frf[dof], H[:, p], rtol=rtol)


@pytest.mark.slow
def test_stepped_sine_matches_the_analytic_receptance(linear_session):
    rig, path, summary = linear_session
    assert not summary.aborted and summary.runs == {"random": "complete", "sine_0.5N_up": "complete"}
    with open_session(path) as s:
        run = s.run("sine_0.5N_up")
        assert_matches_receptance(rig, run)
        # refinement added lines near the two resonances
        assert len(run.frequency) > 25
        assert run.units["frf/x1"] == "m/N" and run.attrs["excitation_dof"] == "x1"


def test_force_is_held_at_every_line_although_the_shaker_loses_force_at_resonance(linear_session):
    rig, path, summary = linear_session
    with open_session(path) as s:
        run = s.run("sine_0.5N_up")
        force = run.arrays["force_amplitude"]
        drive = run.arrays["drive"]
        np.testing.assert_allclose(force, 0.5, rtol=0.01)
        # the drive needed per newton varies strongly: that is the force drop the loop compensates
        gain = force / drive
        assert gain.max() > 3 * gain.min()
        assert run.arrays["steady"].all()
    assert summary.worst_force_error <= 0.01


def test_random_run_h1_is_within_its_random_error(linear_session):
    rig, path, _ = linear_session
    with open_session(path) as s:
        run = s.run("random")
        f = run.frequency
        H = rig.structure.frf(2 * np.pi * f, columns=["x1"])[:, :, 0]
        for p, dof in enumerate(["x1", "x2"]):
            err = np.abs(run.frf[dof] / H[:, p] - 1)
            bound = np.sqrt(2) * run.arrays[f"random_error/{dof}"]
            # window leakage near the lightly damped peaks adds a bias of a few 0.1 %
            assert np.mean(err <= 3 * bound + 0.01) > 0.95
            # no sensor noise here: coherence drops only where leakage bites (the lightly damped peaks)
            assert np.median(run.arrays[f"coherence/{dof}"]) > 0.99
        assert f.min() >= 2.0 and f.max() <= 40.0


@pytest.mark.slow
def test_hardening_rig_jumps_at_different_lines_up_and_down(tmp_path):
    rig = load_rig(RIGS / "hardening.toml")
    text = """
[[stepped_sine]]
force = 0.5
start = 8.0
stop = 13.0
step = 0.1
direction = "both"
[limits]
max_force = 5.0
max_acceleration = 400.0
"""
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "h.h5")
    assert not summary.aborted
    with open_session(tmp_path / "h.h5") as s:
        jumps = {}
        for direction in ("up", "down"):
            run = s.run(f"sine_0.5N_{direction}")
            order = np.argsort(run.frequency)
            f, amp = run.frequency[order], np.abs(run.frf["x"][order])
            i = np.argmax(np.abs(np.diff(np.log(amp))))
            jumps[direction] = f[i]
            assert abs(np.log(amp[i + 1] / amp[i])) > 0.5          # a jump, not a smooth slope
    assert jumps["up"] > jumps["down"] + 0.3


@pytest.mark.slow
def test_abort_from_another_thread_switches_off_and_keeps_the_lines(tmp_path):
    rig = load_rig("paper-2dof")
    text = "[[stepped_sine]]\nforce = 0.8\nstart = 0.8\nstop = 3.2\nstep = 0.025\n[limits]\nmax_force = 5.0\n" \
           "max_acceleration = 50.0\n"
    box = {}

    class AbortAfterFive(CampaignListener):
        def line(self, run, index, m, target):
            if index == 4:
                threading.Thread(target=box["campaign"].abort, args=("operator abort",)).start()

    with emulated_instruments(rig) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "a.h5", listener=AbortAfterFive(),
                           on_campaign=lambda c: box.setdefault("campaign", c))
        assert not inst.shaker.output_enabled()
        events = output_events(inst)
        assert events[-1].detail.startswith("off")
    assert summary.aborted == "operator abort"
    with open_session(tmp_path / "a.h5") as s:
        run = s.run("sine_0.8N_up")
        assert run.status == "aborted" and 5 <= len(run.frequency) <= 7
        assert any(e["kind"] == "safety" and "trip" in e["message"] for e in s.events())


class CtrlCAtLine(CampaignListener):
    """Ctrl-C as the campaign's thread sees it, at the fourth line."""

    def line(self, run, index, m, target):
        if index == 3:
            raise KeyboardInterrupt


SHORT_PLAN = ("[[stepped_sine]]\nforce = 0.8\nstart = 2.8\nstop = 3.2\nstep = 0.05\n[limits]\nmax_force = 5.0\n"
              "max_acceleration = 50.0\n")


def _interrupted(tmp_path) -> KeyboardInterrupt:
    """The short plan interrupted at its fourth line, over an earlier session (``--overwrite``)."""
    (tmp_path / "c.h5").write_bytes(b"an earlier session")
    with emulated_instruments(load_rig("paper-2dof")) as inst:
        with pytest.raises(KeyboardInterrupt) as caught:
            run_plan(plan(SHORT_PLAN), inst, tmp_path / "c.h5", overwrite=True, listener=CtrlCAtLine())
        assert not inst.shaker.output_enabled()
    assert (tmp_path / "c.h5").read_bytes() == b"an earlier session"
    return caught.value


def test_ctrl_c_stays_ctrl_c_when_the_run_cannot_be_closed_in_the_session(tmp_path, monkeypatch):
    """What the user asked for reaches the command (exit 130), the session's failure as a note on it; an
    error's cleanup failing in the file replaces the error instead (test_disk_failure_mid_run_...)."""
    def failing_end(self, *args, **kwargs):
        raise SessionWriteError(f"{self.path}: failed while closing a run: [Errno 28] No space left")

    monkeypatch.setattr(SessionWriter, "end_run", failing_end)
    notes = _interrupted(tmp_path).__notes__
    assert any("could not be closed in the session" in n and "No space left" in n for n in notes)
    assert any("kept beside it as" in n for n in notes)


def test_a_second_ctrl_c_while_the_session_closes_still_says_where_it_went(tmp_path, monkeypatch):
    real_close = SessionWriter.close

    def closed_then_ctrl_c(self, complete=False):
        real_close(self, complete)
        raise KeyboardInterrupt                            # held while the file closed, acting once it had

    monkeypatch.setattr(SessionWriter, "close", closed_then_ctrl_c)
    assert any("kept beside it as" in n for n in _interrupted(tmp_path).__notes__)
    with open_session(tmp_path / "c.incomplete.h5") as s:
        run = s.run("sine_0.8N_up")
        assert run.status == "aborted" and len(run.frequency) == 4
        assert run.attrs["end_reason"] == "interrupted by Ctrl-C"


def test_a_second_ctrl_c_after_the_session_was_said_still_says_where_it_went(capsys):
    """The second Ctrl-C of a double one can come once the session is closed and its place noted on the first, in
    the cleanup that follows (the compiling process ended, the instruments closed): it replaces the first, and the
    command's line still says where the session went."""
    from types import SimpleNamespace

    from app.cli import EXIT_INTERRUPTED, _run

    def interrupted_twice(args):
        try:
            first = KeyboardInterrupt()
            first.add_note("c.h5 is left as it was: the new session is incomplete and was kept beside it as "
                           "c.incomplete.h5")
            raise first
        finally:
            raise KeyboardInterrupt                        # the second, in a later cleanup

    assert _run(SimpleNamespace(run=interrupted_twice, debug=False)) == EXIT_INTERRUPTED
    err = capsys.readouterr().err.strip()
    assert err == ("contactid: interrupted; c.h5 is left as it was: the new session is incomplete and was kept "
                   "beside it as c.incomplete.h5")


@pytest.mark.slow
def test_limit_breach_aborts_with_output_off(tmp_path):
    rig = load_rig(RIGS / "linear-shaker.toml")
    text = LINEAR_PLAN.replace("max_acceleration = 150.0", "max_acceleration = 3.0").split("[[stepped_sine]]")[1]
    text = "[[stepped_sine]]" + text
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "l.h5")
        assert not inst.shaker.output_enabled()
    assert "abort limit exceeded: acc:" in summary.aborted and "m/s^2" in summary.aborted
    with open_session(tmp_path / "l.h5") as s:
        assert s.run("sine_0.5N_up").status == "aborted"


@pytest.mark.slow
def test_disk_failure_mid_run_aborts_safely_and_keeps_the_data(tmp_path, monkeypatch):
    rig = load_rig("paper-2dof")
    text = "[[stepped_sine]]\nforce = 0.8\nstart = 2.8\nstop = 3.2\nstep = 0.05\n[limits]\nmax_force = 5.0\n" \
           "max_acceleration = 50.0\n"
    real_append = SessionWriter.append_line
    calls = {"n": 0}

    def failing_append(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 4:
            raise SessionWriteError(f"{self.path}: failed while appending a line: [Errno 28] No space left")
        return real_append(self, *args, **kwargs)

    monkeypatch.setattr(SessionWriter, "append_line", failing_append)
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "d.h5")
        assert not inst.shaker.output_enabled()
    assert "No space left" in summary.aborted
    with open_session(tmp_path / "d.h5") as s:
        run = s.run("sine_0.8N_up")
        assert len(run.frequency) == 3 and run.status == "aborted"


@pytest.mark.parametrize("text,match", [
    ("[[stepped_sine]]\nforce = 0.8\nstart = 3.0\nstop = 1.0\nstep = 0.1\n[limits]\nmax_force = 5.0\n"
     "max_acceleration = 50.0\n", r"stop \(1.0 Hz\) must be above start"),
    ("[[stepped_sine]]\nforce = 8.0\nstart = 1.0\nstop = 3.0\nstep = 0.1\n[limits]\nmax_force = 5.0\n"
     "max_acceleration = 50.0\n", r"force 8.0 N is not below the abort limit"),
    ("[[stepped_sine]]\nforce = 0.8\nstart = 1.0\nstop = 300.0\nstep = 10\n[limits]\nmax_force = 5.0\n"
     "max_acceleration = 50.0\n", r"beyond the DAQ's Nyquist frequency"),
    ("[random]\nforce_rms = 0.1\nband = [1.0, 500.0]\nduration = 10\n[limits]\nmax_force = 5.0\n"
     "max_acceleration = 50.0\n", r"band reaches 500.0 Hz"),
])
@pytest.mark.slow
def test_impossible_plans_are_refused_before_arming(tmp_path, text, match):
    rig = load_rig("paper-2dof")
    with emulated_instruments(rig) as inst:
        with pytest.raises(InputError, match=match):
            run_plan(plan(text), inst, tmp_path / "x.h5")
        assert output_events(inst) == [] or not any(e.detail.startswith("on") for e in output_events(inst))
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.slow
def test_dropped_frames_are_logged_and_lines_stay_right(tmp_path):
    rig = load_rig(RIGS / "linear-shaker.toml")
    text = LINEAR_PLAN.split("[[stepped_sine]]")[1].replace("step = 0.5", "step = 2.0")
    faults = {"daq": {"drop": 2e-4, "seed": 3}}
    with emulated_instruments(rig, faults=faults) as inst:
        summary = run_plan(plan("[[stepped_sine]]" + text), inst, tmp_path / "f.h5")
    assert not summary.aborted and summary.samples_lost > 0
    with open_session(tmp_path / "f.h5") as s:
        run = s.run("sine_0.5N_up")
        f = run.arrays["measured_frequency"]
        H = rig.structure.frf(2 * np.pi * f, columns=["x1"])[:, 0, 0]
        np.testing.assert_allclose(run.frf["x1"], H, rtol=5e-3)
        assert sum("lost" in e["message"] for e in s.events() if e["kind"] == "fault") > 0


@pytest.mark.slow
def test_paper_2dof_campaign_reproduces_table_1(tmp_path):
    """The paper's numerical example through drivers, emulator, campaign, session, identification and fit:
    kn1, cn, kn2, mu within 1.5 % of 500, 1.0, 750, 0.1 (the paper reached 3 %)."""
    import tomllib

    from analysis.mechanics.model import load_model
    from analysis.loop.workbench import Workbench
    from app.session.data import measurements_from_session
    from drivers.simulation.rig import builtin_rig_path

    rig = load_rig("paper-2dof")
    text = "[[stepped_sine]]\nforce = 0.8\nstart = 0.8\nstop = 3.2\nstep = 0.025\n[limits]\nmax_force = 5.0\n" \
           "max_acceleration = 50.0\n"
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "p.h5")
    assert not summary.aborted
    doc = tomllib.loads(builtin_rig_path("paper-2dof").read_text())
    for el in doc["element"]:
        el["laws"] = [law["law"] for law in el["laws"]]          # the laws, not their values
    with open_session(tmp_path / "p.h5") as s:
        assert s.provenance("rig") is not None                   # kept for provenance, never read below
        wb = Workbench(load_model(doc), measurements_from_session(s))
    wb.start()
    values = {el.name: {t.law.name: t.values for t in el.laws} for el in wb.model.elements}
    assert -values["left"]["cubic"]["k3"] == pytest.approx(500.0, rel=0.015)
    assert values["left"]["quadratic_damping"]["c2"] == pytest.approx(1.0, rel=0.015)
    assert -values["right"]["cubic"]["k3"] == pytest.approx(750.0, rel=0.015)
    assert values["right"]["coulomb"]["fs"] == pytest.approx(0.1, rel=0.015)
