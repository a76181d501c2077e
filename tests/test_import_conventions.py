"""Imports: the force measured per line and response-controlled levels in the CSV long format, and the sign
convention of the drive point checked where the CSV and UFF paths meet (app/importers/conventions.py)."""

import h5py
import numpy as np
import pytest

from app.cli import main
from app.export import export_uff
from app.session import RunSpec, SessionWriter, open_session
from app.session.data import measurements_from_session

F = np.linspace(18.0, 22.0, 21)
W = 2 * np.pi * F


def sdof(scale=1.0):
    """A drive-point receptance of 1 kg at 20 Hz, 1 % damping (Im < 0 under exp(+jwt))."""
    wr = 2 * np.pi * 20.0
    return scale / (wr ** 2 - W ** 2 + 2j * 0.01 * wr * W)


def write_csv(path, rows, columns="frequency_hz,force_n,dof,re,im"):
    path.write_text(columns + "\n" + "\n".join(",".join(str(c) for c in r) for r in rows) + "\n")
    return path


def test_a_reversed_force_is_refused_naming_the_flag_and_recorded_when_given(tmp_path, capsys):
    h = -sdof()                                            # the force's sign reversed
    csv = write_csv(tmp_path / "a.csv", [(f, 0.5, "x1", v.real, v.imag) for f, v in zip(F, h)])
    out = tmp_path / "s.h5"
    assert main(["import", str(csv), "-o", str(out), "--excitation", "x1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "a.csv: run sine_0.5N_up, frf x1 (drive point)" in err and "--force-sign -1" in err
    assert not out.exists()
    assert main(["import", str(csv), "-o", str(out), "--excitation", "x1", "--force-sign", "-1"]) == 0
    with open_session(out) as s:
        np.testing.assert_allclose(s.run("sine_0.5N_up").frf["x1"], sdof(), rtol=1e-15)
    with h5py.File(out) as f:
        assert f["provenance/import/source_0"].attrs["force_sign"] == -1.0


def test_a_mobility_labelled_as_receptance_is_refused(tmp_path, capsys):
    v = 1j * W * sdof()                                   # velocity / force
    csv = write_csv(tmp_path / "m.csv", [(f, 0.5, "x1", x.real, x.imag) for f, x in zip(F, v)])
    assert main(["import", str(csv), "-o", str(tmp_path / "s.h5"), "--excitation", "x1"]) == 2
    assert "mobility" in capsys.readouterr().err


def test_the_uff_path_is_checked_the_same_way(tmp_path, capsys):
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    w.begin_run(RunSpec("sine_0.5N_up", "stepped_sine", 0.5, "up", "x1", ["x1"], 1e3, ["force"], ["N"], {}))
    for f, h in zip(F, -sdof()):
        w.append_line(f, {"x1": h}, {})
    w.end_run("complete")
    w.close()
    files = export_uff(session, tmp_path / "e.uff").files
    assert main(["import", *map(str, files), "-o", str(tmp_path / "i.h5")]) == 2
    assert "--force-sign -1" in capsys.readouterr().err
    assert main(["import", *map(str, files), "-o", str(tmp_path / "i.h5"), "--force-sign", "-1"]) == 0


def test_response_controlled_levels_and_the_force_per_line(tmp_path, capsys):
    """Two levels holding 5 and 20 m/s^2 at x1: the force per line is what the controller needed."""
    h = sdof()
    rows = []
    for target in (5.0, 20.0):
        force = target / (W ** 2 * np.abs(h))             # the force that holds |A| = target
        rows += [(f, "", "x1", v.real, v.imag, fl, 0.1, "x1", "acceleration", target)
                 for f, v, fl in zip(F, h, force)]
    csv = write_csv(tmp_path / "r.csv", rows, "frequency_hz,force_n,dof,re,im,force_amplitude_n,force_phase_rad,"
                                              "control_dof,control_quantity,control_target")
    out = tmp_path / "s.h5"
    assert main(["import", str(csv), "-o", str(out), "--excitation", "x1"]) == 0
    assert "run sine_x1_20mps2_up" in capsys.readouterr().out
    with open_session(out) as s:
        attrs = s.run("sine_x1_5mps2_up").attrs
        assert (attrs["control"], attrs["control_dof"], attrs["control_quantity"], attrs["control_target"],
                attrs["control_units"]) == ("response", "x1", "acceleration", 5.0, "m/s^2")
        m = measurements_from_session(s)
    run = next(r for r in m.sine if r.name == "sine_x1_5mps2_up")
    assert run.control.label() == "5 m/s^2 at x1"
    np.testing.assert_allclose(run.force_per_line, 5.0 / (W ** 2 * np.abs(h)), rtol=1e-15)
    assert run.force == pytest.approx(np.median(run.force_per_line), rel=1e-15)
    # what the level held, recomputed from the stored FRF and force: the target at every line
    np.testing.assert_allclose(W ** 2 * np.abs(run.receptance[:, 0]) * run.force_per_line, 5.0, rtol=1e-12)


@pytest.mark.parametrize("column, value, message", [
    ("force_amplitude_n", "-0.1", "force_amplitude_n: '-0.1' is not a force amplitude > 0 N"),
    ("control_quantity", "jerk", "control_quantity: 'jerk' is not one of displacement, velocity, acceleration"),
])
def test_bad_control_and_force_columns_name_the_line(tmp_path, capsys, column, value, message):
    columns = ["frequency_hz", "force_n", "dof", "re", "im", "force_amplitude_n", "control_dof", "control_quantity",
               "control_target"]
    h = sdof()
    rows = [[f, "", "x1", v.real, v.imag, 0.3, "x1", "acceleration", 5.0] for f, v in zip(F, h)]
    rows[3][columns.index(column)] = value
    csv = write_csv(tmp_path / "b.csv", rows, ",".join(columns))
    assert main(["import", str(csv), "-o", str(tmp_path / "s.h5"), "--excitation", "x1"]) == 2
    err = capsys.readouterr().err
    assert "b.csv: line 5: " + message in err


@pytest.mark.slow
def test_export_csv_long_carries_the_force_per_line_and_the_control_back(tmp_path, capsys):
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    extras = {"force_amplitude": ("N", (), "f8"), "force_phase": ("rad", (), "f8"), "frf_std/x1": ("m/N", (), "f8"),
              "frf_std/x2": ("m/N", (), "f8")}
    control = {"control": "response", "control_dof": "x1", "control_quantity": "acceleration",
               "control_target": 20.0, "control_units": "m/s^2"}
    rng = np.random.default_rng(3)
    held = 0.7 * (1 + 0.2 * rng.random(len(F)))
    for name, force, measured, direction, attrs in (
            ("sine_0.5N_down", 0.5, 0.5 * (1 + 0.2 * rng.random(len(F))), "down", {}),
            ("sine_x1_20mps2_up", float(np.median(held)), held, "up", control)):   # the median: the vocabulary's
        w.begin_run(RunSpec(name, "stepped_sine", force, direction, "x1", ["x1", "x2"], 1e3, ["force"], ["N"],
                            extras, attrs))
        for i, f in enumerate(F[::-1] if direction == "down" else F):
            h = sdof()[np.argmin(np.abs(F - f))]
            w.append_line(f, {"x1": h, "x2": 0.3 * h}, {"force_amplitude": measured[i],
                                                        "force_phase": rng.normal(), "frf_std/x1": 1e-9 * rng.random()
                                                        + 1e-10, "frf_std/x2": 2e-10})
        w.end_run("complete")
    w.close()
    long = tmp_path / "long.csv"
    assert main(["export", str(session), "--csv-long", str(long)]) == 0
    imported = tmp_path / "i.h5"
    assert main(["import", str(long), "-o", str(imported), "--excitation", "x1"]) == 0
    with open_session(session) as a, open_session(imported) as b:
        before, after = measurements_from_session(a), measurements_from_session(b)
    assert [r.name for r in after.sine] == [r.name for r in before.sine]
    for r0, r1 in zip(before.sine, after.sine):
        assert (r1.force, r1.direction, r1.control, r1.sensor_dofs) == (r0.force, r0.direction, r0.control,
                                                                        r0.sensor_dofs)
        for name in ("frequency_hz", "receptance", "receptance_std", "force_per_line"):
            np.testing.assert_array_equal(getattr(r1, name), getattr(r0, name), err_msg=name)


def test_error_by_level_names_a_response_controlled_level_by_its_target(tmp_path):
    """Two sweeps held at 5 m/s^2 are one level, named by the response held; the error per level is the
    closed-form one of a model whose receptance is off by a known factor, and the stored history keeps the
    labels."""
    from analysis.common.measurements import Control, Measurements, SineRun
    from analysis.mechanics.model import load_model
    from analysis.loop.workbench import Workbench
    from app.session import append_model_history, read_model_history

    h = sdof()[:, None]
    held = Control("response", "x1", "acceleration", 5.0)
    runs = [SineRun("sine_0.5N_up", 0.5, "up", "x1", ["x1"], F, 1.1 * h),
            SineRun("sine_x1_5mps2_up", 0.4, "up", "x1", ["x1"], F, h, force_achieved=np.full(len(F), 0.4),
                    control=held),
            SineRun("sine_x1_5mps2_down", 0.4, "down", "x1", ["x1"], F[::-1], h[::-1] * 1.2,
                    force_achieved=np.full(len(F), 0.4), control=held)]
    model = load_model({"structure": {"type": "lumped", "dofs": ["x1"], "mass": [[1.0]],
                                      "stiffness": [[(2 * np.pi * 20.0) ** 2]],
                                      "damping": [[2 * 0.01 * 2 * np.pi * 20.0]]},
                        "element": [{"name": "e", "dof": "x1", "laws": [{"law": "linear", "k": 0.0, "c": 0.0}]}]})
    wb = Workbench(model, Measurements(runs))
    levels = wb.compare().error_by_level
    assert [e.label() for e in levels] == ["0.5 N", "5 m/s^2 at x1"]
    assert levels[0].error == pytest.approx(0.1 / 1.1, rel=1e-9)
    assert levels[1].error == pytest.approx(np.sqrt(0.2 ** 2 / (1 + 1.2 ** 2)), rel=1e-9)   # both sweeps
    assert levels[1].to_json() == {"force": 0.4, "error": levels[1].error, "control": "response",
                                   "control_dof": "x1", "control_quantity": "acceleration", "control_target": 5.0,
                                   "control_units": "m/s^2", "label": "5 m/s^2 at x1"}
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    w.begin_run(RunSpec("sine_0.5N_up", "stepped_sine", 0.5, "up", "x1", ["x1"], 1e3, ["force"], ["N"], {}))
    w.append_line(20.0, {"x1": complex(h[0, 0])}, {})
    w.end_run("complete")
    w.close()
    wb.record("start")
    append_model_history(session, [step.to_json() for step in wb.history], "m.toml")
    with open_session(session) as s:
        step = read_model_history(s)[0]["steps"][0]
    assert step["error_by_level"] == [[0.5, levels[0].error], [0.4, levels[1].error]]
    assert [lv["label"] for lv in step["levels"]] == ["0.5 N", "5 m/s^2 at x1"]


@pytest.mark.parametrize("attrs, message", [
    ({"control": "sideways"}, "attribute control: must be one of force, response, open_loop, got 'sideways'"),
    ({"control": "response", "control_dof": "x1", "control_quantity": "acceleration", "control_target": -5.0},
     "attribute control_target: must be a finite amplitude > 0, got -5.0"),
])
def test_impossible_control_attributes_are_refused_naming_the_run(tmp_path, attrs, message):
    from analysis import InputError
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    w.begin_run(RunSpec("sine_0.5N_up", "stepped_sine", 0.5, "up", "x1", ["x1"], 1e3, ["force"], ["N"], {}, attrs))
    w.append_line(20.0, {"x1": complex(sdof()[10])}, {})
    w.end_run("complete")
    w.close()
    with open_session(session) as s, pytest.raises(InputError, match="run sine_0.5N_up, " + message):
        measurements_from_session(s)
