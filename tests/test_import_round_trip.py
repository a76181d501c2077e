"""export then import needs no flags and gives the analysis the same numbers as the session it came from."""
import json
import tomllib

import numpy as np
import pytest
import pyuff

from analysis.common.measurements import Control
from analysis.mechanics.model import load_model
from app.analyze import run_workbench
from app.cli import main
from app.importers.idlines import RecordTag, decode, encode
from app.importers.runs import SourceOptions
from app.importers.store import ImportRequest, import_files
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.models import asset
from app.campaign.plan import load_plan
from app.session.writer import RunSpec, SessionWriter, open_session
from app.session.data import measurements_from_session
from drivers.simulation.rig import builtin_rig_path, load_rig

PAPER_2DOF_LAWS = {"left": ["cubic", "quadratic_damping"], "right": ["cubic", "coulomb"]}

def _plan(force_rms, band, levels, sweep, max_acceleration):
    """A short plan: a random run, then one sweep (start, stop, step) per force level."""
    sines = "".join(f"[[stepped_sine]]\nforce = {f}\nstart = {sweep[0]}\nstop = {sweep[1]}\nstep = {sweep[2]}\n"
                    for f in levels)
    return (f"[random]\nforce_rms = {force_rms}\nband = {list(band)}\nduration = 24.0\n{sines}"
            f"[limits]\nmax_force = 5.0\nmax_acceleration = {max_acceleration}\n")


PLANS = {"paper-2dof": _plan(0.05, (0.5, 5.0), (0.4, 0.8), (1.0, 2.8, 0.2), 50.0),
         "paper-beam": _plan(0.01, (20.0, 200.0), (0.3, 1.2), (51.5, 54.5, 0.3), 400.0)}


def _laws(wb):
    return {el.name: [(t.law.name, t.values) for t in el.laws] for el in wb.model.elements}


@pytest.mark.slow
# the beam's whole analysis is an acceptance case; the 2-DOF's checks the path in the suite (docs/architecture.md)
@pytest.mark.parametrize("rig", [rig if rig == "paper-2dof" else pytest.param(rig, marks=pytest.mark.acceptance)
                                 for rig in sorted(PLANS)])
def test_simulate_export_import_analyze_gives_the_same_laws_and_error(rig, tmp_path):
    (tmp_path / "plan.toml").write_text(PLANS[rig])
    session = tmp_path / "s.h5"
    with emulated_instruments(load_rig(rig), seed=2) as inst:
        assert not run_plan(load_plan(tmp_path / "plan.toml"), inst, session).aborted
    if rig == "paper-2dof":                     # the rig's structure, the paper's laws to fit
        structure = tomllib.loads(builtin_rig_path(rig).read_text())["structure"]
        elements = [{"name": n, "dof": d, "laws": PAPER_2DOF_LAWS[n]} for n, d in (("left", "x1"), ("right", "x2"))]
        model = tmp_path / "model.toml"
        model.write_text(load_model({"structure": structure, "element": elements}).to_toml())
    else:
        model = asset("paper-beam.model.toml")
    assert main(["export", str(session), "--uff", str(tmp_path / "e.uff")]) == 0       # the default flags
    assert main(["export", str(session), "--csv", str(tmp_path / "csv")]) == 0
    imported, from_csv = tmp_path / "imported.h5", tmp_path / "from_csv.h5"
    assert main(["import", *map(str, sorted(tmp_path.glob("e_*.uff"))), "-o", str(imported)]) == 0   # no flags
    assert main(["import", *map(str, sorted((tmp_path / "csv").glob("*.csv"))), "-o", str(from_csv)]) == 0
    wb0, ranked0 = run_workbench(session, model)
    for again in (imported, from_csv):
        _same_analysis(wb0, ranked0, *run_workbench(again, model))


def _same_analysis(wb0, ranked0, wb1, ranked1):
    assert wb1.compare().error == pytest.approx(wb0.compare().error, rel=1e-6)
    for (name, terms0), terms1 in zip(_laws(wb0).items(), _laws(wb1).values()):
        assert [t for t, _ in terms0] == [t for t, _ in terms1]
        for (_, v0), (_, v1) in zip(terms0, terms1):
            assert v1 == pytest.approx(v0, rel=1e-6), name
        assert wb1.reports[name].verdict.linear == wb0.reports[name].verdict.linear
    assert [(c.element, c.law) for c in ranked1] == [(c.element, c.law) for c in ranked0]
    for c0, c1 in zip(ranked0, ranked1):
        assert c1.error == pytest.approx(c0.error, rel=1e-6)


FS, SEGMENT = 2048.0, 27307          # the demo's random run: lines 0.0749991... Hz apart (not six digits)


def _random_run(w: SessionWriter, rng) -> None:
    """A random run as a campaign writes it: Welch lines of 2048 Hz / 27307 samples, coherence, random error."""
    f = FS / SEGMENT * np.arange(300, 330)
    w.begin_run(RunSpec("random", "random", 0.01, "none", "A.w", ["A.w", "B.theta"], FS, ["force"], ["N"],
                        {"coherence/A.w": ("1", (), "f8"), "coherence/B.theta": ("1", (), "f8"),
                         "random_error/A.w": ("1", (), "f8"), "random_error/B.theta": ("1", (), "f8")},
                        {"segment_length": SEGMENT, "band": [20.0, 200.0], "duration": 60.0}))
    # a drive point takes energy in: Im < 0 (the import checks it, docs/import.md "Conventions")
    w.write_arrays({"frequency": f, "frf/A.w": (rng.normal(size=30) - 1j * np.abs(rng.normal(size=30))) * 1e-5,
                    "frf/B.theta": (rng.normal(size=30) + 1j * rng.normal(size=30)) * 1e-4,
                    "coherence/A.w": rng.random(30), "coherence/B.theta": rng.random(30),
                    "random_error/A.w": rng.random(30) * 0.1, "random_error/B.theta": rng.random(30) * 0.1})
    w.end_run("complete")


def _sdypy_reads(path) -> np.ndarray:
    """What sdypy-EMA's ``Model.read_uff`` does with a file (sdypy/EMA/EMA.py, 0.31): every set read by pyuff,
    the function-type-4 records stacked into one array, the abscissa of the first, the FRF form from the first
    dataset 58's ordinate type. Returns the (records, lines) array."""
    uff = pyuff.UFF(str(path))
    types = uff.get_set_types()
    assert 58 in types
    ind58 = np.argwhere(types == 58)[:, 0]
    data = uff.read_sets()
    frf = np.asarray([data[i]["data"] for i in ind58 if data[i]["func_type"] == 4])
    freq = np.asarray([data[i]["x"] for i in ind58 if data[i]["func_type"] == 4])[0]
    assert frf.dtype == complex and frf.ndim == 2 and frf.shape[1] == len(freq)      # not ragged
    assert np.all(np.diff(freq) > 0)                 # its band cut (_freq_to_index) finds lines in a rising axis
    assert data[ind58[0]]["ordinate_spec_data_type"] == 8                            # receptance
    return frf


def test_the_default_export_holds_every_line_exactly_and_modal_tools_read_each_file(tmp_path):
    """Runs of different lengths, a random run's spacing that six digits cannot hold: the default export (one
    binary file per run) works, keeps every frequency exact and reads as sdypy-EMA reads it."""
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    _random_run(w, np.random.default_rng(3))
    for direction, lines in (("up", (50.0, 50.0125, 50.5)), ("down", (50.5, 50.25, 50.0125, 50.0))):
        w.begin_run(RunSpec(f"sine_0.5N_{direction}", "stepped_sine", 0.5, direction, "A.w", ["A.w", "B.theta"],
                            1e3, ["force"], ["N"]))
        for k, f in enumerate(lines):
            w.append_line(f, {"A.w": 1e-5 * (1 - 1j) * (k + 1), "B.theta": 1e-4j * (k + 1)})
        w.end_run("complete")
    w.close()
    assert main(["export", str(session), "--uff", str(tmp_path / "e.uff")]) == 0
    files = sorted(tmp_path.glob("e_*.uff"))
    assert [p.name for p in files] == ["e_random.uff", "e_sine_0.5N_down.uff", "e_sine_0.5N_up.uff"]
    with open_session(session) as s:
        for path in files:
            run = s.run(path.stem[2:])
            order = np.argsort(run.frequency)                 # a down sweep is written rising
            frf = _sdypy_reads(path)
            np.testing.assert_array_equal(frf, np.stack([run.frf[d][order] for d in run.sensor_dofs]))
            [x] = {tuple(r["x"]) for r in pyuff.UFF(str(path)).read_sets() if r.get("func_type") == 4}
            np.testing.assert_array_equal(x, run.frequency[order])
    assert main(["export", str(session), "--uff", str(tmp_path / "a.uff"), "--ascii"]) == 2    # six digits


@pytest.mark.parametrize("route", ["uff", "csv"])
@pytest.mark.slow
def test_what_the_analysis_reads_survives_export_and_import(tmp_path, route):
    """A short session with everything the analysis uses: FRFs, their noise, the force held, harmonics, and a
    random run's coherence, random error and Welch resolution; exported with the default flags (UFF) or as CSV,
    imported with none."""
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    extras = {"force_amplitude": ("N", (), "f8"), "frf_std/A.w": ("m/N", (), "f8"),
              "frf_std/B.theta": ("rad/N", (), "f8"), "harmonics/acc:A.w": ("m/s^2", (4,), "c16"),
              "harmonics/acc:B.theta": ("rad/s^2", (4,), "c16")}
    rng = np.random.default_rng(1)
    for direction, freqs in (("up", [50.0, 50.0125, 50.5, 51.0]), ("down", [51.0, 50.25, 50.0])):
        w.begin_run(RunSpec(f"sine_0.5N_{direction}", "stepped_sine", 0.5, direction, "A.w", ["A.w", "B.theta"],
                            1e3, ["force"], ["N"], extras))
        for f in freqs:
            # the drive point passive (Im < 0): an import refuses energy flowing out (app/importers/conventions.py)
            frf = {"A.w": complex(rng.normal(), -abs(rng.normal())) * 1e-5,
                   "B.theta": complex(*rng.normal(size=2)) * 1e-4}
            w.append_line(f, frf, {"force_amplitude": 0.5 + rng.normal() * 1e-3,
                                   "frf_std/A.w": 1e-8 * (1 + rng.random()), "frf_std/B.theta": 1e-7,
                                   "harmonics/acc:A.w": rng.normal(size=4) + 1j * rng.normal(size=4),
                                   "harmonics/acc:B.theta": rng.normal(size=4) + 0j})
        w.end_run("complete")
    _random_run(w, rng)
    w.close()
    out = tmp_path / "out"
    out.mkdir()
    assert main(["export", str(session), f"--{route}", str(out / "e.uff" if route == "uff" else out)]) == 0
    files = sorted(out.glob(f"*.{route}"))
    assert len(files) == 3
    import_files(ImportRequest([(str(p), SourceOptions()) for p in files], str(tmp_path / "i.h5")))
    with open_session(session) as a, open_session(tmp_path / "i.h5") as b:
        before, after = measurements_from_session(a), measurements_from_session(b)
        assert b.run("sine_0.5N_down").attrs["imported"]
    r0, r1 = before.random, after.random
    assert r0.resolution == FS / SEGMENT and r1.resolution == r0.resolution      # the leakage allowance kept
    assert (r1.excitation_dof, r1.sensor_dofs, r1.force_rms) == (r0.excitation_dof, r0.sensor_dofs, r0.force_rms)
    for field in ("frequency_hz", "receptance", "coherence", "random_error"):
        np.testing.assert_array_equal(getattr(r1, field), getattr(r0, field), err_msg=field)
    for r0, r1 in zip(before.sine, after.sine):
        assert (r1.name, r1.force, r1.direction, r1.excitation_dof, r1.sensor_dofs) == \
            (r0.name, r0.force, r0.direction, r0.excitation_dof, r0.sensor_dofs)
        assert not r1.noise_estimated
        for field in ("frequency_hz", "receptance", "receptance_std", "force_achieved", "distortion"):
            np.testing.assert_array_equal(getattr(r1, field), getattr(r0, field), err_msg=field)


K2 = np.array([[11000.0, -6000.0], [-6000.0, 12500.0]])      # x1, x2 of 1 kg each: modes at 12.0 and 21.2 Hz
LINES = np.linspace(11.0, 13.0, 11)
HELD = {"control": "response", "control_dof": "x1", "control_quantity": "acceleration", "control_target": 20.0,
        "control_units": "m/s^2"}
MODEL_2DOF = ('[structure]\ntype = "lumped"\ndofs = ["x1", "x2"]\nmass = [[1.0, 0.0], [0.0, 1.0]]\n'
              'stiffness = [[11000.0, -6000.0], [-6000.0, 12500.0]]\ndamping = [[1.1, -0.6], [-0.6, 1.25]]\n'
              '[[element]]\nname = "j"\ndof = "x2"\nlaws = ["linear"]\n')


def _driven_at_x1(f: np.ndarray, kbar: complex) -> np.ndarray:
    """Receptances x1/F, x2/F of the 2-DOF structure with a joint kbar at x2, driven at x1 (lines x DOFs)."""
    w = 2 * np.pi * f[:, None, None]
    dynamic = K2 + np.diag([0.0, 1.0]) * kbar - w ** 2 * np.eye(2) + 1j * w * 1e-4 * K2
    return np.linalg.solve(dynamic, np.broadcast_to([1.0, 0.0], (len(f), 2))[..., None])[..., 0]


def _held_levels_session(path) -> None:
    """A force-controlled sweep down (the force measured at each line drifting around 0.5 N) and a sweep up
    holding 20 m/s^2 at x1 (the force per line what holds it, the run's force their median)."""
    w = SessionWriter(path, software_version="t")
    extras = {"force_amplitude": ("N", (), "f8"), "frf_std/x1": ("m/N", (), "f8"), "frf_std/x2": ("m/N", (), "f8")}
    drift = 0.5 * (1 + 0.2 * np.random.default_rng(5).random(len(LINES)))
    for name, direction, kbar, attrs in (("sine_0.5N_down", "down", 300.0 + 20j, {}),
                                         ("sine_x1_20mps2_up", "up", 150.0 + 40j, HELD)):
        f = LINES[::-1] if direction == "down" else LINES
        h = _driven_at_x1(f, kbar)
        force = 20.0 / ((2 * np.pi * f) ** 2 * np.abs(h[:, 0])) if attrs else drift
        w.begin_run(RunSpec(name, "stepped_sine", float(np.median(force)) if attrs else 0.5, direction, "x1",
                            ["x1", "x2"], 1e3, ["force"], ["N"], extras, attrs))
        for line, x, fl in zip(f, h, force):
            w.append_line(line, {"x1": x[0], "x2": x[1]}, {"force_amplitude": fl, "frf_std/x1": 1e-3 * abs(x[0]),
                                                            "frf_std/x2": 1e-3 * abs(x[1])})
        w.end_run("complete")
    w.close()


def _analysis(session, model, capsys) -> dict:
    capsys.readouterr()
    assert main(["analyze", str(session), str(model), "--json", "--no-history"]) == 0
    return json.loads(capsys.readouterr().out)


def _assert_same(a, b, where="analysis"):
    """Every number of two analyze --json outputs equal to 1e-6, every other value equal."""
    assert type(a) is type(b) or {type(a), type(b)} <= {int, float}, where
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert b == pytest.approx(a, rel=1e-6, abs=1e-12), where
    else:
        assert a == b, where


@pytest.mark.slow
def test_how_each_level_was_held_survives_every_export_and_import(tmp_path, capsys):
    """A force-controlled and a response-controlled level, exported by UFF (default flags), per-run CSV and
    the long CSV, imported back: the same runs (names, control, FRFs, force per line) and the same analysis."""
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    _held_levels_session(session)
    model.write_text(MODEL_2DOF)
    assert main(["export", str(session), "--uff", str(tmp_path / "e.uff")]) == 0
    assert main(["export", str(session), "--csv", str(tmp_path / "csv")]) == 0
    assert main(["export", str(session), "--csv-long", str(tmp_path / "long.csv")]) == 0
    routes = {"uff": [*map(str, sorted(tmp_path.glob("e_*.uff")))],
              "csv": [*map(str, sorted((tmp_path / "csv").glob("*.csv")))],
              "csv-long": [str(tmp_path / "long.csv"), "--excitation", "x1"]}
    original = _analysis(session, model, capsys)
    assert [e["label"] for e in original["history"][0]["error_by_level"]] == ["0.5 N", "20 m/s^2 at x1"]
    with open_session(session) as s:
        before = measurements_from_session(s).sine
    for route, args in routes.items():
        imported = tmp_path / f"{route}.h5"
        assert main(["import", *args, "-o", str(imported)]) == 0, route
        capsys.readouterr()
        with open_session(imported) as s:
            after = measurements_from_session(s).sine
        assert [r.name for r in after] == [r.name for r in before], route
        for r0, r1 in zip(before, after):
            assert (r1.control, r1.force, r1.direction, r1.sensor_dofs) == \
                (r0.control, r0.force, r0.direction, r0.sensor_dofs), route
            for name in ("frequency_hz", "receptance", "receptance_std", "force_per_line"):
                np.testing.assert_array_equal(getattr(r1, name), getattr(r0, name), err_msg=f"{route} {name}")
        _assert_same(original, _analysis(imported, model, capsys), route)


@pytest.mark.parametrize("route, wrong, message", [
    ("uff", "held=acceleration", "record 2: id3: held= must be displacement, velocity or acceleration"),
    ("uff", "target=20.0", "record 2: id3: target='twenty' is not a number"),
    ("csv", "control=response", "line 2: control= must be one of force, response, open_loop"),
    ("csv", "target=20.0", "line 2: target= must be a finite amplitude > 0, got -20.0"),
])
def test_an_impossible_control_tag_is_refused_naming_file_record_and_tag(tmp_path, capsys, route, wrong, message):
    session = tmp_path / "s.h5"
    _held_levels_session(session)
    bad = {"held=acceleration": "held=jerk0000000", "target=20.0": "target=twenty" if route == "uff" else
           "target=-20.0", "control=response": "control=sideways"}[wrong]
    if route == "uff":
        assert main(["export", str(session), "--uff", str(tmp_path / "e.uff"), "--ascii"]) == 0
        path = tmp_path / "e_sine_x1_20mps2_up.uff"
        text = path.read_text()
        assert wrong in text
        path.write_text(text.replace(wrong, bad.ljust(len(wrong))))    # the 80-column lines kept
    else:
        assert main(["export", str(session), "--csv", str(tmp_path / "csv")]) == 0
        path = tmp_path / "csv" / "sine_x1_20mps2_up.csv"
        path.write_text(path.read_text().replace(wrong, bad))
    out = tmp_path / "i.h5"
    assert main(["import", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{path}: {message}" in err, err
    assert not out.exists()


@pytest.mark.parametrize("control", [Control("open_loop", "x1", "force", 0.7),
                                     Control("response", "B.theta", "velocity", 0.30000000000000004)])
def test_a_held_level_is_read_back_from_its_id_lines_exactly(control):
    """Every mode's words fit the 80 columns (the time shortened beside a long target) and give the same control
    back (an open-loop level's target is its force); without them a level was held at its force."""
    tag = RecordTag("r", "frf", "A.w", "A.w", "stepped_sine", 0.7, "up", "complete", 3, control=control)
    ids = encode(tag, "2026-11-23T10:00:00+00:00", "1.0", "run r")
    assert ids["id3"].startswith("2026-11-23T") and " control=" in ids["id3"] and len(ids["id3"]) <= 80
    assert decode(ids, "f.uff: record 2").control == control
    assert decode({**ids, "id3": "2026-11-23T10:00:00+00:00"}, "f").control == Control("force", "A.w", "force", 0.7)
