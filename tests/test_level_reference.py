"""The modal structure type and the reference from the lowest stepped-sine level, against an SDOF rig with a
Jenkins joint integrated by RK4 in tests/rk4_rig.py (known stuck frequency and damping), through the commands:
``import`` of a CSV with the force measured per line, ``reference``, ``analyze --auto``."""
import json
import re
import tomllib

import numpy as np
import pytest

import rk4_rig
from analysis import InputError, load_structure
from analysis.common.measurements import Measurements, SineRun
from analysis.laws.base import Origin
from analysis.linear.level_reference import reference_from_level
from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench
from app.cli import main
from app.session import open_session
from app.session.data import measurements_from_session

LINES = np.linspace(19.0, 25.0, 41)
LEVELS = (0.002, 0.01, 0.03, 0.06)           # N: the lowest stuck, the others slipping more and more


def test_modal_structure_is_the_modal_sum_with_residual_terms():
    table = {"type": "modal", "dofs": ["a", "b"], "frequencies": [10.0, 30.0], "damping": [0.01, 0.02],
             "shapes": [[0.5, 0.3], [0.4, -0.6]], "residual_flexibility": [[1e-6, 2e-7], [2e-7, 0.0]],
             "residual_inertia": [[-0.5, 0.0], [0.0, -0.1]]}
    s = load_structure(table)
    w = 2 * np.pi * np.array([5.0, 10.0, 20.0, 31.0])
    H = s.frf(w)
    wr, z = 2 * np.pi * np.array([10.0, 30.0]), np.array([0.01, 0.02])
    phi = np.array(table["shapes"])
    for i, wi in enumerate(w):
        expected = sum(np.outer(phi[r], phi[r]) / (wr[r] ** 2 - wi ** 2 + 2j * z[r] * wr[r] * wi) for r in range(2))
        expected += np.array(table["residual_flexibility"]) + np.array(table["residual_inertia"]) / wi ** 2
        np.testing.assert_allclose(H[i], expected, rtol=1e-12)
    np.testing.assert_allclose(s.natural_frequencies(), [10.0, 30.0])
    # M, K, C realise the modes: their eigenvalues are the natural frequencies
    lam = np.linalg.eigvals(np.linalg.solve(s.M, s.K))
    np.testing.assert_allclose(np.sort(np.sqrt(lam.real)) / (2 * np.pi), [10.0, 30.0], rtol=1e-12)
    with pytest.raises(InputError, match=r"\[structure\]\.shapes"):
        load_structure({**table, "shapes": [[0.5, 0.3]]})


@pytest.fixture(scope="module")
def rk4_levels():
    """The RK4 rig's four levels, the force drifting +-25 % around each target."""
    return rk4_rig.campaign(LEVELS, LINES, drift=0.25)


@pytest.fixture(scope="module")
def rk4_session(tmp_path_factory, rk4_levels):
    """The drifting levels imported from CSV with the force measured at each line."""
    folder = tmp_path_factory.mktemp("rk4")
    levels = rk4_levels
    rk4_rig.write_csv(folder / "rig.csv", levels, LEVELS)
    session = folder / "rig.h5"
    assert main(["import", str(folder / "rig.csv"), "-o", str(session), "--excitation", "x1"]) == 0
    return session


@pytest.mark.slow
def test_reference_from_the_lowest_level_has_the_rigs_frequency_and_damping(rk4_session, capsys):
    model = rk4_session.with_name("reference.toml")
    assert main(["reference", str(rk4_session), "-o", str(model)]) == 0
    out = capsys.readouterr().out
    table = tomllib.loads(model.read_text())
    s = table["structure"]
    assert s["type"] == "modal" and s["dofs"] == ["x1"]
    assert s["frequencies"][0] == pytest.approx(rk4_rig.stuck_frequency_hz(), rel=1e-3)
    assert s["damping"][0] == pytest.approx(rk4_rig.stuck_damping(), rel=0.05)
    # mass-normalised: the modal mass is the rig's
    assert s["shapes"][0][0] ** -2 == pytest.approx(rk4_rig.M, rel=0.02)
    origin = table["element"][0].pop("origin")
    assert table["element"] == [{"name": "joint", "dof": "x1", "laws": [], "in_reference": True}]
    # where the laws are measured from: the drive point at the lowest level's resonance
    assert origin["frequency"] == s["frequencies"][0]
    with open_session(rk4_session) as session:
        lowest = next(r for r in measurements_from_session(session).sine if r.name == "sine_0.002N_up")
    line = np.argmin(np.abs(lowest.frequency_hz - origin["frequency"]))
    assert origin["amplitude"] == pytest.approx(abs(lowest.receptance[line, 0]) * lowest.force_per_line[line],
                                                rel=1e-12)
    assert "reference from run sine_0.002N_up" in out
    assert "NONLINEAR already between the two lowest levels" in out          # the 0.01 N level slips
    # a named run, a band without a mode
    assert main(["reference", str(rk4_session), "-o", str(model), "--overwrite", "--run", "nope"]) == 2
    assert "--run" in capsys.readouterr().err


@pytest.mark.slow
def test_import_keeps_the_force_measured_at_each_line(rk4_session):
    with open_session(rk4_session) as s:
        m = measurements_from_session(s)
    run = next(r for r in m.sine if r.name == "sine_0.03N_up")
    np.testing.assert_allclose(run.force_per_line, rk4_rig.drifting(0.03, len(LINES), 0.25, phase=2), rtol=1e-15)
    assert run.force == 0.03 and run.control.mode == "force"


@pytest.mark.acceptance
def test_lowest_level_reference_then_analyze_auto_runs_end_to_end(rk4_session, capsys):
    """From the lowest level's reference and no law, ``analyze --auto`` finds the RK4 rig's Jenkins joint with
    its kt and fs (docs/laws.md, "Measured from the reference")."""
    model = rk4_session.with_name("reference2.toml")
    assert main(["reference", str(rk4_session), "-o", str(model)]) == 0
    capsys.readouterr()
    assert main(["analyze", str(rk4_session), str(model), "--auto", "--json", "--no-history"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [e["label"] for e in result["error_by_level"]] == [f"{f:g} N" for f in LEVELS]
    assert result["error"] < 0.01
    joint = result["elements"][0]
    assert joint["verdict"] == "nonlinear" and joint["in_reference"]
    # from no law at all, the rig's own: its joint measured from the stuck state the reference holds
    assert [law["law"] for law in joint["laws"]] == ["jenkins"] and joint["laws"][0]["from_reference"]
    assert joint["laws"][0]["params"]["kt"] == pytest.approx(rk4_rig.KT, rel=0.02)
    assert joint["laws"][0]["params"]["fs"] == pytest.approx(rk4_rig.FS, rel=0.02)


def _runs(levels, per_line: bool) -> list[SineRun]:
    """The levels as the analysis sees them, with the force measured per line or the nominal level at every
    line."""
    return [SineRun(f"sine_{F0:g}N_up", F0, "up", "x1", ["x1"], lv.frequency_hz, lv.receptance[:, None],
                    np.abs(lv.receptance[:, None]) * 1e-4, lv.force if per_line else None, np.zeros(len(LINES)))
            for F0, lv in zip(LEVELS, levels)]


def _jenkins_fit(runs: list[SineRun]):
    """The Jenkins law fitted on the rig's own reference (m, k, c known): its values and the model's FRF
    error."""
    doc = {"structure": {"type": "lumped", "dofs": ["x1"], "mass": [[rk4_rig.M]], "stiffness": [[rk4_rig.K]],
                         "damping": [[rk4_rig.C]]},
           "element": [{"name": "joint", "dof": "x1", "laws": [{"law": "jenkins"}]}]}
    wb = Workbench(load_model(doc), Measurements(runs))
    wb.identify()
    wb.fit()
    return wb.model.elements[0].laws[0].values, wb.compare().error


def test_a_force_drifting_25_percent_is_analysed_like_one_held(rk4_levels):
    """docs/import.md: with the force measured per line the law is the rig's (kt 6e-6, fs 1e-3 off); with the
    nominal force fs is 19 % off and the FRF error 0.2."""
    values, error = _jenkins_fit(_runs(rk4_levels, per_line=True))
    assert values["kt"] == pytest.approx(rk4_rig.KT, rel=0.05)
    assert values["fs"] == pytest.approx(rk4_rig.FS, rel=0.05)
    assert error < 0.01
    nominal, nominal_error = _jenkins_fit(_runs(rk4_levels, per_line=False))
    assert abs(nominal["fs"] / rk4_rig.FS - 1) > 0.1 and nominal_error > 10 * error


@pytest.mark.acceptance
def test_response_controlled_levels_give_the_law_of_the_force_controlled_ones(tmp_path, rk4_levels):
    """Levels holding 20, 50 and 100 um at x1 (the force per line what the controller needed), imported from CSV:
    the law their kbar gives is the rig's and that of the force-controlled levels."""
    targets = (2e-5, 5e-5, 1e-4)
    csv = tmp_path / "response.csv"
    rk4_rig.write_csv(csv, rk4_rig.response_controlled(targets, LINES), None, response_targets=targets)
    session = tmp_path / "response.h5"
    assert main(["import", str(csv), "-o", str(session), "--excitation", "x1"]) == 0
    from app.session import open_session
    from app.session.data import measurements_from_session
    with open_session(session) as s:
        runs = measurements_from_session(s).sine
    assert sorted(r.name for r in runs) == ["sine_x1_0.0001m_up", "sine_x1_2e-05m_up", "sine_x1_5e-05m_up"]
    for run in runs:
        held = np.abs(run.receptance[:, 0]) * run.force_per_line
        np.testing.assert_allclose(held, run.control.target, rtol=0.02)       # the controller's last correction
        # known noise for the fit (the import estimates it from the FRF's scatter otherwise)
        run.receptance_std = np.abs(run.receptance) * 1e-4
    values, error = _jenkins_fit(runs)
    forced, _ = _jenkins_fit(_runs(rk4_levels, per_line=True))
    for name, truth in (("kt", rk4_rig.KT), ("fs", rk4_rig.FS)):
        assert values[name] == pytest.approx(truth, rel=0.05)
        assert values[name] == pytest.approx(forced[name], rel=0.02)
    assert error < 0.01


@pytest.mark.slow
def test_reference_from_an_emulated_campaigns_lowest_level(tmp_path, capsys):
    """The same rig emulated (tests/rigs/jenkins-sdof.toml) and measured through the drivers, no random run:
    the reference command recovers the stuck frequency and damping, and the Jenkins law on it the joint's kt and fs."""
    import tomllib as toml
    from pathlib import Path

    from app.campaign.instruments import emulated_instruments
    from app.campaign.measure import run_plan
    from app.campaign.plan import parse_plan
    from drivers.simulation.rig import load_rig

    text = "".join(f"[[stepped_sine]]\nforce = {f}\nstart = 21.0\nstop = 25.0\nstep = 0.2\nrefine = false\n"
                   for f in (0.002, 0.01)) + "[limits]\nmax_force = 1.0\nmax_acceleration = 150.0\n"
    session, model = tmp_path / "emulated.h5", tmp_path / "reference.toml"
    with emulated_instruments(load_rig(Path(__file__).parent / "rigs" / "jenkins-sdof.toml"), seed=3) as inst:
        run_plan(parse_plan(toml.loads(text), text, "plan.toml"), inst, session)
    assert main(["reference", str(session), "-o", str(model)]) == 0
    s = tomllib.loads(model.read_text())["structure"]
    assert s["frequencies"][0] == pytest.approx(rk4_rig.stuck_frequency_hz(), rel=1e-3)
    assert s["damping"][0] == pytest.approx(rk4_rig.stuck_damping(), rel=0.05)
    assert "NONLINEAR already between the two lowest levels" in capsys.readouterr().out
    # the Jenkins joint added by hand, measured from the stuck state the reference holds: the rig's kt and fs
    assert main(["analyze", str(session), str(model), "--add", "joint:jenkins", "--json", "--no-history"]) == 0
    law = json.loads(capsys.readouterr().out)["elements"][0]["laws"][0]["params"]
    assert law["kt"] == pytest.approx(rk4_rig.KT, rel=0.05) and law["fs"] == pytest.approx(rk4_rig.FS, rel=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("in_reference", [True, False])
def test_a_jenkins_added_to_the_lowest_levels_reference_is_measured_from_its_stuck_state(rk4_session, capsys,
                                                                                          in_reference):
    """The lowest level holds the joint stuck, so its reference holds the slider's stiffness kt already
    (docs/laws.md, "Measured from the reference"). The element is marked so, and the Jenkins added by hand is
    measured from its stuck state: the RK4 rig's kt and fs, and an FRF error far below the reference's.
    Without the mark (the law added on top of a structure that holds kt already) the fit misses the rig."""
    model = rk4_session.with_name(f"reference_{in_reference}.toml")
    assert main(["reference", str(rk4_session), "-o", str(model)]) == 0
    if not in_reference:
        model.write_text(re.sub(r"in_reference = true\n(origin = .*\n)?", "", model.read_text()))
    capsys.readouterr()
    assert main(["analyze", str(rk4_session), str(model), "--add", "joint:jenkins", "--json", "--no-history"]) == 0
    result = json.loads(capsys.readouterr().out)
    law = result["elements"][0]["laws"][0]["params"]
    right = (law["kt"] == pytest.approx(rk4_rig.KT, rel=0.05) and law["fs"] == pytest.approx(rk4_rig.FS, rel=0.05))
    assert right == in_reference, law
    if in_reference:
        assert result["error"] < 0.05, result["error"]


LINEAR_RIG_TOML = """name = "sdof"
[structure]
type = "lumped"
dofs = ["x1"]
mass = [[1.0]]
stiffness = [[1.0e4]]
[excitation]
dof = "x1"
[sensors]
dofs = ["x1"]
"""


def test_in_reference_is_read_written_and_refused_where_it_cannot_hold():
    """docs/contracts.md §3: ``in_reference = true`` on a model's element makes its laws measured from their
    small-amplitude state; it survives a write and a read; a rig (the truth, simulated) and a non-boolean
    value are refused, naming the field."""
    from drivers.simulation.rig import parse_rig
    doc = {"structure": {"type": "lumped", "dofs": ["x1"], "mass": [[1.0]], "stiffness": [[1.0e4]]},
           "element": [{"name": "joint", "dof": "x1", "laws": [{"law": "jenkins"}, {"law": "cubic"}],
                        "in_reference": True}]}
    model = load_model(doc)
    el = model.elements[0]
    assert el.in_reference and el.surroundings.in_reference
    assert [t.law.from_reference for t in el.laws] == [True, False]          # a cubic has nothing to subtract
    assert el.law("iwan").from_reference and not model.copy().elements[0].laws[1].law.from_reference
    again = load_model(tomllib.loads(model.to_toml()))
    assert again.elements[0].in_reference and again.elements[0].laws[0].law.from_reference
    plain = load_model({**doc, "element": [{**doc["element"][0], "in_reference": False}]})
    assert not plain.elements[0].laws[0].law.from_reference and "in_reference" not in plain.to_toml()
    with pytest.raises(InputError, match=r"in_reference.*true or false"):
        load_model({**doc, "element": [{**doc["element"][0], "in_reference": "yes"}]})
    rig = (LINEAR_RIG_TOML + '[[element]]\nname = "joint"\ndof = "x1"\nin_reference = true\n'
           'laws = [{ law = "jenkins", kt = 1e3, fs = 1.0 }]\n')
    with pytest.raises(InputError, match=r"in_reference"):
        parse_rig(rig)


def test_an_origin_is_read_written_and_refused_without_in_reference():
    """docs/contracts.md §3: ``origin = { amplitude, frequency }`` beside ``in_reference = true`` makes the
    element's laws measured from its state there (docs/laws.md, "Measured from the reference"); it survives a
    write and a read; without ``in_reference``, or with a size that is no amplitude, it is refused naming the
    field."""
    doc = {"structure": {"type": "lumped", "dofs": ["x1"], "mass": [[1.0]], "stiffness": [[1.0e4]]},
           "element": [{"name": "joint", "dof": "x1", "laws": [{"law": "jenkins"}, {"law": "linear"}],
                        "in_reference": True, "origin": {"amplitude": 2e-5, "frequency": 80.0}}]}
    model = load_model(doc)
    el = model.elements[0]
    origin = Origin(2e-5, 2 * np.pi * 80.0)
    assert el.origin == origin and el.surroundings.origin == origin and el.law("iwan").origin == origin
    assert [t.law.origin for t in el.laws] == [origin, None]          # a linear law corrects the reference
    again = load_model(tomllib.loads(model.to_toml()))
    assert again.elements[0].origin == origin and again.elements[0].laws[0].law is el.laws[0].law
    assert model.copy().elements[0].origin == origin
    with pytest.raises(InputError, match=r"\[\[element\]\]\[0\]\.origin.*in_reference = true"):
        load_model({**doc, "element": [{**doc["element"][0], "in_reference": False}]})
    with pytest.raises(InputError, match=r"origin\.amplitude.*> 0"):
        load_model({**doc, "element": [{**doc["element"][0], "origin": {"amplitude": 0.0, "frequency": 80.0}}]})
    with pytest.raises(InputError, match=r"origin\.phase"):
        load_model({**doc, "element": [{**doc["element"][0], "origin": {"amplitude": 1e-5, "frequency": 80.0,
                                                                         "phase": 0.0}}]})


def _cubic_damping_receptance(frequency_hz: np.ndarray, force: np.ndarray, c3: float, periods: int = 150,
                              steps: int = 256) -> np.ndarray:
    """An SDOF with a cubic damper at its drive point, ``m x'' + c x' + c3 x'^3 + k x = F sin(w t)``, integrated by
    RK4 here (vectorised over lines, each from the linear steady state, in its own time tau = w t): the
    fundamental of the last period over F."""
    m, k, c = 1.0, 15791.367, 1.2566        # 20 Hz, 0.5 % of critical
    w, F = 2 * np.pi * frequency_hz, force
    start = F / (k - m * w ** 2 + 1j * c * w)
    x, v, h, tau = start.imag.copy(), w * start.real, 2 * np.pi / steps, 0.0

    def rhs(tau, x, v):
        return v / w, (F * np.sin(tau) - c * v - c3 * v ** 3 - k * x) / (m * w)

    last = np.zeros((steps, w.size))
    for n in range(periods * steps):
        k1 = rhs(tau, x, v)
        k2 = rhs(tau + h / 2, x + h / 2 * k1[0], v + h / 2 * k1[1])
        k3 = rhs(tau + h / 2, x + h / 2 * k2[0], v + h / 2 * k2[1])
        k4 = rhs(tau + h, x + h * k3[0], v + h * k3[1])
        x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        tau += h
        if n >= (periods - 1) * steps:
            last[n - (periods - 1) * steps] = x
    t = h * np.arange(1, steps + 1)
    return 2 / steps * ((last * np.sin(t)[:, None]).sum(axis=0) + 1j * (last * np.cos(t)[:, None]).sum(axis=0)) / F


CUBIC_C3 = 300.0          # N s^3/m^3: the cubic damper of the RK4 rig below


@pytest.fixture(scope="module")
def cubic_damping_session(tmp_path_factory):
    """Four force levels of the RK4 cubic-damper rig, imported, and the reference made from the lowest."""
    folder = tmp_path_factory.mktemp("cubic")
    levels, lines = (0.05, 0.1, 0.2, 0.4), np.linspace(19.0, 21.0, 41)
    f, force = np.tile(lines, len(levels)), np.repeat(levels, len(lines))
    H = _cubic_damping_receptance(f, force, CUBIC_C3)
    with open(folder / "rig.csv", "w") as fh:
        fh.write("frequency_hz,force_n,dof,re,im\n")
        fh.writelines(f"{float(fi)!r},{float(Fi)!r},x1,{float(hi.real)!r},{float(hi.imag)!r}\n"
                      for fi, Fi, hi in zip(f, force, H))
    session, reference = folder / "rig.h5", folder / "reference.toml"
    assert main(["import", str(folder / "rig.csv"), "-o", str(session), "--excitation", "x1"]) == 0
    assert main(["reference", str(session), "-o", str(reference)]) == 0
    return session, reference


@pytest.mark.slow
def test_a_law_measured_from_the_reference_levels_own_state_recovers_a_damper_that_acts_there(
        cubic_damping_session, capsys):
    """docs/laws.md, "Measured from the reference": a cubic damper dissipates at every amplitude, so the lowest
    level's reference holds part of it already. Measured from that level's resonance (the element's ``origin``)
    the law refitted on all levels is the rig's, within a few per cent; measured from no amplitude it holds that
    part twice and the fit takes it out of c3, with twice the FRF error. The data come from an RK4 integrator
    written here, not from the project's simulator."""
    session, reference = cubic_damping_session
    text = reference.read_text()
    assert "origin = { amplitude = " in text
    found = {}
    for name, text in (("origin", text), ("none", re.sub(r"origin = .*\n", "", text))):
        model = reference.with_name(f"{name}.toml")
        model.write_text(text)
        capsys.readouterr()
        assert main(["analyze", str(session), str(model), "--add", "joint:cubic_damping", "--json",
                     "--no-history"]) == 0
        result = json.loads(capsys.readouterr().out)
        found[name] = (result["elements"][0]["laws"][0]["params"]["c3"], result["error"])
    assert found["origin"][0] == pytest.approx(CUBIC_C3, rel=0.05), found
    assert found["none"][0] < 0.9 * CUBIC_C3 and found["none"][1] > 1.5 * found["origin"][1], found


@pytest.mark.slow
def test_the_window_says_where_an_elements_laws_are_measured_from(cubic_damping_session, qtbot):
    """The Model tab's laws tree names the reference level's state the element's laws are measured from, with
    the text ``analyze`` prints as its tooltip."""
    from app.gui.main_window import MainWindow
    session, reference = cubic_damping_session
    model = reference.with_name("with_law.toml")
    model.write_text(reference.read_text().replace("laws = []", 'laws = [{ law = "cubic_damping", c3 = 250.0 }]'))
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.lab.open_session(str(session))
    window.lab.load_model_file(str(model))
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=120000):
        window.lab.analyze()
    tree = window.model.laws
    [top] = [tree.topLevelItem(i) for i in range(tree.topLevelItemCount())
             if tree.topLevelItem(i).text(0).startswith("joint")]
    notes = [top.child(i) for i in range(top.childCount())]
    [note] = [n for n in notes if n.text(0) == "laws measured from the joint's state at the reference's level"]
    origin = load_model(tomllib.loads(model.read_text())).elements[0].origin
    assert f"amplitude {origin.X:.4g}, {origin.w / (2 * np.pi):.6g} Hz" in note.toolTip(0)


def test_the_origin_is_the_drive_point_at_the_resonance_not_at_the_largest_displacement():
    """docs/laws.md, "Measured from the reference": a level held at a constant acceleration has its largest
    displacement at its lowest line; the joint's state the reference holds is the one at its resonance, whose lines
    decide the modal fit: the origin is the mode's fitted frequency and the drive point's amplitude at the line
    nearest it, within ``--band`` where one is given."""
    fn, zeta, acceleration = 80.0, 0.002, 5.0
    f = np.linspace(78.0, 82.0, 81)
    w, wn = 2 * np.pi * f, 2 * np.pi * fn
    H = 1.0 / (wn ** 2 - w ** 2 + 2j * zeta * wn * w)              # m/N, a unit modal mass
    force = acceleration / (w ** 2 * np.abs(H))                      # the controller holds |a| = 5 m/s^2
    run = SineRun("sine_5mps2_up", 1.0, "up", "x1", ["x1"], f, H[:, None], force_achieved=force)
    reference = reference_from_level(Measurements([run]))
    fitted = reference.fit.frequency[0]
    assert fitted == pytest.approx(fn, rel=1e-6)
    assert reference.origin.w == pytest.approx(2 * np.pi * fitted, rel=1e-12)
    line = np.argmin(np.abs(f - fitted))
    assert reference.origin.X == pytest.approx(acceleration / w[line] ** 2, rel=1e-9)
    assert reference.origin.X < 0.97 * acceleration / w[0] ** 2      # not the lowest line's larger displacement
    band = reference_from_level(Measurements([run]), band=(79.0, 82.0))
    assert (band.origin.X, band.origin.w) == pytest.approx((reference.origin.X, reference.origin.w), rel=1e-9)
