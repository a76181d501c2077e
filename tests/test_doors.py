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
from app.session.file import SessionWriteError
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
    (["a", "a/b"], "a"),                 # a dataset and a group of one name: the writer crashed
    (["x1", "../x2"], "x1"),             # not a path: a DOF name, once stored as nested HDF5 groups
    (["x" * 65, "x2"], "x2"),            # longer than any format carries
])
def test_a_dof_name_that_is_no_name_is_refused_at_import_naming_file_and_field(tmp_path, capsys, dofs, excitation):
    csv = long_csv(tmp_path / "c.csv", dofs)
    out = tmp_path / "s.h5"
    assert main(["import", str(csv), "-o", str(out), "--excitation", excitation]) == 2
    bad = next(d for d in dofs if dof_name_problem(d))
    # refused at the first row that names it, by its file line
    first_row = 2 + len(FREQS) * dofs.index(bad)
    one_line_error(capsys, f"c.csv: line {first_row}: dof", dof_name_problem(bad))
    assert not out.exists()


def test_the_plan_holds_dof_names_to_the_same_rule_in_the_same_words():
    text = f'[[phase_resonance]]\ndof = "a/b"\nforces = [0.1]\nstart = 1.5\n{LIMITS}'
    with pytest.raises(InputError) as err:
        parse_plan(__import__("tomllib").loads(text), text, "p.toml")
    assert "[[phase_resonance]][0].dof" in str(err.value) and dof_name_problem("a/b") in str(err.value)
    for good in ("x1", "A.w", "O.theta", "n_12"):
        assert dof_name_problem(good) is None


@pytest.mark.slow
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
        one_line_error(capsys, "c.csv: line 2: force_n", force_problem(float(force)))     # the row that gives it
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


@pytest.mark.slow
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
@pytest.mark.slow
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


@pytest.mark.slow
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


_HISTORY = [{"step": 0, "action": "start", "error": 0.5, "model": "[structure]\n",
             "error_by_level": [{"force": 0.8, "error": 0.5}]}]


def test_the_history_is_stored_when_the_kernel_copies_the_session_in_pieces(tmp_path, monkeypatch):
    """One ``sendfile`` call copies at most 2 GiB and returns early when a signal arrives (a profiler's stop):
    the session's copy held the first call's bytes only, and ``analyze`` failed on a truncated file after its
    whole analysis. Copied call by call, every byte is there; a source that ends early is refused, unchanged."""
    path = tmp_path / "s.h5"
    write_session(path)
    runs = _runs(path)
    real, counts = os.sendfile, []

    def in_pieces(out_fd, in_fd, offset, count):
        counts.append(count)
        return real(out_fd, in_fd, offset, min(count, 65536))

    monkeypatch.setattr(os, "sendfile", in_pieces)
    assert append_model_history(path, _HISTORY).name == "analysis_0"
    assert len(counts) == -(-counts[0] // 65536) > 2
    after = _runs(path)
    assert list(after) == list(runs) and all(list(after[r]) == list(runs[r]) and all(
        np.array_equal(after[r][k], v) for k, v in runs[r].items()) for r in runs)
    with h5py.File(path, "r") as f:
        assert "analysis_0" in f["models"]
    before = path.read_bytes()
    monkeypatch.setattr(os, "sendfile", lambda out_fd, in_fd, offset, count: 0 if offset else
                        real(out_fd, in_fd, offset, 4096))
    with pytest.raises(SessionWriteError, match=r"s\.h5: the file ended at byte 4096 of the \d+ it had when its "
                                                r"copy began; the session is unchanged"):
        append_model_history(path, _HISTORY)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


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


# --------------------------------------------------------------------------- force spectra: silently wrong -> refused
def _spectrum_import(tmp_path, values, func_type=12, label="N", id1="Force spectrum", x=None, *flags):
    """A controller's UFF: the FRFs of test_force_spectrum and one force spectrum record (record 2)."""
    from test_force_spectrum import DOFS as SPECTRUM_DOFS, _record, _spectrum, _write
    path = tmp_path / "c.uff"
    _write(path, [_record(), _spectrum(values, func_type, label, id1, x)])
    out = tmp_path / "s.h5"
    return main(["import", str(path), "-o", str(out), *SPECTRUM_DOFS, *flags]), out


def test_a_negative_auto_spectrum_is_refused_not_its_magnitude_taken(tmp_path, capsys):
    from test_force_spectrum import FORCE
    power = FORCE ** 2 * np.array([1, -1, 1, 1])
    rc, out = _spectrum_import(tmp_path, power, 2, "N^2", "Force autopower")
    assert rc == 2 and not out.exists()
    one_line_error(capsys, "c.uff", "record 2: data", "line 1 at 10.5 Hz", "an auto spectrum (a power, function "
                   "type 2) is real and >= 0")


@pytest.mark.parametrize("id1, factor", [("Force spectrum peak values (not RMS)", 1.0),
                                         ("Force spectrum, non-RMS", 1.0),
                                         ("Force spectrum RMS", np.sqrt(2.0)),
                                         ("Force spectrum peak-to-peak", 0.5)])
def test_an_id_line_that_denies_rms_is_read_as_peak(tmp_path, capsys, id1, factor):
    """"peak values (not RMS)" was read as RMS and multiplied by sqrt 2."""
    from app.session import open_session
    from test_force_spectrum import FORCE
    rc, out = _spectrum_import(tmp_path, FORCE, 12, "N", id1)
    assert rc == 0, capsys.readouterr().err
    with open_session(out) as s:
        (name,) = s.run_names()
        np.testing.assert_allclose(s.run(name).arrays["force_amplitude"], FORCE * factor, rtol=1e-12)


def test_labels_that_say_both_peak_and_rms_are_refused(tmp_path, capsys):
    from test_force_spectrum import FORCE
    rc, out = _spectrum_import(tmp_path, FORCE, 12, "N", "Force spectrum peak RMS")
    assert rc == 2 and not out.exists()
    one_line_error(capsys, "c.uff", "record 2: id1", "its labels say rms (id1) and peak (id1)")


def test_two_values_at_one_line_of_a_force_spectrum_are_refused(tmp_path, capsys):
    """Two values at one line: one was used."""
    from test_force_spectrum import LINES
    x = np.array([10.0, 10.5, 10.5, 11.0, 11.5])
    rc, out = _spectrum_import(tmp_path, np.array([0.14, 0.19, 0.3, 0.23, 0.2]), 12, "N", "F", x)
    assert rc == 2 and not out.exists()
    one_line_error(capsys, "c.uff", "record 2: x", "lines 1 and 2 are both at 10.5 Hz", "one force a line")
    assert LINES[1] == 10.5


def test_a_force_spectrum_beside_frfs_read_as_random_is_refused(tmp_path, capsys):
    """A spectrum was attached to a random run with ``--kind random``."""
    from test_force_spectrum import FORCE
    rc, out = _spectrum_import(tmp_path, FORCE, 12, "N", "F", None, "--kind", "random", "--force-amplitude", "0.2")
    assert rc == 2 and not out.exists()
    one_line_error(capsys, "c.uff", "record 2: func_type", "read as a random run (--kind random)")


def test_a_stepped_sine_csv_of_two_levels_read_as_random_is_refused(tmp_path, capsys):
    """A stepped-sine CSV imported with ``--kind random`` became two random runs, of which ``analyze`` used one
    without saying which; a second random run appended is refused likewise, and a session holding two is named."""
    csv = long_csv(tmp_path / "c.csv")
    csv.write_text(csv.read_text() + "".join(long_csv(tmp_path / "d.csv", force="1.6").read_text()
                                             .splitlines(True)[1:]))
    out = tmp_path / "s.h5"
    assert main(["import", str(csv), "-o", str(out), "--excitation", "x2", "--kind", "random"]) == 2
    one_line_error(capsys, "c.csv", "run random", "second random run", "--kind random")
    assert not out.exists()
    assert main(["import", str(tmp_path / "d.csv"), "-o", str(out), "--excitation", "x2", "--kind", "random"]) == 0
    before = out.read_bytes()
    assert main(["import", str(tmp_path / "d.csv"), "-o", str(out), "--excitation", "x2", "--kind", "random",
                 "--append"]) == 2
    one_line_error(capsys, "d.csv", "second random run")
    assert out.read_bytes() == before
    with h5py.File(out, "r+") as f:                       # a session written otherwise: the reader names both
        f.copy(f["runs/random"], f["runs"], name="random_2")
    assert main(["reference", str(out), "-o", str(tmp_path / "m.toml")]) == 2
    one_line_error(capsys, "s.h5", "/runs/random_2", "runs random and random_2 are both random runs")


# --------------------------------------------------------------------------- unclear -> one line naming file and line
def _csv_rows(path) -> list[str]:
    return long_csv(path).read_text().splitlines()


@pytest.mark.parametrize("change, words", [
    # a row of x1 moved to the end of the file: named by its own file line, not a 0-based line of the run
    (lambda rows: rows[:5] + rows[6:] + [rows[5]],
     ("c.csv: line 61: frequency_hz", "after 3.5 Hz (line 30) among the rows of dof x1 at 0.8 N")),
    # a row of another level among the rows of one: that row is named, with its column
    (lambda rows: rows[:10] + [rows[10].replace(",0.8", ",0.9")] + rows[11:],
     ("c.csv: line 11: force_n", "the row of dof x1 at", "holds level 0.9 N, while the other rows of its run hold "
      "0.8 N")),
    # ' x1' beside 'x1': a line given twice, not "frequencies out of order"
    (lambda rows: rows + [r.replace(",x1,", ", x1,") for r in rows[1:31]],
     ("c.csv: line 62: frequency_hz", "dof x1 at 0.8 N has 1.0 Hz on line 2 already", "the dof cell ' x1' is read "
      "as 'x1'")),
    # a measured force that differs between the DOFs of a line: both named by file line
    (lambda rows: [rows[0] + ",force_amplitude_n"] + [r + (",0.9" if i == 33 else ",0.8")
                                                      for i, r in enumerate(rows[1:], 1)],
     ("c.csv: line 34: force_amplitude_n", "dof x2 at 0.8 N has force_amplitude_n 0.9, dof x1 0.8 (line 4)")),
])
def test_csv_errors_name_the_file_line_of_the_row_at_fault(tmp_path, capsys, change, words):
    """CSV errors gave a 1-based file line next to a 0-based line within the run; a row that split a level was
    blamed on frequency_hz at another line; a DOF ' x1' beside 'x1' was "frequencies out of order"."""
    csv = tmp_path / "c.csv"
    csv.write_text("\n".join(change(_csv_rows(csv))) + "\n")
    assert main(["import", str(csv), "-o", str(tmp_path / "s.h5"), "--excitation", "x2"]) == 2
    err = one_line_error(capsys, *words)
    assert "out of order at line" not in err


def test_a_per_run_csv_names_the_file_line_of_a_bad_frequency(tmp_path, capsys):
    session = tmp_path / "s.h5"
    write_session(session)
    assert main(["export", str(session), "--csv", str(tmp_path / "c")]) == 0
    (csv,) = (tmp_path / "c").glob("*.csv")
    rows = csv.read_text().splitlines()
    rows.insert(5, "")                                    # a blank line: the file lines below it move by one
    rows[7] = rows[7].replace(rows[7].split(",")[0], "0.5", 1)
    csv.write_text("\n".join(rows) + "\n")
    assert main(["import", str(csv), "-o", str(tmp_path / "b.h5")]) == 2
    one_line_error(capsys, csv.name, "line 8: frequency [Hz]", "0.5 Hz after", "(line 7)")


@pytest.mark.slow
def test_a_run_of_one_line_is_exported_to_uff_and_read_back(tmp_path, capsys):
    """A valid one-line run could not be exported to UFF, and the message was pyuff's."""
    rows = _csv_rows(tmp_path / "c.csv")
    (tmp_path / "c.csv").write_text("\n".join([rows[0], rows[1], rows[31]]) + "\n")
    session = tmp_path / "s.h5"
    assert main(["import", str(tmp_path / "c.csv"), "-o", str(session), "--excitation", "x2"]) == 0
    for form in ("--binary", "--ascii"):
        assert main(["export", str(session), "--uff", str(tmp_path / "o.uff"), form, "--overwrite"]) == 0, \
            capsys.readouterr().err
        (uff,) = tmp_path.glob("o_*.uff")
        assert main(["import", str(uff), "-o", str(tmp_path / "b.h5"), "--overwrite"]) == 0
        before, after = _runs(session)["sine_0.8N_up"], _runs(tmp_path / "b.h5")["sine_0.8N_up"]
        assert np.array_equal(after["frequency"], before["frequency"]) and after["status"] == "complete"
        # binary: every double kept; ASCII: the E20.11 of its data lines
        np.testing.assert_allclose(after["frf/x1"], before["frf/x1"], rtol=0 if form == "--binary" else 1e-10)


def test_reference_names_the_session_and_says_what_a_random_only_session_is(tmp_path, capsys):
    """``reference`` errors named no file; on a random-only session it said "no stepped-sine run measures its
    drive point"."""
    single = tmp_path / "one.h5"
    write_session(single, sensors=("x2",))
    assert main(["reference", str(single), "-o", str(tmp_path / "m.toml")]) == 2
    one_line_error(capsys, "one.h5: --band: run sine_0.8N_up: 2 mode(s) found for 1 sensor(s)")
    random = tmp_path / "r.h5"
    assert main(["import", str(long_csv(tmp_path / "c.csv")), "-o", str(random), "--excitation", "x2", "--kind",
                 "random"]) == 0
    capsys.readouterr()
    assert main(["reference", str(random), "-o", str(tmp_path / "m.toml")]) == 2
    err = one_line_error(capsys, "r.h5: has only a random run", "contactid analyze")
    assert "drive point" not in err and not (tmp_path / "m.toml").exists()


def test_reference_warns_of_a_model_that_misses_its_own_level(tmp_path, capsys):
    """``reference`` wrote a model whose FRF error on its own level was 0.846 without a warning."""
    session, model = tmp_path / "one.h5", tmp_path / "m.toml"
    write_session(session, sensors=("x2",))
    assert main(["reference", str(session), "-o", str(model), "--band", "1.9", "3.5"]) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("contactid: warning: ") and str(model) in err and err.count("\n") == 0, err
    assert "misses its own level sine_0.8N_up by an FRF error of" in err and "--band" in err
    assert model.exists()
    assert main(["reference", str(session), "-o", str(tmp_path / "good.toml"), "--band", "1.0", "1.8"]) == 0
    assert "warning" not in capsys.readouterr().err


def damaged_session(session) -> bytes:
    """A session written at ``session`` with one byte of its first FRF chunk flipped; its bytes."""
    write_session(session)
    with h5py.File(session, "r") as f:
        offset = f["runs/sine_0.8N_up/frf/x1"].id.get_chunk_info(0).byte_offset
    data = bytearray(session.read_bytes())
    data[offset + 5] ^= 0xFF
    session.write_bytes(bytes(data))
    return bytes(data)


def test_recover_reports_damaged_data_rather_than_nothing_to_recover(tmp_path, capsys):
    """``recover`` said "closed normally, nothing to recover" on a file with flipped data chunks, which
    ``export`` and ``analyze`` then refused as damaged."""
    session = tmp_path / "s.h5"
    data = damaged_session(session)
    assert main(["recover", str(session)]) == 2
    one_line_error(capsys, "s.h5", "fail their checksum", "/runs/sine_0.8N_up/frf/x1: line(s) 0-29 of 30",
                   "the file is unchanged")
    assert session.read_bytes() == data


def test_recover_repairs_a_run_left_running_under_a_live_pid_that_is_no_writer(tmp_path, capsys):
    """A run still "running" under a live, unrelated pid: "closed normally, nothing to recover"."""
    session = tmp_path / "s.h5"
    _left_by_a_dead_writer(session)
    other = subprocess.Popen(["sleep", "60"])           # alive, not Python, not holding the file
    try:
        with h5py.File(session, "r+") as f:
            f.attrs["writer_pid"] = other.pid
        assert main(["recover", str(session)]) == 0
        assert "marked aborted and incomplete: sine_0.8N_up" in capsys.readouterr().out
        assert _runs(session)["sine_0.8N_up"]["status"] == "aborted"
    finally:
        other.kill()
        other.wait()


# --------------------------------------------------------------------------- --add, [updating].modes
def test_analyze_add_of_a_law_the_element_has_is_refused_before_any_work(tmp_path, capsys):
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session)
    model.write_text(PAPER_STRUCTURE + '\n[[element]]\nname = "right"\ndof = "x2"\nlaws = ["cubic"]\n')
    import time
    start = time.monotonic()
    assert main(["analyze", str(session), str(model), "--add", "right:cubic", "--no-history"]) == 2
    one_line_error(capsys, "m.toml: --add right:cubic", "element 'right' has law 'cubic' already "
                   "([[element]][0].laws[0])")
    assert main(["analyze", str(session), str(model), "--add", "right:coulomb", "--add", "right:coulomb",
                 "--no-history"]) == 2
    one_line_error(capsys, "m.toml: --add right:coulomb", "law 'coulomb' is added twice to element 'right'")
    assert time.monotonic() - start < 5             # refused before the identification, not after it


@pytest.mark.parametrize("modes, words", [("[3]", "mode 3, but the structure has 2 mode(s)"),
                                          ("[1, 1]", "names mode 1 twice"),
                                          ("[]", "must be a list of mode numbers"),
                                          ("[2]", "1 mode(s) cannot determine the 2 parameters")])
def test_updating_modes_the_model_has_not_are_refused_when_it_is_read(tmp_path, capsys, modes, words):
    parameters = '["stiffness[0][0]", "mass[1][1]"]' if modes == "[2]" else '["stiffness[0][0]"]'
    model = tmp_path / "m.toml"
    model.write_text(PAPER_STRUCTURE + f'\n[updating]\nparameters = {parameters}\nmodes = {modes}\n')
    assert main(["modes", str(model)]) == 2
    one_line_error(capsys, "m.toml: [updating].modes", words)


def test_updating_modes_the_random_run_does_not_show_are_refused():
    """More modes to match than the measurement shows at all: an error naming the model file and the field (an
    untrusted mode still leaves the reference as given, with a note)."""
    from analysis.common.measurements import RandomRun
    from analysis.linear.reference import reference_from_random
    from analysis.mechanics.model import load_model
    f = np.linspace(0.9, 1.7, 200)                        # the first mode (1.27 Hz) alone
    run = RandomRun("x2", ["x1", "x2"], f, np.array([receptance(x) for x in f]), None, None, 0.05)
    doc = __import__("tomllib").loads(PAPER_STRUCTURE + '\n[updating]\nparameters = ["stiffness[0][0]"]\n'
                                                        'modes = [1, 2]\n')
    with pytest.raises(InputError) as err:
        reference_from_random(load_model(doc, "m.toml"), run)
    assert str(err.value).startswith("m.toml: [updating].modes: 2 modes to match, but the random run shows 1")
    doc["updating"]["modes"] = [1]
    assert reference_from_random(load_model(doc, "m.toml"), run).update is not None


# --------------------------------------------------------------------------- simulate --overwrite through a link
@pytest.mark.slow
def test_simulate_overwrite_onto_a_link_replaces_its_target_and_keeps_the_link(tmp_path):
    """``simulate --overwrite`` onto a symlink replaced the link with a regular file and left its target."""
    real, link, plan = tmp_path / "real" / "s.h5", tmp_path / "link.h5", tmp_path / "p.toml"
    real.parent.mkdir()
    write_session(real)
    link.symlink_to(real)
    plan.write_text('[[stepped_sine]]\nforce = 0.8\nstart = 1.0\nstop = 1.1\nstep = 0.05\ndirection = "up"\n'
                    + LIMITS)
    assert main(["simulate", "paper-2dof", str(plan), "-o", str(link), "--overwrite", "--quiet"]) == 0
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert sorted(_runs(real)) == ["sine_0.8N_up"] and len(_runs(real)["sine_0.8N_up"]["frequency"]) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.h5", "p.toml", "real"]
    assert [p.name for p in real.parent.iterdir()] == ["s.h5"]        # no temporary left beside the target


# --------------------------------------------------------------------------- own UFF tags
@pytest.mark.parametrize("old, new, words", [
    (b"status=complete", b"status=exploded", ("id4", "status=exploded is not one of complete, failed, aborted")),
    (b"force=0.8 ", b"force=0.9 ", ("record 3: id4", "force 0.8 differs from 0.9 in record 2 of the same run")),
    (b"convention=exp(+jwt)", b"convention=exp(-jwt)", ("id5", "is not contactid's exp(+jwt)")),
])
def test_own_uff_tags_that_no_run_has_or_that_records_disagree_on_are_refused(tmp_path, capsys, old, new, words):
    """``status=exploded`` was stored as ``aborted``; records that disagreed (on ``target=``, on the level) were
    accepted and the first won."""
    session = tmp_path / "s.h5"
    write_session(session)
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff")]) == 0
    (uff,) = tmp_path.glob("o_*.uff")
    uff.write_bytes(uff.read_bytes().replace(old, new, 1))        # the first record only
    assert main(["import", str(uff), "-o", str(tmp_path / "b.h5")]) == 2
    one_line_error(capsys, uff.name, *words)
    assert not (tmp_path / "b.h5").exists()


# --------------------------------------------------------------------------- the audit of issue 54: each of its kind
def _quantity_rows() -> list[list[str]]:
    """The rows of docs/session-format.md's table of quantities, as cells."""
    text = (ROOT / "docs/session-format.md").read_text()
    section = text[text.index("## Quantities\n"):]
    section = section[:section.index("\n## ", 1)]
    return [[c.strip() for c in line.strip().strip("|").split(" | ")] for line in section.splitlines()
            if line.startswith("| ") and not line.startswith("| quantity") and not line.startswith("|---")]


def _bound(text: str) -> float:
    """``1e-06``, ``1000`` or ``-2*pi`` as a number."""
    factor, _, pi = text.partition("*")
    return float(factor) * (np.pi if pi == "pi" else 1.0)


def test_the_docs_table_of_quantities_states_the_ranges_the_code_enforces():
    """docs/ holds the table of quantities with their ranges: each range there is the constant the doors ask, so
    the doc cannot drift from the code; every range constant of quantities.py has its row."""
    import re
    from analysis.common import quantities
    scalar = {"MAX_PHASE": lambda v: (-v, v), "MAX_DOF_NAME": lambda v: (1, v),
              "FORCE_LEVEL_FACTOR": lambda v: (1 / v, v)}
    rows = _quantity_rows()
    assert len(rows) >= 25 and all(len(r) == 5 for r in rows), [r for r in rows if len(r) != 5]
    checked = set()
    for quantity, unit, accepted, rule, formats in rows:
        assert unit and formats, quantity
        named = re.match(r'`([A-Z_]+)(?:\["(\w+)"\])?`', rule)
        if not named or not hasattr(quantities, named[1]):
            continue
        name, key = named.groups()
        value = getattr(quantities, name)
        expected = scalar[name](value) if name in scalar else (value[key] if key else value)
        stated = re.match(r"`(\S+) \.\. (\S+)`", accepted)
        assert stated, f"{quantity}: the range is not stated as `lo .. hi`: {accepted}"
        np.testing.assert_allclose([_bound(stated[1]), _bound(stated[2])], expected, rtol=1e-12,
                                   err_msg=f"docs/session-format.md, {quantity}: {name}{[key] if key else ''}")
        checked.add(name)
    constants = {n for n in vars(quantities) if n.isupper() and (n.endswith("_RANGE") or n in scalar)}
    assert constants <= checked, f"no row of the table states {sorted(constants - checked)}"
    for key in quantities.RESPONSE_RANGE:                 # one row per response quantity
        assert any(f'RESPONSE_RANGE["{key}"]' in r[3] for r in rows), key


@pytest.mark.parametrize("quantity, target", [("acceleration", "1e300"), ("acceleration", "1e-300"),
                                              ("displacement", "2.0"), ("velocity", "1e-12")])
def test_a_response_target_no_lab_holds_is_refused_at_the_csv(tmp_path, capsys, quantity, target):
    """A response target of 1e300 m/s^2 (or 1e-300) was stored, exported and read back without a word."""
    from analysis.common.quantities import response_target_problem
    out = tmp_path / "s.h5"
    assert main(["import", str(response_csv(tmp_path / "c.csv", quantity=quantity, target=target)), "-o", str(out),
                 "--excitation", "x2"]) == 2
    one_line_error(capsys, "c.csv: line 2: control_target", response_target_problem(quantity, float(target)))
    assert not out.exists()


def test_a_response_target_no_lab_holds_is_refused_by_the_plan_the_uff_tags_and_the_session_reader(tmp_path,
                                                                                                    capsys):
    from analysis.common.quantities import response_target_problem
    words = response_target_problem("acceleration", 1e-300)
    err = _plan_error(f'[[stepped_sine]]\nresponse = 1e-300\nquantity = "acceleration"\ndof = "x2"\nstart = 1.0\n'
                      f'stop = 1.2\nstep = 0.1\n{LIMITS}')
    assert err == f"p.toml: [[stepped_sine]][0].response: {words}", err
    session = tmp_path / "good.h5"
    assert main(["import", str(response_csv(tmp_path / "c.csv")), "-o", str(session), "--excitation", "x2"]) == 0
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff")]) == 0
    capsys.readouterr()
    (uff,) = tmp_path.glob("o_*.uff")
    uff.write_bytes(uff.read_bytes().replace(b"target=5.0", b"target=1e9"))      # one length: a binary UFF58
    assert main(["import", str(uff), "-o", str(tmp_path / "b.h5")]) == 2
    one_line_error(capsys, uff.name, "id3", "target= " + response_target_problem("acceleration", 1e9))
    with h5py.File(session, "r+") as f:
        (run,) = f["runs"].values()
        run.attrs["control_target"] = 1e300
    assert main(["export", str(session), "--csv-long", str(tmp_path / "l.csv")]) == 2
    one_line_error(capsys, "good.h5", "attribute control_target", response_target_problem("acceleration", 1e300))


def test_dof_names_in_the_uff_tags_and_the_import_options_are_refused_where_they_are_written(tmp_path, capsys):
    """``rsp=`` and ``ref=`` were blamed on ``attribute sensor_dofs`` or on id3's ``at=``; ``--dof 1+Z=a/b`` and
    ``--excitation a:b`` on session attributes the user never wrote."""
    session = tmp_path / "s.h5"
    write_session(session)
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff")]) == 0
    (uff,) = tmp_path.glob("o_*.uff")
    good = uff.read_bytes()
    for old, new in ((b"rsp=x1", b"rsp=.."), (b"ref=x2", b"ref=a/")):
        uff.write_bytes(good.replace(old, new))
        assert main(["import", str(uff), "-o", str(tmp_path / "b.h5")]) == 2
        one_line_error(capsys, uff.name, "record 2: id2", f"{new[:4].decode()} {dof_name_problem(new[4:].decode())}")
    csv = long_csv(tmp_path / "c.csv")
    assert main(["import", str(csv), "-o", str(tmp_path / "b.h5"), "--excitation", "a:b"]) == 2
    one_line_error(capsys, "--excitation", dof_name_problem("a:b"))
    assert main(["import", str(uff), "-o", str(tmp_path / "b.h5"), "--dof", "1+Z=a/b"]) == 2
    one_line_error(capsys, "--dof: 1+Z=a/b", dof_name_problem("a/b"))
    assert not (tmp_path / "b.h5").exists()


def test_records_that_disagree_on_the_control_are_named_in_the_words_of_the_tags(tmp_path, capsys):
    """The message showed Python's ``Control(mode='response', ...)`` instead of the tags as written."""
    session = tmp_path / "s.h5"
    assert main(["import", str(response_csv(tmp_path / "c.csv")), "-o", str(session), "--excitation", "x2"]) == 0
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff")]) == 0
    capsys.readouterr()
    (uff,) = tmp_path.glob("o_*.uff")
    uff.write_bytes(uff.read_bytes().replace(b"target=5.0", b"target=6.0", 1))
    assert main(["import", str(uff), "-o", str(tmp_path / "b.h5")]) == 2
    err = one_line_error(capsys, uff.name, "record 3: id3", "control 'control=response at=x2 held=acceleration "
                         "target=5.0' differs from 'control=response at=x2 held=acceleration target=6.0' in record 2")
    assert "Control(" not in err


@pytest.mark.parametrize("form", ["--uff", "--csv", "--csv-long"])
def test_a_line_where_a_sensor_saw_nothing_is_refused_by_every_export_in_one_wording(tmp_path, capsys, form):
    """NaN lines (a sensor that saw nothing: FRF and std NaN): ``--uff`` refused them, while ``--csv`` and
    ``--csv-long`` wrote cells their own import refuses."""
    session = tmp_path / "s.h5"
    write_session(session)
    with h5py.File(session, "r+") as f:
        f["runs/sine_0.8N_up/frf/x1"][3] = np.nan
        f["runs/sine_0.8N_up/frf_std/x1"][3] = np.nan
    target = tmp_path / {"--uff": "o.uff", "--csv": "c", "--csv-long": "l.csv"}[form]
    assert main(["export", str(session), form, str(target)]) == 2
    one_line_error(capsys, "s.h5: run sine_0.8N_up, dataset frf/x1: line 3: the sensor at x1 saw nothing there",
                   "has no value its import reads as such; nothing exported")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


@pytest.mark.slow
def test_csv_long_keeps_a_std_of_zero_and_the_std_of_each_dof_that_has_one(tmp_path):
    """A std of 0 at one line (the session's rule: >= 0) made ``--csv-long`` drop the run's std without a word,
    and the import refused a 0; a std stored for one DOF only was dropped too."""
    session, csv, back = tmp_path / "s.h5", tmp_path / "l.csv", tmp_path / "b.h5"
    write_session(session)
    with h5py.File(session, "r+") as f:
        f["runs/sine_0.8N_up/frf_std/x1"][5] = 0.0
        del f["runs/sine_0.8N_up/frf_std/x2"]
    assert main(["export", str(session), "--csv-long", str(csv)]) == 0
    assert main(["import", str(csv), "-o", str(back), "--excitation", "x2"]) == 0
    before, after = _runs(session)["sine_0.8N_up"], _runs(back)["sine_0.8N_up"]
    assert np.array_equal(after["frf_std/x1"], before["frf_std/x1"]) and after["frf_std/x1"][5] == 0
    assert "frf_std/x2" not in after


@pytest.mark.parametrize("form", ["--uff", "--csv"])
def test_an_export_names_why_a_run_failed_which_no_format_carries(tmp_path, capsys, form):
    """A failed run's ``end_reason`` was left out without a word (the status itself comes back)."""
    session = tmp_path / "s.h5"
    write_session(session, levels=((0.8, True, "complete"), (1.6, False, "failed")))
    assert main(["export", str(session), form, str(tmp_path / ("o.uff" if form == "--uff" else "c"))]) == 0
    out = capsys.readouterr().out
    assert "left out" in out and "sine_1.6N_up: end_reason 'the force missed its target'" in out, out
    assert "sine_0.8N_up: end_reason" not in out


def test_a_coherence_above_one_is_refused_at_every_door(tmp_path, capsys):
    """A coherence of 7 read from a UFF coherence record was stored: the session reader, which every import
    passes, holds coherence to 0..1."""
    from analysis.common.quantities import coherence_problem
    session = tmp_path / "s.h5"
    write_session(session)
    with h5py.File(session, "r+") as f:
        f["runs/sine_0.8N_up"].create_dataset("coherence/x1", data=np.r_[np.full(3, 0.9), 7.0, np.full(26, 0.9)])
    assert main(["export", str(session), "--csv-long", str(tmp_path / "l.csv")]) == 2
    one_line_error(capsys, "s.h5", "dataset coherence/x1", "line 3", coherence_problem(7.0))
    assert coherence_problem(1.0 + 1e-12) is None and coherence_problem(0.0) is None


def test_import_of_a_folder_says_it_is_a_folder(tmp_path, capsys):
    """``import`` of a folder said "file not found"."""
    (tmp_path / "d.uff").mkdir()
    assert main(["import", str(tmp_path / "d.uff"), "-o", str(tmp_path / "s.h5")]) == 2
    one_line_error(capsys, "d.uff", "is a folder, not a file to import")



# --------------------------------------------------------------------------- the audit after the pass
def _cli(args, stdout=subprocess.PIPE, close=True) -> tuple[int, str]:
    """Run ``contactid ARGS`` in a child; with ``close`` its stdout reader is gone before it prints (``| head
    -0``). The exit status and stderr."""
    child = subprocess.Popen([sys.executable, "-c", "import sys; from app.cli import main; sys.exit(main())",
                              *map(str, args)], cwd=ROOT, stdout=stdout, stderr=subprocess.PIPE,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    if close and child.stdout is not None:
        child.stdout.close()
    err = child.stderr.read().decode()
    return child.wait(timeout=300), err


@pytest.mark.parametrize("command", [pytest.param("analyze", marks=pytest.mark.slow), "import", "export --csv-long",
                                     "export --uff", "export --csv"])
@pytest.mark.slow
def test_every_command_finishes_its_work_when_the_reader_closes_the_pipe(tmp_path, command):
    """``analyze S M -o F.toml | head -1``, ``import ... | head -0``, ``export ... | head -0``: a BrokenPipeError
    traceback (exit 1), the files written or not depending on when the report filled the pipe."""
    session = tmp_path / "s.h5"
    write_session(session)
    model = tmp_path / "m.toml"
    model.write_text(PAPER_STRUCTURE + '\n[[element]]\nname = "right"\ndof = "x2"\nlaws = ["cubic"]\n')
    args, made = {
        "analyze": (["analyze", session, model, "-o", tmp_path / "f.toml", "--report", tmp_path / "plots"],
                    [tmp_path / "f.toml", tmp_path / "plots" / "frf.png"]),
        "import": (["import", long_csv(tmp_path / "c.csv"), "-o", tmp_path / "b.h5", "--excitation", "x2"],
                   [tmp_path / "b.h5"]),
        "export --csv-long": (["export", session, "--csv-long", tmp_path / "l.csv"], [tmp_path / "l.csv"]),
        "export --uff": (["export", session, "--uff", tmp_path / "o.uff"], [tmp_path / "o_sine_0.8N_up.uff"]),
        "export --csv": (["export", session, "--csv", tmp_path / "c"], [tmp_path / "c" / "sine_0.8N_up.csv"]),
    }[command]
    status, err = _cli(args)
    assert status == 0, err
    assert "Traceback" not in err and "Error" not in err and "error" not in err, err
    assert all(p.exists() and p.stat().st_size for p in made), [p for p in made if not p.exists()]
    if command == "analyze":
        assert "[[element]]" in (tmp_path / "f.toml").read_text()
        with h5py.File(session, "r") as f:          # the history it stores after the report is stored too
            assert len(f["models"]) == 1


@pytest.mark.slow
def test_a_full_standard_output_says_what_was_written_not_that_nothing_was(tmp_path):
    """``reference S -o M.toml > /dev/full`` said "nothing was written" although M.toml was written."""
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session)
    with open("/dev/full", "w") as full:
        status, err = _cli(["reference", session, "-o", model], stdout=full, close=False)
    assert status == 2, err
    assert 'type = "modal"' in model.read_text()
    lines = [line for line in err.splitlines() if "warning" not in line]
    assert len(lines) == 1 and "nothing was written" not in err and "Traceback" not in err, err
    assert lines[0].startswith("contactid: error: standard output: not written: No space left on device"), err
    assert f"wrote {model}" in lines[0], err


@pytest.mark.slow
def test_csv_long_names_what_no_column_carries(tmp_path, capsys):
    """``export --csv-long`` left out ``distortion`` (which the analysis reads) and a failed run's ``end_reason``
    and ``incomplete`` without a word, where ``--uff`` and ``--csv`` name theirs."""
    session = tmp_path / "s.h5"
    write_session(session, levels=((0.8, True, "complete"), (1.6, False, "failed")), force_target=True)
    with h5py.File(session, "r+") as f:
        f["runs/sine_0.8N_up"].create_dataset("distortion", data=np.full(len(FREQS), 0.01))
        f["runs/sine_1.6N_up"].attrs["incomplete"] = True
    assert main(["export", str(session), "--csv-long", str(tmp_path / "l.csv")]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note:")]
    assert notes == [
        "note: left out (no column of the CSV long format carries it): sine_0.8N_up: distortion, force_target",
        "note: left out (no column of the CSV long format carries it): sine_1.6N_up: force_target, "
        "end_reason 'the force missed its target', incomplete (its writer stopped during the run)"], notes
    # what a column carries is not named: std, the measured force (its phasor is rebuilt from the two)
    assert not any(word in " ".join(notes) for word in ("frf_std", "force_amplitude", "force_phase"))


def test_frf_only_says_it_left_out_what_the_user_chose_to_leave_out(tmp_path, capsys):
    """``--uff --frf-only`` said "no UFF58 record carries it" of the per-line records it was asked to drop."""
    session = tmp_path / "s.h5"
    write_session(session, force_target=True)
    assert main(["export", str(session), "--uff", str(tmp_path / "o.uff"), "--frf-only"]) == 0
    out = capsys.readouterr().out
    assert ("note: left out (no UFF58 record carries it): sine_0.8N_up: force_target\n" in out
            and "note: left out (--frf-only: FRF records only, as asked): sine_0.8N_up: force_amplitude, "
                "force_phase, force_phasor, frf_std/x1, frf_std/x2\n" in out), out
    assert main(["export", str(session), "--uff", str(tmp_path / "p.uff")]) == 0     # without it: no such note
    assert "--frf-only" not in capsys.readouterr().out


@pytest.mark.parametrize("command", ["analyze", "predict"])
@pytest.mark.parametrize("law, words", [("{ law = \"cubic\", k3 = 1e300 }", "laws[0].k3: 1e+300"),
                                        ("{ law = \"linear\", k = 1e200, c = 0.0 }", "laws[0].k: 1e+200"),
                                        ("{ law = \"cubic_damping\", c3 = -1e250 }", "laws[0].c3: -1e+250")])
def test_a_law_value_no_physical_law_has_is_refused_when_the_model_is_read(tmp_path, capsys, command, law,
                                                                          words):
    """``k3 = 1e300``: ``predict`` and ``analyze`` printed numpy RuntimeWarnings and an FRF error of inf."""
    import warnings
    session, model = tmp_path / "s.h5", tmp_path / "m.toml"
    write_session(session)
    model.write_text(PAPER_STRUCTURE + f'\n[[element]]\nname = "right"\ndof = "x2"\nlaws = [{law}]\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)        # one leaking would be an exit 1 here
        assert main([command, str(session), str(model), *(["--no-history"] if command == "analyze" else [])]) == 2
    one_line_error(capsys, "m.toml", f"[[element]][0].{words}", "no finite prediction", "1e+100 N")


def test_law_values_a_lab_can_meet_are_read_and_the_rule_is_the_documented_one():
    """The bound refuses slips, not stiff contacts: every law's example, a micro-amplitude cubic of 1e16 N/m^3, a
    rigid stop of 1e30 N/m and a value just under the bound are read; the docs state the bound the code holds."""
    from analysis.laws import LAWS
    from analysis.mechanics.model import MAX_LAW_FORCE, check_law_force
    for law in LAWS.values():
        check_law_force(law, dict(law.example), "m.toml", "laws[0]")
    check_law_force(LAWS["cubic"], {"k3": 1e16}, "m.toml", "laws[0]")
    check_law_force(LAWS["gap"], {"k": 1e30, "gap": 1e-6}, "m.toml", "laws[0]")
    check_law_force(LAWS["cubic"], {"k3": 1e99}, "m.toml", "laws[0]")
    with pytest.raises(InputError, match=r"laws\[0\]\.k3"):
        check_law_force(LAWS["cubic"], {"k3": 1e101}, "m.toml", "laws[0]")
    assert MAX_LAW_FORCE == 1e100
    docs = (ROOT / "docs/session-format.md").read_text() + (ROOT / "docs/contracts.md").read_text()
    assert "`MAX_LAW_FORCE` = 1e100 N" in docs and "at most\n1e100 N" in docs


def test_recover_and_the_session_reader_number_the_lines_of_a_run_alike(tmp_path, capsys):
    """``recover`` numbered lines from 1 (``line(s) 1-30``) while the session reader numbers them from 0 (``line
    3`` is ``frf/x1[3]``); the docs say from 0."""
    session = tmp_path / "s.h5"
    damaged_session(session)
    assert main(["recover", str(session)]) == 2
    recovered = one_line_error(capsys, "line(s) 0-29 of 30")
    assert main(["export", str(session), "--csv-long", str(tmp_path / "l.csv")]) == 2
    read = one_line_error(capsys, "/runs/sine_0.8N_up/frf/x1", "line(s) 0-29 of 30")
    assert "1-30" not in recovered + read
    assert "**Lines are numbered from 0**" in (ROOT / "docs/session-format.md").read_text()
