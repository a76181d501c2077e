"""UFF58 files (ASCII and binary, read with pyuff) to imported runs (docs/import.md).

Records are numbered from 1 in file order. Dataset 58 records of function type 4 (FRF) become stepped-sine
runs (or a random run with ``--kind random``), function type 1 (time response) a random run through the
project's H1/H2/Hv estimator; contactid's own tagged per-line records (:mod:`.idlines`) go back to their run;
everything else (headers, units, geometry, spectra, coherence of other systems) is skipped and listed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyuff

from analysis.errors import InputError

from .idlines import RecordTag, decode
from .runs import (KINDS, ImportedRun, SourceOptions, check_axis, check_values, in_sweep_order, sine_run_name,
                   sweep_direction)
from .time_history import random_run_from_time_histories
from .units import FORCES, RESPONSES, FileUnits, file_default, to_receptance, unit_factor

FUNC_TIME, FUNC_FRF = 1, 4
UNITS = 164
FREQUENCY_TYPES = (0, 18)          # unknown or frequency
LINE_QUANTITIES = {"frf_std": ("frf_std/{dof}", "m/N"), "coherence": ("coherence/{dof}", "1"),
                   "random_error": ("random_error/{dof}", "1"), "force_amplitude": ("force_amplitude", "N"),
                   "distortion": ("distortion", "1")}
ID_KEYS = ("id1", "id2", "id3", "id4", "id5")


@dataclass
class Record:
    """One dataset 58 record as read, with its 1-based number in the file."""

    number: int
    fields: dict
    tag: RecordTag | None

    def where(self, name: str) -> str:
        return f"record {self.number}: {name}"


@dataclass
class FrfEntry:
    """A FRF record converted to receptance."""

    record: Record
    response: str
    excitation: str
    frequency: np.ndarray
    receptance: np.ndarray


def read_records(path: str) -> tuple[list[Record], FileUnits | None, list[str]]:
    """Every dataset 58 record of a file, its units (dataset 164, if any) and notes on the other datasets."""
    try:
        uff = pyuff.UFF(path)
        types = [int(t) for t in uff.get_set_types()] if uff.get_n_sets() else []
    except Exception as exc:           # pyuff reports every parse failure as a bare Exception
        raise InputError(f"not a readable universal file ({exc})", path) from None
    if not types:
        raise InputError("holds no universal-file dataset (not a UFF file?)", path)
    records, others, units = [], [], None
    for i, kind in enumerate(types):
        if kind == UNITS:
            units = _units(uff, i, path)
        if kind != 58:
            others.append(i + 1)
            continue
        try:
            fields = uff.read_sets(i)
        except Exception as exc:
            raise InputError(f"cannot be read as dataset 58 ({exc}; a binary file from another system may need "
                             "pyuff.fix_58b)", path, f"record {i + 1}") from None
        ids = {k: str(fields.get(k, "")).strip() for k in ID_KEYS}
        records.append(Record(i + 1, fields, decode(ids, f"{path}: record {i + 1}")))
    notes = [f"skipped datasets {', '.join(str(n) for n in others)} (types "
             f"{', '.join(sorted({str(types[n - 1]) for n in others}))}: not function records)"] if others else []
    return records, units, notes


def _units(uff, index: int, path: str) -> FileUnits:
    try:
        fields = uff.read_sets(index)
        units = FileUnits(float(fields["length"]), float(fields["force"]))
    except Exception as exc:           # pyuff: a bare Exception
        raise InputError(f"cannot be read as units dataset 164 ({exc})", path, f"record {index + 1}") from None
    if not (units.length > 0 and units.force > 0):
        raise InputError("unit factors must be > 0", path, f"record {index + 1}: length, force")
    return units


def read_uff(path: str, options: SourceOptions) -> tuple[list[ImportedRun], list[Record], list[str]]:
    """The runs of one UFF58 file, its dataset 58 records and notes (skipped records, assumed units)."""
    records, units, notes = read_records(path)
    frf = [r for r in records if r.fields.get("func_type") == FUNC_FRF and (r.tag is None or r.tag.quantity == "frf")]
    time = [r for r in records if r.fields.get("func_type") == FUNC_TIME and r.tag is None]
    extra = [r for r in records if r.tag is not None and r.tag.quantity != "frf"]
    skipped = [r for r in records if r not in frf and r not in time and r not in extra]
    if not frf and not time:
        first = records[0] if records else None
        if first is None:
            raise InputError("holds no dataset 58 record (no FRF or time history)", path)
        raise InputError(f"function type {first.fields.get('func_type')} is not an FRF (4) or a time history (1), "
                         "and no record of the file is", path, first.where("func_type"))
    if skipped:
        notes.append(f"skipped records {', '.join(str(r.number) for r in skipped)} (function types "
                     f"{', '.join(sorted({str(r.fields.get('func_type')) for r in skipped}))}: "
                     "neither FRF nor time history)")
    runs = _frf_runs(path, frf, options, units, notes)
    if time:
        runs.append(random_run_from_time_histories(path, [(r.number, r.fields) for r in time], options, units,
                                                   notes))
    _attach_line_quantities(path, runs, extra)
    return [in_sweep_order(r) for r in runs], records, notes


def _dof(path: str, record: Record, node_field: str, dir_field: str, options: SourceOptions,
         fallback: str | None) -> tuple[str, float]:
    node, direction = int(record.fields.get(node_field, 0)), int(record.fields.get(dir_field, 0))
    mapped = options.dof_name(node, direction)
    if mapped is not None:
        return mapped
    if fallback:
        return fallback, 1.0
    sign = "-" if direction < 0 else "+"
    raise InputError(f"node {node} direction {sign}{abs(direction)} is not mapped to a model DOF "
                     f"(give --dof {node}{sign}{abs(direction)}=NAME" +
                     (" or --excitation NAME)" if node_field == "ref_node" else ")"), path, record.where(node_field))


def _frf_entry(path: str, record: Record, options: SourceOptions, units: FileUnits | None,
               notes: list[str]) -> FrfEntry:
    f = record.fields
    x = np.asarray(f["x"], float)
    data = np.asarray(f["data"])
    if not np.iscomplexobj(data):
        raise InputError("an FRF record must hold complex data", path, record.where("ord_data_type"))
    if int(f.get("abscissa_spec_data_type", 0)) not in FREQUENCY_TYPES or \
            str(f.get("abscissa_axis_units_lab", "")).strip().upper() not in ("", "NONE", "HZ"):
        raise InputError("the abscissa must be frequency in Hz", path, record.where("abscissa_axis_units_lab"))
    if record.tag is not None:
        response, excitation, sign = record.tag.response, record.tag.reference, 1.0
        scale, kind = 1.0, 8
    else:
        kind = int(f.get("ordinate_spec_data_type", 0))
        if kind not in RESPONSES:
            raise InputError(f"ordinate specific data type {kind} is not displacement (8), velocity (11) or "
                             "acceleration (12)", path, record.where("ordinate_spec_data_type"))
        denominator = int(f.get("orddenom_spec_data_type", 0))
        if denominator not in FORCES:
            raise InputError(f"ordinate denominator specific data type {denominator} is not a force (13 or 9)",
                             path, record.where("orddenom_spec_data_type"))
        num = unit_factor(kind, f.get("ordinate_axis_units_lab", ""), path, record.where("ordinate_axis_units_lab"),
                          file_default(units, f, "ordinate"))
        den = unit_factor(denominator, f.get("orddenom_axis_units_lab", ""), path,
                          record.where("orddenom_axis_units_lab"), file_default(units, f, "orddenom"))
        if num.assumed or den.assumed:
            notes.append(f"record {record.number}: no unit label and no units dataset 164; SI assumed")
        response, s1 = _dof(path, record, "rsp_node", "rsp_dir", options, None)
        excitation, s2 = _dof(path, record, "ref_node", "ref_dir", options, options.excitation)
        sign, scale = s1 * s2, num.factor / den.factor
    check_axis(x, path, record.where("x"))
    check_values(data, path, record.where("data"))
    keep = x > 0
    if not keep.all():
        notes.append(f"record {record.number}: the line at 0 Hz is left out")
    return FrfEntry(record, response, excitation, x[keep], to_receptance(sign * scale * data[keep], x[keep], kind))


def _run_key(record: Record) -> tuple:
    return ("tag", record.tag.run) if record.tag is not None else ("load case", record.fields.get("load_case_id", 0))


def _frf_runs(path: str, frf: list[Record], options: SourceOptions, units: FileUnits | None,
              notes: list[str]) -> list[ImportedRun]:
    groups: dict[tuple, list[FrfEntry]] = {}
    for record in frf:
        groups.setdefault(_run_key(record), []).append(_frf_entry(path, record, options, units, notes))
    return [_run_from_entries(path, entries, options) for entries in groups.values()]


def _run_from_entries(path: str, entries: list[FrfEntry], options: SourceOptions) -> ImportedRun:
    first = entries[0]
    frf: dict[str, np.ndarray] = {}
    for e in entries:
        if e.excitation != first.excitation:
            raise InputError(f"excitation {e.excitation} differs from {first.excitation} of record "
                             f"{first.record.number} in the same run", path, e.record.where("ref_node"))
        if len(e.frequency) != len(first.frequency) or not np.allclose(e.frequency, first.frequency, rtol=1e-9):
            raise InputError(f"frequency lines differ from those of record {first.record.number} of the same run",
                             path, e.record.where("x"))
        if e.response in frf:
            raise InputError(f"a second FRF of {e.response} in the same run", path, e.record.where("rsp_node"))
        frf[e.response] = e.receptance
    tag = first.record.tag
    if tag is not None:
        kind, force, direction, name, status = tag.kind, tag.force, tag.direction, tag.run, tag.status
    else:
        kind = KINDS[options.kind or "sine"]
        force = options.force
        if force is None:
            if kind == "stepped_sine":
                raise InputError("the file does not say the force level of its stepped-sine FRFs: give it "
                                 "(--force-amplitude N)",
                                 path, first.record.where("force"))
            force = 0.0
        direction = "none" if kind == "random" else sweep_direction(first.frequency, options.direction)
        name = "random" if kind == "random" else sine_run_name(force, direction)
        status = "complete"
    return ImportedRun(name, kind, float(force), direction, first.excitation, first.frequency, frf, status=status,
                       source=path, records=[e.record.number for e in entries])


def _attach_line_quantities(path: str, runs: list[ImportedRun], extra: list[Record]) -> None:
    by_name = {r.name: r for r in runs}
    for record in extra:
        tag = record.tag
        run = by_name.get(tag.run)
        if run is None:
            raise InputError(f"{tag.quantity} of run {tag.run}, which has no FRF record in the file", path,
                             record.where("id1"))
        values = np.asarray(record.fields["data"], float)
        if len(values) != len(run.frequency):
            raise InputError(f"{len(values)} lines, but run {tag.run} has {len(run.frequency)}", path,
                             record.where("num_pts"))
        check_values(values, path, record.where("data"))
        key, units = LINE_QUANTITIES[tag.quantity]
        run.arrays[key.format(dof=tag.response)] = (units, values)
        run.records.append(record.number)
