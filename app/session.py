"""Session files: HDF5, written incrementally and crash-safe (CONTRACTS.md §7, docs/session-format.md).

While a run is measured the file is in HDF5 single-writer/multiple-reader (SWMR) mode: each completed line is
appended and flushed, readers (the GUI) follow along, and a crash or SIGKILL loses at most the line in
progress -- SWMR orders its writes so the file on disk is always consistent. SWMR cannot create objects, so
each run's datasets are made when the run begins (with the file briefly out of SWMR mode) and its status is
written when it ends.

A file whose writer died is still marked as open for writing; :func:`open_session` reads it anyway and
reports such runs as incomplete, and :func:`recover_session` copies it into a clean file with those runs marked
``status = "aborted"``, ``incomplete = True``.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import h5py
import numpy as np

from analysis.errors import InputError

FORMAT = "contactid-session"
FORMAT_VERSION = 1
EVENT_DTYPE = np.dtype([("time", "f8"), ("iso_time", "S32"), ("run", "S64"), ("kind", "S24"),
                        ("message", "S400")])


class SessionWriteError(RuntimeError):
    """The session file could not be written (full disk, unwritable path, removed medium)."""


def _now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="seconds")


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _attrs(obj: h5py.HLObject) -> dict:
    """An HDF5 object's attributes, text as ``str``."""
    return {k: _text(v) if isinstance(v, (bytes, str)) else v for k, v in obj.attrs.items()}


def _append_event(events: h5py.Dataset, seconds: float, run: str, kind: str, message: str) -> None:
    """Append one row to the event log (kind and message cut to their column widths)."""
    row = np.array([(seconds, _now_iso().encode(), run.encode(), kind.encode()[:24], message.encode()[:400])],
                   dtype=EVENT_DTYPE)
    events.resize(events.shape[0] + 1, axis=0)
    events[-1:] = row


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


# --------------------------------------------------------------------------- writer
class SessionWriter:
    """Create a session file and append to it as a campaign runs.

    Parameters
    ----------
    path : str or Path
    overwrite : bool
        An existing file is refused unless this is set (``--force``).
    plan_text, rig_text : str
        The plan file text and, for simulated sessions only, the rig file text (``/provenance/rig``).
    software_version, command : str
    instruments : dict, optional
        Identities of the instruments (role -> {"url", "idn"}), stored as JSON in the ``instruments``
        attribute of ``/provenance``.
    """

    def __init__(self, path, *, overwrite: bool = False, plan_text: str = "", rig_text: str | None = None,
                 software_version: str = "", command: str = "", instruments: dict | None = None):
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise InputError("exists already; choose another name or pass --force to overwrite it", str(self.path))
        self.t0 = time.monotonic()
        self._file: h5py.File | None = None
        self._run: str | None = None
        self._datasets: dict[str, h5py.Dataset] = {}     # the open run's datasets, by path in the run
        try:
            with h5py.File(self.path, "w", libver="latest") as f:
                f.attrs["format"] = FORMAT
                f.attrs["format_version"] = FORMAT_VERSION
                f.attrs["created"] = _now_iso()
                f.attrs["software_version"] = software_version
                f.attrs["writer_host"] = socket.gethostname()
                f.attrs["writer_pid"] = os.getpid()
                prov = f.create_group("provenance")
                prov.create_dataset("plan", data=plan_text)
                prov.create_dataset("command", data=command)
                if rig_text is not None:
                    prov.create_dataset("rig", data=rig_text)
                prov.attrs["instruments"] = json.dumps(instruments or {})
                f.create_group("runs")
                f.create_dataset("events", shape=(0,), maxshape=(None,), dtype=EVENT_DTYPE, chunks=(256,))
        except OSError as exc:
            raise SessionWriteError(f"{self.path}: cannot create the session file ({exc})") from None

    # -- file state -----------------------------------------------------------
    def _open(self, swmr: bool) -> h5py.File:
        if self._file is None:
            try:
                self._file = h5py.File(self.path, "r+", libver="latest")
            except OSError as exc:
                raise SessionWriteError(f"{self.path}: cannot reopen the session file ({exc})") from None
            if swmr:
                self._file.swmr_mode = True
        return self._file

    def _dataset(self, name: str) -> h5py.Dataset:
        ds = self._datasets.get(name)
        if ds is None:
            ds = self._datasets[name] = self._file["runs"][self._run][name]
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

    # -- runs -----------------------------------------------------------------
    def begin_run(self, spec: RunSpec) -> None:
        """Create the run's group and datasets, then enter SWMR mode for appending lines."""
        if self._run is not None:
            raise RuntimeError(f"run {self._run!r} is still open")
        self._close()
        with self._guard(f"creating run {spec.name}"):
            f = self._open(swmr=False)
            g = f["runs"].create_group(spec.name)
            g.attrs.update({"kind": spec.kind, "force": float(spec.force), "direction": spec.direction,
                            "status": "running", "excitation_dof": spec.excitation_dof,
                            "sensor_dofs": json.dumps(spec.sensor_dofs), "sample_rate": float(spec.sample_rate),
                            "started": _now_iso()})
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
                               dtype="f4", chunks=(8192, len(spec.raw_channels)), compression="gzip",
                               compression_opts=4, shuffle=True)
            raw["data"].attrs["units"] = json.dumps(spec.raw_units)
            _grow(raw, "line_start", (), "i8", "sample")
            _grow(raw, "line_count", (), "i8", "sample")
            f.flush()
            self._close()
            self._open(swmr=True)
        self._run = spec.name
        self.log("run", f"{spec.kind} run started: force {spec.force:g} N, direction {spec.direction}",
                 run=spec.name)

    def append_line(self, frequency_hz: float, frf: dict[str, complex], extras: dict | None = None,
                    raw: np.ndarray | None = None) -> None:
        """Append one completed line (frequency, FRF per sensor DOF, extras, raw samples) and flush."""
        with self._guard("appending a line"):
            _append(self._dataset("frequency"), frequency_hz)
            for dof, value in frf.items():
                _append(self._dataset(f"frf/{dof}"), value)
            for name, value in (extras or {}).items():
                _append(self._dataset(name), value)
            data = self._dataset("raw/data")
            start = data.shape[0]
            count = 0 if raw is None else len(raw)
            if count:
                data.resize(start + count, axis=0)
                data[start:] = raw
            _append(self._dataset("raw/line_start"), start)
            _append(self._dataset("raw/line_count"), count)
            self._file.flush()

    def write_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Write whole per-line arrays at once (a random run's FRFs): resize each dataset and fill it."""
        with self._guard("writing the run's results"):
            for name, value in arrays.items():
                value = np.asarray(value)
                ds = self._dataset(name)
                ds.resize(value.shape[0], axis=0)
                ds[...] = value.astype(ds.dtype)
            self._file.flush()

    def append_raw(self, samples: np.ndarray) -> None:
        """Append raw samples that belong to no single line (the random run's record)."""
        with self._guard("appending raw samples"):
            d = self._dataset("raw/data")
            start = d.shape[0]
            d.resize(start + len(samples), axis=0)
            d[start:] = samples
            self._file.flush()

    def end_run(self, status: str, reason: str = "") -> None:
        """Leave SWMR mode and record the run's status ("complete" or "aborted")."""
        if status not in ("complete", "aborted"):
            raise ValueError(f"status must be 'complete' or 'aborted', got {status!r}")
        run, self._run = self._run, None
        if run is None:
            return
        self.log("run", f"run ended: {status}" + (f" ({reason})" if reason else ""), run=run)
        self._close()
        with self._guard(f"closing run {run}"):
            f = self._open(swmr=False)
            g = f["runs"][run]
            g.attrs["status"] = status
            g.attrs["ended"] = _now_iso()
            if reason:
                g.attrs["end_reason"] = reason
            self._close()

    # -- events ---------------------------------------------------------------
    def log(self, kind: str, message: str, run: str | None = None) -> None:
        """Append an event (fault, operator action, note) with its time since the session started."""
        seconds = time.monotonic() - self.t0
        with self._guard("logging an event"):
            opened_here = self._file is None
            f = self._open(swmr=False)
            _append_event(f["events"], seconds, run or self._run or "", kind, message)
            f.flush()
            if opened_here:
                self._close()

    def close(self) -> None:
        """End an open run as aborted (if any) and close the file."""
        if self._run is not None:
            self.end_run("aborted", "session closed while the run was open")
        self._close()


class _WriteGuard:
    """Turns any failure to write into SessionWriteError, leaving what was flushed intact."""

    def __init__(self, writer: SessionWriter, what: str):
        self.writer, self.what = writer, what

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, (OSError, KeyError, ValueError, RuntimeError)) \
                and not issubclass(exc_type, SessionWriteError):
            raise SessionWriteError(f"{self.writer.path}: failed while {self.what}: {exc}") from exc
        return False


def _grow(parent: h5py.Group, name: str, shape: tuple, dtype: str, units: str) -> h5py.Dataset:
    ds = parent.create_dataset(name, shape=(0,) + shape, maxshape=(None,) + shape, dtype=dtype,
                               chunks=(64,) + shape)
    ds.attrs["units"] = units
    return ds


def _append(ds: h5py.Dataset, value) -> None:
    n = ds.shape[0]
    ds.resize(n + 1, axis=0)
    ds[n] = np.asarray(value, dtype=ds.dtype)   # h5py will not convert float -> complex itself


# --------------------------------------------------------------------------- reader
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

    Use :meth:`refresh` to see lines appended since opening.
    """

    def __init__(self, path):
        self.path = Path(path)
        try:
            self._file = h5py.File(self.path, "r", libver="latest", swmr=True)
        except FileNotFoundError:
            raise InputError("file not found", str(self.path)) from None
        except OSError as exc:
            raise InputError(f"not a readable HDF5 session ({exc})", str(self.path)) from None
        if _text(self._file.attrs.get("format", "")) != FORMAT:
            self._file.close()
            raise InputError(f"not a contactid session (root attribute format is not {FORMAT!r})", str(self.path))
        self.writer_alive = _writer_alive(self._file)

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def refresh(self) -> None:
        """Reopen to see runs and lines added since opening (SWMR readers must reopen to see new objects)."""
        self._file.close()
        self._file = h5py.File(self.path, "r", libver="latest", swmr=True)
        self.writer_alive = _writer_alive(self._file)

    @property
    def attrs(self) -> dict:
        return _attrs(self._file)

    def provenance(self, key: str) -> str | None:
        prov = self._file.get("provenance")
        if prov is None or key not in prov:
            return None
        return _text(prov[key][()])

    def run_names(self) -> list[str]:
        return list(self._file["runs"].keys())

    def events(self) -> list[dict]:
        ev = self._file["events"]
        ev.refresh()
        return [{"time": float(r["time"]), "iso_time": _text(r["iso_time"]), "run": _text(r["run"]),
                 "kind": _text(r["kind"]), "message": _text(r["message"])} for r in ev[()]]

    def run(self, name: str) -> RunData:
        g = self._file["runs"][name]
        attrs = _attrs(g)
        for ds in _datasets(g):
            ds.refresh()
        n = g["frequency"].shape[0]
        arrays, units, lines = {}, {}, {}
        for ds in _datasets(g):
            rel = ds.name[len(g.name) + 1:]
            units[rel] = _text(ds.attrs.get("units", ""))
            if not rel.startswith("raw/"):
                lines[rel] = ds.shape[0] if ds.shape else 0
            if rel.startswith(("frf/", "raw/")) or rel == "frequency":
                continue
            arrays[rel] = ds[:n]
        frf = {dof: g["frf"][dof][:n] for dof in g["frf"]}
        incomplete = attrs["status"] == "running" and not self.writer_alive or bool(attrs.get("incomplete", False))
        return RunData(name, attrs, g["frequency"][:n], frf, arrays, units, incomplete, lines)

    def raw(self, name: str, line: int | None = None) -> tuple[np.ndarray, list[str], float]:
        """Raw samples of a run (or of one line), their channel names and the sample rate."""
        raw = self._file["runs"][name]["raw"]
        for key in ("data", "line_start", "line_count"):
            raw[key].refresh()
        channels = json.loads(_text(raw.attrs["channels"]))
        if line is None:
            return raw["data"][()], channels, float(raw.attrs["sample_rate"])
        start, count = int(raw["line_start"][line]), int(raw["line_count"][line])
        return raw["data"][start:start + count], channels, float(raw.attrs["sample_rate"])

    def runs(self, kind: str | None = None) -> list[RunData]:
        out = [self.run(n) for n in self.run_names()]
        return [r for r in out if kind is None or r.kind == kind]


def _datasets(group: h5py.Group) -> Iterable[h5py.Dataset]:
    found: list[h5py.Dataset] = []
    group.visititems(lambda _, obj: found.append(obj) if isinstance(obj, h5py.Dataset) else None)
    return found


def _writer_alive(f: h5py.File) -> bool:
    """Whether the process that wrote the file is still running (on this host)."""
    if _text(f.attrs.get("writer_host", "")) != socket.gethostname():
        return False
    pid = int(f.attrs.get("writer_pid", -1))
    if pid <= 0:
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def open_session(path) -> Session:
    """Open a session for reading (safe while it is being written, and after its writer crashed)."""
    return Session(path)


def recover_session(path) -> list[str]:
    """Make a session whose writer died readable and writable again.

    Copies everything into a fresh file next to it, marks the runs still "running" as
    ``status = "aborted"``, ``incomplete = True``, logs the recovery, and replaces the original atomically.
    Returns the names of the runs that were marked. Does nothing to a file closed normally.
    """
    path = Path(path)
    try:
        with h5py.File(path, "r+", libver="latest"):
            return []                                   # closed normally: nothing to recover
    except OSError:
        pass
    with Session(path) as s:
        if s.writer_alive:
            raise InputError("is still being written by a running process; wait for it to finish", str(path))
        src = s._file
        tmp = path.with_name(path.name + ".recovering")
        marked = []
        with h5py.File(tmp, "w", libver="latest") as dst:
            for key, value in src.attrs.items():
                dst.attrs[key] = value
            for key in src:
                src.copy(src[key], dst, name=key)
            for name, g in dst["runs"].items():
                if _text(g.attrs.get("status", "")) == "running":
                    g.attrs["status"] = "aborted"
                    g.attrs["incomplete"] = True
                    g.attrs["end_reason"] = "the writing process stopped without closing the run (crash or kill)"
                    marked.append(name)
            _append_event(dst["events"], 0.0, "", "recovery",
                          f"recovered after the writer stopped; incomplete runs: {', '.join(marked)}")
    os.replace(tmp, path)
    return marked


def append_model_history(path, steps: list[dict], model_source: str = "") -> str:
    """Store one analysis's model history (the workbench's steps) under ``/models/analysis_<k>``.

    Each step keeps its action, error, error by level and the model as TOML text, so the error falling step by
    step can be read back. A crashed session is recovered first. Returns the group's name.
    """
    recover_session(path)
    try:
        with h5py.File(path, "r+", libver="latest") as f:
            models = f.require_group("models")
            name = f"analysis_{len(models)}"
            g = models.create_group(name)
            g.attrs["created"] = _now_iso()
            g.attrs["model_source"] = model_source
            for step in steps:
                s = g.create_group(f"step_{step['step']:03d}")
                s.attrs["action"] = step["action"]
                s.attrs["error"] = float(step["error"])
                s.create_dataset("model", data=step["model"])
                levels = np.array([[e["force"], e["error"]] for e in step["error_by_level"]], float)
                d = s.create_dataset("error_by_level", data=levels.reshape(-1, 2))
                d.attrs["columns"] = json.dumps(["force [N]", "error [1]"])
            return name
    except OSError as exc:
        raise SessionWriteError(f"{path}: cannot store the model history ({exc})") from None


def read_model_history(session: Session) -> list[dict]:
    """Every stored analysis: ``{"name", "created", "steps": [{"action", "error", "model", "error_by_level"}]}``,
    ``error_by_level`` as ``[[force N, error], ...]``."""
    f = session._file
    if "models" not in f:
        return []
    out = []
    for name, g in f["models"].items():
        steps = [{"action": _text(s.attrs["action"]), "error": float(s.attrs["error"]),
                  "model": _text(s["model"][()]), "error_by_level": s["error_by_level"][()].tolist()}
                 for _, s in sorted(g.items())]
        out.append({"name": name, "created": _text(g.attrs.get("created", "")), "steps": steps})
    return out
