"""Session files: round trip, concurrent reading, crash safety, refusal to overwrite, write failures."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis import InputError
from app.session import RunSpec, SessionWriteError, SessionWriter, open_session, recover_session

ROOT = Path(__file__).resolve().parents[1]


def spec(name="sine_0.8N_up"):
    return RunSpec(name, "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0, ["force", "acc:x1", "acc:x2"],
                   ["N", "m/s^2", "m/s^2"], extras={"force_amplitude": ("N", (), "f8"),
                                                    "harmonics/force": ("N", (4,), "c16")})


def test_round_trip_with_units_and_events(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path, plan_text="plan", rig_text="rig", software_version="1.2", command="contactid x")
    w.begin_run(spec())
    for i in range(5):
        w.append_line(1.0 + i, {"x1": 1e-3 * (i + 1j), "x2": 2e-3}, {"force_amplitude": 0.8 + 0.001 * i,
                                                                       "harmonics/force": np.arange(4) * 1j},
                      raw=np.ones((10 + i, 3)))
    w.log("fault", "DAQ frame 12 lost")
    w.end_run("complete")
    w.close()
    with open_session(path) as s:
        assert s.attrs["format"] == "contactid-session" and s.attrs["format_version"] == 1
        assert s.attrs["software_version"] == "1.2" and "T" in s.attrs["created"]
        assert s.provenance("rig") == "rig" and s.provenance("plan") == "plan"
        r = s.run("sine_0.8N_up")
        assert r.status == "complete" and not r.incomplete and r.kind == "stepped_sine"
        assert r.sensor_dofs == ["x1", "x2"] and r.excitation_dof == "x2" and r.force == 0.8
        np.testing.assert_allclose(r.frequency, [1, 2, 3, 4, 5])
        np.testing.assert_allclose(r.frf["x1"], 1e-3 * (np.arange(5) + 1j))
        np.testing.assert_allclose(r.arrays["harmonics/force"][2], np.arange(4) * 1j)
        assert r.units["frf/x1"] == "m/N" and r.units["frequency"] == "Hz" and r.units["force_amplitude"] == "N"
        raw, channels, fs = s.raw("sine_0.8N_up", line=3)
        assert raw.shape == (13, 3) and channels == ["force", "acc:x1", "acc:x2"] and fs == 100.0
        kinds = [e["kind"] for e in s.events()]
        assert "fault" in kinds and kinds.count("run") == 2


def test_reader_follows_a_run_being_written(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path)
    w.begin_run(spec())
    w.append_line(1.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})
    reader = open_session(path)
    assert len(reader.run("sine_0.8N_up").frequency) == 1
    for i in range(3):
        w.append_line(2.0 + i, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})
    assert len(reader.run("sine_0.8N_up").frequency) == 4          # no reopen needed for new lines
    assert reader.run("sine_0.8N_up").status == "running" and not reader.run("sine_0.8N_up").incomplete
    reader.close()
    w.end_run("complete")
    w.close()


def test_existing_file_is_not_overwritten_without_force(tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes(b"precious")
    with pytest.raises(InputError, match="exists already.*--force"):
        SessionWriter(path)
    assert path.read_bytes() == b"precious"
    SessionWriter(path, overwrite=True).close()
    assert h5py.is_hdf5(path)


def test_unwritable_path_is_a_write_error(tmp_path):
    with pytest.raises(SessionWriteError, match="cannot create"):
        SessionWriter(tmp_path / "no" / "such" / "dir" / "s.h5")


def test_not_a_session_is_refused(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(InputError, match="not a contactid session"):
        open_session(path)
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(InputError, match="not a readable HDF5 session"):
        open_session(tmp_path / "text.h5")


@pytest.mark.parametrize("seed", range(4))
def test_sigkill_at_a_random_moment_keeps_every_completed_line(tmp_path, seed):
    rng = np.random.default_rng(seed)
    path = tmp_path / "killed.h5"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "session_writer_child.py"), str(path)],
                            stdout=subprocess.PIPE, text=True, env=env)
    target = int(rng.integers(3, 40))
    done = -1
    while done < target:
        line = proc.stdout.readline()
        assert line, "writer ended early"
        done = int(line)
    time.sleep(float(rng.uniform(0, 0.02)))          # land anywhere inside the next line's write
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with open_session(path) as s:
        r = s.run("sine_0.8N_up")
        n = len(r.frequency)
        assert n >= done + 1                              # every line reported done is there
        np.testing.assert_allclose(r.frequency, 1.0 + 0.01 * np.arange(n))
        np.testing.assert_allclose(r.frf["x1"].real, np.arange(n))
        for i in range(n):
            raw, _, _ = s.raw("sine_0.8N_up", line=i)
            assert raw.shape == (500, 3) and np.all(raw == i)
        assert r.incomplete and r.status == "running"
    assert recover_session(path) == ["sine_0.8N_up"]
    with h5py.File(path, "r") as f:                        # a normal open works again
        g = f["runs/sine_0.8N_up"]
        assert g.attrs["status"] == "aborted" and g.attrs["incomplete"]
        assert g["frequency"].shape[0] == n
    with open_session(path) as s:
        assert s.run("sine_0.8N_up").incomplete
        assert any(e["kind"] == "recovery" for e in s.events())
    assert recover_session(path) == []


def test_write_failure_mid_run_keeps_the_lines_so_far(tmp_path, monkeypatch):
    path = tmp_path / "s.h5"
    w = SessionWriter(path)
    w.begin_run(spec())
    w.append_line(1.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(h5py.File, "flush", full_disk)
    with pytest.raises(SessionWriteError, match="No space left"):
        w.append_line(2.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})
    monkeypatch.undo()
    w.end_run("aborted", "disk full")
    w.close()
    with open_session(path) as s:
        r = s.run("sine_0.8N_up")
        assert r.status == "aborted" and r.attrs["end_reason"] == "disk full"
        assert r.frequency[0] == 1.0
