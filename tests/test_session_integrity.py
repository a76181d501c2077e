"""Nothing measured is lost or overwritten by a later command, a typo, a damaged file, a full disk or a
read-only medium; every such case is one line naming the file and the object, exit status 2 for bad input."""
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from app.cli import main
from app.session.writer import RunSpec, SessionWriter, open_session
from session_helpers import MODEL, ROOT, plain_open, write_session

RUN = "sine_0.8N_up"


@pytest.fixture(scope="module")
def session_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("integrity")
    write_session(folder / "s.h5")
    (folder / "model.toml").write_text(MODEL)
    return folder / "s.h5", folder / "model.toml"


@pytest.fixture
def copies(session_files, tmp_path):
    session, model = session_files
    shutil.copy(session, tmp_path / "s.h5")
    shutil.copy(model, tmp_path / "model.toml")
    return tmp_path / "s.h5", tmp_path / "model.toml"


def one_line_error(capsys, *names) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("contactid: error: ")
    for name in names:
        assert str(name) in err
    return err


# ----------------------------------------------------------------------------- analyze -o
@pytest.mark.parametrize("which", ["session", "model"])
def test_analyze_never_writes_over_one_of_its_inputs(copies, capsys, which):
    session, model = copies
    target = session if which == "session" else model
    before = target.read_bytes()
    assert main(["analyze", str(session), str(model), "-o", str(target), "--overwrite"]) == 2
    assert "also an input" in one_line_error(capsys, target)
    assert target.read_bytes() == before


@pytest.mark.slow
def test_analyze_output_refuses_an_existing_toml_without_force_and_shows_earlier_analyses(copies, capsys):
    session, model = copies
    fitted = session.parent / "fitted.toml"
    fitted.write_text("# keep me\n")
    assert main(["analyze", str(session), str(model), "-o", str(fitted)]) == 2
    assert "exists already" in one_line_error(capsys, fitted)
    assert fitted.read_text() == "# keep me\n"
    assert main(["analyze", str(session), str(model)]) == 0          # stores analysis_0
    assert "stored in the session as /models/analysis_0" in capsys.readouterr().out
    assert main(["analyze", str(session), str(model), "-o", str(fitted), "--overwrite"]) == 0
    out = capsys.readouterr().out
    assert "earlier analyses stored in this session (1):" in out and "analysis_0" in out
    assert "stored in the session as /models/analysis_1" in out
    assert "[structure]" in fitted.read_text()
    assert sorted(p.name for p in session.parent.iterdir()) == ["fitted.toml", "model.toml", "s.h5"]
    with h5py.File(session, "r") as f:                                # still whole, runs untouched
        assert sorted(f["models"]) == ["analysis_0", "analysis_1"]
        assert f[f"runs/{RUN}/frequency"].shape == (25,)


# ----------------------------------------------------------------------------- damaged sessions
@pytest.mark.parametrize("percent", [10, 50, 90])
def test_a_truncated_session_is_one_line_naming_the_file(copies, capsys, percent):
    session, model = copies
    os.truncate(session, session.stat().st_size * percent // 100)
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    assert "damaged or truncated" in one_line_error(capsys, session)


def drop_dataset(f):
    del f[f"runs/{RUN}/frf/x1"]


def drop_attribute(f):
    del f[f"runs/{RUN}"].attrs["sensor_dofs"]


def garble_attribute(f):
    f[f"runs/{RUN}"].attrs["sensor_dofs"] = "[x1, x2"


def drop_runs(f):
    del f["runs"]


@pytest.mark.parametrize("damage,where", [
    (drop_dataset, f"/runs/{RUN}/frf/x1"),
    (drop_attribute, f"/runs/{RUN}@sensor_dofs"),
    (garble_attribute, f"/runs/{RUN}@sensor_dofs"),
    (drop_runs, "/runs"),
])
def test_a_session_missing_a_dataset_or_attribute_is_one_line_naming_it(copies, capsys, damage, where):
    session, model = copies
    with h5py.File(session, "r+") as f:
        damage(f)
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    one_line_error(capsys, session, where)
    assert main(["export", str(session), "--csv", str(session.parent / "csv")]) == 2
    one_line_error(capsys, session, where)


# ----------------------------------------------------------------------------- a typo in acquire
def test_a_typo_in_acquire_leaves_the_complete_session_as_it_was(copies, capsys):
    session, _ = copies
    before = session.read_bytes()
    plan = session.parent / "p.toml"
    plan.write_text("[[stepped_sine]]\nforce = 0.8\nstart = 1.0\nstop = 1.2\nstep = 0.1\n[limits]\n"
                    "max_force = 5.0\nmax_acceleration = 50.0\n")
    code = main(["acquire", str(plan), "-o", str(session), "--overwrite", "--shaker", "sim://paper-2dof/shaker",
                 "--daq", "sim://paper-2dof/daq", "--excitation", "x2", "--sensors", "q"])
    assert code != 0 and "q" in capsys.readouterr().err
    assert session.read_bytes() == before
    fresh = session.parent / "fresh.h5"                  # without --overwrite: no empty file blocks the retry
    assert main(["acquire", str(plan), "-o", str(fresh), "--shaker", "sim://paper-2dof/shaker", "--daq",
                 "sim://paper-2dof/daq", "--excitation", "x2", "--sensors", "q"]) != 0
    assert sorted(p.name for p in session.parent.iterdir()) == ["model.toml", "p.toml", "s.h5"]


# ----------------------------------------------------------------------------- full disk, read-only medium
def _unshare_works() -> bool:
    try:
        return subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                              capture_output=True).returncode == 0
    except OSError:
        return False


needs_private_mount = pytest.mark.skipif(
    not _unshare_works(), reason="a private tmpfs needs `unshare -m` and mount rights (root); not permitted here")


def on_small_disk(tmp_path, size: str, commands: str) -> subprocess.CompletedProcess:
    """Run shell ``commands`` with a private tmpfs of ``size`` mounted at $DISK (gone afterwards: copy what
    is to be checked to $OUT); $PY runs Python with contactid on its path."""
    disk = tmp_path / "disk"
    disk.mkdir()
    env = dict(os.environ, PYTHONPATH=str(ROOT), DISK=str(disk), OUT=str(tmp_path), PY=sys.executable)
    return subprocess.run(["unshare", "-m", "sh", "-c", f'mount -t tmpfs -o size={size} tmpfs "$DISK" && {commands}'],
                          env=env, cwd=ROOT, capture_output=True, text=True)


FILL = 'dd if=/dev/zero of="$DISK/fill" bs=4k 2>/dev/null; '
AFTER = 'echo $? > "$OUT/rc"; cp "$DISK/s.h5" "$OUT/after.h5"; ls -A "$DISK" > "$OUT/listing"'


@needs_private_mount
@pytest.mark.slow
def test_analyze_on_a_full_disk_reports_and_leaves_the_session_whole(copies, tmp_path):
    """Without -o the analysis is printed and says its history was not stored; with -o it is refused before it
    starts (the fitted model could not be written), one line, exit 2. The session is not changed by a byte."""
    session, model = copies
    before = session.read_bytes()
    done = on_small_disk(tmp_path, "1m", 'cp "$OUT/s.h5" "$OUT/model.toml" "$DISK"/ && ' + FILL +
                         '$PY -m app.cli analyze "$DISK/s.h5" "$DISK/model.toml" > "$OUT/plain" 2> "$OUT/plain_err"; '
                         'echo $? > "$OUT/plain_rc"; '
                         '$PY -m app.cli analyze "$DISK/s.h5" "$DISK/model.toml" -o "$DISK/fitted.toml" '
                         '> "$OUT/stdout" 2> "$OUT/stderr"; ' + AFTER)
    assert done.returncode == 0, done.stderr
    plain = (tmp_path / "plain").read_text()
    assert (tmp_path / "plain_rc").read_text().strip() == "0", (tmp_path / "plain_err").read_text()
    assert "FRF error of the model" in plain                                # the analysis is there
    assert "model history NOT stored" in plain and "free space" in plain
    out, err = (tmp_path / "stdout").read_text(), (tmp_path / "stderr").read_text()
    assert out == "" and err.count("\n") == 1 and "not enough free space to write the fitted model" in err
    assert (tmp_path / "rc").read_text().strip() == "2"
    assert (tmp_path / "after.h5").read_bytes() == before                   # not a byte changed
    assert (tmp_path / "listing").read_text().split() == ["fill", "model.toml", "s.h5"]   # no 0-byte output


@needs_private_mount
@pytest.mark.slow
def test_analyze_of_a_read_only_session_works_and_says_the_history_was_not_stored(copies, tmp_path):
    on_small_disk(tmp_path, "2m", 'cp "$OUT/s.h5" "$OUT/model.toml" "$DISK"/ && mount -o remount,ro "$DISK" && '
                  '$PY -m app.cli analyze "$DISK/s.h5" "$DISK/model.toml" > "$OUT/stdout" 2> "$OUT/stderr"; ' + AFTER)
    out = (tmp_path / "stdout").read_text()
    assert (tmp_path / "rc").read_text().strip() == "0", (tmp_path / "stderr").read_text()
    assert "FRF error of the model" in out and "model history NOT stored" in out and "read-only" in out


@pytest.mark.slow
@needs_private_mount
def test_simulate_on_a_disk_that_fills_ends_the_run_cleanly(tmp_path):
    plan = tmp_path / "p.toml"
    plan.write_text("[[stepped_sine]]\nforce = 0.8\nstart = 0.8\nstop = 3.2\nstep = 0.05\n[limits]\n"
                    "max_force = 5.0\nmax_acceleration = 50.0\n")
    on_small_disk(tmp_path, "1300k", '$PY -m app.cli simulate paper-2dof "$OUT/p.toml" -o "$DISK/s.h5" --quiet '
                  '> "$OUT/stdout" 2> "$OUT/stderr"; ' + AFTER)
    out, err = (tmp_path / "stdout").read_text(), (tmp_path / "stderr").read_text()
    assert (tmp_path / "rc").read_text().strip() == "3", err              # aborted, not a crash
    assert "not enough free space" in err and "output off" in err
    lines = int(out.split(" lines;")[0].split()[-1])
    with plain_open(tmp_path / "after.h5", timeout=0) as f:               # any HDF5 reader opens it
        g = f[f"runs/{RUN}"]
        assert g.attrs["status"] == "aborted" and "free space" in g.attrs["end_reason"]
        assert g["frequency"].shape[0] == g["frf/x1"].shape[0] == g["raw/line_count"].shape[0] == lines > 0
    with open_session(tmp_path / "after.h5") as s:
        assert not s.run(RUN).incomplete
    assert (tmp_path / "listing").read_text().split() == ["s.h5"]


@pytest.mark.slow
@needs_private_mount
def test_a_disk_filled_by_another_program_during_simulate_leaves_a_session_recover_repairs(tmp_path):
    """Another program fills the disk while a run is measured: the campaign ends aborted with one line, and once
    there is room `contactid recover` makes the file readable by any tool with the lines written before."""
    plan = tmp_path / "p.toml"
    plan.write_text("[[stepped_sine]]\nforce = 0.8\nstart = 0.8\nstop = 3.2\nstep = 0.002\n[limits]\n"
                    "max_force = 5.0\nmax_acceleration = 50.0\n")
    on_small_disk(tmp_path, "3m",
                  '$PY -m app.cli simulate paper-2dof "$OUT/p.toml" -o "$DISK/s.h5" --quiet > "$OUT/stdout" '
                  '2> "$OUT/stderr" & P=$!; '
                  # filled mid-run, well before the run closes (a fill while the writer closes the run is the case
                  # of test_recover_of_a_run_closed_on_a_full_disk_leaves_out_the_reads_that_do_not_finish)
                  'while [ "$(stat -c %s "$DISK/s.h5" 2>/dev/null || echo 0)" -lt 300000 ]; do sleep 0.1; done; '
                  + FILL + 'wait $P; echo $? > "$OUT/rc"; rm "$DISK/fill"; '
                  'timeout 300 $PY -m app.cli recover "$DISK/s.h5" > "$OUT/recover" 2>&1; echo $? > "$OUT/recover_rc"; '
                  'cp "$DISK/s.h5" "$OUT/after.h5"; ls -A "$DISK" > "$OUT/listing"')
    err = (tmp_path / "stderr").read_text()
    assert (tmp_path / "rc").read_text().strip() == "3", err                # aborted, not a crash
    assert err.count("campaign aborted") == 1 and "Traceback" not in err and "file write failed" not in err
    assert (tmp_path / "recover_rc").read_text().strip() == "0", (tmp_path / "recover").read_text()
    with plain_open(tmp_path / "after.h5", timeout=0) as f:                 # any HDF5 reader opens it
        g = f[f"runs/{RUN}"]
        assert g.attrs["status"] == "aborted"
        assert min(g["frequency"].shape[0], g["frf/x1"].shape[0]) > 0
        assert f["events"][-1]["kind"] == b"recovery"
    assert main(["export", str(tmp_path / "after.h5"), "--csv", str(tmp_path / "csv")]) == 0
    assert (tmp_path / "listing").read_text().split() == ["s.h5"]


# A run closed while another program filled the disk (tests/data/full_past_offset.c, LD_PRELOAD into a writer
# that wrote 5 lines and then closed its run with every write past 32 bytes beyond the file's end failing with
# ENOSPC): the superblock says "open for writing", the run's new attributes point past what reached the disk, and
# reading its attribute "ended" spins inside HDF5 forever.
CLOSED_ON_A_FULL_DISK = ROOT / "tests" / "data" / "run_closed_on_a_full_disk.h5.gz"


def _closed_on_a_full_disk(tmp_path):
    import gzip

    path = tmp_path / "s.h5"
    path.write_bytes(gzip.decompress(CLOSED_ON_A_FULL_DISK.read_bytes()))
    return path


@pytest.mark.slow
def test_recover_of_a_run_closed_on_a_full_disk_leaves_out_the_reads_that_do_not_finish(tmp_path, capsys,
                                                                                          monkeypatch):
    import app.session.salvage as salvage
    from app.session.superblock import write_flags

    monkeypatch.setattr(salvage, "ITEM_SECONDS", 1.5)
    session = _closed_on_a_full_disk(tmp_path)
    assert write_flags(session) == 1                                      # left open outside SWMR mode
    assert main(["recover", str(session)]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "recovered" in out
    assert "/runs/sine_0@ended (reading it did not finish)" in out       # named, not waited on
    with plain_open(session, timeout=0) as f:                             # any HDF5 reader opens it
        g = f["runs/sine_0"]
        assert g.attrs["status"] == "aborted" and g.attrs["incomplete"]
        assert g["frequency"].shape == g["frf/x1"].shape == (5,)           # every line written before is kept
        np.testing.assert_allclose(g["frequency"][()], 1.0 + 0.01 * np.arange(5))
        assert f["events"][-1]["kind"] == b"recovery" and b"did not finish" in f["events"][-1]["message"]
    assert main(["export", str(session), "--csv", str(tmp_path / "csv")]) == 0


@pytest.mark.slow
def test_recover_gives_up_in_one_line_when_too_many_reads_do_not_finish(tmp_path, capsys, monkeypatch):
    import app.session.salvage as salvage

    monkeypatch.setattr(salvage, "ITEM_SECONDS", 1.5)
    monkeypatch.setattr(salvage, "MAX_STALLS", 0)
    session = _closed_on_a_full_disk(tmp_path)
    before = session.read_bytes()
    assert main(["recover", str(session)]) == 2
    err = one_line_error(capsys, session, "/runs/sine_0@ended")
    assert "did not finish" in err and "unchanged" in err
    assert session.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


CLOSE_ON_A_DISK_FULL_PAST = """
import ctypes, os, sys
import numpy as np
from app.session.file import RunSpec, SessionFile, SessionHeader, SessionWriteError
path = sys.argv[1]
f = SessionFile(path, path + ".tmp", False, SessionHeader(plan_text="x", software_version="t"))
f.begin_run(RunSpec("sine_0", "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0, ["force", "acc:x1", "acc:x2"],
                    ["N", "m/s^2", "m/s^2"], extras={"force_amplitude": ("N", (), "f8")}), 0.0)
for i in range(5):
    f.append_line(1.0 + 0.01 * i, {"x1": complex(i, 1), "x2": complex(i, 2)}, {"force_amplitude": 0.8},
                  raw=np.full((50, 3), i, dtype=np.float32))
ctypes.CDLL(None).enospc_limit(ctypes.c_longlong(os.path.getsize(path) + 32))
try:
    f.end_run("complete", "", 1.0)
except SessionWriteError:
    os._exit(3)                                  # as the writer process ends after a failed write
"""


@pytest.mark.slow
@needs_private_mount
@pytest.mark.skipif(shutil.which("gcc") is None, reason="builds tests/data/full_past_offset.c")
def test_a_run_closed_while_the_disk_fills_is_recovered_without_hanging(tmp_path):
    """The fixture's case made afresh on a private tmpfs: the writer closes its run while every write past 32
    bytes beyond the file's end fails with ENOSPC; recover then repairs the file within its time bounds."""
    shim = tmp_path / "full.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-o", str(shim), str(ROOT / "tests" / "data" / "full_past_offset.c"),
                    "-ldl"], check=True)
    (tmp_path / "close.py").write_text(CLOSE_ON_A_DISK_FULL_PAST)
    on_small_disk(tmp_path, "4m", f'LD_PRELOAD={shim} $PY "$OUT/close.py" "$DISK/s.h5"; echo $? > "$OUT/rc"; '
                  'timeout 300 $PY -m app.cli recover "$DISK/s.h5" > "$OUT/recover" 2>&1; '
                  'echo $? > "$OUT/recover_rc"; cp "$DISK/s.h5" "$OUT/after.h5"')
    assert (tmp_path / "rc").read_text().strip() == "3"                     # the close failed
    out = (tmp_path / "recover").read_text()
    assert (tmp_path / "recover_rc").read_text().strip() == "0", out
    assert "did not finish" in out and out.count("\n") == 1
    with plain_open(tmp_path / "after.h5", timeout=0) as f:
        g = f["runs/sine_0"]
        assert g.attrs["status"] == "aborted" and g["frequency"].shape == (5,)


def test_a_run_left_running_in_a_file_its_writer_closed_is_marked_aborted_by_recover(copies, capsys):
    """The write that failed was the run's status, the file's flags were cleared: every reader opens it, and
    recover closes the run as aborted."""
    session, _ = copies
    with h5py.File(session, "r+") as f:
        f[f"runs/{RUN}"].attrs["status"] = "running"
    assert main(["recover", str(session)]) == 0
    assert f"run(s) marked aborted and incomplete: {RUN}" in capsys.readouterr().out
    with plain_open(session, timeout=0) as f:
        assert f[f"runs/{RUN}"].attrs["status"] == "aborted" and f[f"runs/{RUN}"].attrs["incomplete"]
        assert f[f"runs/{RUN}/frequency"].shape == (25,)
    assert main(["recover", str(session)]) == 0 and "nothing to recover" in capsys.readouterr().out


def _mark_open_for_writing(path):
    """Set the superblock's "open for writing" flag, as a writer that stopped outside SWMR mode leaves it."""
    from app.session.superblock import lookup3

    with open(path, "r+b") as fh:
        block = bytearray(fh.read(48))
        block[11] = 1
        block[44:48] = lookup3(bytes(block[:44])).to_bytes(4, "little")
        fh.seek(0)
        fh.write(block)


def test_the_superblock_checksum_is_hdf5s(copies):
    from app.session.superblock import lookup3

    block = copies[0].read_bytes()[:48]                          # written by HDF5 itself
    assert block[8] == 3 and int.from_bytes(block[44:48], "little") == lookup3(block[:44])


def test_a_session_left_open_outside_swmr_mode_is_named_and_recover_repairs_it(copies, capsys):
    session, model = copies
    _mark_open_for_writing(session)
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(session, "r")
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    assert "contactid recover" in one_line_error(capsys, session)
    assert main(["recover", str(session)]) == 0
    with plain_open(session, timeout=0) as f:
        assert f[f"runs/{RUN}/frequency"].shape == (25,)
        assert f[f"runs/{RUN}"].attrs["status"] == "complete"   # closed before: not marked
        assert f["events"][-1]["kind"] == b"recovery"


# ----------------------------------------------------------------------------- checksums
def _flip_a_bit(path, dataset, chunk=0, byte=3):
    """Flip one bit of a stored chunk of ``dataset``, behind HDF5's back (a disk or a copy going wrong)."""
    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(chunk)
    with open(path, "r+b") as fh:
        fh.seek(info.byte_offset + byte)
        value = fh.read(1)[0]
        fh.seek(info.byte_offset + byte)
        fh.write(bytes([value ^ 0x10]))


@pytest.mark.parametrize("dataset", [f"/runs/{RUN}/frf/x1", f"/runs/{RUN}/frequency",
                                     f"/runs/{RUN}/force_amplitude"])
def test_a_flipped_bit_in_measured_data_is_refused_naming_the_dataset_and_lines(copies, capsys, dataset):
    session, model = copies
    with h5py.File(session, "r") as f:
        assert f[dataset].fletcher32 and f[dataset].chunks
    _flip_a_bit(session, dataset)
    assert main(["analyze", str(session), str(model), "--no-history"]) == 2
    err = one_line_error(capsys, session, dataset)
    assert "checksum failure" in err and "line(s) 0-24 of 25" in err      # numbered from 0, as the session reader numbers lines


def test_a_checksum_failure_names_only_the_damaged_chunk(tmp_path):
    from app.session.file import LINES_PER_CHUNK

    session = tmp_path / "long.h5"
    w = SessionWriter(session, software_version="test")
    w.begin_run(RunSpec(RUN, "stepped_sine", 0.8, "up", "x2", ["x1"], 100.0, ["force"], ["N"]))
    for f in np.linspace(1.0, 2.0, 2 * LINES_PER_CHUNK + 10):
        w.append_line(f, {"x1": 1e-3 + 1e-4j})
    w.end_run("complete")
    w.close()
    _flip_a_bit(session, f"/runs/{RUN}/frf/x1", chunk=1)
    with open_session(session) as s, pytest.raises(Exception) as caught:
        s.run(RUN)
    assert f"line(s) {LINES_PER_CHUNK}-{2 * LINES_PER_CHUNK - 1} of {2 * LINES_PER_CHUNK + 10}" in str(caught.value)


@pytest.mark.slow
def test_a_session_written_without_checksums_is_still_read(copies, capsys):
    session, model = copies
    with h5py.File(session, "r+") as f:                  # as sessions were written before checksums
        run = f[f"runs/{RUN}"]
        for name in ("frequency", "frf/x1", "frf/x2", "force_amplitude"):
            data, attrs = run[name][()], dict(run[name].attrs)
            del run[name]
            run.create_dataset(name, data=data, maxshape=(None,), chunks=(64,))
            run[name].attrs.update(attrs)
            assert not run[name].fletcher32
    assert main(["analyze", str(session), str(model), "--no-history"]) == 0
    assert "FRF error of the model" in capsys.readouterr().out
