"""Issue 54: one rule per quantity at every door, nothing lost on the way out and back, nothing lost through a
link. Each test is one case of the hostile pass: a traceback (exit 1) that is now a one-line error (exit 2),
or data an export dropped or changed that now come back."""
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis.common.quantities import dof_name_problem, force_problem
from app.campaign.plan import parse_plan
from app.cli import main
from app.session.writer import RunSpec, SessionWriter, append_model_history
from analysis.common.errors import InputError
from paper_structure import PAPER_STRUCTURE

ROOT = Path(__file__).resolve().parents[1]
M, K = np.diag([1.0, 2.0]), np.array([[200.0, -100.0], [-100.0, 200.0]])
FREQS = np.linspace(1.0, 3.5, 30)
LIMITS = "[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n"


def receptance(f):
    om = 2 * np.pi * f
    return np.linalg.inv(K - om ** 2 * M + 0.02j * om * K)[:, 1]


def write_session(path, levels=((0.8, True, "complete"),), phase_run=False, force_target=False,
                  sensors=("x1", "x2")):
    """The paper's linear 2-DOF structure, one stepped-sine run per ``(force, with frf_std, status)``, each line
    with the force measured as a campaign stores it (amplitude, phase, phasor); optionally a phase-resonance run
    and a dataset no interchange format carries (``force_target``)."""
    w = SessionWriter(path, software_version="test")
    for force, std, status in levels:
        extras = {"force_amplitude": ("N", (), "f8"), "force_phase": ("rad", (), "f8"),
                  "force_phasor": ("N", (), "c16")}
        if std:
            extras.update({f"frf_std/{d}": ("m/N", (), "f8") for d in sensors})
        if force_target:
            extras["force_target"] = ("N", (), "f8")
        w.begin_run(RunSpec(f"sine_{force:g}N_up", "stepped_sine", force, "up", "x2", list(sensors), 100.0,
                            ["force"], ["N"], extras))
        for i, f in enumerate(FREQS):
            H = receptance(f)
            measured = force * (1 + 0.01 * np.sin(i)) * np.exp(0.1j + 0.01j * i)
            line = {"force_amplitude": abs(measured), "force_phase": float(np.angle(measured)),
                    "force_phasor": measured}
            H = dict(zip(("x1", "x2"), H))
            if std:
                line.update({f"frf_std/{d}": 1e-4 * abs(H[d]) for d in sensors})
            if force_target:
                line["force_target"] = force
            w.append_line(f, {d: H[d] for d in sensors}, line)
        w.end_run(status, "the force missed its target" if status == "failed" else "")
    if phase_run:
        extras = {"harmonics/acc:x2": ("m/s^2", (3,), "c16"), "lock_converged": ("1", (), "?"),
                  "force_amplitude": ("N", (), "f8")}
        w.begin_run(RunSpec("phase_x2_90deg", "phase_resonance", 0.2, "up", "x2", ["x1", "x2"], 100.0, ["force"],
                            ["N"], extras, {"phase_dof": "x2", "target_phase": 90.0, "phase_tolerance": 1.0,
                                            "forces": json.dumps([0.1, 0.2]), "start": 1.5}))
        for force, f in ((0.1, 1.55), (0.2, 1.54)):
            H = receptance(f)
            w.append_line(f, {"x1": H[0], "x2": H[1]}, {"harmonics/acc:x2": np.array([1.0 + 0j, 0.01, 0.001]),
                                                        "lock_converged": True, "force_amplitude": force})
        w.end_run("complete")
    w.close()


def one_line_error(capsys, *names) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("contactid: error: "), err
    assert "Traceback" not in err and "debug" not in err, err
    for name in names:
        assert str(name) in err, err
    return err


def long_csv(path, dofs=("x1", "x2"), force="0.8", cells: dict[str, str] | None = None):
    """One level in the CSV long format: the receptances at FREQS, the level's ``force`` and ``cells`` (column ->
    the same cell on every row; an empty cell: not given)."""
    cells = {"force_n": force, **(cells or {})}
    rows = [",".join(["frequency_hz", "dof", "re", "im", *cells])]
    for i, dof in enumerate(dofs):
        rows += [",".join([repr(float(f)), dof, repr(float(receptance(f)[i].real)),
                           repr(float(receptance(f)[i].imag)), *cells.values()]) for f in FREQS]
    path.write_text("\n".join(rows) + "\n")
    return path


# --------------------------------------------------------------------------- tracebacks (exit 1) -> exit 2
@pytest.mark.parametrize("dofs, excitation", [
    ([".", "x2"], "x2"),                 # names the run's own group: the writer crashed (SessionWriteError)
    (["a", "a/b"], "a/b"),               # a dataset and a group of one name: the writer crashed
    (["x1", "../x2"], "../x2"),          # not a path: a DOF name, once stored as nested HDF5 groups
    (["x" * 65, "x2"], "x2"),            # longer than any format carries
])
def test_a_dof_name_that_is_no_name_is_refused_at_import_naming_file_and_field(tmp_path, capsys, dofs, excitation):
    csv = long_csv(tmp_path / "c.csv", dofs)
    out = tmp_path / "s.h5"
    assert main(["import", str(csv), "-o", str(out), "--excitation", excitation]) == 2
    bad = next(d for d in dofs if dof_name_problem(d))
    one_line_error(capsys, "c.csv", "sensor_dofs" if bad != excitation else "excitation_dof",
                   dof_name_problem(bad))
    assert not out.exists()


def test_the_plan_holds_dof_names_to_the_same_rule_in_the_same_words():
    text = f'[[phase_resonance]]\ndof = "a/b"\nforces = [0.1]\nstart = 1.5\n{LIMITS}'
    with pytest.raises(InputError) as err:
        parse_plan(__import__("tomllib").loads(text), text, "p.toml")
    assert "[[phase_resonance]][0].dof" in str(err.value) and dof_name_problem("a/b") in str(err.value)
    for good in ("x1", "A.w", "O.theta", "n_12"):
        assert dof_name_problem(good) is None


def test_reference_writes_its_model_before_it_prints_so_a_closed_pipe_costs_nothing(tmp_path):
    """``contactid reference S -o M.toml | head -1``: the model was never written (BrokenPipeError)."""
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session)
    child = subprocess.Popen([sys.executable, "-c", "import sys; from app.cli import main; sys.exit(main())",
                              "reference", str(session), "-o", str(model)], cwd=ROOT, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)})
    child.stdout.close()                     # the reader is gone before the first line is printed
    err = child.stderr.read().decode()
    assert child.wait(timeout=120) == 0, err
    assert "Traceback" not in err and "Error" not in err, err
    assert 'type = "modal"' in model.read_text()


def _plan_error(text: str) -> str:
    with pytest.raises(InputError) as err:
        parse_plan(__import__("tomllib").loads(text), text, "p.toml")
    return str(err.value)


@pytest.mark.parametrize("quantity", ["acceleration", "velocity", "displacement"])
def test_a_response_target_the_abort_limit_forbids_is_refused_by_the_plan(quantity):
    """``response = 1e300``: OverflowError in the drive ratio once the shaker ran."""
    err = _plan_error(f'[[stepped_sine]]\nresponse = 1e300\nquantity = "{quantity}"\ndof = "x2"\nstart = 1.0\n'
                      f'stop = 1.2\nstep = 0.1\n{LIMITS}')
    assert err.startswith("p.toml: [[stepped_sine]][0].response: ") and "max_acceleration = 50" in err, err
    # a target below the limit at every line is a plan
    parse_plan(__import__("tomllib").loads(t := f'[[stepped_sine]]\nresponse = 0.001\nquantity = "{quantity}"\n'
                                           f'dof = "x2"\nstart = 1.0\nstop = 1.2\nstep = 0.1\n{LIMITS}'), t)


def test_a_force_no_lab_applies_is_refused_by_the_plan_and_by_the_import_in_the_same_words(tmp_path, capsys):
    """``[[phase_resonance]] forces = [1e-12]``: a NaN frequency and a ValueError after 23 s on the shaker."""
    err = _plan_error(f'[[phase_resonance]]\ndof = "x2"\nforces = [1e-12]\nstart = 1.5\n{LIMITS}')
    assert "[[phase_resonance]][0].forces" in err and force_problem(1e-12) in err, err
    assert "[[stepped_sine]][0].force" in _plan_error(f"[[stepped_sine]]\nforce = 1e-9\nstart = 1.0\nstop = 1.2\n"
                                                      f"step = 0.1\n{LIMITS}")
    for force in ("1e-300", "1e300"):
        csv = long_csv(tmp_path / "c.csv", ["x1", "x2"], force)
        assert main(["import", str(csv), "-o", str(tmp_path / "s.h5"), "--excitation", "x2"]) == 2
        one_line_error(capsys, "c.csv", "attribute force", force_problem(float(force)))
        assert not (tmp_path / "s.h5").exists()


@pytest.mark.parametrize("force", [1e300, 1e-300])
def test_analyze_refuses_a_session_whose_force_no_lab_applies(tmp_path, capsys, force):
    """A session with a force of 1e300 N or 1e-300 N: LinAlgError (or ValueError) in ``analyze``."""
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session, levels=((force, True, "complete"),))
    model.write_text(PAPER_STRUCTURE + '\n[[element]]\nname = "right"\ndof = "x2"\nlaws = ["cubic"]\n')
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    one_line_error(capsys, "s.h5", "attribute force", force_problem(force))


def test_a_modal_structure_whose_shapes_realise_no_mass_is_refused(tmp_path, capsys):
    """A modal ``shapes = [[1e200]]``: a mass of 1e-400 kg, 0 in floating point, and LinAlgError in ``analyze``."""
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session, sensors=("x2",))
    model.write_text('[structure]\ntype = "modal"\ndofs = ["x2"]\nfrequencies = [1.2]\n'
                     'damping = [0.01]\nshapes = [[1e200]]\n\n'
                     '[[element]]\nname = "joint"\ndof = "x2"\nlaws = ["cubic"]\n')
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    one_line_error(capsys, "m.toml", "[structure].shapes", "mass matrix")


def test_recover_on_a_folder_is_a_one_line_error(tmp_path, capsys):
    """``recover`` on a directory: IsADirectoryError (and every command reading a session likewise)."""
    folder = tmp_path / "d.h5"
    folder.mkdir()
    assert main(["recover", str(folder)]) == 2
    one_line_error(capsys, "d.h5", "is a folder, not a session file")
    assert main(["export", str(folder), "--csv-long", str(tmp_path / "l.csv")]) == 2
    one_line_error(capsys, "d.h5", "is a folder")


# --------------------------------------------------------------------------- data lost
def _runs(path) -> dict[str, dict]:
    """Each run's status and per-line datasets (by path within the run), read and closed."""
    out = {}
    with h5py.File(path, "r") as f:
        for name, g in f["runs"].items():
            run = {"status": g.attrs["status"]}
            g.visititems(lambda key, obj, run=run: run.update({key: obj[()], f"{key}@units": obj.attrs.get("units")})
                         if isinstance(obj, h5py.Dataset) else None)
            out[name] = run
    return out


def test_uff_export_carries_the_measured_force_phase_and_phasor_and_names_what_it_leaves_out(tmp_path, capsys):
    """The default UFF export dropped ``force_phase`` and ``force_phasor`` without a word."""
    session = tmp_path / "s.h5"
    write_session(session, force_target=True)
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff")]) == 0
    out = capsys.readouterr().out
    assert "note: left out (no UFF58 record carries it): sine_0.8N_up: force_target" in out, out
    assert main(["import", *map(str, sorted(tmp_path.glob("o_*.uff"))), "-o", str(tmp_path / "b.h5")]) == 0
    before, after = _runs(session)["sine_0.8N_up"], _runs(tmp_path / "b.h5")["sine_0.8N_up"]
    assert np.array_equal(after["force_phase"], before["force_phase"])
    assert after["force_phase@units"] == "rad"
    np.testing.assert_allclose(after["force_phasor"], before["force_phasor"], rtol=1e-15, atol=0)


@pytest.mark.parametrize("form", ["--uff", "--csv"])
def test_phase_resonance_runs_are_left_out_by_name_and_what_is_written_imports_back(tmp_path, capsys, form):
    """Phase-resonance runs were exported by ``--uff`` and ``--csv``, and then refused by the import."""
    session = tmp_path / "s.h5"
    write_session(session, phase_run=True)
    target = tmp_path / ("o.uff" if form == "--uff" else "csv")
    assert main(["export", str(session), form, str(target)]) == 0
    assert "left out" in (out := capsys.readouterr().out) and "phase_x2_90deg (phase resonance" in out, out
    written = sorted(tmp_path.glob("o_*.uff")) if form == "--uff" else sorted(target.glob("*.csv"))
    assert [p.stem.removeprefix("o_") for p in written] == ["sine_0.8N_up"]
    assert main(["import", *map(str, written), "-o", str(tmp_path / "b.h5")]) == 0
    # a session holding nothing else: refused, naming what was left out, nothing written
    only = tmp_path / "only.h5"
    write_session(only, levels=(), phase_run=True)
    assert main(["export", str(only), form, str(tmp_path / "x")]) == 2
    one_line_error(capsys, "only.h5", "phase_x2_90deg")
    assert not list(tmp_path.glob("x*"))


def test_csv_long_keeps_each_runs_std_and_a_failed_run_stays_failed(tmp_path):
    """``--csv-long`` dropped the ``std`` of every run as soon as one run had none, and turned a ``failed`` run
    into ``complete``."""
    session, csv, back = tmp_path / "s.h5", tmp_path / "l.csv", tmp_path / "b.h5"
    write_session(session, levels=((0.8, True, "complete"), (1.6, False, "failed")))
    assert main(["export", str(session), "--csv-long", str(csv)]) == 0
    assert main(["import", str(csv), "-o", str(back), "--excitation", "x2"]) == 0
    before, after = _runs(session), _runs(back)
    for d in ("x1", "x2"):
        assert np.array_equal(after["sine_0.8N_up"][f"frf_std/{d}"], before["sine_0.8N_up"][f"frf_std/{d}"])
    assert not any(k.startswith("frf_std") for k in after["sine_1.6N_up"])
    assert [after[n]["status"] for n in ("sine_0.8N_up", "sine_1.6N_up")] == ["complete", "failed"]
    # the UFF and per-run CSV paths keep the status too
    assert main(["export", str(session), "--csv", str(tmp_path / "c")]) == 0
    assert main(["import", *map(str, sorted((tmp_path / "c").glob("*.csv"))), "-o", str(tmp_path / "c.h5")]) == 0
    assert _runs(tmp_path / "c.h5")["sine_1.6N_up"]["status"] == "failed"


def _left_by_a_dead_writer(path) -> None:
    """A session whose writer died with a run open: status "running", writer pid of no live process."""
    write_session(path)
    with h5py.File(path, "r+") as f:
        f["runs/sine_0.8N_up"].attrs["status"] = "running"
        f.attrs["writer_pid"] = 2 ** 22 + 12345           # above Linux's largest pid: no such process


@pytest.mark.parametrize("operation", ["recover", "history", "append"])
def test_an_operation_on_a_session_given_as_a_link_updates_the_real_file_and_keeps_the_link(tmp_path, operation):
    """Symlinked sessions: ``recover``, ``analyze`` (history) and ``import --append`` replaced the link with a
    regular file and left the real session unrepaired, or without its new history or runs."""
    real, link = tmp_path / "real" / "s.h5", tmp_path / "link.h5"
    real.parent.mkdir()
    if operation == "recover":
        _left_by_a_dead_writer(real)
    else:
        write_session(real)
    link.symlink_to(real)
    if operation == "recover":
        assert main(["recover", str(link)]) == 0
        assert _runs(real)["sine_0.8N_up"]["status"] == "aborted"
    elif operation == "history":            # what `analyze` stores after its report (app/analyze.py)
        append_model_history(link, [{"step": 0, "action": "start", "error": 0.5, "model": "[structure]\n",
                                     "error_by_level": [{"force": 0.8, "error": 0.5}]}])
        with h5py.File(real, "r") as f:
            assert "analysis_0" in f["models"]
    else:
        csv = long_csv(tmp_path / "c.csv", ["x1", "x2"], "1.2")
        assert main(["import", str(csv), "-o", str(link), "--append", "--excitation", "x2"]) == 0
        assert sorted(_runs(real)) == ["sine_0.8N_up", "sine_1.2N_up"]
    assert link.is_symlink() and link.resolve() == real.resolve()
    expected = ["c.csv", "link.h5", "real"] if operation == "append" else ["link.h5", "real"]
    assert sorted(p.name for p in tmp_path.iterdir()) == expected
    assert [p.name for p in real.parent.iterdir()] == ["s.h5"]        # no temporary left beside the target


# --------------------------------------------------------------------------- silently wrong -> refused or noted
def _analyze_refuses(tmp_path, capsys, model_text: str, *names) -> str:
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session)
    model.write_text(model_text)
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    return one_line_error(capsys, "m.toml", *names)


@pytest.mark.parametrize("laws", ['["cubic", "cubic"]', '[{ law = "cubic", k3 = 1e4 }, "cubic"]'])
def test_a_law_named_twice_on_one_element_is_refused_naming_file_and_field(tmp_path, capsys, laws):
    """``laws = ["cubic", "cubic"]`` was fitted twice: two terms no fit tells apart."""
    _analyze_refuses(tmp_path, capsys, PAPER_STRUCTURE + f'\n[[element]]\nname = "right"\ndof = "x2"\nlaws = {laws}\n',
                     "[[element]][0].laws[1].law", "law 'cubic' is named twice on element 'right'")


@pytest.mark.parametrize("hz", ["1e300", "1e-9"])
def test_a_modal_frequency_no_vibration_has_is_refused_in_the_words_of_the_session_reader(tmp_path, capsys, hz):
    """A modal ``frequencies = [1e300]`` was accepted."""
    from analysis.common.quantities import frequency_problem
    err = _analyze_refuses(tmp_path, capsys, '[structure]\ntype = "modal"\ndofs = ["x2"]\n'
                           f'frequencies = [{hz}]\ndamping = [0.01]\nshapes = [[0.7]]\n\n'
                           '[[element]]\nname = "joint"\ndof = "x2"\nlaws = ["cubic"]\n',
                           "[structure].frequencies", frequency_problem(float(hz)))
    assert "1000 Hz" not in err and "1e+06 Hz" in err


@pytest.mark.parametrize("path, words", [("springs[7].k", "no structure parameter at 'springs[7].k'"),
                                         ("dofs", "'dofs' must be a positive number to be updated")])
def test_a_bad_updating_path_is_refused_when_the_model_is_read_without_a_random_run(tmp_path, capsys, path, words):
    """A bad ``[updating]`` path was accepted when the session had no random run (nothing was updated)."""
    _analyze_refuses(tmp_path, capsys, PAPER_STRUCTURE + f'\n[updating]\nparameters = ["{path}"]\n\n'
                     '[[element]]\nname = "right"\ndof = "x2"\nlaws = ["cubic"]\n', "[updating].parameters", words)


def response_csv(path, force="", quantity="acceleration", dof="x2", target="5.0"):
    """A response-controlled level, its cells as given."""
    return long_csv(path, force=force, cells={"force_amplitude_n": "0.3", "control_dof": dof,
                                              "control_quantity": quantity, "control_target": target})


def test_a_csv_row_with_a_force_and_a_response_target_is_refused_in_the_plans_words(tmp_path, capsys):
    """``force_n`` and ``control_target`` on one level: ``force_n`` was dropped."""
    from analysis.common.quantities import force_and_response
    out = tmp_path / "s.h5"
    assert main(["import", str(response_csv(tmp_path / "c.csv", force="0.8")), "-o", str(out),
                 "--excitation", "x2"]) == 2
    one_line_error(capsys, "c.csv: line 2: force_n", force_and_response("control_target"))
    assert not out.exists()
    assert force_and_response("response") in _plan_error(f'[[stepped_sine]]\nforce = 0.5\nresponse = 2.0\n'
                                                         f'dof = "x2"\nstart = 1.0\nstop = 1.2\nstep = 0.1\n{LIMITS}')
    # the level as a response alone is one
    assert main(["import", str(response_csv(tmp_path / "c.csv")), "-o", str(out), "--excitation", "x2"]) == 0


@pytest.mark.parametrize("column", ["control_quantity", "control_dof"])
def test_a_csv_control_quantity_or_dof_without_a_target_is_refused_in_the_plans_words(tmp_path, capsys, column):
    """``control_quantity`` or ``control_dof`` without a target was ignored (a force level)."""
    from analysis.common.quantities import held_without_target
    cells = {"quantity": "acceleration" if column == "control_quantity" else "",
             "dof": "x2" if column == "control_dof" else ""}
    csv = response_csv(tmp_path / "c.csv", force="0.8", target="", **cells)
    assert main(["import", str(csv), "-o", str(tmp_path / "s.h5"), "--excitation", "x2"]) == 2
    one_line_error(capsys, f"c.csv: line 2: {column}", held_without_target("control_target = <amplitude>"))
    plan = f'[[stepped_sine]]\nforce = 0.5\nquantity = "velocity"\nstart = 1.0\nstop = 1.2\nstep = 0.1\n{LIMITS}'
    assert held_without_target("response = <amplitude>") in _plan_error(plan)


def test_a_response_held_at_a_dof_nothing_measures_is_refused_from_csv_and_from_the_uff_at_tag(tmp_path, capsys):
    """A control DOF that nothing measures was accepted, from CSV and from the UFF ``at=`` tag."""
    from analysis.common.quantities import control_dof_problem
    words = control_dof_problem("response", "x9", ["x1", "x2"], "x2")
    assert main(["import", str(response_csv(tmp_path / "c.csv", dof="x9")), "-o", str(tmp_path / "s.h5"),
                 "--excitation", "x2"]) == 2
    one_line_error(capsys, "c.csv: line 2: control_dof", words)
    session = tmp_path / "good.h5"
    assert main(["import", str(response_csv(tmp_path / "c.csv")), "-o", str(session), "--excitation", "x2"]) == 0
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff")]) == 0
    capsys.readouterr()
    (uff,) = tmp_path.glob("o_*.uff")
    assert uff.read_bytes().count(b"at=x2") >= 2             # (a binary UFF58: bytes of one length replaced)
    uff.write_bytes(uff.read_bytes().replace(b"at=x2", b"at=x9"))
    assert main(["import", str(uff), "-o", str(tmp_path / "b.h5")]) == 2
    one_line_error(capsys, uff.name, "id3", "at= " + words)
    # held= and target= belong to a response level: without control=response they were ignored
    from analysis.common.quantities import held_without_target
    uff.write_bytes(uff.read_bytes().replace(b"control=response at=x9", b"at=x2".ljust(22)))
    assert main(["import", str(uff), "-o", str(tmp_path / "b.h5")]) == 2
    one_line_error(capsys, uff.name, "id3", held_without_target("control=response"))
    # the session reader holds its control_dof attribute to the same rule
    with h5py.File(session, "r+") as f:
        (run,) = f["runs"].values()
        run.attrs["control_dof"] = "x9"
    assert main(["export", str(session), "--csv-long", str(tmp_path / "l.csv")]) == 2
    one_line_error(capsys, "good.h5", "attribute control_dof", words)


def _with_measured_force(path, amplitude="0.8", phase="0.1"):
    """The long CSV of one 0.8 N level with the force measured at each line."""
    return long_csv(path, cells={"force_amplitude_n": amplitude, "force_phase_rad": phase})


def test_a_phase_of_1e300_rad_is_refused_at_the_csv_the_uff_and_the_session_reader(tmp_path, capsys):
    """A phase of 1e300 rad was stored: no digit of it is left below one turn."""
    from analysis.common.quantities import phase_problem
    out = tmp_path / "s.h5"
    assert main(["import", str(_with_measured_force(tmp_path / "c.csv", phase="1e300")), "-o", str(out),
                 "--excitation", "x2"]) == 2
    one_line_error(capsys, "c.csv: line 2: force_phase_rad", phase_problem(1e300))
    assert not out.exists()
    for phase in ("-3.14159", "6.283"):          # -pi..pi and 0..2 pi are both phases
        assert phase_problem(float(phase)) is None
    # the session reader, and through it the UFF's force_phase records (the session's own export)
    session = tmp_path / "big.h5"
    write_session(session)
    with h5py.File(session, "r+") as f:
        f["runs/sine_0.8N_up/force_phase"][3] = 1e300
    assert main(["export", str(session), "--csv-long", str(tmp_path / "l.csv")]) == 2
    one_line_error(capsys, "big.h5", "dataset force_phase", "line 3", phase_problem(1e300))


def test_a_force_far_from_its_level_is_noted_at_import(tmp_path, capsys):
    """3000 N measured on a 0.3 N level was stored without a word; it may be real (a gauge's units), so it is
    noted, and kept."""
    csv = _with_measured_force(tmp_path / "c.csv", amplitude="8000")
    assert main(["import", str(csv), "-o", str(tmp_path / "s.h5"), "--excitation", "x2"]) == 0
    out = capsys.readouterr().out
    assert "run sine_0.8N_up: the force measured at 30 of 30 line(s) is more than 10 times off the level's 0.8 N " \
           "(line 0: 8000 N, 1e+04 times)" in out, out
    assert main(["import", str(_with_measured_force(tmp_path / "d.csv", amplitude="0.81")), "-o",
                 str(tmp_path / "t.h5"), "--excitation", "x2"]) == 0
    assert "times off" not in capsys.readouterr().out
