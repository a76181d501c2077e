"""Session files (docs/contracts.md §7, docs/session-format.md): writing one as a campaign runs, reading one
(also while it is written), repairing one whose writer was killed, storing model histories.

:class:`SessionWriter` hands every write to a writer process of its own (:mod:`app.session.file`) that outlives
the acquiring process: after a SIGKILL of ``simulate`` or ``acquire`` or a crash of the GUI the writer closes
the file cleanly, with every completed line, and any HDF5 reader opens it. Only if the writer process itself
dies (SIGKILL of it, power cut) is the file left marked as open for writing, without the lines it held (those
of its last quarter second); :func:`open_session` reads it
anyway (SWMR) and reports such runs as incomplete, and :func:`recover_session` (``contactid recover``) makes it
readable by any tool with those runs marked ``status = "aborted"``, ``incomplete = True``.
"""
from __future__ import annotations

import functools
import json
import os
import socket
import subprocess
import sys
import threading
import time
import traceback
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterable

import h5py
import numpy as np

from analysis.common.child import python_child
from analysis.common.errors import InputError
from analysis.common.held_signals import signals_held
from analysis.common.quantities import dof_name_problem

from app.session.file import (EVENT_DTYPE, FORMAT, FORMAT_VERSION, RunSpec, SessionHeader, SessionWriteError,
                              append_event, mark_incomplete, now_iso)
from app.session.outputs import (NotWritten, atomic_replace, check_output, require_free_space, temporary_path,
                                 through_links, write_failure)
from app.session.salvage import SalvageError, salvage, swmr_read_access
from app.session.superblock import write_flags
from app.session.wire import encode_call, receive_reply, write_frame

__all__ = ["FORMAT", "FORMAT_VERSION", "RunData", "RunSpec", "Session", "SessionWriteError", "SessionWriter",
           "StoredHistory", "append_model_history", "needs_recovery", "open_session", "read_model_history",
           "recover_session"]

# Bytes that must stay free beyond each write, so that a run can still be closed (status, end time, event) and
# the file closed cleanly when the disk is about to fill.
FREE_SPACE_RESERVE = 1 << 20
# Room ``recover`` wants beyond the size of the session it copies (the new event, the copy's own metadata).
RECOVERY_MARGIN = 64 << 10
_WRITER_STOPPED = ("the session writer process stopped ({how}); the lines written before are kept (if other "
                   "HDF5 tools refuse the file, `contactid recover {path}` repairs it)")
#: Seconds a writer has to end after a call cut short before it is sent SIGTERM (:meth:`SessionWriter._stop_process`)
CUT_EXIT_S = 2.0
_WRITER_GONE = (OSError, EOFError, ValueError)      # what the pipe raises once the writer process has stopped
_WRITER_CUT = ("the session writer process was ended when a call to it was cut short ({how}); it closed the file "
               "with every line sent before")


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _attrs(obj: h5py.HLObject) -> dict:
    """An HDF5 object's attributes, text as ``str``."""
    return {k: _text(v) if isinstance(v, (bytes, str)) else v for k, v in obj.attrs.items()}


# --------------------------------------------------------------------------- writer
def kept_beside(path: Path) -> Path:
    """A free name beside ``path`` for a new session that could not replace it: ``NAME.incomplete.h5``, or
    ``NAME.incomplete-2.h5`` and so on."""
    n = 1
    while True:
        kept = path.with_name(f"{path.stem}.incomplete{'' if n == 1 else f'-{n}'}{path.suffix}")
        if not kept.exists():
            return kept
        n += 1


class SessionWriter:
    """Create a session file and append to it as a campaign runs (through the writer process).

    Every method returns once the writer process has the data: a line whose ``append_line`` returned survives any
    later crash of this process. The writer writes lines at most once per ``HOLD_SECONDS`` (0.25 s): one that
    comes later after its last write at once, those that come sooner together when the time is up
    (:mod:`app.session.file`); every other call returns once its data is flushed in the file, the held lines
    before it. Before each write the free space is checked (the data plus
    ``FREE_SPACE_RESERVE``): a disk about to fill raises SessionWriteError while the run can still be closed.

    Parameters
    ----------
    path : str or Path
    overwrite : bool
        An existing file is refused (InputError) unless this is set (``--overwrite``); it is replaced only once the
        first measured data is in.
    plan_text, rig_text : str
        The plan file text and, for simulated sessions only, the rig file text (``/provenance/rig``).
    software_version, command : str
    instruments : dict, optional
        Identities of the instruments (role -> {"url", "idn"}), stored as JSON in the ``instruments``
        attribute of ``/provenance``.
    """

    def __init__(self, path, *, overwrite: bool = False, plan_text: str = "", rig_text: str | None = None,
                 software_version: str = "", command: str = "", instruments: dict | None = None):
        self.path = check_output(path, overwrite=overwrite, field=None)
        # a session given as a symbolic link is written through it: the new file replaces the link's target,
        # from a temporary beside that target, and the link stays a link (app/session/outputs.py)
        self.target = through_links(self.path)
        self.kept_path = kept_beside(self.target) if self.target.exists() else None
        try:
            require_free_space(self.path, FREE_SPACE_RESERVE, "start a session")
        except OSError as exc:
            raise InputError(exc.strerror, str(self.path)) from None
        self.t0 = time.monotonic()
        self._lock = threading.Lock()
        self._run: str | None = None
        self._stopped = ""                                   # why the writer process stopped, if it did
        self._proc = _start_writer_process()
        header = SessionHeader(plan_text, rig_text, software_version, command, instruments or {})
        try:
            self._call("create", path=str(self.target), temporary=str(temporary_path(self.target)),
                       overwrite=overwrite, header=asdict(header),
                       kept=None if self.kept_path is None else str(self.kept_path))
        except BaseException:
            self._stop_process()
            raise

    @property
    def writer_pid(self) -> int:
        """The writer process (what ``writer_pid`` in the file names)."""
        return self._proc.pid

    def _seconds(self) -> float:
        return time.monotonic() - self.t0

    def _call(self, method: str, **kwargs) -> None:
        """One call and its reply, whole: a signal that comes meanwhile acts once the reply is in
        (:func:`analysis.common.held_signals.signals_held`). An exchange cut short all the same (a second signal)
        ends the writer process -- the pipe may hold half a call, or a reply no one read -- which closes the file
        with every call it received whole, as after a death of this process."""
        with self._lock:
            if self._proc is None:
                raise SessionWriteError(self._stopped or f"{self.path}: the session is closed")
            frame = encode_call(method, kwargs)
            sent = replied = False
            broken = None
            try:
                with signals_held():
                    sent = True
                    try:
                        write_frame(self._proc.stdin, frame)
                        error = receive_reply(self._proc.stdout)
                    except _WRITER_GONE as exc:
                        broken = exc
                        raise
                    replied = True
            except BaseException as exc:
                if replied:
                    raise                               # a signal held until the reply was in: nothing is cut
                if broken is not None:
                    self._raise_writer_stopped(exc, broken)
                if sent:
                    self._stop_process(cut=True)
                    self._stopped = f"{self.path}: " + _WRITER_CUT.format(how=type(exc).__name__, path=self.path)
                raise
        if error is not None:
            raise SessionWriteError(error)

    def _raise_writer_stopped(self, exc: BaseException, broken: BaseException) -> None:
        """The writer process stopped (``broken``: the pipe's error): SessionWriteError; a stop held meanwhile
        (``exc``) goes on, carrying it as a note."""
        code = self._stop_process()
        how = f"killed by signal {-code}" if code < 0 else f"exit status {code}"
        self._stopped = f"{self.path}: " + _WRITER_STOPPED.format(how=how, path=self.path)
        if exc is broken:
            raise SessionWriteError(self._stopped) from None
        exc.add_note(self._stopped)
        raise exc

    def _require_space(self, nbytes: int) -> None:
        try:
            require_free_space(self.path, nbytes + FREE_SPACE_RESERVE, "write the next data")
        except OSError as exc:
            raise SessionWriteError(f"{self.path}: {exc.strerror}; what was measured before is kept") from None

    # -- runs -----------------------------------------------------------------
    def begin_run(self, spec: RunSpec) -> None:
        """Create the run's group and datasets, then enter SWMR mode for appending lines."""
        if self._run is not None:
            raise RuntimeError(f"run {self._run!r} is still open")
        self._require_space(0)
        self._call("begin_run", spec=asdict(spec), seconds=self._seconds())
        self._run = spec.name

    def append_line(self, frequency_hz: float, frf: dict[str, complex], extras: dict | None = None,
                    raw: np.ndarray | None = None) -> None:
        """Append one completed line (frequency, FRF per sensor DOF, extras, raw samples) and flush."""
        self._require_space(0 if raw is None else np.asarray(raw).nbytes)
        self._call("append_line", frequency_hz=float(frequency_hz), frf=frf, extras=extras or {}, raw=raw)

    def write_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Write whole per-line arrays at once (a random run's FRFs): resize each dataset and fill it."""
        arrays = {k: np.asarray(v) for k, v in arrays.items()}
        self._require_space(sum(a.nbytes for a in arrays.values()))
        self._call("write_arrays", arrays=arrays)

    def append_raw(self, samples: np.ndarray) -> None:
        """Append raw samples that belong to no single line (the random run's record)."""
        samples = np.asarray(samples)
        self._require_space(samples.nbytes)
        self._call("append_raw", samples=samples)

    def end_run(self, status: str, reason: str = "", attrs: dict | None = None) -> None:
        """Leave SWMR mode and record the run's status ("complete", "failed": ended but its data missed the
        plan, or "aborted") and ``attrs``, run attributes known only at its end (a response-controlled run's
        measured force)."""
        if status not in ("complete", "failed", "aborted"):
            raise ValueError(f"status must be 'complete', 'failed' or 'aborted', got {status!r}")
        run, self._run = self._run, None
        if run is not None:
            self._call("end_run", status=status, reason=reason, seconds=self._seconds(), attrs=attrs or {})

    # -- events ---------------------------------------------------------------
    def log(self, kind: str, message: str, run: str | None = None) -> None:
        """Append an event (fault, operator action, note) with its time since the session started."""
        self._call("log", seconds=self._seconds(), kind=kind, message=message, run=run)

    def close(self, complete: bool = False) -> None:
        """End an open run as aborted (if any) and close the file. A session in which nothing was measured is
        not kept (an existing file it was to replace stays as it was); one that was to replace an existing
        file does so only when ``complete`` (the campaign measured all it planned), else it is kept beside it
        at :attr:`kept_path` (:attr:`written_to` says which). Nothing to do after the writer process stopped
        (that was reported by the call that found it)."""
        if self._proc is None:
            return
        self._run = None
        try:
            self._call("close", seconds=self._seconds(), complete=complete)
        finally:
            self._stop_process()

    @property
    def written_to(self) -> Path:
        """Where the session is (after :meth:`close`): the output, or beside it when it could not replace it."""
        if self.kept_path is not None and self.kept_path.exists():
            return self.kept_path
        return self.path

    def _stop_process(self, cut: bool = False) -> int | None:
        """End the writer process (it closes the file at the end of its input); its exit status. After an exchange
        ``cut`` short, a writer still there after ``CUT_EXIT_S`` is sent SIGTERM, which it takes as the end of its
        input: a process forked meanwhile (an analysis's workers) may hold a copy of the pipe, and the end of the
        input would wait for it. By then the writer waits for the rest of the call cut short, every whole one
        before it executed."""
        proc, self._proc = self._proc, None
        if proc is None:
            return None
        for stream in (proc.stdin, proc.stdout):
            try:
                stream.close()
            except OSError:
                pass                                  # the writer is gone already
        if cut:
            try:
                return proc.wait(CUT_EXIT_S)
            except subprocess.TimeoutExpired:
                proc.terminate()
        return proc.wait()


def _start_writer_process() -> subprocess.Popen:
    """``python -m app.session`` (the writer loop of :mod:`app.session.file`) in a session of its own: Ctrl-C or a
    kill of the acquiring process's group does not reach it, so it can close the file after the acquiring process
    is gone."""
    command, env = python_child("app.session")
    return subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, start_new_session=True,
                            close_fds=True)


# --------------------------------------------------------------------------- reader
# Held by every read of a session in this process, whatever thread or Session makes it (see one_reader)
_SESSION_FILES = threading.RLock()


def one_reader(read):
    """``read`` (a :class:`Session` method or a function reading a session with h5py) made while no other read
    of a session runs in this process, every HDF5 object it opened closed before the next one starts.

    A SWMR reader refreshes a dataset (H5Drefresh) to see the lines its writer appended. HDF5 keeps one chunk
    index per dataset for all the handles the process has open on it -- in any thread, file object or Session --
    and a refresh made while a second handle is open leaves that index reading every chunk as the first: from
    line 64 on (LINES_PER_CHUNK) a run reads its first 64 lines over and over, with no error (h5py issue 2803).
    h5py's lock makes each HDF5 call atomic, not a read of a run (open, refresh, read); the window reads the
    session it opens in its own thread while the backbones' and the analysis's workers read it in theirs, so
    their reads are serialised here. A read's handles live in its own frames: its return frees them, and the
    frames of an error it raises are cleared here, before the lock is let go."""
    @functools.wraps(read)
    def serialised(*args, **kwargs):
        with _SESSION_FILES:
            before = sys.exc_info()[1]               # an error the caller is handling: not this read's
            try:
                return read(*args, **kwargs)
            except BaseException as exc:
                seen: set[int] = set()
                while exc is not None and exc is not before and id(exc) not in seen:
                    seen.add(id(exc))
                    traceback.clear_frames(exc.__traceback__)
                    exc = exc.__cause__ or exc.__context__
                raise
    return serialised


REQUIRED_RUN_ATTRS = ("kind", "force", "direction", "status", "excitation_dof", "sensor_dofs")


@dataclass
class RunData:
    """One run as read back: attributes and per-line arrays (all in SI units, see ``units``).

    ``lines`` holds the number of lines stored in each per-line dataset (``frequency``, ``frf/<dof>`` and the
    others outside ``raw/``), before the arrays are cut to the length of ``frequency``."""

    name: str
    attrs: dict
    frequency: np.ndarray
    frf: dict[str, np.ndarray]
    arrays: dict[str, np.ndarray]
    units: dict[str, str]
    incomplete: bool
    lines: dict[str, int] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return self.attrs["kind"]

    @property
    def force(self) -> float:
        return float(self.attrs["force"])

    @property
    def status(self) -> str:
        return self.attrs["status"]

    @property
    def sensor_dofs(self) -> list[str]:
        return json.loads(self.attrs["sensor_dofs"])

    @property
    def excitation_dof(self) -> str:
        return self.attrs["excitation_dof"]

    @property
    def direction(self) -> str:
        return self.attrs["direction"]


class Session:
    """A session opened for reading (also while another process is writing it).

    Use :meth:`refresh` to see lines appended since opening. Anything the file lacks or cannot give (a missing
    run attribute or dataset, a truncated or damaged file) is an InputError naming the file and the object.
    Sessions may be read in several threads at once: every method touching the file is :func:`one_reader`.
    """

    @one_reader
    def __init__(self, path):
        self.path = Path(path)
        self._file = _open_for_reading(self.path)
        try:
            with self._reading("/ (root attributes)"):
                if _text(self._file.attrs.get("format", "")) != FORMAT:
                    raise InputError(f"not a contactid session (root attribute format is not {FORMAT!r})",
                                     str(self.path))
                self.writer_alive = _writer_alive(self._file)
        except InputError:
            self._file.close()
            raise

    @one_reader
    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @contextmanager
    def _reading(self, what: str):
        """Failures to read ``what`` as one InputError naming the file and the object."""
        try:
            yield
        except InputError:
            raise
        except (OSError, RuntimeError, KeyError, ValueError, TypeError, AttributeError, IndexError) as exc:
            raise InputError(f"cannot be read ({type(exc).__name__}: {exc}); the file is damaged or truncated",
                             str(self.path), what) from None

    def _object(self, where: str, kind=h5py.Dataset):
        """The dataset (or group) at ``where``; InputError naming it when it is missing."""
        obj = self._file.get(where)
        if not isinstance(obj, kind):
            what = "dataset" if kind is h5py.Dataset else "group"
            raise InputError(f"missing {what} (the session is incomplete or damaged)", str(self.path), where)
        return obj

    @one_reader
    def refresh(self) -> bool:
        """Reopen to see runs and lines added since opening (SWMR readers must reopen to see new objects).

        False (the view so far kept) when the file cannot be opened at this moment -- the writer holds it out
        of SWMR mode for an instant while it creates or closes a run."""
        try:
            fresh = _open_for_reading(self.path)
        except InputError:
            return False
        self._file.close()
        self._file = fresh
        with self._reading("/ (root attributes)"):
            self.writer_alive = _writer_alive(self._file)
        return True

    @property
    @one_reader
    def attrs(self) -> dict:
        with self._reading("/ (root attributes)"):
            return _attrs(self._file)

    @one_reader
    def provenance(self, key: str) -> str | None:
        with self._reading(f"/provenance/{key}"):
            prov = self._file.get("provenance")
            if prov is None or key not in prov:
                return None
            return _text(prov[key][()])

    @one_reader
    def run_names(self) -> list[str]:
        with self._reading("/runs"):
            return list(self._object("/runs", h5py.Group).keys())

    @one_reader
    def events(self) -> list[dict]:
        with self._reading("/events"):
            ev = self._object("/events")
            ev.refresh()
            return [{"time": float(r["time"]), "iso_time": _text(r["iso_time"]), "run": _text(r["run"]),
                     "kind": _text(r["kind"]), "message": _text(r["message"])} for r in ev[()]]

    @one_reader
    def run(self, name: str) -> RunData:
        where = f"/runs/{name}"
        with self._reading(where):
            g = self._object(where, h5py.Group)
            attrs = _attrs(g)
            dofs = self._run_attrs(where, attrs)
            # each dataset opened once, and refreshed before any is read: a refresh made while another handle
            # of the dataset is open spoils its chunk index (one_reader). Loops, not comprehensions: a
            # comprehension's closure would keep the handles past an error's cleared frames.
            datasets = {}
            for ds in _datasets(g):
                datasets[ds.name[len(g.name) + 1:]] = ds
                ds.refresh()
            n = self._run_dataset(datasets, where, "frequency").shape[0]
            arrays, units, lines = {}, {}, {}
            for rel, ds in datasets.items():
                units[rel] = _text(ds.attrs.get("units", ""))
                if not rel.startswith("raw/"):
                    lines[rel] = ds.shape[0] if ds.shape else 0
                if rel.startswith(("frf/", "raw/")) or rel == "frequency":
                    continue
                arrays[rel] = self._lines(ds, n)
            frf = {}
            for dof in dofs:
                frf[dof] = self._lines(self._run_dataset(datasets, where, f"frf/{dof}"), n)
            frequency = self._lines(datasets["frequency"], n)
        incomplete = attrs["status"] == "running" and not self.writer_alive or bool(attrs.get("incomplete", False))
        return RunData(name, attrs, frequency, frf, arrays, units, incomplete, lines)

    def _run_dataset(self, datasets: dict[str, h5py.Dataset], where: str, rel: str) -> h5py.Dataset:
        """The run's dataset ``rel`` among its ``datasets``; InputError naming it when it is missing."""
        if rel not in datasets:
            self._object(f"{where}/{rel}")          # raises, naming a missing dataset as every read names it
        return datasets[rel]

    def _lines(self, ds: h5py.Dataset, n: int) -> np.ndarray:
        """The first ``n`` lines of ``ds``; a chunk whose checksum fails is an InputError naming the dataset and
        the lines it holds."""
        with self._reading(ds.name):
            # a live writer rewrites the chunk of its last line in place: a read that meets it half-written fails
            # its checksum once, and reads whole a moment later
            for _ in range(LIVE_READ_ATTEMPTS if self.writer_alive else 1):
                try:
                    return ds[:n]
                except OSError:
                    time.sleep(0.05)
                    ds.refresh()
            damaged = _damaged_lines(ds, n)
            if not damaged:
                return ds[:n]
        raise InputError(f"checksum failure: the stored data of line(s) {damaged} of {n} are damaged (the file "
                         f"changed after it was written)", str(self.path), ds.name)

    def _parsed(self, where: str, attrs: dict, key: str, parse):
        """``parse(attrs[key])``, or InputError naming the attribute."""
        try:
            return parse(attrs[key])
        except (ValueError, TypeError) as exc:
            raise InputError(f"unreadable attribute ({exc})", str(self.path), f"{where}@{key}") from None

    def _run_attrs(self, where: str, attrs: dict) -> list[str]:
        """Check a run's attributes are there and readable; returns its sensor DOFs."""
        for key in REQUIRED_RUN_ATTRS:
            if key not in attrs:
                raise InputError("missing attribute (the session is incomplete or damaged)", str(self.path),
                                 f"{where}@{key}")
        dofs = self._parsed(where, attrs, "sensor_dofs", json.loads)
        self._parsed(where, attrs, "force", float)
        if not isinstance(dofs, list) or not all(isinstance(d, str) for d in dofs):
            raise InputError(f"must be a JSON list of DOF names, got {attrs['sensor_dofs']!r}", str(self.path),
                             f"{where}@sensor_dofs")
        for d in dofs:      # a name that is a path (a/b, ..) would read another dataset than its own
            if dof_name_problem(d):
                raise InputError(dof_name_problem(d), str(self.path), f"{where}@sensor_dofs")
        return dofs

    @one_reader
    def raw(self, name: str, line: int | None = None) -> tuple[np.ndarray, list[str], float]:
        """Raw samples of a run (or of one line), their channel names and the sample rate."""
        where = f"/runs/{name}/raw"
        with self._reading(where):
            raw = self._object(where, h5py.Group)
            for key in ("data", "line_start", "line_count"):
                self._object(f"{where}/{key}").refresh()
            data = self._object(f"{where}/data")
            channels = json.loads(_text(raw.attrs["channels"]))
            rate = float(raw.attrs["sample_rate"])
            if line is None:
                return data[()], channels, rate
            start, count = int(raw["line_start"][line]), int(raw["line_count"][line])
            return data[start:start + count], channels, rate

    def runs(self, kind: str | None = None) -> list[RunData]:
        out = [self.run(n) for n in self.run_names()]
        return [r for r in out if kind is None or r.kind == kind]


LIVE_READ_ATTEMPTS = 5        # reads of a chunk a live writer may be rewriting, before it is called damaged


def require_session_file(path: Path) -> None:
    """InputError naming ``path`` unless it is an existing file (not a folder): every command that reads or
    repairs a session asks this first."""
    if not path.exists():
        raise InputError("file not found", str(path))
    if path.is_dir():
        raise InputError("is a folder, not a session file", str(path))


def _open_for_reading(path: Path) -> h5py.File:
    """The file opened for reading in SWMR mode (safe while it is written, and after its writer crashed)."""
    require_session_file(path)
    try:
        fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ,
                            fapl=swmr_read_access())
        return h5py.File(fid)
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        if _left_open(path):
            raise InputError(f"was left open for writing by a process that stopped (a crash, or a write that "
                             f"failed on a full disk); `contactid recover {path}` repairs it", str(path)) from None
        raise InputError(f"not a readable HDF5 session ({exc})", str(path)) from None


def _damaged_lines(ds: h5py.Dataset, n: int) -> str:
    """The lines (ranges numbered from 0 as every message of the session reader numbers them -- the index an HDF5
    reader gives the dataset: "64-127, 192-199") of the first ``n`` of ``ds`` in chunks that cannot be read (a
    Fletcher-32 checksum failure); "" when every chunk reads."""
    step = ds.chunks[0] if ds.chunks else max(n, 1)
    ranges = []
    for start in range(0, n, step):
        stop = min(start + step, n)
        try:
            ds[start:stop]
        except OSError:
            ranges.append(f"{start}-{stop - 1}" if stop - 1 > start else f"{start}")
    return ", ".join(ranges)


def _datasets(group: h5py.Group) -> Iterable[h5py.Dataset]:
    found: list[h5py.Dataset] = []
    group.visititems(lambda _, obj: found.append(obj) if isinstance(obj, h5py.Dataset) else None)
    return found


def _dataset_names(f: h5py.File) -> list[bytes]:
    """The path of every dataset of the file, walked without making an h5py object of each group."""
    names: list[bytes] = []
    h5py.h5o.visit(f.id, lambda name, info: names.append(name) if info.type == h5py.h5o.TYPE_DATASET else None,
                   info=True)
    return names


def _reads_whole(dsid: h5py.h5d.DatasetID) -> bool:
    """Whether every stored chunk of a dataset reads, its filters (the Fletcher-32 checksum) passing.

    One read in the file's own type, with no conversion, so a scan of thousands of runs costs what their bytes
    cost and not an h5py object and a type conversion per chunk. Variable-length data are read through h5py,
    which frees what HDF5 allocates for them."""
    tid = dsid.get_type()
    try:
        if tid.detect_class(h5py.h5t.VLEN) or (tid.get_class() == h5py.h5t.STRING and tid.is_variable_str()):
            h5py.Dataset(dsid)[()]
        else:
            buffer = np.empty(dsid.get_space().get_simple_extent_npoints() * tid.get_size(), np.uint8)
            dsid.read(h5py.h5s.ALL, h5py.h5s.ALL, buffer, mtype=tid)
    except OSError:
        return False
    return True


def _process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie -- exited, not yet reaped -- does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True                                   # no /proc: trust the signal test
    return stat.rsplit(")", 1)[-1].split()[0] != "Z"


def _may_write(pid: int, path) -> bool:
    """Whether live process ``pid`` may be the file's writer: it has the file open, or it is a Python interpreter
    (the writer process, or a program writing a session in-process). After a crash the system may give the
    writer's pid to any other program (a shell, a daemon); that one is no writer, and the runs the dead writer
    left "running" are to be recovered, not waited for. Where /proc does not tell, it may be the writer."""
    try:
        if "python" in Path(os.readlink(f"/proc/{pid}/exe")).name.lower():
            return True
        wanted = os.stat(path)
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                held = os.stat(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue                                # closed meanwhile, or not a file
            if (held.st_dev, held.st_ino) == (wanted.st_dev, wanted.st_ino):
                return True
    except OSError:
        return True
    return False


def _writer_alive(f: h5py.File) -> bool:
    """Whether the process that writes the file is still running (on this host)."""
    if _text(f.attrs.get("writer_host", "")) != socket.gethostname():
        return False
    pid = int(f.attrs.get("writer_pid", -1))
    if pid <= 0:
        return False
    return pid == os.getpid() or (_process_alive(pid) and _may_write(pid, f.filename))


@one_reader
def damaged_data(path) -> list[str]:
    """The datasets of a session whose stored chunks fail their checksum (Fletcher-32), each with the lines
    affected ("/runs/r/frf/x1: line(s) 0-29 of 30", numbered from 0): data changed after the writer closed the file, which no
    recovery brings back (``recover`` says so rather than "nothing to recover")."""
    found = []
    with _open_for_reading(Path(path)) as f:
        for name in _dataset_names(f):
            dsid = h5py.h5d.open(f.id, name)
            if dsid.get_space().get_simple_extent_type() == h5py.h5s.NULL or _reads_whole(dsid):
                continue
            ds = h5py.Dataset(dsid)
            if not ds.shape:
                found.append(f"{ds.name}: its value")
                continue
            lines = _damaged_lines(ds, ds.shape[0])
            if lines:
                found.append(f"{ds.name}: line(s) {lines} of {ds.shape[0]}")
    return found


def open_session(path) -> Session:
    """Open a session for reading (safe while it is being written, and after its writer crashed)."""
    return Session(path)


# --------------------------------------------------------------------------- repair and model history
def _left_open(path: Path) -> bool:
    """Whether the file's superblock says it is open for writing outside SWMR mode (a writer that stopped in the
    middle of a non-SWMR write: no HDF5 reader, SWMR or not, opens it before the flags are cleared)."""
    flags = write_flags(path)
    return flags is not None and bool(flags & 1) and not flags & 4


def _locked_by_a_writer(path: Path) -> bool:
    """Whether a live process holds the file's HDF5 write lock."""
    import fcntl

    with open(path, "rb") as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
    return False


@one_reader
def needs_recovery(path) -> bool:
    """Whether plain HDF5 readers refuse the session because its writer died with it open, or its writer is gone
    and left a run "running" (a write that failed while the run was being closed, after the file's flags were
    cleared).

    InputError when the file is missing, not a session, or being written by a live process."""
    path = Path(path)
    require_session_file(path)
    if _left_open(path):
        if _locked_by_a_writer(path):
            raise InputError("is still being written by a running process; wait for it to finish", str(path))
        return True
    with Session(path) as s:
        alive = s.writer_alive
    left_running = False
    try:
        with h5py.File(path, "r") as f:
            closed = True
            runs = f.get("runs", {})
            if not isinstance(runs, (h5py.Group, dict)):
                raise InputError("/runs: is not a group of runs: not a contactid session", str(path))
            left_running = not alive and any(_text(g.attrs.get("status", "running")) == "running"
                                             for g in runs.values())
    except OSError as exc:
        if "truncated file" in str(exc):     # cut short: no repair brings back what is missing
            raise InputError(f"is truncated, damaged beyond a repair ({exc})", str(path)) from None
        closed = False
    if alive and not closed:
        raise InputError("is still being written by a running process; wait for it to finish", str(path))
    return not closed or left_running


def _copy_objects(path: Path, target: Path) -> list[str]:
    """Everything of a session that plain readers refuse that can still be read, copied into a new clean file;
    returns what could not be read. A file left open outside SWMR mode is read from an image in memory whose
    superblock flags are cleared (as ``h5clear`` does); one left open in SWMR mode is read as a SWMR reader. The
    reads run in a child process, each bounded in time (:mod:`app.session.salvage`)."""
    try:
        return salvage(path, target, image=_left_open(path))
    except SalvageError as exc:
        raise InputError(f"cannot recover the session: {exc}; the file is unchanged", str(path)) from None


def _mark_running_runs(f: h5py.File, lost: list[str]) -> list[str]:
    """Runs a dead writer left "running" (or whose status it was writing when it stopped): marked aborted and
    incomplete, with a recovery event that also names what could not be read."""
    marked = []
    for name, g in f["runs"].items():
        if _text(g.attrs.get("status", "running")) == "running":
            _trim_to_whole_lines(g)
            mark_incomplete(g, "the writing process stopped without closing the run (crash, kill or full disk)")
            marked.append(name)
    message = f"recovered after the writer stopped; incomplete runs: {', '.join(marked) or 'none'}"
    if lost:
        message += f"; unreadable, left out: {', '.join(lost)}"
    if "events" not in f:                               # the log itself was lost: a new one records the recovery
        f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(256,))
    append_event(f["events"], 0.0, "", "recovery", message)
    return marked


def _trim_to_whole_lines(run: h5py.Group) -> int:
    """Cut a run a dead writer left running to the lines stored whole: every per-line dataset (all but the raw
    ones, and the raw lines' starts and counts where the run stores raw samples per line) to the fewest lines any
    holds, and the raw samples to the end of the last of them. A writer killed inside a line leaves some datasets
    one line longer than others (a line is written dataset by dataset); contactid reads the lines all hold, and
    any other HDF5 reader must find the same. Returns the lines kept."""
    per_line = [ds for ds in _datasets(run) if not ds.name[len(run.name) + 1:].startswith("raw/") and ds.shape]
    raw = run.get("raw")
    by_line = (raw is not None and _text(run.attrs.get("kind", "")) != "random"
               and all(k in raw for k in ("line_start", "line_count", "data")))
    if by_line:
        per_line += [raw["line_start"], raw["line_count"]]
    if not per_line:
        return 0
    n = min(ds.shape[0] for ds in per_line)
    if by_line:
        ends = raw["line_start"][:n] + raw["line_count"][:n]
        while n and ends[n - 1] > raw["data"].shape[0]:      # the last line's samples not all written
            n -= 1
        raw["data"].resize(int(ends[n - 1]) if n else 0, axis=0)
    for ds in per_line:
        if ds.shape[0] > n:
            ds.resize(n, axis=0)
    return n


@contextmanager
def _rewritten(path: Path, extra_bytes: int, what: str, reserve: int = FREE_SPACE_RESERVE):
    """The session opened for writing as a new version beside itself (repaired first if a dead writer left it
    open), renamed over the old one when the ``with`` body succeeds: a failure, a full disk or a crash leaves
    the old file as it was. Yields ``(file, runs marked incomplete by the repair)``."""
    repair = needs_recovery(path)
    with atomic_replace(path, extra_bytes + reserve, what) as temp:
        if repair:
            lost = _copy_objects(path, temp)
        else:
            _copy_bytes(path, temp)
        with h5py.File(temp, "r+", libver="latest") as f:
            yield f, (_mark_running_runs(f, lost) if repair else [])


def _copy_bytes(source: Path, target: Path) -> None:
    """Every byte of ``source`` into ``target``, in the kernel. One ``sendfile`` call copies at most 2 GiB and
    returns early when a signal arrives (a debugger's or profiler's stop, a timer): it is called until the count
    is reached, and a source that ends before its size raises."""
    with open(source, "rb") as src, open(target, "wb") as dst:
        size = os.fstat(src.fileno()).st_size
        done = 0
        while done < size:
            sent = os.sendfile(dst.fileno(), src.fileno(), done, size - done)
            if sent == 0:
                raise OSError(f"the file ended at byte {done} of the {size} it had when its copy began")
            done += sent


def recover_session(path) -> list[str]:
    """Make a session whose writer died readable by any HDF5 tool.

    Copies everything into a fresh file next to it, marks the runs still "running" as ``status = "aborted"``,
    ``incomplete = True``, logs the recovery, and replaces the original atomically. Returns the names of the runs
    that were marked. Does nothing to a file closed normally (returns [])."""
    path = Path(path)
    if not needs_recovery(path):
        return []
    try:
        # no reserve beyond the copy: a copy that does not fit is removed, the original stays as it is
        with _rewritten(path, 0, "recover the session", reserve=RECOVERY_MARGIN) as (_, marked):
            return marked
    except OSError as exc:
        raise NotWritten(f"cannot recover the session: {write_failure(exc)}; the file is unchanged",
                         str(path)) from None


@dataclass
class StoredHistory:
    """Where an analysis's model history went: its group, and runs a repair of the file marked incomplete."""

    name: str
    recovered_runs: list[str]


def append_model_history(path, steps: list[dict], model_source: str = "") -> StoredHistory:
    """Store one analysis's model history (the workbench's steps) under ``/models/analysis_<k>``.

    Each step keeps its action, error, error by level and the model as TOML text, so the error falling step by
    step can be read back. The file is rewritten beside itself and renamed into place (a crashed session is
    repaired on the way), so nothing already in it can be damaged. SessionWriteError says why the history was
    not stored (read-only medium, full disk, a live writer) -- the session is then untouched."""
    path = Path(path)
    if not os.access(path, os.W_OK) or not os.access(path.parent, os.W_OK):
        raise SessionWriteError(f"{path}: the session (or its folder) is read-only")
    size = sum(len(step["model"].encode()) + 4096 for step in steps)
    try:
        with _rewritten(path, size, "store the model history") as (f, recovered):
            models = f.require_group("models")
            name = f"analysis_{len(models)}"
            g = models.create_group(name)
            g.attrs["created"] = now_iso()
            g.attrs["model_source"] = model_source
            for step in steps:
                s = g.create_group(f"step_{step['step']:03d}")
                s.attrs["action"] = step["action"]
                s.attrs["error"] = float(step["error"])
                s.create_dataset("model", data=step["model"])
                levels = np.array([[e["force"], e["error"]] for e in step["error_by_level"]], float)
                d = s.create_dataset("error_by_level", data=levels.reshape(-1, 2))
                d.attrs["columns"] = json.dumps(["force [N]", "error [1]"])
                # how each level was held: a response-controlled level is named by its target response
                d.attrs["levels"] = json.dumps([{k: v for k, v in e.items() if k not in ("force", "error")}
                                                for e in step["error_by_level"]])
        return StoredHistory(name, recovered)
    except InputError as exc:
        raise SessionWriteError(str(exc)) from None
    except OSError as exc:
        raise SessionWriteError(f"{path}: {exc.strerror or exc}; the session is unchanged") from None


def _levels(dataset) -> list[dict]:
    raw = dataset.attrs.get("levels")
    return json.loads(_text(raw)) if raw is not None else [{} for _ in range(len(dataset))]


@one_reader
def read_model_history(session: Session) -> list[dict]:
    """Every stored analysis: ``{"name", "created", "model_source", "steps": [{"action", "error", "model",
    "error_by_level", "levels"}]}``, ``error_by_level`` as ``[[force N, error], ...]`` and ``levels`` how each was
    held (``{"label", "control", ...}``; empty dicts in histories stored before it was kept)."""
    f = session._file
    with session._reading("/models"):
        if "models" not in f:
            return []
        out = []
        for name, g in f["models"].items():
            steps = [{"action": _text(s.attrs["action"]), "error": float(s.attrs["error"]),
                      "model": _text(s["model"][()]), "error_by_level": s["error_by_level"][()].tolist(),
                      "levels": _levels(s["error_by_level"])}
                     for _, s in sorted(g.items())]
            out.append({"name": name, "created": _text(g.attrs.get("created", "")),
                        "model_source": _text(g.attrs.get("model_source", "")), "steps": steps})
    return out
