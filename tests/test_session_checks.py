"""Sessions with impossible contents are refused naming file, run and dataset; unfinished runs are noted."""
import json

import h5py
import numpy as np
import pytest

from analysis import load_structure
from app.cli import main
from app.session.writer import RunSpec, SessionWriter

STRUCTURE = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
             "stiffness": [[200.0, -100.0], [-100.0, 200.0]]}
# the same structure as a model file (JSON lists and strings are TOML), with a linear joint on x2 to identify
MODEL = "[structure]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in STRUCTURE.items()) \
    + '\n[[element]]\nname = "right"\ndof = "x2"\nlaws = ["linear"]\n'
K_TRUE, C_TRUE = 50.0, 0.5          # the joint on x2 that made the data
RUN = "sine_0.8N_up"


def write_session(path, lines=12):
    """A complete session of a linear 2-DOF system with a joint k, c on x2: exact receptances."""
    truth = load_structure(STRUCTURE)
    K = truth.K.copy()
    K[1, 1] += K_TRUE
    C = np.zeros((2, 2))
    C[1, 1] = C_TRUE
    f = np.linspace(0.8, 3.2, lines)
    H = truth.with_matrices(K=K, C=C).frf(2 * np.pi * f, columns=["x2"])[:, :, 0]
    w = SessionWriter(path)
    w.begin_run(RunSpec(RUN, "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 256.0, ["force", "acc:x1", "acc:x2"],
                        ["N", "m/s^2", "m/s^2"], extras={"force_amplitude": ("N", (), "f8"), "frf_std/x1": ("m/N", (), "f8"),
                                "frf_std/x2": ("m/N", (), "f8")}))
    for i in range(lines):
        w.append_line(f[i], {"x1": H[i, 0], "x2": H[i, 1]}, {"force_amplitude": 0.8, "frf_std/x1": 1e-4 * abs(H[i, 0]),
                                                           "frf_std/x2": 1e-4 * abs(H[i, 1])})
    w.end_run("complete")
    w.close()
    return path


@pytest.fixture
def files(tmp_path):
    model = tmp_path / "model.toml"
    model.write_text(MODEL)
    return write_session(tmp_path / "s.h5"), model


def analyze(capsys, session, model, *extra):
    rc = main(["analyze", str(session), str(model), "--no-history", *extra])
    out, err = capsys.readouterr()
    return rc, out, err


def replace(group, name, data):
    del group[name]
    group.create_dataset(name, data=data, maxshape=(None,) + np.shape(data)[1:])


def real_frf(f):
    replace(f["runs"][RUN]["frf"], "x1", f["runs"][RUN]["frf"]["x1"][()].real)


def shorter_frequency(f):
    f["runs"][RUN]["frequency"].resize((3,))


def negative_frequency(f):
    f["runs"][RUN]["frequency"][2] = -1.5


def nan_frf(f):
    f["runs"][RUN]["frf"]["x2"][4] = np.nan + 0j


def missing_frf(f):
    del f["runs"][RUN]["frf"]["x1"]


def unknown_version(f):
    f.attrs["format_version"] = 99


def bad_sensor_list(f):
    f["runs"][RUN].attrs["sensor_dofs"] = "[x1, x2"


def unknown_kind(f):
    f["runs"][RUN].attrs["kind"] = "chirp"


def zero_force(f):
    f["runs"][RUN].attrs["force"] = 0.0


@pytest.mark.parametrize("damage, where, message", [
    (unknown_version, "root attribute format_version", "format version 99 is not one this contactid reads"),
    (real_frf, f"run {RUN}, dataset frf/x1", "holds real numbers"),
    (shorter_frequency, f"run {RUN}, dataset frf/x1", "has 12 lines but dataset frequency has 3"),
    (negative_frequency, f"run {RUN}, dataset frequency", "line 2 is -1.5 Hz"),
    (nan_frf, f"run {RUN}, dataset frf/x2", "line 4 is"),
    # the reader finds these two first, naming the HDF5 path of the object
    (missing_frf, f"/runs/{RUN}/frf/x1", "missing dataset"),
    (bad_sensor_list, f"/runs/{RUN}@sensor_dofs", "unreadable attribute"),
    (unknown_kind, f"run {RUN}, attribute kind", "must be one of random, stepped_sine"),
    (zero_force, f"run {RUN}, attribute force", "must be a finite force > 0 N"),
])
@pytest.mark.slow
def test_impossible_contents_are_refused_naming_file_run_and_dataset(capsys, files, damage, where, message):
    session, model = files
    with h5py.File(session, "r+") as f:
        damage(f)
    rc, out, err = analyze(capsys, session, model)
    assert rc == 2 and out == ""
    assert err.startswith(f"contactid: error: {session}: {where}: ") and message in err
    assert err.count("\n") == 1


def test_sound_session_is_analysed_without_notes(capsys, files):
    rc, out, err = analyze(capsys, *files, "--json")
    assert rc == 0, err
    result = json.loads(out)
    assert result["unfinished_runs"] == []
    linear = result["elements"][0]["laws"][0]["params"]
    assert linear["k"] == pytest.approx(K_TRUE, rel=1e-6) and linear["c"] == pytest.approx(C_TRUE, rel=1e-6)


@pytest.mark.slow
def test_run_recovered_after_a_crash_is_analysed_with_a_note(capsys, files):
    session, model = files
    with h5py.File(session, "r+") as f:          # what recovery leaves: the line in progress reached frf/x1 only
        g = f["runs"][RUN]
        g.attrs.update({"status": "aborted", "incomplete": True,
                        "end_reason": "the writing process stopped without closing the run (crash or kill)"})
        for name in ("frequency", "frf/x2", "force_amplitude", "frf_std/x1", "frf_std/x2"):
            g[name].resize((11,))
    rc, out, err = analyze(capsys, session, model)
    assert rc == 0, err
    assert out.startswith(f"note: run {RUN} is incomplete: the process writing it stopped during the run "
                          "(crash or kill); its 11 lines measured before are used")
    rc, out, err = analyze(capsys, session, model, "--json")
    note, = json.loads(out)["unfinished_runs"]
    assert note["run"] == RUN and note["incomplete"] is True and note["lines"] == 11 and note["status"] == "aborted"
    assert "incomplete" in note["note"]


def test_aborted_run_is_noted_with_its_reason(capsys, files):
    session, model = files
    with h5py.File(session, "r+") as f:
        f["runs"][RUN].attrs.update({"status": "aborted", "end_reason": "limit max_force"})
    rc, out, err = analyze(capsys, session, model)
    assert rc == 0 and f"note: run {RUN} was aborted (limit max_force); its 12 lines" in out


@pytest.mark.slow
def test_failed_run_is_read_and_noted_with_its_reason(capsys, files):
    # a run that ran to its end but missed its force target is kept and analysed, never taken as complete
    session, model = files
    with h5py.File(session, "r+") as f:
        f["runs"][RUN].attrs.update({"status": "failed", "end_reason": "force OFF TARGET at 3 of 12 lines"})
    rc, out, err = analyze(capsys, session, model)
    assert rc == 0 and f"note: run {RUN} failed (force OFF TARGET at 3 of 12 lines)" in out
    rc, out, err = analyze(capsys, session, model, "--json")
    note, = json.loads(out)["unfinished_runs"]
    assert note["status"] == "failed" and note["lines"] == 12


@pytest.mark.slow
def test_lines_where_a_sensor_saw_nothing_are_left_out_with_a_note(capsys, files):
    """A campaign stores a fundamental below one count of the DAQ as NaN, FRF and standard deviation both: those
    lines hold no FRF to analyse and are left out, named; the other lines give the joint as before. A NaN FRF
    without that mark (its standard deviation finite) stays refused."""
    session, model = files
    with h5py.File(session, "r+") as f:
        g = f["runs"][RUN]
        for i in (0, 1):
            g["frf"]["x1"][i] = np.nan + 1j * np.nan
            g["frf_std"]["x1"][i] = np.nan
    rc, out, err = analyze(capsys, session, model, "--json")
    assert rc == 0, err
    result = json.loads(out)
    assert result["unresolved_lines"] == [{"run": RUN, "left_out": 2, "lines": 12}]
    linear = result["elements"][0]["laws"][0]["params"]
    assert linear["k"] == pytest.approx(K_TRUE, rel=1e-6) and linear["c"] == pytest.approx(C_TRUE, rel=1e-6)
    rc, out, err = analyze(capsys, session, model)
    assert out.startswith(f"note: run {RUN}: 2 of 12 line(s) left out: a sensor saw nothing there")
    with h5py.File(session, "r+") as f:
        f["runs"][RUN]["frf_std"]["x1"][1] = 1e-6          # an FRF lost, not a sensor below one count
    rc, out, err = analyze(capsys, session, model)
    assert rc == 2 and f"run {RUN}, dataset frf/x1: line 1 is (nan+nanj); FRFs must be finite" in err
