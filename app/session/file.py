"""Writing a session file (docs/session-format.md): the HDF5 side, and the writer process that runs it.

:class:`SessionFile` does the HDF5 work. It is run by a writer process of its own (``python -m
app.session.file``, started by :class:`app.session.writer.SessionWriter`) that outlives the acquiring process: when
the acquiring process dies (SIGKILL, a crash of the GUI), its end of the pipe closes, and the writer marks the
open run as aborted and incomplete and closes the file cleanly, so any HDF5 reader opens it with every completed
line. While a run is measured the file is in SWMR mode and lines are flushed whole, so readers (the GUI's
Session tab) follow along. A line that reaches the writer process ``HOLD_SECONDS`` or more after its last write is
written at once; lines that come faster are held until ``HOLD_SECONDS`` after that write and written together (one
append to each dataset and one flush for all of them, where each line cost some 26 appends and a flush). A kill of
the writer process itself loses at most the lines it held: none of a real rig, whose lines take seconds each, and
those of its last ``HOLD_SECONDS`` of a simulation (``contactid recover`` then makes the file readable by any
tool).

The file is first written under a temporary name beside its destination and moved into place once the first
measured data is in: a start that fails leaves the old file (``--overwrite``) or no file.

This module imports only NumPy, h5py and the standard library so that the writer process starts quickly.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import select
import signal
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from app.session.wire import receive_call, send_reply

FORMAT = "contactid-session"
FORMAT_VERSION = 1
EVENT_DTYPE = np.dtype([("time", "f8"), ("iso_time", "S32"), ("run", "S64"), ("kind", "S24"),
                        ("message", "S400")])
REOPEN_WAIT = 30.0
"""How long the writer waits for a reader that holds the file's lock before it reports a write failure (s)."""
LINES_PER_CHUNK = 64
"""Lines per chunk of the per-line datasets; each chunk carries a Fletcher-32 checksum that HDF5 checks on read."""
RAW_ROWS_PER_CHUNK = 1024
"""Samples per chunk of ``raw/data``. Each line's flush compresses the whole chunk its samples end in, again: a
chunk of about a line's record (a stepped sine's line holds 500-1000 samples at 256-512 Hz) is compressed once or
twice, where 8192 rows were compressed at every one of the ten lines they held."""
HOLD_SECONDS = 0.25
"""The writer process writes lines at most once per this many seconds: a line that comes later than that after its
last write is written at once, the lines that come sooner together when the time is up. A real rig measures a line
in seconds, so each is written as it comes and a kill of the writer loses none that was completed; a simulation
sends dozens a second, and one write of many lines costs little more than one of a single line."""
HOLD_BYTES = 256 << 10
"""Raw bytes held at most: a batch's write stays well within the free-space reserve each call is checked against
(``app.session.writer.FREE_SPACE_RESERVE``, 1 MiB)."""
CRASH_REASON = "the acquiring process stopped without closing the run (crash or kill)"


def sync_file(path) -> None:
    """Flush a file's data to the disk (before it is renamed into place)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _locked(exc: OSError) -> bool:
    """Whether opening failed only because another process holds the file's HDF5 lock."""
    return "unable to lock file" in str(exc)

class SessionWriteError(RuntimeError):
    """The session file could not be written (full disk, unwritable path, removed medium)."""


def now_iso(timespec: str = "seconds") -> str:
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec=timespec)


def append_event(events: h5py.Dataset, seconds: float, run: str, kind: str, message: str) -> None:
    """Append one row to the event log (kind and message cut to their column widths)."""
    row = np.array([(seconds, now_iso().encode(), run.encode(), kind.encode()[:24], message.encode()[:400])],
                   dtype=EVENT_DTYPE)
    events.resize(events.shape[0] + 1, axis=0)
    events[-1:] = row


def mark_incomplete(run: h5py.Group, reason: str) -> None:
    """Close a run whose writing stopped mid-way: aborted, incomplete, with the reason."""
    run.attrs["status"] = "aborted"
    run.attrs["incomplete"] = True
    run.attrs["end_reason"] = reason
    run.attrs["ended"] = now_iso()


# --------------------------------------------------------------------------- run description
@dataclass
class RunSpec:
    """What a run is, for creating its group.

    ``extras`` names per-line quantities (name -> (units, shape of one line's value, dtype)); ``raw_channels``
    and ``raw_units`` describe the raw time blocks.
    """

    name: str
    kind: str                          # "random" | "stepped_sine"
    force: float                       # N: rms for random, amplitude for stepped sine
    direction: str                     # "up" | "down" | "none"
    excitation_dof: str
    sensor_dofs: list[str]
    sample_rate: float
    raw_channels: list[str]
    raw_units: list[str]
    extras: dict[str, tuple[str, tuple, str]] = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)


@dataclass
class SessionHeader:
    """What a new session file records before its first run."""

    plan_text: str = ""
    rig_text: str | None = None
    software_version: str = ""
    command: str = ""
    instruments: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- the HDF5 side
class SessionFile:
    """A new session file, written in this process (see the module docstring for the writer process).

    Parameters
    ----------
    path : Path
        Where the session goes; it is written at ``temporary`` until the first measured data is in.
    temporary : Path
        A name beside ``path`` (same file system) for the file before it is moved into place.
    overwrite : bool
        Whether an existing ``path`` may be replaced then.
    header : SessionHeader
    """

    def __init__(self, path, temporary, overwrite: bool, header: SessionHeader, kept: str | None = None):
        self.path, self.temporary = Path(path), Path(temporary)
        self.overwrite = overwrite
        self.kept = None if kept is None else Path(kept)  # where a session that could not replace ``path`` goes
        self.in_place = False                          # moved to ``path`` yet?
        self.measured = False                          # holds measured data?
        self.replacing = False                         # to replace an existing file once it is complete
        self.all_complete = True                       # every run ended "complete" so far
        self.failed = False                            # a write failed: the file is no longer written to
        self._file: h5py.File | None = None
        self._run: str | None = None
        self._datasets: dict[str, h5py.Dataset] = {}     # the open run's datasets, by path in the run
        self._held: list[tuple[dict, np.ndarray | None]] = []   # lines taken, not yet written (hold_line)
        self._written_at = -np.inf                       # time.monotonic() of the last write of held lines
        self._held_bytes = 0
        try:
            with h5py.File(self.temporary, "w", libver="latest") as f:
                f.attrs["format"] = FORMAT
                f.attrs["format_version"] = FORMAT_VERSION
                # to the microsecond: a fitted model names its session by it (docs/session-format.md)
                f.attrs["created"] = now_iso("microseconds")
                f.attrs["software_version"] = header.software_version
                f.attrs["writer_host"] = socket.gethostname()
                f.attrs["writer_pid"] = os.getpid()
                prov = f.create_group("provenance")
                prov.create_dataset("plan", data=header.plan_text)
                prov.create_dataset("command", data=header.command)
                if header.rig_text is not None:
                    prov.create_dataset("rig", data=header.rig_text)
                prov.attrs["instruments"] = json.dumps(header.instruments or {})
                f.create_group("runs")
                f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(256,))
        except OSError as exc:
            self.temporary.unlink(missing_ok=True)
            raise SessionWriteError(f"{self.path}: cannot create the session file ({exc})") from None

    @property
    def where(self) -> Path:
        """The file's current name."""
        return self.path if self.in_place else self.temporary

    # -- file state -----------------------------------------------------------
    def _open(self, swmr: bool) -> h5py.File:
        if self._file is None:
            deadline = time.monotonic() + REOPEN_WAIT
            while True:
                try:
                    self._file = h5py.File(self.where, "r+", libver="latest")
                    break
                except OSError as exc:
                    # a reader (HDFView, h5py) that opened the file between two writes holds its lock for a while
                    if not _locked(exc) or time.monotonic() > deadline:
                        raise SessionWriteError(f"{self.path}: cannot reopen the session file ({exc})") from None
                    time.sleep(0.05)
            if swmr:
                self._file.swmr_mode = True
        return self._file

    def _dataset(self, name: str) -> h5py.Dataset:
        ds = self._datasets.get(name)
        if ds is None:
            group = self._file["runs"][self._run]
            if name not in group:
                raise SessionWriteError(f"{self.path}: run {self._run} has no dataset {name!r}")
            ds = self._datasets[name] = group[name]
        return ds

    def _close(self) -> None:
        self._datasets = {}
        if self._file is not None:
            try:
                self._file.close()
            finally:
                self._file = None

    def _guard(self, what: str):
        return _WriteGuard(self, what)

    def _measured(self) -> None:
        """Data is in: move the file into place (the first time) -- unless it is to replace an existing file,
        which it does only when it closes complete (:meth:`_settle_replacement`)."""
        if self.measured:
            return
        if self.path.exists() and not self.overwrite:
            raise SessionWriteError(f"{self.path}: another program created this file while the session was "
                                    f"starting; it is left as it is")
        self.measured = True
        if self.path.exists():
            self.replacing = True
            return
        os.replace(self.temporary, self.path)
        self.in_place = True

    def _settle_replacement(self) -> None:
        """The file is closed: a session that was to replace an existing one does so if every run is complete;
        otherwise the old file stays and this one is kept beside it (``kept``), so that neither is lost."""
        if not self.replacing:
            return
        target = self.path if self.all_complete or self.kept is None else self.kept
        sync_file(self.temporary)
        os.replace(self.temporary, target)

    # -- runs -----------------------------------------------------------------
    def begin_run(self, spec: RunSpec, seconds: float) -> None:
        """Create the run's group and datasets, then enter SWMR mode for appending lines."""
        if self._run is not None:
            raise SessionWriteError(f"{self.path}: run {self._run!r} is still open")
        self._close()
        with self._guard(f"creating run {spec.name}"):
            f = self._open(swmr=False)
            g = f["runs"].create_group(spec.name)
            g.attrs.update({"kind": spec.kind, "force": float(spec.force), "direction": spec.direction,
                            "status": "running", "excitation_dof": spec.excitation_dof,
                            "sensor_dofs": json.dumps(spec.sensor_dofs), "sample_rate": float(spec.sample_rate),
                            "started": now_iso()})
            g.attrs["force_units"] = "N"
            for key, value in spec.attrs.items():
                g.attrs[key] = value
            _grow(g, "frequency", (), "f8", "Hz")
            frf = g.create_group("frf")
            frf.attrs["units"] = "m/N"
            frf.attrs["quantity"] = "receptance"
            for dof in spec.sensor_dofs:
                _grow(frf, dof, (), "c16", "m/N")
            for name, (units, shape, dtype) in spec.extras.items():
                parent = g
                for part in name.split("/")[:-1]:
                    parent = parent.require_group(part)
                _grow(parent, name.split("/")[-1], tuple(shape), dtype, units)
            raw = g.create_group("raw")
            raw.attrs["channels"] = json.dumps(spec.raw_channels)
            raw.attrs["units"] = json.dumps(spec.raw_units)
            raw.attrs["sample_rate"] = float(spec.sample_rate)
            raw.create_dataset("data", shape=(0, len(spec.raw_channels)), maxshape=(None, len(spec.raw_channels)),
                               dtype="f4", chunks=(RAW_ROWS_PER_CHUNK, len(spec.raw_channels)), compression="gzip",
                               compression_opts=4, shuffle=True, fletcher32=True)
            raw["data"].attrs["units"] = json.dumps(spec.raw_units)
            _grow(raw, "line_start", (), "i8", "sample")
            _grow(raw, "line_count", (), "i8", "sample")
            append_event(f["events"], seconds, spec.name, "run",
                         f"{spec.kind} run started: force {spec.force:g} N, direction {spec.direction}")
            f.flush()
            self._close()
            self._open(swmr=True)
        self._run = spec.name

    def append_line(self, frequency_hz: float, frf: dict, extras: dict | None = None,
                    raw: np.ndarray | None = None) -> None:
        """Append one completed line (frequency, FRF per sensor DOF, extras, raw samples) and flush."""
        self.hold_line(frequency_hz, frf, extras, raw)
        self.write_held()

    def hold_line(self, frequency_hz: float, frf: dict, extras: dict | None = None,
                  raw: np.ndarray | None = None) -> None:
        """Take one completed line, to be written with the lines after it by :meth:`write_held`. Every value is
        checked against its dataset and converted to its type here, so a line that cannot be stored is refused
        by its own call and the lines held before it are not touched."""
        with self._guard("appending a line"):
            values = {"frequency": frequency_hz, **{f"frf/{dof}": value for dof, value in frf.items()},
                      **(extras or {})}
            row = {}
            for name, value in values.items():
                ds = self._dataset(name)
                # h5py will not convert float -> complex itself; numpy converts as ``ds[n] = value`` would
                row[name] = np.asarray(value, dtype=ds.dtype).reshape(ds.shape[1:])
            data = self._dataset("raw/data")
            self._dataset("raw/line_start"), self._dataset("raw/line_count")
            if raw is not None:
                raw = np.asarray(raw, dtype=data.dtype)
                if raw.ndim != 2 or raw.shape[1] != data.shape[1]:
                    raise ValueError(f"raw samples of shape {raw.shape}; the run records {data.shape[1]} channels")
            self._held.append((row, raw))
            self._held_bytes += 0 if raw is None else raw.nbytes

    @property
    def held(self) -> int:
        """Lines taken and not yet written."""
        return len(self._held)

    def hold_left(self) -> float:
        """Seconds until the held lines are due (<= 0: write them now): ``HOLD_SECONDS`` after the last write."""
        if len(self._held) >= LINES_PER_CHUNK or self._held_bytes >= HOLD_BYTES:
            return 0.0
        return self._written_at + HOLD_SECONDS - time.monotonic()

    def write_held(self) -> None:
        """Write the held lines, in the order taken: one append of their rows to each dataset, their raw samples
        at once, then one flush, so readers see whole lines only. The data are those line-by-line appends
        write, to the bit."""
        if not self._held:
            return
        lines, self._held, self._held_bytes = self._held, [], 0
        with self._guard("appending a line"):
            columns: dict[str, list[np.ndarray]] = {}
            for row, _ in lines:
                for name, value in row.items():
                    columns.setdefault(name, []).append(value)
            for name, rows in columns.items():
                _append(self._dataset(name), np.stack(rows))
            data = self._dataset("raw/data")
            counts = np.array([0 if raw is None else len(raw) for _, raw in lines], dtype=np.int64)
            starts = data.shape[0] + np.cumsum(counts) - counts
            if counts.sum():
                _append(data, np.concatenate([raw for _, raw in lines if raw is not None]))
            _append(self._dataset("raw/line_start"), starts)
            _append(self._dataset("raw/line_count"), counts)
            self._file.flush()
            self._measured()
        self._written_at = time.monotonic()

    def write_arrays(self, arrays: dict) -> None:
        """Write whole per-line arrays at once (a random run's FRFs): resize each dataset and fill it."""
        self.write_held()
        with self._guard("writing the run's results"):
            for name, value in arrays.items():
                value = np.asarray(value)
                ds = self._dataset(name)
                ds.resize(value.shape[0], axis=0)
                ds[...] = value.astype(ds.dtype)
            self._file.flush()
            self._measured()

    def append_raw(self, samples: np.ndarray) -> None:
        """Append raw samples that belong to no single line (the random run's record)."""
        self.write_held()
        with self._guard("appending raw samples"):
            d = self._dataset("raw/data")
            start = d.shape[0]
            d.resize(start + len(samples), axis=0)
            d[start:] = samples
            self._file.flush()
            self._measured()

    def end_run(self, status: str, reason: str, seconds: float, attrs: dict | None = None) -> None:
        """Leave SWMR mode and record the run's status ("complete", "failed" or "aborted") and ``attrs``."""
        self.write_held()
        run, self._run = self._run, None
        if run is None:
            return
        self.all_complete = self.all_complete and status == "complete"
        with self._guard(f"closing run {run}"):
            self._close()                   # the SWMR file's last flush: a full disk may fail it too
            f = self._open(swmr=False)
            g = f["runs"][run]
            g.attrs["status"] = status
            g.attrs["ended"] = now_iso()
            for key, value in (attrs or {}).items():
                g.attrs[key] = value
            if reason:
                g.attrs["end_reason"] = reason
            append_event(f["events"], seconds, run, "run", f"run ended: {status}" + (f" ({reason})" if reason else ""))
            self._close()

    # -- events ---------------------------------------------------------------
    def log(self, seconds: float, kind: str, message: str, run: str | None = None) -> None:
        """Append an event (fault, operator action, note) with its time since the session started."""
        with self._guard("logging an event"):
            opened_here = self._file is None
            f = self._open(swmr=False)
            append_event(f["events"], seconds, run or self._run or "", kind, message)
            f.flush()
            if opened_here:
                self._close()

    def close(self, seconds: float, complete: bool = False) -> None:
        """End an open run as aborted (if any) and close the file; a file with no measured data is removed.
        ``complete``: the campaign measured everything it planned (a replacement needs it)."""
        self.all_complete = self.all_complete and complete
        try:
            if self._run is not None:
                self.end_run("aborted", "session closed while the run was open", seconds)
        finally:
            self._close()
            self._leave_temporary()

    def _leave_temporary(self) -> None:
        """The file is closed: settle a replacement, or remove a temporary file that holds no measurement."""
        if self.replacing:
            self._settle_replacement()
        elif not self.in_place:
            self.temporary.unlink(missing_ok=True)

    def abandon(self, seconds: float) -> None:
        """The acquiring process is gone: write the lines it completed, mark the open run incomplete and close
        the file cleanly."""
        try:
            self.write_held()
        except SessionWriteError:
            self.leave()                    # as after any failed write: the file keeps its last whole flush
        run, self._run = self._run, None
        self.all_complete = False
        try:
            self._close()
            if run is not None and self.measured:
                with self._guard("closing the session after the acquiring process stopped"):
                    f = self._open(swmr=False)
                    mark_incomplete(f["runs"][run], CRASH_REASON)
                    append_event(f["events"], seconds, run, "recovery",
                                 f"run {run} closed by the session writer: {CRASH_REASON}")
        finally:
            self._close()
            self._leave_temporary()


    def leave(self) -> None:
        """After a failed write: end the writer process without closing the file. HDF5 would flush its cache on
        close, on a disk that is full; the file keeps the state of its last whole flush, marked as open for SWMR
        writing, which SWMR readers (``open_session``) read and ``contactid recover`` closes."""
        if not self.in_place:
            self.temporary.unlink(missing_ok=True)
        os._exit(0)


class _WriteGuard:
    """Turns any failure to write into SessionWriteError, leaving what was flushed intact."""

    def __init__(self, writer: SessionFile, what: str):
        self.writer, self.what = writer, what

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, (OSError, KeyError, ValueError, RuntimeError)) \
                and not issubclass(exc_type, SessionWriteError):
            if issubclass(exc_type, (OSError, RuntimeError)):
                # the file on disk is as the last whole flush left it: any further write (closing the run)
                # could only damage that, so the writer stops here (see serve)
                self.writer.failed = True
                raise SessionWriteError(
                    f"{self.writer.path}: failed while {self.what}: {_reason(exc)}; the lines written before are "
                    f"kept; `contactid recover {self.writer.path}` closes the run once there is room") from exc
            raise SessionWriteError(f"{self.writer.path}: failed while {self.what}: {exc}") from exc
        return False


def _reason(exc: BaseException) -> str:
    """An I/O failure in one line: the system's words for its errno, else HDF5's first line."""
    code = getattr(exc, "errno", None)
    return os.strerror(code) if code else " ".join(str(exc).split("(")[0].split()) or type(exc).__name__


def _grow(parent: h5py.Group, name: str, shape: tuple, dtype: str, units: str) -> h5py.Dataset:
    ds = parent.create_dataset(name, shape=(0,) + shape, maxshape=(None,) + shape, dtype=dtype,
                               chunks=(LINES_PER_CHUNK,) + shape, fletcher32=True)
    ds.attrs["units"] = units
    return ds


def _append(ds: h5py.Dataset, rows: np.ndarray) -> None:
    """Write ``rows`` (in the dataset's type, one per line) as the dataset's next rows.

    Through h5py's low-level calls (extent, hyperslab, write): the high-level ``resize`` and ``__setitem__`` cost
    110 us a dataset against 35 us; the bytes written are the same."""
    dsid = ds.id
    shape = dsid.shape
    row = shape[1:]
    count = (len(rows),) + row
    dsid.set_extent((shape[0] + len(rows),) + row)
    data = np.ascontiguousarray(np.asarray(rows, dtype=ds.dtype).reshape(count))
    target = dsid.get_space()
    target.select_hyperslab((shape[0],) + (0,) * len(row), count)
    dsid.write(h5py.h5s.create_simple(count), target, data)


# --------------------------------------------------------------------------- the writer process
class _Stop(Exception):
    """SIGTERM while waiting for the next call."""


def _calls(file: SessionFile | None, method: str, kwargs: dict) -> SessionFile | None:
    """Execute one call; returns the session file (created by the first call). A line is held, and written
    with the held lines once they are due (:meth:`SessionFile.hold_left`)."""
    if method == "create":
        return SessionFile(kwargs["path"], kwargs["temporary"], kwargs["overwrite"],
                           SessionHeader(**kwargs["header"]), kwargs.get("kept"))
    if method == "begin_run":
        spec = dict(kwargs["spec"])
        spec["extras"] = {k: (u, tuple(s), d) for k, (u, s, d) in spec["extras"].items()}
        file.begin_run(RunSpec(**spec), kwargs["seconds"])
    elif method == "append_line":
        file.hold_line(**kwargs)
        if file.hold_left() <= 0:
            file.write_held()
    elif method in ("write_arrays", "append_raw", "end_run", "log", "close"):
        getattr(file, method)(**kwargs)
    else:
        raise SessionWriteError(f"unknown call {method!r}")
    return file


def serve(calls, replies) -> int:
    """Execute calls from ``calls`` until ``close`` (exit 0) or the end of the stream (the sender died: the
    file is closed on its behalf, with every line it sent, exit 0). SIGINT and SIGHUP are the terminal's and are
    ignored; SIGTERM closes the file as if the sender had died. Held lines are written when they are due, whether
    or not another call comes; a write that fails then is the reply to the next call."""
    waiting = {"now": False, "stop": False}

    def terminate(*_):
        waiting["stop"] = True
        if waiting["now"]:
            raise _Stop

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, terminate)
    file: SessionFile | None = None
    seconds = 0.0
    failure = None                                  # a write of held lines that failed between calls
    while not waiting["stop"]:
        waiting["now"] = True
        try:
            due = file is not None and file.held and not _arrives(calls, file.hold_left())
            call = None if due else receive_call(calls)
        except _Stop:
            due, call = False, None
        waiting["now"] = False
        if due:
            try:
                file.write_held()
            except SessionWriteError as exc:
                failure = str(exc)
            continue
        if call is None:
            break
        method, kwargs = call
        seconds = kwargs.get("seconds", seconds)
        error, failure = failure, None
        try:
            if error is None:
                file = _calls(file, method, kwargs)
        except SessionWriteError as exc:
            error = str(exc)
        except Exception as exc:  # reported to the acquiring process, which ends the campaign safely
            error = f"session writer failed in {method}: {type(exc).__name__}: {exc}"
        try:
            send_reply(replies, error)
        except OSError:
            break                                   # the sender died waiting for this reply
        if file is not None and file.failed:
            file.leave()
        if method == "close" and error is None:
            return 0
    if file is not None:
        if file.failed:
            file.leave()
        file.abandon(seconds)
    return 0


def _arrives(calls, seconds: float) -> bool:
    """Whether a call begins to arrive on ``calls`` within ``seconds``. The sender waits for each reply before
    its next call, so nothing of a call is left in the reader's buffer once the last one is answered."""
    return seconds > 0 and bool(select.select([calls], [], [], seconds)[0])


def main() -> int:
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    sys.stdout = sys.stderr                       # nothing but replies on the reply pipe
    return serve(sys.stdin.buffer, replies)
