"""The reference from a random run: Welch resolution and its Hann leakage bias against independent truth (the
window's analytic kernel, a 1-DOF and a 2-DOF time-marched by an exact zero-order-hold discretisation written
here), every mode in the band, low coherence and a stuck structure, and a random-only session through
``contactid analyze``."""
import json
import tomllib

import numpy as np
import pytest
import scipy.signal

from analysis import InputError
from analysis.signals.frf_estimation import (FRFEstimator, auto_resolution, expected_h1, hann_kernel, welch_averages)
from analysis.common.measurements import RandomRun
from analysis.signals.modal_fit import LOW_COHERENCE, fit_modes, hann_damping_bias, leakage_bias
from analysis.mechanics.model import load_model
from analysis.linear.reference import held_frequencies, reference_from_random
from app.cli import main
from app.campaign.plan import parse_plan
from app.session.writer import RunSpec, SessionWriter
from drivers.simulation.rig import builtin_rig_path

# a linear 2-DOF with modes near 12.7 and 24.5 Hz, force at x2
RIG_12 = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 1.0]],
          "stiffness": [[12000.0, -6000.0], [-6000.0, 12500.0]], "rayleigh": [0.5, 1.5e-4]}


def zoh_response(M, C, K, dof, force, dt):
    """Displacements of M q'' + C q' + K q = b f(t) under a force held constant over each sample (exact
    zero-order-hold discretisation: the discrete poles are exp(s dt) of the continuous ones)."""
    n = len(M)
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ C]])
    B = np.concatenate([np.zeros(n), Mi[:, dof]])[:, None]
    out = []
    for i in range(n):
        out_row = np.zeros((1, 2 * n))
        out_row[0, i] = 1.0
        Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, B, out_row, np.zeros((1, 1))), dt, method="zoh")
        num, den = scipy.signal.ss2tf(Ad, Bd, Cd, Dd)
        out.append(scipy.signal.lfilter(num[0], den, force))
    return np.stack(out, axis=1)


def welch_run(M, C, K, dof, fs, segment, averages, noise=0.0, seed=0):
    """(estimator) of a white-force random run of ``averages`` Hann segments, response noise relative to its rms."""
    rng = np.random.default_rng(seed)
    force = rng.normal(size=(averages + 1) * segment // 2)
    x = zoh_response(M, C, K, dof, force, 1.0 / fs)
    x = x + noise * x.std(axis=0) * rng.normal(size=x.shape)
    est = FRFEstimator(fs, segment)
    est.add_data(force, x)
    return est


def test_hann_kernel_variance_and_peak_bias_match_the_analytic_limit():
    """Parseval on the Hann window gives the kernel's variance df^2 / 3, hence a peak bias of H1 of
    -(4/3) (df / B)^2 for a mode of half-power bandwidth B as df / B -> 0."""
    df = 0.1
    v = np.linspace(-200, 200, 400001) * df
    k = hann_kernel(v, df)
    assert (v**2 * k).sum() / k.sum() == pytest.approx(df**2 / 3, rel=1e-4)
    fn, zeta = 10.0, 0.002
    wn, B = 2 * np.pi * fn, 2 * zeta * fn

    def H(f):
        return 1 / (wn**2 - (2 * np.pi * f) ** 2 + 2j * zeta * wn * 2 * np.pi * f)

    for r, tol in ((0.025, 0.005), (0.05, 0.015)):
        bias = (expected_h1(H, np.array([fn]), r * B)[0] / H(fn) - 1).real
        assert bias == pytest.approx(-4 / 3 * r**2, rel=tol)


def test_damping_bias_predicted_for_a_welch_estimate_of_a_time_marched_1dof():
    """The stated leakage bias is what a real Welch estimate of a 1-DOF (exact ZOH time marching) shows: about
    +85 % at one line per half-power bandwidth, +30 % at two, +10 % at four."""
    fs, fn, zeta = 64.0, 2.0, 0.015
    wn = 2 * np.pi * fn
    for segment in (1024, 2048, 4096):
        est = welch_run(np.eye(1), np.array([[2 * zeta * wn]]), np.array([[wn**2]]), 0, fs, segment, 60)
        f = est.frequency
        keep = (f > 1) & (f < 3)
        measured = fit_modes(f[keep], est.get_H1()[keep], n_modes=1).damping[0] / zeta - 1
        predicted = hann_damping_bias(fn, zeta, fs / segment)
        assert measured == pytest.approx(predicted, abs=0.04)
        # and the correction, solved from the fitted damping, comes back to the truth
        corrected = leakage_bias(fn, zeta * (1 + measured), fs / segment).corrected
        assert corrected == pytest.approx(zeta, rel=0.04)
    assert hann_damping_bias(fn, zeta, 64.0 / 1024) > 0.7 and hann_damping_bias(fn, zeta, 64.0 / 4096) < 0.12


def test_auto_resolution_lines_per_bandwidth_bounded_by_the_run():
    # long enough: six lines per half-power bandwidth 2 * 0.02 * 10 Hz
    r = auto_resolution((10.0, 50.0), 1000.0, 0.02)
    assert r.resolution == pytest.approx(0.4 / 6) and not r.limited_by_duration and r.averages >= 8
    # too short: as fine as 8 averages allow
    r = auto_resolution((0.5, 5.0), 120.0, 0.01)
    assert r.limited_by_duration and r.averages == 8 and r.resolution == pytest.approx(9 / 240)
    assert welch_averages(120.0, 9 / 240) == 8 and welch_averages(10.0, 0.05) == 0


PLAN = "[random]\nforce_rms = 0.05\nband = [0.5, 5.0]\nduration = 120.0\n{extra}\n[limits]\nmax_force = 5.0\n" \
       "max_acceleration = 50.0\n"


def test_plan_resolution_and_expected_damping():
    spec = parse_plan(tomllib.loads(PLAN.format(extra="resolution = 0.05")), "", "p.toml").random
    assert spec.welch().resolution == 0.05 and spec.welch().averages == 11
    spec = parse_plan(tomllib.loads(PLAN.format(extra="expected_damping = 0.05")), "", "p.toml").random
    assert spec.resolution is None and spec.welch().resolution == pytest.approx(9 / 240)


@pytest.mark.parametrize("extra,match", [
    ("resolution = 0.01", r"p.toml: \[random\].resolution: 0.01 Hz needs 100 s segments"),
    ("resolution = 1.0", r"\[random\].resolution: 1 Hz leaves fewer than 8 lines"),
    ("resolution = -1.0", r"\[random\].resolution"),
    ("expected_damping = 0.7", r"\[random\].expected_damping: must be a damping ratio below 0.5"),
    ("expected_damping = \"low\"", r"\[random\].expected_damping"),
])
def test_bad_random_resolution_is_one_line_naming_the_field(extra, match):
    with pytest.raises(InputError, match=match) as err:
        parse_plan(tomllib.loads(PLAN.format(extra=extra)), "", "p.toml")
    assert "\n" not in str(err.value)


def two_dof_run(noise=0.01, seed=3):
    """RIG_12 time-marched under white force at x2, Welch at the automatic resolution of a 200 s run."""
    from analysis import load_structure
    s = load_structure(RIG_12)
    fs = 128.0
    res = auto_resolution((5.0, 40.0), 200.0, 0.01)
    segment = int(round(fs / res.resolution))
    est = welch_run(s.M, s.C, s.K, 1, fs, segment, res.averages, noise=noise, seed=seed)
    f = est.frequency
    band = (f >= 5.0) & (f <= 40.0)
    return s, RandomRun("x2", ["x1", "x2"], f[band], est.get_H1()[band], est.get_coherence()[band],
                        est.get_random_error()[band], 1.0, fs / segment)


def test_every_mode_of_a_linear_2dof_random_run_with_its_leakage_bias():
    s, run = two_dof_run()
    true_f = s.natural_frequencies()
    wn = 2 * np.pi * true_f
    true_zeta = 0.5 / (2 * wn) + 1.5e-4 * wn / 2
    model = load_model({"structure": RIG_12, "element": [{"name": "j", "dof": "x2"}]})
    ref = reference_from_random(model, run)
    m = ref.modal
    assert len(m.frequency) == 2 and np.all(np.diff(m.frequency) > 0)
    np.testing.assert_allclose(m.frequency, true_f, rtol=5e-4)             # within 0.05 %
    assert not m.low_coherence.any() and not ref.stuck and ref.trusted.all()
    # the damping, fitted and corrected for the stated leakage bias
    for i, b in enumerate(ref.leakage):
        assert m.damping[i] / true_zeta[i] - 1 == pytest.approx(b.bias, abs=0.05)
        assert b.corrected == pytest.approx(true_zeta[i], rel=0.05)
    assert "Hann leakage" in ref.text() and "LOW COHERENCE" not in ref.text()


def test_low_coherence_modes_are_warned_and_not_used_for_updating():
    s, run = two_dof_run(noise=10.0)
    doc = {"structure": dict(RIG_12), "element": [{"name": "j", "dof": "x2"}],
           "updating": {"parameters": ["stiffness[0][0]"], "modes": [1]}}
    ref = reference_from_random(load_model(doc), run)
    assert ref.modal.coherence.max() < LOW_COHERENCE and ref.modal.low_coherence.all()
    assert ref.update is None and "reference NOT updated" in ref.text() and "LOW COHERENCE" in ref.text()


def test_held_frequencies_are_the_structure_with_the_element_clamped():
    # x2 held: x1 alone on k11 = 200 N/m, 1 kg; x1 - x2 held: one body of 3 kg on the two ground springs
    s = load_model({"structure": {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
                                  "stiffness": [[200.0, -100.0], [-100.0, 200.0]]}}).structure
    assert held_frequencies(s, [np.array([0.0, 1.0])]) == pytest.approx([np.sqrt(200.0) / (2 * np.pi)])
    assert held_frequencies(s, [np.array([1.0, -1.0])]) == pytest.approx([np.sqrt(200.0 / 3) / (2 * np.pi)])


def random_only_session(path, run: RandomRun, segment: int, fs: float):
    w = SessionWriter(path, software_version="test")
    dofs = run.sensor_dofs
    extras = {f"{kind}/{d}": ("1", (), "f8") for kind in ("coherence", "random_error") for d in dofs}
    w.begin_run(RunSpec("random", "random", 1.0, "none", run.excitation_dof, dofs, fs, ["force"], ["N"], extras,
                        {"band": [5.0, 40.0], "duration": 200.0, "segment_length": segment}))
    arrays = {"frequency": run.frequency_hz}
    for p, d in enumerate(dofs):
        arrays[f"frf/{d}"] = run.receptance[:, p]
        arrays[f"coherence/{d}"] = run.coherence[:, p]
        arrays[f"random_error/{d}"] = run.random_error[:, p]
    w.write_arrays(arrays)
    w.end_run("complete")
    w.close()


def test_random_only_session_through_analyze(tmp_path, capsys):
    s, run = two_dof_run()
    path = tmp_path / "random.h5"
    random_only_session(path, run, int(round(128.0 / run.resolution)), 128.0)
    model = tmp_path / "model.toml"
    model.write_text('[structure]\ntype = "lumped"\ndofs = ["x1", "x2"]\nmass = [[1.0, 0.0], [0.0, 1.0]]\n'
                     'stiffness = [[11000.0, -6000.0], [-6000.0, 12500.0]]\n[[element]]\nname = "j"\ndof = "x2"\n'
                     '[updating]\nparameters = ["stiffness[0][0]"]\nmodes = [1]\n', encoding="utf-8")
    assert main(["analyze", str(path), str(model), "--json", "-o", str(tmp_path / "fitted.toml")]) == 0
    out = json.loads(capsys.readouterr().out)
    modes = out["reference"]["modes"]
    np.testing.assert_allclose([m["frequency"] for m in modes], s.natural_frequencies(), rtol=5e-4)
    assert all(m["trusted"] and "leakage" in m for m in modes)
    assert out["reference"]["updating"]["parameters"]["stiffness[0][0]"]["after"] == pytest.approx(12000.0, rel=2e-3)
    fitted = tomllib.loads((tmp_path / "fitted.toml").read_text())
    assert fitted["structure"]["stiffness"][0][0] == pytest.approx(12000.0, rel=2e-3)
    # without [updating]: every mode in the band, in text
    model.write_text(model.read_text().split("[updating]")[0], encoding="utf-8")
    assert main(["analyze", str(path), str(model)]) == 0
    text = capsys.readouterr().out
    assert "mode 1:" in text and "mode 2:" in text and "no stepped-sine run" in text
    # a law cannot be added without a stepped-sine run: one line, exit 2
    assert main(["analyze", str(path), str(model), "--add", "j:coulomb"]) == 2
    assert "no stepped-sine run to fit a law to" in capsys.readouterr().err


@pytest.mark.slow
def test_paper_2dof_random_run_at_low_level_is_seen_stuck(tmp_path, capsys):
    """The paper's 2-DOF rig at 0.05 N rms: friction (fs = 0.1 N) holds x2, and the one resonance is x1 on the
    held x2 (sqrt(200) / 2 pi = 2.2508 Hz). No pole on a bound is a mode, the modes are ascending, the stuck
    structure is said and no mode of it trusted. Whether its coherence is low depends on how often the joint
    slips in the run (0.17-0.62 over four noise seeds): a joint held throughout responds linearly, so the held
    structure is told by its frequency."""
    plan = tmp_path / "random.toml"
    plan.write_text(PLAN.format(extra=""), encoding="utf-8")
    session = tmp_path / "s.h5"
    assert main(["simulate", "paper-2dof", str(plan), "-o", str(session), "--quiet"]) == 0
    capsys.readouterr()
    model = builtin_rig_path("paper-2dof")             # the rig file is a model file: the truth as reference
    assert main(["analyze", str(session), str(model), "--json"]) == 0
    ref = json.loads(capsys.readouterr().out)["reference"]
    freqs = [m["frequency"] for m in ref["modes"]]
    assert freqs == sorted(freqs) and all(0.5 <= f <= 5.0 for f in freqs)
    assert all(m["damping"] > 1.01e-6 for m in ref["modes"])
    assert not any(m["trusted"] for m in ref["modes"]) and ref["warnings"]
    assert ref["stuck"] and ref["stuck"][0]["elements"] == ["right"]
    assert ref["stuck"][0]["frequency"] == pytest.approx(np.sqrt(200.0) / (2 * np.pi), rel=0.01)
    assert main(["analyze", str(session), str(model)]) == 0
    text = capsys.readouterr().out
    assert "STUCK" in text
