"""Phase resonance: the frequency locked to a 90 deg lag, force level by level, on emulated rigs through the drivers.

Truth: the hardening (Duffing) oscillator's backbone w^2 = (k + 3/4 k3 X^2) / m, at which a viscously damped
SDOF lags its force by exactly 90 deg; paper-2dof's first-harmonic backbone by the describing-function
eigenproblem of the true rig (analysis/prediction/backbone.py, tested against truth in tests/test_backbone.py)."""
import threading
import tomllib
from pathlib import Path

import numpy as np
import pytest

from analysis import InputError
from app.campaign import CampaignListener, emulated_instruments, parse_plan, run_plan
from app.campaign.phase_resonance import PhaseTrack, lag_error
from app.session import open_session
from drivers.simulation.rig import load_rig

RIGS = Path(__file__).parent / "rigs"
K, M, K3 = 3947.8, 1.0, 4.0e7                     # tests/rigs/hardening.toml
HARDENING_PLAN = """
[[phase_resonance]]
dof = "x"
forces = [0.05, 0.1, 0.2, 0.4]
start = 10.0
[limits]
max_force = 15.0
max_acceleration = 400.0
"""


def plan(text: str):
    return parse_plan(tomllib.loads(text), text, "plan.toml")


def displacement(run, dof):
    w = 2 * np.pi * run.frequency
    return np.abs(run.arrays[f"harmonics/acc:{dof}"][:, 1]) / w ** 2


@pytest.mark.slow
def test_the_lock_follows_the_duffing_backbone_up_its_branch(tmp_path):
    with emulated_instruments(load_rig(RIGS / "hardening.toml"), seed=1) as inst:
        summary = run_plan(plan(HARDENING_PLAN), inst, tmp_path / "s.h5")
        assert not inst.shaker.output_enabled()
    assert summary.complete, summary.text()
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("phase_x_90deg")
        assert run.attrs["kind"] == "phase_resonance" and run.attrs["target_phase"] == 90.0
        a = run.arrays
        np.testing.assert_allclose(a["force_amplitude"], [0.05, 0.1, 0.2, 0.4], rtol=0.01)
        assert a["lock_converged"].all() and (np.abs(a["phase_error"]) <= 1.0).all()
        assert (np.abs(a["phase_lag"] - 90.0) <= 1.0).all() and (a["lock_iterations"] >= 1).all()
        assert (a["shaker_time"] > 0).all()
        np.testing.assert_array_equal(a["force_phase"], np.angle(a["force_phasor"]))    # the force, measured whole
        assert run.units["force_phase"] == "rad"
        X = displacement(run, "x")
        backbone = np.sqrt((K + 0.75 * K3 * X ** 2) / M) / (2 * np.pi)
        np.testing.assert_allclose(run.frequency, backbone, rtol=0.005)
        assert X[-1] > 3.5e-3 and run.frequency[-1] > 10.5       # up the branch, 0.5 Hz above the linear mode
        events = [e["message"] for e in s.events() if e["kind"] == "lock"]
        assert len(events) == 4 and "0.4 N locked at" in events[-1]


@pytest.mark.slow
def test_paper_2dof_locks_on_the_first_mode_s_backbone(tmp_path):
    from analysis.prediction.backbone import predict_backbone
    from analysis.mechanics.model import load_model
    from analysis.common.tables import load_toml
    from drivers.simulation.rig import builtin_rig_path

    text = ('[[phase_resonance]]\ndof = "x2"\nforces = [0.2, 0.4, 0.8]\nstart = 1.27\n'
            '[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n')
    with emulated_instruments(load_rig("paper-2dof"), seed=1) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "s.h5")
    assert summary.complete, summary.text()
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("phase_x2_90deg")
        assert run.arrays["lock_converged"].all()
        X = displacement(run, "x2")
    rig = load_model(load_toml(builtin_rig_path("paper-2dof")), "rig")
    predicted = predict_backbone(rig.structure, rig.elements, "x2", "displacement", X, 1.27)
    np.testing.assert_allclose(run.frequency, predicted.arrays()[1], rtol=0.005)
    assert run.frequency[-1] < 0.95 * run.frequency[0]            # the softening cubics: the mode comes down


@pytest.mark.slow
def test_an_abort_during_a_lock_switches_off_and_keeps_the_points_measured(tmp_path):
    box = {}

    class AbortAfterFirst(CampaignListener):
        def phase_point(self, run, index, point):
            if index == 0:
                threading.Thread(target=box["campaign"].abort, args=("operator abort",)).start()

    with emulated_instruments(load_rig(RIGS / "hardening.toml"), seed=1) as inst:
        summary = run_plan(plan(HARDENING_PLAN), inst, tmp_path / "s.h5", listener=AbortAfterFirst(),
                           on_campaign=lambda c: box.update(campaign=c))
        assert not inst.shaker.output_enabled()
    assert summary.aborted == "operator abort"
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("phase_x_90deg")
        assert run.status == "aborted" and 1 <= len(run.frequency) <= 2


def test_the_secant_locks_a_lone_mode_in_a_few_steps_within_its_step_bound():
    fn, zeta = 10.0, 0.01

    def lag(f):                       # a viscously damped SDOF, lag of x behind F in degrees
        r = f / fn
        return float(np.degrees(np.arctan2(2 * zeta * r, 1 - r * r)))

    track, f, previous = PhaseTrack(), 9.7, None
    for steps in range(1, 30):
        error = lag_error(lag(f), 90.0)
        if abs(error) <= 0.1:
            break
        f_next = track.next_frequency(f, error, previous)
        if track.steepest > 0:        # at most 30 deg at the steepest slope seen (a quarter band, at the mode)
            assert abs(f_next - f) <= 30.0 / track.steepest + 1e-12
        previous, f = (f, error), f_next
    assert f == pytest.approx(fn, rel=1e-3) and steps < 20
    assert track.steepest == pytest.approx(np.degrees(1 / (zeta * fn)), rel=0.2)   # the slope at the mode


@pytest.mark.parametrize("table, field, says", [
    ('dof = "x"\nforces = [0.2, 0.1]\nstart = 10.0', "forces", "must rise"),
    ('dof = "x"\nforces = []\nstart = 10.0', "forces", "list of 1 to"),
    ('dof = "x"\nforces = [0.2]\nstart = 10.0\nphase = 200.0', "phase", "0 to 180"),
    ('dof = "x"\nforces = [20.0]\nstart = 10.0', "forces", "abort limit"),
    ('forces = [0.2]\nstart = 10.0', "dof", "required"),
    ('dof = "x"\nforces = [0.2]\nstart = 10.0\nlock = 1', "lock", "unknown key"),
])
def test_a_wrong_phase_resonance_table_is_refused_naming_the_field(table, field, says):
    with pytest.raises(InputError) as err:
        plan(f"[[phase_resonance]]\n{table}\n[limits]\nmax_force = 15.0\nmax_acceleration = 400.0\n")
    assert f"[[phase_resonance]][0].{field}" in str(err.value) and says in str(err.value)


def test_a_phase_lock_at_a_dof_without_accelerometer_is_refused_before_arming(tmp_path):
    text = HARDENING_PLAN.replace('dof = "x"', 'dof = "y"')
    with emulated_instruments(load_rig(RIGS / "hardening.toml"), seed=1) as inst:
        with pytest.raises(InputError, match=r"\[\[phase_resonance\]\]\[0\]\.dof.*'y' carries no accelerometer"):
            run_plan(plan(text), inst, tmp_path / "s.h5")
        assert not inst.shaker.output_enabled()
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.slow
def test_a_level_that_does_not_lock_is_stored_unconverged_and_fails_the_run(tmp_path):
    text = HARDENING_PLAN.replace("start = 10.0", "start = 9.0\nmax_iterations = 2")
    with emulated_instruments(load_rig(RIGS / "hardening.toml"), seed=1) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "s.h5")
        assert not inst.shaker.output_enabled()
    assert summary.runs == {"phase_x_90deg": "failed"} and "did not converge at" in summary.failed["phase_x_90deg"]
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("phase_x_90deg")
        assert len(run.frequency) == 4 and not run.arrays["lock_converged"][0]
        assert run.arrays["lock_iterations"][0] == 2 and abs(run.arrays["phase_error"][0]) > 1.0


@pytest.mark.slow
def test_analyze_compares_the_locked_points_with_the_fitted_model_s_backbone(tmp_path, capsys):
    import json

    from app.cli import main

    text = HARDENING_PLAN.replace("[limits]", '[[stepped_sine]]\nresponse = 0.001\nquantity = "displacement"\n'
                                              'dof = "x"\nstart = 9.7\nstop = 10.5\nstep = 0.1\nrefine = false\n'
                                              '[limits]')
    with emulated_instruments(load_rig(RIGS / "hardening.toml"), seed=1) as inst:
        assert run_plan(plan(text), inst, tmp_path / "s.h5").complete
    (tmp_path / "model.toml").write_text((RIGS / "hardening.toml").read_text().split("[excitation]")[0]
                                         .replace('laws = [ { law = "cubic", k3 = 4.0e7 } ]', 'laws = ["cubic"]'),
                                         encoding="utf-8")
    args = ["analyze", str(tmp_path / "s.h5"), str(tmp_path / "model.toml"), "--no-history"]
    assert main(args + ["--json", "--report", str(tmp_path / "report")]) == 0
    out = json.loads(capsys.readouterr().out)
    backbones = {b["measured"]["method"]: b for b in out["backbones"]}
    locked = backbones["phase resonance (90 deg)"]
    assert locked["measured"]["runs"] == ["phase_x_90deg"] and len(locked["measured"]["points"]) == 4
    # the power balance's damping against the Duffing oscillator's c / (2 m w) at each locked frequency
    for p in locked["measured"]["points"]:
        assert p["damping_ratio"] == pytest.approx(1.5 / (2 * M * 2 * np.pi * p["frequency_hz"]), rel=0.02)
    assert max(abs(e) for e in locked["frequency_error"]) < 0.005
    assert max(abs(e) for e in locked["damping_error"]) < 0.02
    assert 0 < out["backbone_error"] < 0.005 and 0 < out["damping_error"] < 0.02
    assert (tmp_path / "report" / "backbone.png").exists()
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "point(s) of phase_x_90deg, phase resonance (90 deg)" in text
    assert f"RMS relative error of the model: natural frequency {out['backbone_error']:.3g}, damping ratio " \
           f"{out['damping_error']:.3g}" in text
    # the loop from no law: each step says the errors of frequency and damping before and after. The response
    # level holds one amplitude, where a linear spring fits its FRFs as well as the cubic; the locked points reach
    # 0.5 to 4 mm, and the kbar identified at them calls for the cubic, which follows the backbone
    (tmp_path / "model.toml").write_text((tmp_path / "model.toml").read_text().replace('["cubic"]', "[]"))
    assert main(args + ["--auto", "--json"]) == 0
    auto = json.loads(capsys.readouterr().out)
    (step,) = auto["auto"]["steps"]
    assert step["laws"] == ["cubic"] and step["backbone_error_after"] == pytest.approx(auto["backbone_error"])
    assert step["backbone_error_after"] < 5e-4 < 0.02 < step["backbone_error_before"]
    assert step["damping_error_after"] < 0.005
    (spring,) = auto["elements"]
    assert spring["laws"][0]["params"]["k3"] == pytest.approx(4.0e7, rel=0.01)


def test_a_phase_resonance_run_just_begun_reads_as_no_point_yet():
    from app.session import measurements_from_session
    from app.session.writer import RunData

    begun = RunData("phase_x_90deg", {"kind": "phase_resonance", "status": "running", "direction": "up",
                                      "force": 0.05, "excitation_dof": "x", "sensor_dofs": '["x"]',
                                      "phase_dof": "x", "target_phase": 90.0},
                    np.empty(0), {"x": np.empty(0, complex)}, {}, {}, False)

    class Live:
        def runs(self):
            return [begun]

    assert measurements_from_session(Live()).phase == []
