"""Response-controlled stepped sine: a level holds a response amplitude at a DOF instead of a force.

Truth: a Duffing oscillator held at one displacement amplitude a responds, to first order, as the linear
oscillator of stiffness k + 3/4 k3 a^2 (single-harmonic balance written out here); on paper-beam the joint's kbar
from response-controlled levels against that of force-controlled levels at the same joint amplitude."""
import tomllib
from pathlib import Path

import numpy as np
import pytest

from analysis import InputError
from analysis.identification.identify import identify_complex_stiffness
from analysis.common.measurements import Control
from app.campaign import emulated_instruments, parse_plan, run_plan
from app.session import check_control, measurements_from_session, open_session
from drivers.simulation.rig import load_rig

RIGS = Path(__file__).parent / "rigs"
K, M, C, K3 = 3947.8, 1.0, 1.5, 4.0e7          # tests/rigs/hardening.toml


def plan(text: str):
    return parse_plan(tomllib.loads(text), text, "plan.toml")


LIMITS = "\n[limits]\nmax_force = 15.0\nmax_acceleration = 400.0\n"
HARDENING_LEVEL = """
[[stepped_sine]]
response = 0.0015
quantity = "displacement"
dof = "x"
force_limit = 8.0
start = 9.5
stop = 10.7
step = 0.1
direction = "both"
refine = false
""" + LIMITS


# ----------------------------------------------------------------------------- plan
def test_a_response_level_names_its_run_by_dof_amplitude_and_unit():
    p = plan(HARDENING_LEVEL)
    spec = p.sine[0]
    assert [spec.run_name(d) for d in spec.directions] == ["sine_x_0.0015m_up", "sine_x_0.0015m_down"]
    assert spec.control("x") == Control("response", "x", "displacement", 0.0015)
    assert spec.force == 8.0 and spec.response.force_limit == 8.0
    accel = plan('[[stepped_sine]]\nresponse = 20.0\ndof = "x1"\nstart = 1.0\nstop = 2.0\nstep = 0.5\n' + LIMITS)
    assert accel.sine[0].run_name("up") == "sine_x1_20mps2_up"
    assert accel.sine[0].response.force_limit == 7.5               # half of max_force where not given
    velocity = plan('[[stepped_sine]]\nresponse = 0.01\nquantity = "velocity"\ndof = "x1"\nstart = 1.0\n'
                    'stop = 2.0\nstep = 0.5\n' + LIMITS)
    assert velocity.sine[0].run_name("up") == "sine_x1_0.01mps_up"
    force = plan('[[stepped_sine]]\nforce = 0.8\nstart = 1.0\nstop = 2.0\nstep = 0.5\n' + LIMITS)
    assert force.sine[0].run_name("up") == "sine_0.8N_up"
    assert force.sine[0].control("x1") == Control("force", "x1", "force", 0.8)


@pytest.mark.parametrize("table, field, says", [
    ('force = 0.5\nresponse = 2.0\ndof = "x"', "[[stepped_sine]][0].force", "not both"),
    ('response = 2.0', "[[stepped_sine]][0].dof", "required"),
    ('response = 2.0\ndof = "x"\nquantity = "jerk"', "[[stepped_sine]][0].quantity", "must be one of"),
    ('response = 2.0\ndof = "x"\nforce_limit = 15.0', "[[stepped_sine]][0].force_limit", "abort limit"),
    ('response = -2.0\ndof = "x"', "[[stepped_sine]][0].response", "> 0"),
    ('force = 0.5\ndof = "x"', "[[stepped_sine]][0].dof", "response-controlled level"),
])
def test_a_wrong_response_level_is_refused_naming_the_field(table, field, says):
    with pytest.raises(InputError) as err:
        plan(f"[[stepped_sine]]\n{table}\nstart = 9.5\nstop = 10.5\nstep = 0.1\n" + LIMITS)
    assert field in str(err.value) and says in str(err.value)


def test_control_attributes_absent_read_as_force_and_wrong_ones_are_refused():
    def error(what, message):
        return InputError(message, "s.h5", f"run r, {what}")

    assert check_control({}, "x1", 0.8, error) == Control("force", "x1", "force", 0.8)
    with pytest.raises(InputError, match="attribute control_target"):
        check_control({"control": "response", "control_quantity": "velocity", "control_target": -1.0}, "x1", 0.8,
                      error)
    with pytest.raises(InputError, match="attribute control: must be one of"):
        check_control({"control": "position"}, "x1", 0.8, error)


# ----------------------------------------------------------------------------- hardening rig, against truth
@pytest.fixture(scope="module")
def hardening_session(tmp_path_factory):
    path = tmp_path_factory.mktemp("response") / "hardening.h5"
    with emulated_instruments(load_rig(RIGS / "hardening.toml"), seed=1) as inst:
        summary = run_plan(plan(HARDENING_LEVEL), inst, path)
        assert not inst.shaker.output_enabled()
    return path, summary


def test_a_held_displacement_makes_the_duffing_oscillator_linear_at_that_amplitude(hardening_session):
    path, summary = hardening_session
    assert summary.complete, summary.text()
    with open_session(path) as s:
        for name in ("sine_x_0.0015m_up", "sine_x_0.0015m_down"):
            run = s.run(name)
            a = run.arrays["response_amplitude"]
            np.testing.assert_allclose(a, 0.0015, rtol=0.01)              # every line holds its target
            np.testing.assert_allclose(run.arrays["response_target"], 0.0015)
            # the displacement is the measured acceleration fundamental over w^2
            w = 2 * np.pi * run.arrays["measured_frequency"]
            np.testing.assert_allclose(a, np.abs(run.arrays["harmonics/acc:x"][:, 1]) / w ** 2, rtol=1e-9)
            # first-order harmonic balance of the Duffing oscillator at the line's amplitude
            truth = 1.0 / (K + 0.75 * K3 * a ** 2 - M * w ** 2 + 1j * C * w)
            np.testing.assert_allclose(run.frf["x"], truth, rtol=5e-3)
            assert np.isnan(run.arrays["force_target"]).all()


def test_up_and_down_sweeps_at_one_response_amplitude_show_no_jump(hardening_session):
    path, _ = hardening_session
    with open_session(path) as s:
        up, down = s.run("sine_x_0.0015m_up"), s.run("sine_x_0.0015m_down")
        np.testing.assert_allclose(up.frequency, down.frequency[::-1])
        # each line holds its amplitude within 1 %, and near the resonance the FRF moves about twice that with
        # it; the force-controlled sweeps of this rig differ by x2 or more between their jumps
        np.testing.assert_allclose(up.frf["x"], down.frf["x"][::-1], rtol=0.03)


def test_the_session_records_the_control_of_each_run(hardening_session):
    path, _ = hardening_session
    with open_session(path) as s:
        run = s.run("sine_x_0.0015m_up")
        assert run.attrs["control"] == "response" and run.attrs["control_dof"] == "x"
        assert run.attrs["control_quantity"] == "displacement" and run.attrs["control_units"] == "m"
        assert run.attrs["control_target"] == 0.0015
        # the run's force is the median of the force measured at its lines (older readers get a level)
        assert run.attrs["force"] == pytest.approx(np.median(run.arrays["force_amplitude"]))
        measurements = measurements_from_session(s)
    controls = {r.name: r.control for r in measurements.sine}
    assert controls["sine_x_0.0015m_down"] == Control("response", "x", "displacement", 0.0015)


# ----------------------------------------------------------------------------- paper-beam (Iwan joint)
@pytest.mark.slow
def test_paper_beam_holds_an_acceleration_at_the_drive_point(tmp_path):
    text = ('[[stepped_sine]]\nresponse = 10.0\ndof = "A.w"\nstart = 52.25\nstop = 53.25\nstep = 0.25\n'
            'refine = false\n[limits]\nmax_force = 5.0\nmax_acceleration = 400.0\n')
    with emulated_instruments(load_rig("paper-beam"), seed=1) as inst:
        summary = run_plan(plan(text), inst, tmp_path / "s.h5")
    assert summary.complete, summary.text()
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("sine_A.w_10mps2_up")
        np.testing.assert_allclose(run.arrays["response_amplitude"], 10.0, rtol=0.01)
        np.testing.assert_allclose(np.abs(run.arrays["harmonics/acc:A.w"][:, 1]), 10.0, rtol=0.01)
        # the force it took dips at the resonance (about 52.8 Hz at this amplitude)
        force = run.arrays["force_amplitude"]
        assert np.argmin(force) in (1, 2, 3) and force.max() / force.min() > 2


RESPONSE_LEVELS = (2.0, 5.0, 10.0, 20.0)          # m/s^2 at A.w
FORCE_LEVELS = (0.02, 0.1, 0.3, 1.2)              # N


def _beam_plan() -> str:
    sweep = 'start = 51.0\nstop = 54.5\nstep = 0.1\ndirection = "up"\n'
    text = "".join(f'[[stepped_sine]]\nresponse = {a}\ndof = "A.w"\nforce_limit = 4.0\n{sweep}\n'
                   for a in RESPONSE_LEVELS)
    text += "".join(f"[[stepped_sine]]\nforce = {f}\n{sweep}\n" for f in FORCE_LEVELS)
    return text + "[limits]\nmax_force = 5.0\nmax_acceleration = 400.0\n"


@pytest.fixture(scope="module")
def beam_levels(tmp_path_factory):
    """paper-beam measured at four response amplitudes and four forces over the first mode."""
    path = tmp_path_factory.mktemp("beam") / "levels.h5"
    with emulated_instruments(load_rig("paper-beam"), seed=1) as inst:
        summary = run_plan(plan(_beam_plan()), inst, path)
    assert summary.complete, summary.text()
    with open_session(path) as s:
        return path, measurements_from_session(s)


def _tangential(run, structure, elements):
    ident = identify_complex_stiffness(structure, run.receptance, run.sensor_dofs, run.excitation_dof, elements,
                                       w=run.w, force=run.force_per_line, noise_std=run.receptance_std)
    good = ~ident.ill_conditioned & np.isfinite(ident.kbar).all(axis=1)
    return ident.amplitude[good, 1], ident.kbar[good, 1], ident.kbar_std[good, 1]


@pytest.mark.slow
def test_paper_beam_response_levels_hold_their_targets_and_agree_with_force_levels_on_kbar(beam_levels):
    from analysis.mechanics.model import load_model
    from analysis.common.tables import load_toml
    from drivers.simulation.rig import builtin_rig_path

    path, measurements = beam_levels
    with open_session(path) as s:
        for a in RESPONSE_LEVELS:
            run = s.run(f"sine_A.w_{a:g}mps2_up")
            np.testing.assert_allclose(run.arrays["response_amplitude"], a, rtol=0.01)
            mag = np.abs(run.frf["A.w"])                                   # no jumps: a smooth peak
            assert np.max(np.abs(np.diff(np.log(mag), 2))) < 0.2
    model = load_model(load_toml(builtin_rig_path("paper-beam")), "rig")
    force_runs = [r for r in measurements.sine if r.control.mode == "force"]
    X, K, S = (np.concatenate(v) for v in zip(*(_tangential(r, model.structure, model.elements)
                                                 for r in force_runs)))
    order = np.argsort(X)
    X, K, S = X[order], K[order], S[order]
    for run in (r for r in measurements.sine if r.control.response):
        x, k, std = _tangential(run, model.structure, model.elements)
        assert len(x) > 30
        assert x.max() / x.min() < 1.05               # every line of a level sits at nearly one joint amplitude
        # kbar of the force levels at the same joint amplitude (interpolated in log amplitude)
        at = np.log(x)
        k_force = np.interp(at, np.log(X), K.real) + 1j * np.interp(at, np.log(X), K.imag)
        s_force = np.interp(at, np.log(X), S)
        assert np.all(np.abs(k - k_force) <= np.hypot(std, s_force)), run.name


# ----------------------------------------------------------------------------- analyze: frequency and damping
HARDENING_MODEL = """[structure]
type = "lumped"
dofs = ["x"]
mass = [[1.0]]
stiffness = [[3947.8]]
damping = [[1.5]]

[[element]]
name = "spring"
dof = "x"
laws = ["cubic"]
"""


@pytest.mark.slow
def test_analyze_reports_frequency_and_damping_against_response_amplitude(hardening_session, tmp_path, capsys):
    import json

    from app.cli import main

    path, _ = hardening_session
    (tmp_path / "model.toml").write_text(HARDENING_MODEL, encoding="utf-8")
    args = ["analyze", str(path), str(tmp_path / "model.toml"), "--no-history"]
    assert main(args + ["--json", "--report", str(tmp_path / "report")]) == 0
    (bb,) = json.loads(capsys.readouterr().out)["backbones"]
    assert bb["measured"]["dof"] == "x" and bb["measured"]["quantity"] == "displacement"
    assert sorted(bb["measured"]["runs"]) == ["sine_x_0.0015m_down", "sine_x_0.0015m_up"]
    # the Duffing oscillator at 1.5 mm: w^2 = (k + 3/4 k3 a^2) / m, with the fitted k3 near the rig's
    truth = np.sqrt(K + 0.75 * K3 * 0.0015 ** 2) / (2 * np.pi)
    for point in bb["measured"]["points"] + bb["predicted"]["points"]:
        assert point["frequency_hz"] == pytest.approx(truth, rel=1e-3)
        assert point["damping_ratio"] == pytest.approx(C / (2 * np.sqrt(K + 0.75 * K3 * 0.0015 ** 2)), rel=0.05)
    assert (tmp_path / "report" / "backbone.png").stat().st_size > 10_000
    assert main(args) == 0
    assert "natural frequency and damping against response amplitude" in capsys.readouterr().out


BEAM_MODEL_ELEMENTS = """
[[element]]
name = "normal"
dof = "O.w"
laws = ["linear"]

[[element]]
name = "tangential"
dof = "O.theta"
laws = ["iwan"]
"""


@pytest.mark.slow
def test_paper_beam_frequency_and_damping_against_amplitude_agree_with_the_fitted_model(beam_levels):
    """The model fitted to all the levels (the rig's beam, a linear normal contact and an Iwan joint, their values
    fitted) predicts the measured natural frequency within 0.5 % and the damping within 10 % at every response
    level."""
    from analysis.prediction.backbone import compare_backbones
    from analysis.mechanics.model import load_model
    from analysis.common.tables import parse_toml
    from analysis.loop.workbench import Workbench
    from drivers.simulation.rig import builtin_rig_path

    rig = builtin_rig_path("paper-beam").read_text(encoding="utf-8")
    text = rig[rig.index("[structure]"):rig.index("[[element]]")] + BEAM_MODEL_ELEMENTS
    _, measurements = beam_levels
    wb = Workbench(load_model(parse_toml(text, "model.toml"), "model.toml"), measurements)
    wb.start()
    (comparison,) = compare_backbones(wb.model.structure, wb.model.elements, measurements.sine)
    amplitude, frequency, damping = comparison.measured.arrays()
    np.testing.assert_allclose(amplitude, RESPONSE_LEVELS, rtol=0.01)
    assert np.all(np.diff(frequency) < 0) and np.all(np.diff(damping) > 0)    # the joint softens and damps
    assert np.max(np.abs(comparison.frequency_error)) < 0.005
    assert np.max(np.abs(comparison.damping_error)) < 0.10
    assert all(p.converged for p in comparison.predicted.points)
