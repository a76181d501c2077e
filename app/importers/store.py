"""Imported runs into a session: read every file first, then write the session in one piece.

The runs go through :class:`app.session.writer.SessionWriter`, so an imported session has the schema of an acquired one.
Each run is marked (attributes ``imported = true``, ``source_file``, ``source_format``, ``source_records``) and
``/provenance/import/source_<k>`` keeps each file's name, size, sha256, format, id lines and the import's notes.
A new session is written under a temporary name and moved into place when complete; ``append`` writes a copy of
the existing session with the new runs and replaces the original only when that copy is complete.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from analysis.common.errors import InputError
from analysis.common.quantities import force_level_note

from app.session import (LINES_PER_CHUNK, RunData, RunSpec, SessionWriter, atomic_output, check_output, check_run,
                         open_session, require_free_space)
from .conventions import apply_force_sign, check_drive_point
from .csv_long import read_csv_long
from .csv_runs import is_run_csv, read_csv_run
from .idlines import ID_KEYS
from .runs import ImportedRun, SourceFile, SourceOptions
from .uff import read_uff

# What an imported session takes on the disk, estimated from the data (measured on imports of 1 to 50 runs of
# 6 to 20000 lines: the estimate is 1.3 to 1.9 times the file written): a session's fixed part, each run's
# groups and attributes, and each chunk of a per-line dataset (its index entry and checksum), besides the data.
SESSION_BYTES = 256 << 10
RUN_BYTES = 64 << 10
CHUNK_BYTES = 128


@dataclass
class ImportRequest:
    """Files (each with its own options), the session to write and how."""

    sources: list[tuple[str, SourceOptions]]
    output: str
    append: bool = False
    overwrite: bool = False
    command: str = ""
    software_version: str = ""


@dataclass
class ImportResult:
    """Runs stored (name, source file) and what the import noticed."""

    runs: list[tuple[str, str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _digest(path: Path) -> tuple[int, str]:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return path.stat().st_size, h.hexdigest()


def read_source(path: str, options: SourceOptions) -> SourceFile:
    """One file read completely (UFF58 unless its name ends in .csv)."""
    p = Path(path)
    if p.is_dir():
        raise InputError("is a folder, not a file to import", path)
    if not p.is_file():
        raise InputError("file not found", path)
    size, sha = _digest(p)
    if p.suffix.lower() == ".csv" and options.records:
        raise InputError("only a UFF file has records to pick; this is a CSV file", path, "--records")
    if p.suffix.lower() == ".csv" and is_run_csv(path):
        runs, header, notes = read_csv_run(path)
        source = SourceFile(path, "csv-run", size, sha, [header], runs, notes)
    elif p.suffix.lower() == ".csv":
        runs, header, notes = read_csv_long(path, options)
        source = SourceFile(path, "csv-long", size, sha, [header], runs, notes)
    else:
        runs, records, notes = read_uff(path, options)
        binary = any(r.fields.get("binary") for r in records)
        id_lines = [[str(r.fields.get(k, "")).strip() for k in ID_KEYS] for r in records]
        source = SourceFile(path, "uff58b" if binary else "uff58", size, sha, id_lines, runs, notes)
    _conventions(source, options.force_sign)
    for run in source.runs:
        _force_phasor(run)
    return source


def _force_phasor(run: ImportedRun) -> None:
    """``force_phasor`` (N, complex), the measured force as a campaign stores it, where the file carries its
    amplitude and phase but not the phasor itself (UFF58, the CSV long format): ``amplitude * exp(j phase)``."""
    if "force_phasor" in run.arrays or "force_amplitude" not in run.arrays or "force_phase" not in run.arrays:
        return
    (_, amplitude), (_, phase) = run.arrays["force_amplitude"], run.arrays["force_phase"]
    run.arrays["force_phasor"] = ("N", np.asarray(amplitude, float) * np.exp(1j * np.asarray(phase, float)))


def _conventions(source: SourceFile, force_sign: float) -> None:
    """Where the CSV and UFF paths meet: the force sign applied, then every drive point's convention checked."""
    source.force_sign = force_sign
    for run in source.runs:
        apply_force_sign(run, force_sign)
        check_drive_point(run, source.path, force_sign)
    if force_sign < 0:
        source.notes.append("force sign reversed (--force-sign -1): every FRF's sign changed")


def estimated_bytes(files: list[SourceFile]) -> int:
    """Bytes the runs of ``files`` take in a session (see SESSION_BYTES): an upper estimate from their data."""
    total = SESSION_BYTES
    for source in files:
        total += sum(len(line) for record in source.id_lines for line in record) + RUN_BYTES
        for run in source.runs:
            chunks = -(-len(run.frequency) // LINES_PER_CHUNK)
            datasets = [run.frequency, *run.frf.values(), *(v for _, v in run.arrays.values())]
            per_line = sum(np.asarray(d).itemsize for d in datasets) + 16          # + raw/line_start, line_count
            total += RUN_BYTES + chunks * (LINES_PER_CHUNK * per_line + (len(datasets) + 2) * CHUNK_BYTES)
            if run.raw is not None:
                total += run.raw.data.size * 4                                     # float32 samples
    return total


def _stored_status(run: ImportedRun) -> tuple[str, str]:
    """The status (and end reason) a run is stored with: a finished run's own (complete, failed -- measured to
    its end but missing its plan -- or aborted); a source's other statuses make it aborted."""
    if run.status in ("complete", "failed", "aborted"):
        return run.status, ""
    return "aborted", f"the source says status {run.status}"


def control_attrs(run: ImportedRun) -> dict:
    """The run attributes saying how its level was held (docs/session-format.md); none for force control."""
    c = run.control
    if c is None or c.mode == "force":
        return {}
    return {"control": c.mode, "control_dof": c.dof, "control_quantity": c.quantity,
            "control_target": float(c.target), "control_units": c.units}


def _as_stored(run: ImportedRun) -> RunData:
    """The run as a session will hold it, for the checks every session passes before it is analysed."""
    attrs = {"kind": run.kind, "status": _stored_status(run)[0], "direction": run.direction, "force": run.force,
             "excitation_dof": run.excitation_dof, "sensor_dofs": json.dumps(list(run.frf)), **control_attrs(run)}
    return RunData(run.name, attrs, run.frequency, run.frf, {k: v for k, (_, v) in run.arrays.items()},
                   {k: u for k, (u, _) in run.arrays.items()}, incomplete=False)


def check_like_a_session(source: SourceFile) -> None:
    """Every run of a file passes what ``analyze`` checks of a session (app/session_checks.py) before anything
    is written: an import never stores what the analysis would refuse."""
    for run in source.runs:
        check_run(_as_stored(run), source.path)
        mode = run.control.mode if run.control is not None else "force"
        if mode != "response" and "force_amplitude" in run.arrays:     # a force held, or driven open loop
            note = force_level_note(run.arrays["force_amplitude"][1], run.force)    # (analysis/common/quantities.py)
            if note:
                source.notes.append(f"run {run.name}: {note}")


def safe_run_name(name: str) -> str:
    """A run name as a single HDF5 group name: characters other than letters, digits and ``_ . + -`` (a ``/``
    would make nested groups) become ``_``, and leading or trailing dots go."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", name).strip(".") or "run"


def _existing_runs(path: str) -> list[str]:
    with open_session(path) as s:
        if s.writer_alive and any(s.run(n).status == "running" for n in s.run_names()):
            raise InputError("is still being written by a running process; wait for it to finish", path, "-o")
        return s.run_names()


def _one_random_run(files: list[SourceFile], appended_to: str | None) -> None:
    """A session holds one random run, the low-level reference (the analysis takes one): the import refuses a
    second one -- such as a stepped-sine CSV of two levels read with ``--kind random`` -- rather than let the
    analysis take either."""
    found = [(run.name, source.path) for source in files for run in source.runs if run.kind == "random"]
    if appended_to is not None:
        with open_session(appended_to) as s:
            found = [(name, appended_to) for name in s.run_names() if s.run(name).kind == "random"] + found
    if len(found) > 1:
        (first, where), (second, path) = found[:2]
        how = " (--kind random: each level of the file becomes a random run)" if where == path else ""
        raise InputError(f"would be the session's second random run, after {first} of {Path(where).name}{how}: a "
                         "session holds one random run, the low-level reference; import one", path,
                         f"run {second}")


def _unique_names(files: list[SourceFile], taken: list[str], notes: list[str]) -> None:
    used = set(taken)
    for source in files:
        for run in source.runs:
            base = safe_run_name(run.name)
            name, k = base, 2
            while name in used:
                name, k = f"{base}_{k}", k + 1
            if name != run.name:
                why = "the name is taken" if base in used else "a run's name is one HDF5 group name"
                notes.append(f"{source.path}: run {run.name} stored as {name} ({why})")
                run.name = name
            used.add(name)


def import_files(request: ImportRequest) -> ImportResult:
    """Read every file, then write (or append to) the session; nothing is written if any file is bad."""
    inputs = [p for p, _ in request.sources]
    if not inputs:
        raise InputError("give at least one file to import")
    files = [read_source(p, o) for p, o in request.sources]
    for source in files:
        check_like_a_session(source)
    if not any(f.runs for f in files):
        raise InputError("no run in the files", ", ".join(inputs))
    result = ImportResult()
    if request.append:
        if not Path(request.output).exists():
            raise InputError("does not exist: --append adds runs to an existing session", request.output, "-o")
        check_output(request.output, inputs=inputs, overwrite=True)
        taken = _existing_runs(request.output)
    else:
        check_output(request.output, inputs=inputs, overwrite=request.overwrite)
        taken = []
    _one_random_run(files, request.output if request.append else None)
    _unique_names(files, taken, result.notes)
    runs = estimated_bytes(files)
    # --append: a copy of the session, and the new runs written beside it before they are moved into the copy
    needed = 2 * runs + os.path.getsize(request.output) if request.append else runs
    require_free_space(request.output, needed, "write the session")
    with atomic_output(request.output, inputs=inputs, overwrite=request.append or request.overwrite) as temp:
        if request.append:
            _append(request, files, Path(request.output), temp)
        else:
            _write_runs(request, files, temp)
            _store_provenance(temp, files, first_index=0)
    for f in files:
        result.runs += [(r.name, f.path) for r in f.runs]
        result.notes += [f"{f.path}: {n}" for n in f.notes]
    return result


def _append(request: ImportRequest, files: list[SourceFile], original: Path, temp: Path) -> None:
    """Copy the session, write the new runs beside it with the writer, and move them into the copy."""
    shutil.copyfile(original, temp)
    scratch = temp.with_name(temp.name + ".runs")
    try:
        _write_runs(request, files, scratch)
        with h5py.File(scratch, "r") as src, h5py.File(temp, "r+", libver="latest") as dst:
            for name in src["runs"]:
                src.copy(src["runs"][name], dst["runs"], name=name)
            events, new = dst["events"], src["events"][()]
            events.resize(events.shape[0] + len(new), axis=0)
            events[-len(new):] = new
            index = len(dst["provenance"]["import"]) if "import" in dst["provenance"] else 0
        _store_provenance(temp, files, first_index=index)
    finally:
        scratch.unlink(missing_ok=True)


def _write_runs(request: ImportRequest, files: list[SourceFile], path: Path) -> None:
    writer = SessionWriter(path, software_version=request.software_version, command=request.command)
    try:
        for source in files:
            for run in source.runs:
                _write_run(writer, run, source)
    finally:
        writer.close()


def _write_run(writer: SessionWriter, run: ImportedRun, source: SourceFile) -> None:
    extras = {name: (units, (), "c16" if np.iscomplexobj(values) else "f8")
              for name, (units, values) in run.arrays.items()}
    raw = run.raw
    attrs = {"imported": True, "source_file": Path(source.path).name, "source_format": source.format,
             "source_records": json.dumps(run.records)}
    if run.segment_length:
        attrs["segment_length"] = int(run.segment_length)      # as a campaign's random run has it
    writer.begin_run(RunSpec(run.name, run.kind, run.force, run.direction, run.excitation_dof, list(run.frf),
                             run.sample_rate, raw.channels if raw else ["force"], raw.units if raw else ["N"],
                             extras, {**attrs, **control_attrs(run)}))
    arrays = {"frequency": run.frequency, **{f"frf/{d}": v for d, v in run.frf.items()},
              **{name: values for name, (_, values) in run.arrays.items()}}
    if run.kind == "stepped_sine":                     # no raw samples for any line
        arrays["raw/line_start"] = arrays["raw/line_count"] = np.zeros(len(run.frequency), int)
    writer.write_arrays(arrays)
    if raw is not None:
        writer.append_raw(raw.data.astype(np.float32))
    writer.log("import", f"imported from {Path(source.path).name} ({source.format}), records "
                         f"{', '.join(str(r) for r in run.records)}", run=run.name)
    writer.end_run(*_stored_status(run))


def _store_provenance(path: Path, files: list[SourceFile], first_index: int) -> None:
    """``/provenance/import/source_<k>``: one group per file read."""
    now = _dt.datetime.now(_dt.timezone.utc).astimezone().isoformat(timespec="seconds")
    with h5py.File(path, "r+", libver="latest") as f:
        group = f["provenance"].require_group("import")
        for k, source in enumerate(files, start=first_index):
            g = group.create_group(f"source_{k}")
            g.attrs.update({"name": Path(source.path).name, "path": str(Path(source.path).resolve()),
                            "size": source.size, "sha256": source.sha256, "format": source.format,
                            "imported": now, "runs": json.dumps([r.name for r in source.runs]),
                            "notes": json.dumps(source.notes), "force_sign": float(source.force_sign)})
            lines = np.array(source.id_lines, dtype=object) if source.id_lines else np.empty((0, 0), object)
            g.create_dataset("id_lines", data=lines, dtype=h5py.string_dtype())
