"""Session files: round trip, concurrent reading, crash safety, refusal to overwrite, write failures."""
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis import InputError
from app.session.outputs import temporary_path
from app.session.writer import RunSpec, SessionWriteError, SessionWriter, open_session, recover_session
from app.session.file import RAW_ROWS_PER_CHUNK, SessionFile, SessionHeader
from session_helpers import plain_open

ROOT = Path(__file__).resolve().parents[1]


def spec(name="sine_0.8N_up"):
    return RunSpec(name, "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0, ["force", "acc:x1", "acc:x2"],
                   ["N", "m/s^2", "m/s^2"], extras={"force_amplitude": ("N", (), "f8"),
                                                    "harmonics/force": ("N", (4,), "c16")})


def test_the_writer_process_loads_the_session_package_without_its_reader_and_checks():
    """``python -m app.session`` imports the package before the writer's module: the package's names are
    imported when first asked for, so the writer process starts with NumPy and h5py only."""
    code = "import sys, app.session.file; print(' '.join(sorted(sys.modules)))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT,
                            env=dict(os.environ, PYTHONPATH=str(ROOT))).stdout.split()
    assert "h5py" in loaded
    assert not [m for m in loaded if m.split(".")[0] == "analysis" or m in ("app.session.checks", "app.session.data",
                                                                          "app.session.writer")]
    import app.session

    assert app.session.SessionWriter is SessionWriter and app.session.LINES_PER_CHUNK == 64
    assert all(getattr(app.session, name) is not None for name in app.session.__all__)
    with pytest.raises(AttributeError, match="no_such_name"):
        app.session.no_such_name


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


def test_raw_records_across_chunks_read_back_exactly(tmp_path):
    """Lines' raw records shorter and longer than a chunk of ``raw/data``, ending anywhere in one (each line's
    flush rewrites the chunk it ends in), read back bit for bit."""
    rng = np.random.default_rng(3)
    sizes = [RAW_ROWS_PER_CHUNK // 3, RAW_ROWS_PER_CHUNK - 1, 1, 2 * RAW_ROWS_PER_CHUNK + 5, 677, 677, 677]
    records = [rng.normal(size=(n, 3)).astype("f4") for n in sizes]
    path = tmp_path / "s.h5"
    w = SessionWriter(path)
    w.begin_run(spec())
    for i, record in enumerate(records):
        w.append_line(1.0 + i, {"x1": 1e-3, "x2": 2e-3}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)},
                      raw=record)
    w.end_run("complete")
    w.close()
    with open_session(path) as s:
        for i, record in enumerate(records):
            raw, _, _ = s.raw("sine_0.8N_up", line=i)
            assert raw.tobytes() == record.tobytes()


def until(condition, what: str, seconds: float = 60.0) -> None:
    """Wait for ``condition``; fail naming ``what`` if it never holds (a bound on a hang, not a timing)."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, f"never: {what}"
        time.sleep(0.02)


def test_reader_follows_a_run_being_written(tmp_path):
    """The writer process holds lines for at most HOLD_SECONDS and writes them with no further call: a reader
    sees them without reopening the file."""
    path = tmp_path / "s.h5"
    w = SessionWriter(path)
    w.begin_run(spec())
    w.append_line(1.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})
    until(path.exists, "the first line moves the file into place")
    reader = open_session(path)
    assert len(reader.run("sine_0.8N_up").frequency) == 1
    for i in range(3):
        w.append_line(2.0 + i, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})
    until(lambda: len(reader.run("sine_0.8N_up").frequency) == 4, "the held lines reach the reader")
    assert reader.run("sine_0.8N_up").status == "running" and not reader.run("sine_0.8N_up").incomplete
    reader.close()
    w.end_run("complete")
    w.close()


def test_the_reader_setting_made_past_h5py_holds_h5py_lock(monkeypatch):
    """HDF5 is not built thread-safe; h5py serialises every call into it with one lock. A call made past h5py
    (through ctypes) must hold that lock too, or it corrupts another thread's call into HDF5."""
    import threading

    from h5py._objects import phil

    from app.session import salvage
    free_to_others = []

    class Library:
        def H5Pset_metadata_read_attempts(self, fapl, attempts):      # noqa: N802 (HDF5's name)
            def other_thread():
                got = phil.acquire(False)
                free_to_others.append(got)
                if got:
                    phil.release()
            t = threading.Thread(target=other_thread)
            t.start()
            t.join()
    monkeypatch.setattr(salvage, "_hdf5_library", lambda: Library())
    salvage.swmr_read_access()
    assert free_to_others == [False]


READ_IN_THREADS = """
import sys, threading, time
import numpy as np
from app.session.writer import RunSpec, SessionWriter, open_session
path, seconds = sys.argv[1], float(sys.argv[2])
w = SessionWriter(path, software_version="test")
w.begin_run(RunSpec("r", "stepped_sine", 0.8, "up", "x2", ["x1"], 100.0, ["force"], ["N"]))
for i in range(20):
    w.append_line(1.0 + i, {"x1": complex(i, 1)})
w.end_run("complete")
w.close()
stop, reads, errors = time.monotonic() + seconds, [], []
def reader():
    try:
        while time.monotonic() < stop:
            with open_session(path) as s:
                assert len(s.run("r").frequency) == 20
            reads.append(1)
    except Exception as exc:
        errors.append(repr(exc))
threads = [threading.Thread(target=reader) for _ in range(4)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print(len(reads), errors)
"""


@pytest.mark.slow
def test_sessions_opened_and_read_by_four_threads_at_once(tmp_path):
    """A GUI reads one session in several threads (the followed file, a backbone, an export): every open and
    read completes, none fails or crashes the process."""
    done = subprocess.run([sys.executable, "-c", READ_IN_THREADS, str(tmp_path / "s.h5"), "3"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    reads, errors = done.stdout.split(" ", 1)
    assert int(reads) > 100 and errors.strip() == "[]"



def three_chunk_session(path) -> tuple[np.ndarray, np.ndarray]:
    """A finished session of one random run of 150 lines (three chunks of LINES_PER_CHUNK); its frequencies and
    its FRF at x1 as written."""
    frequency, frf = 20.0 + 0.15 * np.arange(150), (1.0 + np.arange(150)) * (1 - 1j) * 1e-6
    w = SessionWriter(path, software_version="test")
    w.begin_run(RunSpec("random", "random", 0.1, "none", "x1", ["x1"], 100.0, ["force"], ["N"]))
    w.write_arrays({"frequency": frequency, "frf/x1": frf})
    w.end_run("complete")
    w.close()
    return frequency, frf


class WatchedLock:
    """The session readers' lock, telling ``waiting`` when a thread has to wait for it."""

    def __init__(self, waiting):
        self.lock, self.waiting = threading.RLock(), waiting

    def __enter__(self):
        if not self.lock.acquire(blocking=False):
            self.waiting.set()
            self.lock.acquire()

    def __exit__(self, *exc):
        self.lock.release()


def test_a_session_read_in_one_thread_while_another_reads_it_reads_what_the_file_holds(tmp_path, monkeypatch):
    """The window reads the session it opens while the analysis worker reads it too. HDF5 refreshing a dataset
    (a SWMR reader's refresh) that another handle of the process holds open reads every chunk of it as the first
    from then on (line 64 read as line 0). Here the second thread's read starts while the first one is in the
    middle of its own, its datasets open and refreshed: it must wait for it, and both read the file's lines."""
    from app.session import writer

    path = tmp_path / "s.h5"
    frequency, frf = three_chunk_session(path)
    either = threading.Event()           # the second reader waits for the first, or has read already
    monkeypatch.setattr(writer, "_SESSION_FILES", WatchedLock(either), raising=False)
    first, second = open_session(path), open_session(path)
    read = {}

    def second_reader():
        try:
            read["second"] = second.run("random")
        finally:
            either.set()
    other = threading.Thread(target=second_reader)
    lines = writer.Session._lines

    def in_the_middle(self, ds, n):
        if self is first and not other.is_alive() and not either.is_set():
            other.start()
            assert either.wait(60), "the second reader neither read nor waited"
        return lines(self, ds, n)
    monkeypatch.setattr(writer.Session, "_lines", in_the_middle)
    read["first"] = first.run("random")
    other.join()
    first.close()
    second.close()
    for which in ("first", "second"):
        np.testing.assert_array_equal(read[which].frequency, frequency, err_msg=which)
        np.testing.assert_array_equal(read[which].frf["x1"], frf, err_msg=which)


def test_a_refused_read_leaves_no_dataset_of_the_session_open(tmp_path):
    """A dataset handle outliving its read (kept by the error's traceback) would be open when another thread's
    read refreshes the dataset: a read that fails closes what it opened before it lets the next one start."""
    path = tmp_path / "s.h5"
    three_chunk_session(path)
    with h5py.File(path, "r+") as f:
        del f["runs/random/frf/x1"]
    with open_session(path) as s:
        with pytest.raises(InputError, match="frf/x1: missing dataset") as refused:
            s.run("random")
        assert refused.value.__traceback__ is not None
        assert h5py.h5f.get_obj_count(s._file.id, h5py.h5f.OBJ_DATASET) == 0


def test_lines_held_and_written_together_store_what_line_by_line_appends_store(tmp_path):
    rng = np.random.default_rng(5)
    lines = [(1.0 + i, {"x1": complex(*rng.normal(size=2)), "x2": 1e-3j * i},
              {"force_amplitude": float(rng.normal()), "harmonics/force": rng.normal(size=4) + 1j * rng.normal(size=4)},
              None if n is None else rng.normal(size=(n, 3)))         # float64 samples, stored as float32
             for i, n in enumerate([5, None, 1100, 0, 7, 300])]
    paths = tmp_path / "one.h5", tmp_path / "held.h5"
    for path in paths:
        f = SessionFile(path, temporary_path(path), False, SessionHeader())
        f.begin_run(spec(), 0.0)
        if path == paths[0]:
            for one in lines:
                f.append_line(*one)
        else:
            for one in lines[:3]:
                f.hold_line(*one)
            f.write_held()
            for one in lines[3:]:
                f.hold_line(*one)
            assert f.held == 3
        f.end_run("complete", "", 1.0)                     # writes what is held first
        f.close(1.0, complete=True)
    with h5py.File(paths[0], "r") as a, h5py.File(paths[1], "r") as b:
        names = []
        a["runs"].visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        assert len(names) == 8
        for name in names:
            x, y = a["runs"][name], b["runs"][name]
            assert x.dtype == y.dtype and x.shape == y.shape and x[()].tobytes() == y[()].tobytes(), name
        assert b["runs/sine_0.8N_up/raw/line_count"][()].tolist() == [5, 0, 1100, 0, 7, 300]


def test_a_line_the_writer_cannot_store_is_refused_without_the_lines_held_before_it(tmp_path):
    path = tmp_path / "s.h5"
    f = SessionFile(path, temporary_path(path), False, SessionHeader())
    f.begin_run(spec(), 0.0)
    f.hold_line(1.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8})
    with pytest.raises(SessionWriteError, match="channels"):
        f.hold_line(2.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8}, raw=np.zeros((10, 2)))
    with pytest.raises(SessionWriteError, match="frf/x9"):
        f.hold_line(2.0, {"x9": 1j})
    f.end_run("complete", "", 1.0)
    f.close(1.0, complete=True)
    with h5py.File(path, "r") as h:
        assert h["runs/sine_0.8N_up/frequency"][()].tolist() == [1.0]


def _serve(calls_in, replies_out):
    """``app.session.file.serve`` in this process; the signal handlers it sets are put back."""
    from app.session.file import serve

    kept = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM)}
    try:
        return serve(calls_in, replies_out)
    finally:
        for s, handler in kept.items():
            signal.signal(s, handler)


def _opening_calls(path) -> list[tuple[str, dict]]:
    from dataclasses import asdict

    return [("create", {"path": str(path), "temporary": str(temporary_path(path)), "overwrite": False,
                        "header": asdict(SessionHeader())}),
            ("begin_run", {"spec": asdict(spec()), "seconds": 0.0})]


def _line_call(i):
    return ("append_line", {"frequency_hz": 1.0 + i, "frf": {"x1": 1j, "x2": 1j}, "extras": {"force_amplitude": 0.8},
                            "raw": np.full((50, 3), i, dtype=np.float32)})


def test_lines_held_when_the_acquiring_process_goes_are_in_the_closed_file(tmp_path, monkeypatch):
    import io

    import app.session.file as file
    from app.session.wire import send_call

    monkeypatch.setattr(file, "HOLD_SECONDS", 3600.0)       # every line still held when the input ends
    path = tmp_path / "s.h5"
    read, write = os.pipe()
    with os.fdopen(write, "wb") as calls:
        for method, kwargs in _opening_calls(path) + [_line_call(i) for i in range(3)]:
            send_call(calls, method, kwargs)
    with os.fdopen(read, "rb") as calls:
        assert _serve(calls, io.BytesIO()) == 0
    with h5py.File(path, "r") as f:                        # closed by the writer loop, which ran here
        g = f["runs/sine_0.8N_up"]
        assert g["frequency"][()].tolist() == [1.0, 2.0, 3.0] and g["raw/line_start"][()].tolist() == [0, 50, 100]
        assert np.all(g["raw/data"][100:150] == 2)
        assert g.attrs["status"] == "aborted" and g.attrs["incomplete"]


def _writer_with_two_lines(path) -> SessionWriter:
    w = SessionWriter(path)
    w.begin_run(spec())
    for i in range(2):
        w.append_line(1.0 + i, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8}, np.full((50, 3), i))
    return w


def _third_line(w: SessionWriter) -> None:
    w.append_line(3.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8}, np.full((50, 3), 2))


def test_a_call_cut_short_ends_the_writer_which_closes_the_file_with_the_lines_sent_before(tmp_path, monkeypatch):
    """Half a call on the pipe (an exchange stopped by a second Ctrl-C, or any error mid-frame) would leave the
    writer waiting for its rest and this process for its reply: the writer is ended instead, as if this process
    had died, and a later call says why."""
    import app.session.writer as writer
    from app.session.wire import write_frame

    path = tmp_path / "s.h5"
    w = _writer_with_two_lines(path)

    def cut_short(stream, parts):
        write_frame(stream, parts)                         # this call whole, then half of the next
        stream.write(b"\x20\x00\x00\x00\x00\x00\x00\x00{\"method\": ")
        stream.flush()
        raise KeyboardInterrupt

    monkeypatch.setattr(writer, "write_frame", cut_short)
    with pytest.raises(KeyboardInterrupt):
        _third_line(w)
    monkeypatch.undo()
    with pytest.raises(SessionWriteError, match="cut short"):
        w.end_run("aborted", "interrupted")
    w.close()                                              # nothing left to do
    with h5py.File(path, "r") as f:                        # closed by the writer when its input ended
        g = f["runs/sine_0.8N_up"]
        assert g["frequency"][()].tolist() == [1.0, 2.0, 3.0] and g.attrs["incomplete"]      # the whole ones


def test_a_call_cut_short_while_another_process_holds_the_pipe_still_ends_the_writer(tmp_path, monkeypatch):
    """A process forked while the session is open (an analysis's workers) holds a copy of the pipe: the writer's
    input does not end when this process closes it, and the writer is sent SIGTERM instead."""
    import app.session.writer as writer

    def cut_short(stream, parts):
        stream.write(parts[0])                             # the frame's length, nothing more
        stream.flush()
        raise KeyboardInterrupt

    path = tmp_path / "s.h5"
    w = _writer_with_two_lines(path)
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                              pass_fds=(w._proc.stdin.fileno(),))
    try:
        monkeypatch.setattr(writer, "CUT_EXIT_S", 0.2)
        monkeypatch.setattr(writer, "write_frame", cut_short)
        with pytest.raises(KeyboardInterrupt):
            _third_line(w)
        assert holder.poll() is None                       # the writer ended with its input still open
    finally:
        holder.kill()
        holder.wait()
    with h5py.File(path, "r") as f:
        g = f["runs/sine_0.8N_up"]
        assert g["frequency"][()].tolist() == [1.0, 2.0] and g.attrs["incomplete"]


def test_ctrl_c_during_a_call_acts_once_its_reply_is_in_and_the_writer_goes_on(tmp_path, monkeypatch, ctrl_c):
    import app.session.writer as writer
    from app.session.wire import write_frame

    def then_ctrl_c(stream, parts):
        write_frame(stream, parts)
        signal.raise_signal(signal.SIGINT)                 # while the reply is still to come

    path = tmp_path / "s.h5"
    w = _writer_with_two_lines(path)
    monkeypatch.setattr(writer, "write_frame", then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        _third_line(w)
    monkeypatch.undo()
    w.end_run("aborted", "interrupted by Ctrl-C")          # the writer is still there
    w.close()
    with h5py.File(path, "r") as f:
        g = f["runs/sine_0.8N_up"]
        assert g["frequency"][()].tolist() == [1.0, 2.0, 3.0]
        assert g.attrs["status"] == "aborted" and g.attrs["end_reason"] == "interrupted by Ctrl-C"


def test_ctrl_c_held_while_the_writer_is_found_dead_stays_ctrl_c_and_says_so(tmp_path, monkeypatch, ctrl_c):
    import app.session.writer as writer
    from app.session.wire import write_frame

    def ctrl_c_then_write(stream, parts):
        signal.raise_signal(signal.SIGINT)                 # held: the write below finds the writer gone
        write_frame(stream, parts)

    path = tmp_path / "s.h5"
    w = _writer_with_two_lines(path)
    w._proc.kill()
    w._proc.wait()
    monkeypatch.setattr(writer, "write_frame", ctrl_c_then_write)
    with pytest.raises(KeyboardInterrupt) as caught:
        _third_line(w)
    assert any("session writer process stopped (killed by signal 9)" in n for n in caught.value.__notes__)


def test_a_call_that_cannot_be_sent_is_refused_with_the_writer_going_on(tmp_path):
    path = tmp_path / "s.h5"
    w = _writer_with_two_lines(path)
    with pytest.raises(TypeError):
        w.log("note", {"not", "text"})                    # a set: nothing of it reaches the pipe
    _third_line(w)
    w.end_run("complete")
    w.close(complete=True)
    with h5py.File(path, "r") as f:
        assert f["runs/sine_0.8N_up/frequency"][()].tolist() == [1.0, 2.0, 3.0]


def test_a_write_of_held_lines_that_fails_between_calls_is_the_reply_to_the_next(tmp_path, monkeypatch):
    import app.session.file as file
    from app.session.wire import receive_reply, send_call

    class Left(Exception):
        pass

    def leave(self):
        raise Left

    monkeypatch.setattr(file, "HOLD_SECONDS", 0.1)
    monkeypatch.setattr(file.SessionFile, "leave", leave)
    path = tmp_path / "s.h5"
    calls_r, calls_w = os.pipe()
    replies_r, replies_w = os.pipe()
    answers = []

    def acquiring():
        with os.fdopen(calls_w, "wb") as calls, os.fdopen(replies_r, "rb") as replies:
            for method, kwargs in _opening_calls(path):
                send_call(calls, method, kwargs)
                answers.append(receive_reply(replies))
            send_call(calls, *_line_call(0))
            answers.append(receive_reply(replies))           # the first line: written at once
            monkeypatch.setattr(h5py.File, "flush", full_disk)
            send_call(calls, *_line_call(1))
            answers.append(receive_reply(replies))           # within the hold: answered before it is written
            time.sleep(0.4)                                  # the hold ends meanwhile, and its write fails
            send_call(calls, *_line_call(2))
            answers.append(receive_reply(replies))

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    sender = threading.Thread(target=acquiring)
    sender.start()
    with os.fdopen(calls_r, "rb") as calls, os.fdopen(replies_w, "wb") as replies, pytest.raises(Left):
        _serve(calls, replies)
    sender.join()
    assert answers[:4] == [None, None, None, None]
    assert "failed while appending a line: No space left on device" in answers[4]


def line(w, i):
    w.append_line(1.0 + i, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})


def test_existing_file_is_not_overwritten_without_force(tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes(b"precious")
    with pytest.raises(InputError, match="exists already.*--overwrite"):
        SessionWriter(path)
    assert path.read_bytes() == b"precious"


def test_a_forced_session_replaces_the_old_file_only_once_it_closes_complete(tmp_path):
    path = tmp_path / "s.h5"
    path.write_bytes(b"precious")
    w = SessionWriter(path, overwrite=True)
    w.begin_run(spec())
    w.log("note", "armed")
    line(w, 0)
    assert path.read_bytes() == b"precious"              # measuring: the old file stands until the end
    w.end_run("complete")
    w.close(complete=True)
    assert h5py.is_hdf5(path) and w.written_to == path
    assert [p.name for p in tmp_path.iterdir()] == ["s.h5"]


@pytest.mark.parametrize("ending", ["aborted run", "campaign incomplete", "acquirer killed"])
def test_a_forced_session_that_ends_incomplete_leaves_the_old_file_and_is_kept_beside_it(tmp_path, ending):
    path = tmp_path / "s.h5"
    path.write_bytes(b"precious")
    (tmp_path / "s.incomplete.h5").write_bytes(b"an older one")
    w = SessionWriter(path, overwrite=True)
    w.begin_run(spec())
    line(w, 0)
    if ending == "aborted run":
        w.end_run("aborted", "operator")
        w.close(complete=False)
    elif ending == "campaign incomplete":
        w.end_run("complete")
        w.close(complete=False)
    else:
        w._stop_process()                                # the writer process sees its input end
    assert path.read_bytes() == b"precious"
    assert (tmp_path / "s.incomplete.h5").read_bytes() == b"an older one"
    kept = tmp_path / "s.incomplete-2.h5"
    assert w.written_to == kept and h5py.is_hdf5(kept)
    with h5py.File(kept, "r") as f:
        assert f["runs/sine_0.8N_up/frequency"].shape == (1,)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5", "s.incomplete-2.h5", "s.incomplete.h5"]


def test_a_start_that_fails_before_the_first_line_leaves_the_old_file_or_none(tmp_path):
    kept, fresh = tmp_path / "kept.h5", tmp_path / "fresh.h5"
    kept.write_bytes(b"precious")
    for path in (kept, fresh):
        w = SessionWriter(path, overwrite=True)
        w.begin_run(spec())
        w.end_run("aborted", "force limit on the first line")
        w.close()
    assert kept.read_bytes() == b"precious" and not fresh.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["kept.h5"]


def test_an_output_in_a_missing_folder_is_refused_before_anything_starts(tmp_path):
    with pytest.raises(InputError, match="folder does not exist"):
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


def start_child(path):
    """tests/session_writer_child.py writing ``path``: prints the writer process's pid, then each line's index
    once append_line has returned."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "session_writer_child.py"), str(path)],
                            stdout=subprocess.PIPE, text=True, env=env)
    return proc, int(proc.stdout.readline())


def kill_after(proc, target: int, pause: float) -> int:
    """SIGKILL ``proc`` ``pause`` s after it reported line ``target`` done; returns the last line reported."""
    done = -1
    while done < target:
        line = proc.stdout.readline()
        assert line, "writer ended early"
        done = int(line)
    time.sleep(pause)                                    # land anywhere inside the next line's write
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return done


def lines_on_disk(path) -> int:
    """Lines of the child's run a reader finds in the file now."""
    if not path.exists():
        return 0
    with open_session(path) as s:
        return len(s.run("sine_0.8N_up").frequency)


def check_lines(g, n_min):
    """Every line 0..n-1 of the child's run is whole in group ``g`` (n >= n_min); returns n."""
    n = g["frequency"].shape[0]
    assert n >= n_min
    np.testing.assert_allclose(g["frequency"][()], 1.0 + 0.01 * np.arange(n))
    np.testing.assert_allclose(g["frf/x1"][()].real, np.arange(n))
    assert g["force_amplitude"].shape[0] == g["raw/line_start"].shape[0] == n
    starts, counts = g["raw/line_start"][()], g["raw/line_count"][()]
    for i in range(n):
        assert counts[i] == 500 and np.all(g["raw/data"][starts[i]:starts[i] + 500] == i)
    return n


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.slow
def test_sigkill_of_the_acquiring_process_leaves_a_file_any_hdf5_reader_opens(tmp_path, seed):
    rng = np.random.default_rng(seed)
    path = tmp_path / "killed.h5"
    proc, _ = start_child(path)
    done = kill_after(proc, int(rng.integers(3, 40)), float(rng.uniform(0, 0.02)))
    with plain_open(path) as f:                             # no recovery: plain h5py, as HDFView would
        g = f["runs/sine_0.8N_up"]
        check_lines(g, done + 1)
        assert g.attrs["status"] == "aborted" and g.attrs["incomplete"]
        assert "crash or kill" in g.attrs["end_reason"]
    with open_session(path) as s:
        assert s.run("sine_0.8N_up").incomplete
        assert any(e["kind"] == "recovery" for e in s.events())
    assert recover_session(path) == [] and list(tmp_path.iterdir()) == [path]


@pytest.mark.parametrize("seed", range(2))
@pytest.mark.slow
def test_sigkill_of_the_writer_process_is_repaired_by_contactid_recover(tmp_path, capsys, seed):
    from app.cli import main

    rng = np.random.default_rng(10 + seed)
    path = tmp_path / "killed.h5"
    proc, writer = start_child(path)
    target = int(rng.integers(3, 30))
    done = -1
    while done < target:
        done = int(proc.stdout.readline())
    # a kill of the writer loses the lines it still holds (HOLD_SECONDS): those before are to be recovered
    until(lambda: lines_on_disk(path) > done, "the lines returned reach the file")
    time.sleep(float(rng.uniform(0, 0.02)))
    os.kill(writer, signal.SIGKILL)
    proc.wait()                                           # the child fails on its next line
    with pytest.raises(OSError):
        h5py.File(path, "r")                              # marked open for writing: plain readers refuse it
    with open_session(path) as s:                         # contactid still reads it
        r = s.run("sine_0.8N_up")
        assert r.incomplete and len(r.frequency) >= done + 1
    assert main(["recover", str(path)]) == 0
    assert "sine_0.8N_up" in capsys.readouterr().out
    with h5py.File(path, "r") as f:
        g = f["runs/sine_0.8N_up"]
        check_lines(g, done + 1)
        assert g.attrs["status"] == "aborted" and g.attrs["incomplete"]
    assert main(["recover", str(path)]) == 0
    assert "nothing to recover" in capsys.readouterr().out


def test_a_dead_writer_process_is_a_write_error_not_a_hang(tmp_path):
    w = SessionWriter(tmp_path / "s.h5")
    w.begin_run(spec())
    line(w, 0)
    os.kill(w.writer_pid, signal.SIGKILL)
    with pytest.raises(SessionWriteError, match="writer process stopped .*killed by signal 9.*contactid recover"):
        line(w, 1)
    w.close()


def test_write_failure_mid_run_keeps_the_lines_so_far(tmp_path, monkeypatch):
    """The writing side (what the writer process runs): a failed flush is a SessionWriteError and the run can
    still be closed with the lines before it."""
    path = tmp_path / "s.h5"
    w = SessionFile(path, temporary_path(path), False, SessionHeader())
    w.begin_run(spec(), 0.0)
    w.append_line(1.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(h5py.File, "flush", full_disk)
    with pytest.raises(SessionWriteError, match="No space left"):
        w.append_line(2.0, {"x1": 1j, "x2": 1j}, {"force_amplitude": 0.8, "harmonics/force": np.zeros(4)})
    monkeypatch.undo()
    w.end_run("aborted", "disk full", 1.0)
    w.close(1.0)
    with open_session(path) as s:
        r = s.run("sine_0.8N_up")
        assert r.status == "aborted" and r.attrs["end_reason"] == "disk full"
        assert r.frequency[0] == 1.0


def test_writer_errors_come_back_to_the_acquiring_process(tmp_path, monkeypatch):
    w = SessionWriter(tmp_path / "s.h5")
    w.begin_run(spec())
    line(w, 0)
    with pytest.raises(SessionWriteError, match="frf/x9"):      # the writer refuses a DOF the run lacks
        w.append_line(2.0, {"x9": 1j})
    monkeypatch.setattr("app.session.writer.FREE_SPACE_RESERVE", 1 << 62)
    with pytest.raises(SessionWriteError, match="not enough free space.*measured before is kept"):
        line(w, 1)
    monkeypatch.undo()
    w.end_run("aborted", "disk full")
    w.close()
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert f["runs/sine_0.8N_up/frequency"].shape == (1,)


def test_the_writer_ignores_ctrl_c_and_closes_the_file_cleanly_on_sigterm(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path)
    w.begin_run(spec())
    line(w, 0)
    os.kill(w.writer_pid, signal.SIGINT)                  # the terminal's Ctrl-C is the acquiring process's
    line(w, 1)
    os.kill(w.writer_pid, signal.SIGTERM)
    with plain_open(path) as f:                           # closed cleanly, without a recovery
        g = f["runs/sine_0.8N_up"]
        assert g["frequency"].shape == (2,) and g.attrs["status"] == "aborted" and g.attrs["incomplete"]
    with pytest.raises(SessionWriteError, match="writer process stopped"):
        line(w, 2)
    w.close()


def test_recover_cuts_a_line_a_killed_writer_stored_only_in_part(tmp_path):
    """A writer killed inside a line leaves some of its datasets a line longer than others, and the line's raw
    samples short: the repair keeps the lines every dataset holds whole, and the raw samples up to their end."""
    from app.session.writer import _trim_to_whole_lines
    with h5py.File(tmp_path / "s.h5", "w") as f:
        g = f.create_group("run")
        g.attrs["kind"] = "stepped_sine"

        def grow(name, values, shape=()):
            g.create_dataset(name, data=np.asarray(values), maxshape=(None,) + shape, chunks=True)
        grow("frequency", [1.0, 1.1, 1.2, 1.3])                         # line 3 begun: frequency written...
        grow("frf/x1", [0j, 1j, 2j, 3j])
        grow("force_amplitude", [0.8, 0.8, 0.8])                         # ...but not the rest of it
        grow("harmonics/force", np.zeros((4, 6), complex), (6,))
        grow("raw/data", np.zeros((1400, 2), "f4"), (2,))               # line 2's 500 samples not all there
        grow("raw/line_start", [0, 500, 1000])
        grow("raw/line_count", [500, 500, 500])
        assert _trim_to_whole_lines(g) == 2
        assert all(g[k].shape[0] == 2 for k in ("frequency", "frf/x1", "force_amplitude", "harmonics/force",
                                                 "raw/line_start", "raw/line_count"))
        assert g["raw/data"].shape == (1000, 2)
        r = f.create_group("random")
        r.attrs["kind"] = "random"
        r.create_dataset("frequency", data=np.arange(5.0), maxshape=(None,))
        r.create_dataset("frf/x1", data=np.zeros(3, complex), maxshape=(None,))
        r.create_dataset("raw/data", data=np.zeros((700, 2), "f4"), maxshape=(None, 2))
        r.create_dataset("raw/line_start", data=np.zeros(0, "i8"), maxshape=(None,))
        assert _trim_to_whole_lines(r) == 3                              # its raw record belongs to no line
        assert r["frequency"].shape == (3,) and r["raw/data"].shape == (700, 2)


def test_a_line_that_comes_after_the_writers_last_write_is_written_at_once(tmp_path, monkeypatch):
    """A real rig's lines come seconds apart: each is written as it comes, so a kill of the writer loses none that
    was completed; lines that come faster than HOLD_SECONDS are held and written together."""
    import app.session.file as file

    clock = [100.0]
    monkeypatch.setattr(file.time, "monotonic", lambda: clock[0])
    session = None
    for method, kwargs in _opening_calls(tmp_path / "s.h5"):
        session = file._calls(session, method, kwargs)
    session = file._calls(session, *_line_call(0))
    assert session.held == 0                                 # the first line, at once
    clock[0] += 0.01
    session = file._calls(session, *_line_call(1))
    assert session.held == 1 and 0 < session.hold_left() <= file.HOLD_SECONDS   # too soon: held
    clock[0] += file.HOLD_SECONDS
    assert session.hold_left() <= 0
    session.write_held()
    clock[0] += 2.0                                          # a line seconds later
    session = file._calls(session, *_line_call(2))
    assert session.held == 0
    session.close(seconds=0.0)


def test_the_writer_process_runs_this_checkouts_code_from_another_checkouts_folder(tmp_path, monkeypatch):
    """``python -m`` puts the working directory first on the child's import path: started from another checkout's
    folder, the writer would run that checkout's modules."""
    other = tmp_path / "other"
    (other / "app" / "session").mkdir(parents=True)
    (other / "app" / "__init__.py").write_text("")
    (other / "app" / "session" / "__init__.py").write_text("")
    (other / "app" / "session" / "__main__.py").write_text(
        f"open({str(tmp_path / 'foreign')!r}, 'w').close()\n")
    monkeypatch.chdir(other)
    path = tmp_path / "s.h5"
    w = SessionWriter(path)
    w.begin_run(spec())
    line(w, 0)
    w.end_run("complete")
    w.close()
    assert not (tmp_path / "foreign").exists()
    with open_session(path) as s:
        assert len(s.run("sine_0.8N_up").frequency) == 1
