"""UFF58 and CSV export, read back independently (pyuff, csv)."""
import csv
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import pyuff

from analysis import InputError
from app.cli import main
from app.export import export_csv, export_uff, run_file
from app.session.writer import RunSpec, SessionWriter

RUN = "sine_0.5N_up"


def _sine_session(path, freqs, frf=None):
    w = SessionWriter(path, software_version="9.9")
    w.begin_run(RunSpec(RUN, "stepped_sine", 0.5, "up", "B.w", ["A.w", "B.theta"], 1000.0,
                        ["force"], ["N"], extras={"force_amplitude": ("N", (), "f8"), "thd/force": ("1", (), "f8")}))
    for i, f in enumerate(freqs):
        a = (1 + 1j) * 1e-5 * (i + 1) if frf is None else frf[i]
        w.append_line(f, {"A.w": a, "B.theta": -2e-4j * (i + 1)}, {"force_amplitude": 0.5 + 1e-3 * i,
                                                                    "thd/force": 0.01 * i})
    w.end_run("complete")
    return w


@pytest.fixture
def session(tmp_path):
    path = tmp_path / "s.h5"
    freqs = np.array([50.0, 50.5, 51.25, 51.5, 53.0])          # uneven, as after refinement
    w = _sine_session(path, freqs)
    f = 0.25 * np.arange(1, 9)                                 # a random run's FFT lines: even
    w.begin_run(RunSpec("random", "random", 0.3, "none", "B.w", ["A.w", "B.theta"], 1000.0, ["force"], ["N"],
                        extras={"coherence/A.w": ("1", (), "f8"), "coherence/B.theta": ("1", (), "f8")}))
    w.write_arrays({"frequency": f, "frf/A.w": 1e-5 / (1 + 1j * f), "frf/B.theta": 1e-4 / (2 + 1j * f),
                    "coherence/A.w": np.full(8, 0.99), "coherence/B.theta": np.full(8, 0.98)})
    w.end_run("complete")
    w.close()
    return path, freqs


def _records(path):
    return pyuff.UFF(str(path)).read_sets()


def test_one_file_per_run_with_documented_nodes_units_and_tags(session, tmp_path):
    path, freqs = session
    done = export_uff(path, tmp_path / "out.uff", per_run=True)
    assert sorted(done.files) == [run_file(tmp_path / "out.uff", "random"), run_file(tmp_path / "out.uff", RUN)]
    assert run_file(tmp_path / "out.uff", RUN).name == f"out_{RUN}.uff"
    sets = _records(run_file(tmp_path / "out.uff", RUN))
    assert sets[0]["type"] == 151 and "exp(+jwt)" in sets[0]["description"]
    frfs = {s["rsp_ent_name"].strip(): s for s in sets[1:] if s["func_type"] == 4}
    a, b = frfs["A.w"], frfs["B.theta"]
    # stations A, B in natural order are nodes 1, 2; the excitation B.w is not renumbered first
    assert (a["rsp_node"], a["rsp_dir"], a["ref_node"], a["ref_dir"]) == (1, 3, 2, 3)
    assert (b["rsp_node"], b["rsp_dir"]) == (2, 5)
    assert a["id1"] == f"contactid run={RUN} quantity=frf" and a["id2"] == "rsp=A.w ref=B.w"
    assert a["id4"] == "kind=stepped_sine force=0.5 direction=up status=complete"
    assert (a["ordinate_len_unit_exp"], a["ordinate_force_unit_exp"], a["ordinate_axis_units_lab"]) == (1, 0, "m")
    assert (a["orddenom_len_unit_exp"], a["orddenom_force_unit_exp"], a["orddenom_axis_units_lab"]) == (0, 1, "N")
    assert (a["ordinate_spec_data_type"], a["orddenom_spec_data_type"], a["abscissa_axis_units_lab"]) == (8, 13, "Hz")
    assert b["ordinate_len_unit_exp"] == 0 and b["ordinate_axis_units_lab"] == "rad"
    assert a["abscissa_spacing"] == 0
    np.testing.assert_allclose(a["x"], freqs, rtol=1e-12)
    np.testing.assert_allclose(a["data"], (1 + 1j) * 1e-5 * np.arange(1, 6), rtol=1e-12)
    held = next(s for s in sets[1:] if "quantity=force_amplitude" in s["id1"])
    np.testing.assert_allclose(held["data"], 0.5 + 1e-3 * np.arange(5))


def test_random_run_is_evenly_spaced_and_the_default_file_holds_every_run(session, tmp_path):
    path, _ = session
    export_uff(path, tmp_path / "o.uff", per_run=True)
    rnd = next(s for s in _records(run_file(tmp_path / "o.uff", "random")) if s.get("func_type") == 4)
    assert rnd["abscissa_spacing"] == 1 and rnd["abscissa_inc"] == 0.25
    np.testing.assert_allclose(rnd["x"], 0.25 * np.arange(1, 9), rtol=1e-14)
    coherence = [s for s in _records(run_file(tmp_path / "o.uff", "random")) if s.get("func_type") == 6]
    assert len(coherence) == 2
    one = export_uff(path, tmp_path / "all.uff", per_run=False, frf_only=True)
    assert one.files == [tmp_path / "all.uff"] and one.records == 4
    runs = {s["id1"].split()[1] for s in _records(tmp_path / "all.uff")[1:]}
    assert runs == {f"run={RUN}", "run=random"}


def test_an_abscissa_ascii_would_round_is_refused_and_binary_keeps_it(tmp_path):
    freqs = np.array([100.0, 100.0125, 100.025])
    path = tmp_path / "s.h5"
    _sine_session(path, freqs).close()
    with pytest.raises(InputError, match=r"run sine_0.5N_up: frequency: line 1 at 100.0125 Hz .*--binary"):
        export_uff(path, tmp_path / "o.uff", binary=False)
    assert list(tmp_path.glob("*.uff")) == [] and list(tmp_path.glob(".*partial")) == []
    done = export_uff(path, tmp_path / "o.uff")              # the default: binary
    [a] = [s for s in _records(done.files[0]) if s.get("rsp_ent_name", "").strip() == "A.w" and s["func_type"] == 4]
    assert a["binary"] == 1
    np.testing.assert_array_equal(a["x"], freqs)


@pytest.mark.parametrize("bad", ["frf", "frequency"])
def test_nan_is_refused_naming_run_and_line(tmp_path, bad):
    freqs = np.array([10.0, 11.0, 12.0])
    frf = np.array([1e-5, 2e-5, 3e-5], complex)
    if bad == "frf":
        frf[2] = np.nan
    else:
        freqs[1] = np.inf
    path = tmp_path / "s.h5"
    _sine_session(path, freqs, frf).close()
    line = 2 if bad == "frf" else 1
    with pytest.raises(InputError, match=rf"s.h5: run {RUN}, dataset .*: line {line} is .*must be finite"):
        export_uff(path, tmp_path / "o.uff")
    with pytest.raises(InputError, match=rf"s.h5: run {RUN}, dataset .*: line {line} is"):
        export_csv(path, tmp_path / "csv")
    assert not list(tmp_path.rglob("*.uff")) and not list(tmp_path.rglob("*.csv"))


def test_existing_output_and_the_input_are_refused(session, tmp_path):
    path, _ = session
    export_uff(path, tmp_path / "o.uff")
    with pytest.raises(InputError, match="exists already"):
        export_uff(path, tmp_path / "o.uff")
    with pytest.raises(InputError, match="also an input"):
        export_uff(path, path, overwrite=True, per_run=False)


def test_a_failed_write_leaves_no_file(session, tmp_path, monkeypatch):
    path, _ = session

    def fail_midway(self, sets, mode="add", force_double=True):
        with open(self._filename, "w") as fh:
            fh.write("    -1\n    58\n")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pyuff.UFF, "write_sets", fail_midway)
    with pytest.raises(InputError, match="o.uff: not written: No space left on device; no file was left"):
        export_uff(path, tmp_path / "o.uff", per_run=False)
    assert [p.name for p in tmp_path.iterdir()] == ["s.h5"]


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("unshare") is None, reason="needs root for a private tmpfs")
@pytest.mark.slow
def test_full_disk_gives_an_error_and_no_file(session, tmp_path):
    path, _ = session
    disk = tmp_path / "disk"
    disk.mkdir()
    script = (f"mount -t tmpfs -o size=8k tmpfs {disk} && head -c 4096 /dev/zero > {disk}/filler; "
              f"{sys.executable} -m app.cli export {path} --uff {disk}/o.uff; echo rc=$?; ls -A {disk}")
    out = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": os.getcwd()}, timeout=120)
    assert "rc=2" in out.stdout and "not enough free space" in out.stderr and "--debug" not in out.stderr
    assert out.stdout.split("rc=2")[1].split() == ["filler"]


def test_csv_has_units_and_all_lines(session, tmp_path):
    path, freqs = session
    export_csv(path, tmp_path / "csv")
    rows = list(csv.reader((tmp_path / "csv" / f"{RUN}.csv").open()))
    assert rows[1] == [f"# contactid-run run={RUN} kind=stepped_sine force=0.5 direction=up status=complete "
                       "excitation=B.w"]                    # what import reads back (app/importers/csv_runs.py)
    header = rows[2]
    assert header[0] == "frequency [Hz]" and "Re frf A.w [m/N]" in header and "force_amplitude [N]" in header
    data = np.array(rows[3:], float)
    np.testing.assert_allclose(data[:, 0], freqs)
    np.testing.assert_allclose(data[:, header.index("Im frf B.theta [m/N]")], -2e-4 * np.arange(1, 6))


def test_a_run_csv_read_back_refuses_digits_grouped_with_underscores(session, tmp_path, capsys):
    """The CSV export read back follows the long format's rule: ``1_000`` is no number (Python's float would
    read 1000)."""
    path, _ = session
    export_csv(path, tmp_path / "csv")
    exported = tmp_path / "csv" / f"{RUN}.csv"
    rows = exported.read_text().splitlines()
    first = rows[3].split(",")
    rows[3] = ",".join(["1_000"] + first[1:])
    exported.write_text("\n".join(rows) + "\n")
    assert main(["import", str(exported), "-o", str(tmp_path / "back.h5")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'1_000' is not a number" in err and "line 4: column 1" in err
