"""contactid import: UFF58 (ASCII, binary) and CSV from other systems, and contactid's own export, into a
session the workbench analyses like an acquired one.

The foreign files are written here with pyuff (accelerance, as a commercial controller exports it, with
header, units and coherence records between the FRFs) or by hand in CSV, from a small simulator of this file
(RK4 of a 2-DOF system with a cubic spring the model does not know, steady state at every line); the
workbench must find that spring in the imported data.
"""
import csv
import hashlib
import json

import h5py
import numpy as np
import pytest
import pyuff

from analysis import InputError
from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench
from app.analyze import report_text
from app.cli import main
from app.importers.idlines import RecordTag, encode
from app.importers.runs import SourceOptions, parse_dof_map
from app.importers.store import ImportRequest, import_files
from app.session.writer import RunSpec, SessionWriter, open_session
from app.session.data import measurements_from_session

G = 9.80665
M = np.diag([1.0, 2.0])
K = np.array([[200.0, -100.0], [-100.0, 200.0]])
RAYLEIGH = (0.3, 0.004)
C = RAYLEIGH[0] * M + RAYLEIGH[1] * K
K3 = 400.0                          # the hidden cubic spring at x1
FORCES = (0.2, 0.8)
FREQS = np.linspace(0.9, 3.0, 36)
NOISE = 1e-3                        # relative, circular complex
MODEL = {"structure": {"type": "lumped", "dofs": ["x1", "x2"], "mass": M.tolist(), "stiffness": K.tolist(),
                       "rayleigh": list(RAYLEIGH)},
         "element": [{"name": "joint", "dof": "x1", "laws": []}]}
DOFS = ["--dof", "1+Z=x1", "--dof", "2+Z=x2"]


def steady_receptance(freqs, force, settle_seconds=45.0, per_period=64, keep=4):
    """RK4 of M x'' + C x' + K x + k3 x1^3 e1 = F sin(wt) e2 from rest, every line at once; the fundamental
    X (x = Im X e^{jwt}) over the last periods, over F."""
    w = 2 * np.pi * np.asarray(freqs)[:, None]
    dt = 2 * np.pi / w / per_period
    Minv = np.linalg.inv(M)

    def rhs(t, y):
        x, v = y[:, :2], y[:, 2:]
        f = x @ K.T + v @ C.T
        f[:, 0] += K3 * x[:, 0] ** 3
        f[:, 1] -= force * np.sin(w[:, 0] * t[:, 0])
        return np.hstack([v, -f @ Minv.T])

    y, t = np.zeros((len(w), 4)), np.zeros((len(w), 1))
    fundamental = np.zeros((len(w), 2), complex)
    settle = int(np.ceil(settle_seconds * max(freqs))) * per_period
    for i in range(settle + keep * per_period):
        if i >= settle:
            fundamental += y[:, :2] * (np.sin(w * t) + 1j * np.cos(w * t))
        k1 = rhs(t, y)
        k2 = rhs(t + dt / 2, y + dt / 2 * k1)
        k3 = rhs(t + dt / 2, y + dt / 2 * k2)
        k4 = rhs(t + dt, y + dt * k3)
        y, t = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), t + dt
    return fundamental * 2 / (keep * per_period) / force


@pytest.fixture(scope="module")
def measured():
    """Noisy receptances (L, 2) per force level, from the simulator above."""
    rng = np.random.default_rng(3)
    out = {}
    for F in FORCES:
        H = steady_receptance(FREQS, F)
        out[F] = H + NOISE * np.abs(H) / np.sqrt(2) * (rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape))
    return out


def commercial_uff(path, H, binary, extra=True):
    """Accelerance in g/N, nodes 1 and 2 in +Z, the force at node 2, as a controller's export writes it."""
    sets = [pyuff.prepare_151(model_name="Test rig", description="Stepped sine", db_app="Controller",
                              program="Controller 5.2"),
            pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=2, length=1.0, force=1.0,
                              temp=1.0, temp_offset=273.15)] if extra else []
    w = 2 * np.pi * FREQS
    for p in range(2):
        common = dict(binary=int(binary), id1=f"Point{p + 1}:+Z/Point2:+Z", id2="FRF", id3="23-Nov-26 10:00:00",
                      id4="NONE", id5="NONE", load_case_id=1, rsp_ent_name=f"Point{p + 1}", rsp_node=p + 1,
                      rsp_dir=3, ref_ent_name="Point2", ref_node=2, ref_dir=3, abscissa_spacing=0,
                      abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz", x=FREQS)
        sets.append(pyuff.prepare_58(func_type=4, ordinate_spec_data_type=12, ordinate_axis_units_lab="g",
                                     orddenom_spec_data_type=13, orddenom_axis_units_lab="N",
                                     data=-(w ** 2) * H[:, p] / G, **common))
        if extra:
            sets.append(pyuff.prepare_58(func_type=6, ordinate_spec_data_type=0, orddenom_spec_data_type=0,
                                         data=np.full(len(FREQS), 0.999), **common))
    pyuff.UFF(str(path)).write_sets(sets, mode="add")   # a fresh file (pyuff's "overwrite" loses a binary header)
    return path


def hand_csv(path, measured):
    with open(path, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["frequency_hz", "force_n", "dof", "re", "im"])
        for F, H in measured.items():
            for p, dof in enumerate(["x1", "x2"]):
                for f, h in zip(FREQS, H[:, p]):
                    out.writerow([repr(float(f)), F, dof, repr(float(h.real)), repr(float(h.imag))])
    return path


def analyse(session):
    with open_session(session) as s:
        data = measurements_from_session(s)
    wb = Workbench(load_model(MODEL), data)
    wb.start()
    return wb


def imported_session(fmt, measured, tmp_path):
    out = tmp_path / "imported.h5"
    if fmt == "csv":
        assert main(["import", str(hand_csv(tmp_path / "frf.csv", measured)), "-o", str(out),
                     "--excitation", "x2"]) == 0
        return out
    for i, F in enumerate(FORCES):
        f = commercial_uff(tmp_path / f"level{i}.uff", measured[F], binary=fmt == "uff-binary")
        assert main(["import", str(f), "-o", str(out), "--force-amplitude", str(F), *DOFS]
                    + (["--append"] if i else [])) == 0
    return out


@pytest.mark.parametrize("fmt", ["csv", "uff-ascii", "uff-binary"])
@pytest.mark.slow
def test_the_workbench_finds_a_hidden_cubic_spring_in_imported_data(fmt, measured, tmp_path):
    wb = analyse(imported_session(fmt, measured, tmp_path))
    assert not wb.reports["joint"].verdict.linear
    top = wb.candidates()[0]
    assert (top.element, top.law) == ("joint", "cubic") and top.significant
    before = wb.history[-1].error
    wb.add("joint", "cubic")
    assert wb.history[-1].error < 0.2 * before
    assert wb.model.elements[0].laws[0].values["k3"] == pytest.approx(K3, rel=0.05)
    text = report_text(wb, [])
    assert "noise: not measured for sine_0.2N_up, sine_0.8N_up; estimated from each FRF's scatter" in text
    assert "distortion: no harmonics" in text


def test_imported_session_has_the_acquired_schema_marks_and_provenance(measured, tmp_path):
    out = imported_session("uff-binary", measured, tmp_path)
    with open_session(out) as s:
        assert s.run_names() == ["sine_0.2N_up", "sine_0.8N_up"]
        run = s.run("sine_0.8N_up")
        assert run.kind == "stepped_sine" and run.force == 0.8 and run.direction == "up"
        assert run.status == "complete" and run.excitation_dof == "x2" and run.sensor_dofs == ["x1", "x2"]
        assert run.attrs["imported"] and run.attrs["source_file"] == "level1.uff"
        assert run.attrs["source_format"] == "uff58b" and json.loads(run.attrs["source_records"]) == [3, 5]
        np.testing.assert_allclose(run.frequency, FREQS)
        np.testing.assert_allclose(run.frf["x1"], measured[0.8][:, 0], rtol=1e-12)
        assert any("imported from level0.uff" in e["message"] for e in s.events())
    with h5py.File(out, "r") as f:
        assert f["runs/sine_0.8N_up/frf/x1"].attrs["units"] == "m/N"
        sources = f["provenance/import"]
        assert sorted(sources) == ["source_0", "source_1"]
        src = sources["source_1"]
        data = (tmp_path / "level1.uff").read_bytes()
        assert src.attrs["name"] == "level1.uff" and src.attrs["size"] == len(data)
        assert src.attrs["sha256"] == hashlib.sha256(data).hexdigest() and src.attrs["format"] == "uff58b"
        lines = src["id_lines"].asstr()[()]
        assert lines.shape == (4, 5) and lines[0][0] == "Point1:+Z/Point2:+Z"
        assert "skipped datasets 1, 2" in src.attrs["notes"] and "skipped records 4, 6" in src.attrs["notes"]


def test_velocity_and_displacement_ordinates_and_a_reversed_sign(tmp_path):
    w = 2 * np.pi * FREQS
    h = 1 / (100 - w ** 2 + 1j * w)
    sets = [pyuff.prepare_58(binary=0, func_type=4, rsp_node=7, rsp_dir=-3, ref_node=9, ref_dir=3,
                             ordinate_spec_data_type=11, ordinate_axis_units_lab="mm/s", orddenom_spec_data_type=13,
                             orddenom_axis_units_lab="N", abscissa_spec_data_type=18, x=FREQS,
                             data=-1j * w * h * 1e3, id1="v", id2="", id3="", id4="", id5=""),
            pyuff.prepare_58(binary=0, func_type=4, rsp_node=9, rsp_dir=3, ref_node=9, ref_dir=3,
                             ordinate_spec_data_type=8, ordinate_axis_units_lab="m", orddenom_spec_data_type=13,
                             orddenom_axis_units_lab="N", abscissa_spec_data_type=18, x=FREQS, data=2 * h,
                             id1="d", id2="", id3="", id4="", id5="")]
    pyuff.UFF(str(tmp_path / "m.uff")).write_sets(sets, mode="add")   # a fresh file (pyuff's "overwrite" loses a binary header)
    options = SourceOptions("sine", 0.5, None, [parse_dof_map("7+Z=a"), parse_dof_map("9=b")])
    import_files(ImportRequest([(str(tmp_path / "m.uff"), options)], str(tmp_path / "s.h5")))
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("sine_0.5N_up")
    np.testing.assert_allclose(run.frf["a"], h, rtol=1e-9)          # -Z against +Z: sign reversed
    np.testing.assert_allclose(run.frf["b"], 2 * h, rtol=1e-9)


def test_units_dataset_164_applies_where_the_labels_are_empty(tmp_path):
    """Displacement in mm per N, said only by dataset 164 (SI = value / factor) and the unit exponents."""
    w = 2 * np.pi * FREQS
    h = 1 / (100 - w ** 2 + 1j * w)
    sets = [pyuff.prepare_164(units_code=5, units_description="mm", temp_mode=2, length=1000.0, force=1.0,
                              temp=1.0, temp_offset=273.15),
            pyuff.prepare_58(binary=0, func_type=4, rsp_node=1, rsp_dir=3, ref_node=1, ref_dir=3,
                             ordinate_spec_data_type=8, ordinate_len_unit_exp=1, orddenom_spec_data_type=13,
                             orddenom_force_unit_exp=1, abscissa_spec_data_type=18, x=FREQS, data=1e3 * h,
                             id1="d", id2="", id3="", id4="", id5="")]
    pyuff.UFF(str(tmp_path / "mm.uff")).write_sets(sets, mode="add")
    options = SourceOptions(force=0.5, dofs=[parse_dof_map("1=a")])
    import_files(ImportRequest([(str(tmp_path / "mm.uff"), options)], str(tmp_path / "s.h5")))
    with open_session(tmp_path / "s.h5") as s:
        np.testing.assert_allclose(s.run("sine_0.5N_up").frf["a"], h, rtol=1e-9)


@pytest.mark.slow
def test_time_histories_become_a_random_run_through_the_projects_estimator(tmp_path):
    """Force and accelerations of a multisine through the linear 2-DOF system (its exact steady state)."""
    rng = np.random.default_rng(0)
    fs, n = 64.0, 2 ** 15
    t = np.arange(n) / fs
    lines = np.arange(16, 1 + int(6.0 * n / fs), 16) * fs / n  # every 16th line of the record up to 6 Hz
    phase = rng.uniform(0, 2 * np.pi, len(lines))
    wk = 2 * np.pi * lines
    H = np.array([np.linalg.solve(K - w ** 2 * M + 1j * w * C, [0.0, 1.0]) for w in wk])
    e = np.exp(1j * (np.outer(t, wk) + phase))
    force = 0.05 * np.real(e.sum(axis=1))
    acc = 0.05 * np.real(e @ (-(wk ** 2)[:, None] * H))
    sets = []
    for node, kind, units, data in [(2, 13, "N", force), (1, 12, "m/s^2", acc[:, 0]), (2, 12, "g", acc[:, 1] / G)]:
        sets.append(pyuff.prepare_58(binary=1, func_type=1, rsp_node=node, rsp_dir=3, ref_node=0, ref_dir=0,
                                     ordinate_spec_data_type=kind, ordinate_axis_units_lab=units,
                                     orddenom_spec_data_type=0, abscissa_spec_data_type=17, abscissa_spacing=1,
                                     abscissa_axis_units_lab="s", x=t, data=data, id1="time", id2="", id3="",
                                     id4="", id5=""))
    pyuff.UFF(str(tmp_path / "t.uff")).write_sets(sets, mode="add")   # a fresh file (pyuff's "overwrite" loses a binary header)
    assert main(["import", str(tmp_path / "t.uff"), "-o", str(tmp_path / "s.h5"), *DOFS]) == 0
    with open_session(tmp_path / "s.h5") as s:
        run = s.run("random")
        raw, channels, rate = s.raw("random")
    assert run.kind == "random" and run.excitation_dof == "x2" and rate == fs
    assert channels == ["force", "acc:x1", "acc:x2"] and raw.shape == (n, 3)
    assert run.force == pytest.approx(np.std(force))
    f = run.frequency
    assert f[0] > 0 and f[-1] == pytest.approx(6.0, abs=0.2)
    # the Welch segment is kept: the analysis's leakage allowance is the line spacing fs / segment_length
    assert run.attrs["segment_length"] == 512 and np.allclose(np.diff(f), fs / 512)
    with open_session(tmp_path / "s.h5") as s:
        assert measurements_from_session(s).random.resolution == fs / 512
    truth = np.array([np.linalg.solve(K - w ** 2 * M + 1j * w * C, [0.0, 1.0]) for w in 2 * np.pi * f])
    for p, dof in enumerate(["x1", "x2"]):
        good = run.arrays[f"coherence/{dof}"] > 0.99          # 8 s segments blur the first mode
        assert good.sum() >= 20
        np.testing.assert_allclose(run.frf[dof][good], truth[good, p], rtol=0.08)
        assert f"hv/{dof}" in run.arrays and f"random_error/{dof}" in run.arrays


# ------------------------------------------------------------------------------------------ bad input
def _write(path, sets):
    pyuff.UFF(str(path)).write_sets(sets, mode="add")   # a fresh file (pyuff's "overwrite" loses a binary header)
    return str(path)


def _frf(**change):
    fields = dict(binary=0, func_type=4, rsp_node=1, rsp_dir=3, ref_node=2, ref_dir=3, ordinate_spec_data_type=8,
                  ordinate_axis_units_lab="m", orddenom_spec_data_type=13, orddenom_axis_units_lab="N",
                  abscissa_spec_data_type=18, x=np.array([1.0, 2.0, 3.0, 4.0]),
                  data=np.array([1, 2, 3, 4]) * (1 - 1j) * 1e-3, id1="frf", id2="", id3="", id4="", id5="")
    fields.update(change)
    return pyuff.prepare_58(**fields)


def _time(node, kind):
    return pyuff.prepare_58(binary=0, func_type=1, rsp_node=node, rsp_dir=3, ref_node=0, ref_dir=0,
                            ordinate_spec_data_type=kind, orddenom_spec_data_type=0, abscissa_spec_data_type=17,
                            abscissa_spacing=1, x=np.arange(64) / 64.0, data=np.sin(np.arange(64.0)),
                            id1="t", id2="", id3="", id4="", id5="")


BAD_UFF = {
    "not an FRF": ([_frf(func_type=6, data=np.ones(4))], [],
                   r"b.uff: record 1: func_type: function type 6 is a coherence, not an FRF \(4\) "
                   r"or a time history \(1\)"),
    "no force channel": ([_time(1, 12), _time(2, 12)], DOFS,
                         r"b.uff: record 1: ordinate_spec_data_type: no force channel"),
    "DOF not mapped": ([_frf()], ["--dof", "2+Z=x2"],
                       r"b.uff: record 1: rsp_node: node 1 direction \+3 is not mapped to a model DOF"),
    "excitation not mapped": ([_frf()], ["--dof", "1+Z=x1"], r"b.uff: record 1: ref_node: node 2 direction \+3"),
    "frequencies out of order": ([_frf(x=np.array([1.0, 2.0, 1.5, 4.0]))], DOFS,
                                 r"b.uff: record 1: x: frequencies out of order at line 2 \(2.0 then 1.5"),
    "NaN": ([_frf(data=np.array([1, 2, 777, 4]) * (1 - 1j))], DOFS,          # 777 becomes NaN in the file
            r"b.uff: record 1: data: line 2 is .*nan.*not a finite number"),
    "level missing": ([_frf()], ["--dof", "1=x1", "--excitation", "x2"],
                      r"b.uff: record 1: force: the file does not say the force level .*--force-amplitude N"),
    "unknown unit": ([_frf(ordinate_axis_units_lab="furlong")], DOFS,
                     r"b.uff: record 1: ordinate_axis_units_lab: unit 'furlong' not known"),
    "not a force over": ([_frf(orddenom_spec_data_type=12)], DOFS,
                         r"b.uff: record 1: orddenom_spec_data_type: .* 12 \(acceleration\) is not a force"),
}


@pytest.mark.parametrize("case", list(BAD_UFF))
def test_bad_uff_names_file_record_and_field_and_writes_nothing(case, tmp_path, capsys):
    sets, flags, message = BAD_UFF[case]
    tag = RecordTag("sine_1N_up", "frf", "x1", "x2", "stepped_sine", 1.0, "up", "complete")
    good = _write(tmp_path / "a.uff", [_frf(**encode(tag, "", "t", "test"))])     # needs no flags
    bad = _write(tmp_path / "b.uff", sets)
    text = (tmp_path / "b.uff").read_text()                 # pyuff itself writes NaN as 0
    (tmp_path / "b.uff").write_text(text.replace("7.77000000000e+02", "nan".rjust(17), 1))
    force = [] if case == "level missing" else ["--force-amplitude", "0.5"]
    rc = main(["import", good, bad, "-o", str(tmp_path / "s.h5"), *force, *flags])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert __import__("re").search(message, err), err
    assert not (tmp_path / "s.h5").exists() and not list(tmp_path.glob(".*partial*"))


BAD_CSV = {
    "no force level": ("frequency_hz,force_n,dof,re,im\n1,0.5,x1,1,-1\n2,,x1,1,-1\n", "c.csv: line 3: force_n"),
    "not a number": ("frequency_hz,force_n,dof,re,im\n1,0.5,x1,abc,-1\n", "c.csv: line 2: re: 'abc' is not a number"),
    "nan": ("frequency_hz,force_n,dof,re,im\n1,0.5,x1,nan,-1\n", "c.csv: line 2: re: 'nan' is not a finite"),
    "level missing for a DOF": ("frequency_hz,force_n,dof,re,im\n1,0.5,x1,1,-1\n2,0.5,x1,1,-1\n1,0.5,x2,1,-1\n",
                                "c.csv: line 3: dof: dof x2 at 0.5 N has no row at 2.0 Hz, which dof x1 has"),
    "out of order": ("frequency_hz,force_n,dof,re,im\n1,0.5,x1,1,-1\n3,0.5,x1,1,-1\n2,0.5,x1,1,-1\n",
                     "c.csv: line 4: frequency_hz: 2.0 Hz after 3.0 Hz (line 3)"),   # file lines only
    "unknown column": ("frequency_hz,force_n,dof,re,im,phase\n1,0.5,x1,1,-1,0\n", "c.csv: line 1: header: "),
}


@pytest.mark.parametrize("case", list(BAD_CSV))
def test_bad_csv_names_file_line_and_column(case, tmp_path, capsys):
    text, message = BAD_CSV[case]
    (tmp_path / "c.csv").write_text(text)
    rc = main(["import", str(tmp_path / "c.csv"), "-o", str(tmp_path / "s.h5"), "--excitation", "x2"])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and not (tmp_path / "s.h5").exists()


def test_csv_without_excitation_and_bad_dof_map_are_refused(tmp_path):
    (tmp_path / "c.csv").write_text("frequency_hz,force_n,dof,re,im\n1,0.5,x1,1,-1\n")
    with pytest.raises(InputError, match="c.csv: --excitation: a CSV file does not name the excitation"):
        import_files(ImportRequest([(str(tmp_path / "c.csv"), SourceOptions())], str(tmp_path / "s.h5")))
    with pytest.raises(InputError, match="--dof takes NODE"):
        parse_dof_map("A.w=3")


def test_append_keeps_what_was_there_and_a_bad_append_changes_nothing(tmp_path):
    session = tmp_path / "s.h5"
    w = SessionWriter(session, software_version="t")
    w.begin_run(RunSpec("sine_0.5N_up", "stepped_sine", 0.5, "up", "x2", ["x1"], 100.0, ["force"], ["N"]))
    w.append_line(1.0, {"x1": 1e-3 - 1e-3j}, raw=np.ones((10, 1)))
    w.end_run("complete")
    w.close()
    csv_file = tmp_path / "c.csv"
    csv_file.write_text("frequency_hz,force_n,dof,re,im,std\n1,0.5,x1,1e-3,-1e-3,1e-6\n2,0.5,x1,1e-3,-2e-3,1e-6\n")
    options = SourceOptions(excitation="x2")
    with pytest.raises(InputError, match="exists already"):
        import_files(ImportRequest([(str(csv_file), options)], str(session)))
    import_files(ImportRequest([(str(csv_file), options)], str(session), append=True))
    with open_session(session) as s:
        assert s.run_names() == ["sine_0.5N_up", "sine_0.5N_up_2"]
        assert s.raw("sine_0.5N_up")[0].shape == (10, 1)
        np.testing.assert_allclose(s.run("sine_0.5N_up_2").arrays["frf_std/x1"], [1e-6, 1e-6])
    before = hashlib.sha256(session.read_bytes()).hexdigest()
    (tmp_path / "bad.csv").write_text("frequency_hz,force_n,dof,re,im\n1,0.5,x1,1,oops\n")
    with pytest.raises(InputError, match="bad.csv: line 2: im"):
        import_files(ImportRequest([(str(csv_file), options), (str(tmp_path / "bad.csv"), options)], str(session),
                                   append=True))
    assert hashlib.sha256(session.read_bytes()).hexdigest() == before
