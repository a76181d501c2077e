"""UFF58 files (ASCII and binary, read with pyuff) to imported runs (docs/import.md).

Records are numbered from 1 in file order (``--records`` picks some). Dataset 58 records of function type 4
(FRF) become stepped-sine runs (or a random run with ``--kind random``), function type 1 (time response) a random
run through the project's H1/H2/Hv estimator; a force spectrum beside the FRFs (:mod:`.force_spectrum`) and
contactid's own tagged per-line records (:mod:`.idlines`) go back to their run; everything else (headers, units,
geometry, other spectra, coherence of other systems) is skipped and listed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyuff

from analysis.common.errors import InputError
from analysis.common.quantities import control_dof_problem, phase_problem, phases_outside

from .force_spectrum import attach_force_spectra, is_force_spectrum
from .idlines import ID_KEYS, RecordTag, control_words, decode, disagreement
from .runs import (KINDS, ImportedRun, SourceOptions, check_axis, check_values, in_sweep_order, sine_run_name,
                   sweep_direction)
from .time_history import random_run_from_time_histories
from .uff_codes import data_type_name, function_name
from .units import DISPLACEMENT, FORCES, RESPONSES, FileUnits, Scaled, file_default, to_receptance, unit_factor

FUNC_TIME, FUNC_FRF = 1, 4
UNITS = 164
FREQUENCY_TYPES = (0, 18)          # unknown or frequency
LINE_QUANTITIES = {"frf_std": ("frf_std/{dof}", "m/N"), "coherence": ("coherence/{dof}", "1"),
                   "random_error": ("random_error/{dof}", "1"), "force_amplitude": ("force_amplitude", "N"),
                   "force_phase": ("force_phase", "rad"), "distortion": ("distortion", "1")}


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
    if 58 not in types:
        raise InputError(f"holds no dataset 58 record, so no FRF and no time history (its datasets: "
                         f"{', '.join(map(str, types))}); nothing imported", path)
    _check_whole(uff, path)
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
            binary = bool(uff.get_set_formats()[i])
            start, end = (int(b) for b in uff._block_ind[i])      # where pyuff found the record, in bytes
            hint = ("a binary file from another system may need pyuff.fix_58b" if binary else
                    "its header or data lines hold text where a number belongs")
            raise InputError(f"cannot be read as dataset 58 (bytes {start} to {end}: {hint}; pyuff: {exc})", path,
                             f"record {i + 1}") from None
        _check_points(fields, path, i + 1)
        ids = {k: str(fields.get(k, "")).strip() for k in ID_KEYS}
        records.append(Record(i + 1, fields, decode(ids, f"{path}: record {i + 1}")))
    notes = [f"skipped datasets {', '.join(str(n) for n in others)} (types "
             f"{', '.join(sorted({str(types[n - 1]) for n in others}))}: not function records)"] if others else []
    return records, units, notes


def _check_whole(uff, path: str) -> None:
    """Refuse a file that ends inside a dataset (cut short: a copy or download that stopped). pyuff drops such a
    last dataset without a word; after the last whole dataset only its closing ``-1`` may follow."""
    blocks = getattr(uff, "_block_ind", None)          # pyuff's (start, end) byte offsets of the whole datasets
    if blocks is None or not len(blocks):
        return
    end = int(blocks[-1][1])
    with open(path, "rb") as fh:
        fh.seek(end)
        lines = [line.strip() for line in fh.read().splitlines()]
    # the closing -1 (in a binary record it follows the data on the same line), then nothing but blank lines
    closing = next((i for i, line in enumerate(lines) if line.endswith(b"-1")), len(lines))
    if any(lines[closing + 1:]):
        raise InputError(f"the file ends inside this dataset: it is cut short after byte {end} (copied or written "
                         "incompletely?); nothing imported", path, f"record {len(blocks) + 1}")


def _check_points(fields: dict, path: str, number: int) -> None:
    """The record header's number of points is the number of points the record holds; fewer is a record cut
    short (a file copied or exported incompletely), and says so."""
    claimed, held = fields.get("num_pts"), len(fields.get("data", ()))
    if claimed is not None and held < int(claimed):
        raise InputError(f"the record is truncated: its header promises {int(claimed)} points but only {held} "
                         "follow (the file was copied or exported incompletely); nothing imported", path,
                         f"record {number}: num_pts")
    if claimed is None or int(claimed) != held:
        raise InputError(f"the header says {claimed} points, the record holds {held}", path,
                         f"record {number}: num_pts")


def _check_records_complete(path: str, records: list[Record]) -> None:
    """A contactid run whose tags state how many records it has must have them all (a file cut at a record
    boundary loses whole records without a trace otherwise)."""
    by_run: dict[str, list[Record]] = {}
    for r in records:
        if r.tag is not None:
            by_run.setdefault(r.tag.run, []).append(r)
    for run, held in by_run.items():
        stated = held[0].tag.records
        if stated is not None and len(held) != stated:
            raise InputError(f"run {run} has {len(held)} of the {stated} records its id lines state (records= in "
                             "id5): records are missing (a file cut short?); nothing imported", path,
                             held[-1].where("id5"))


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
    _check_records_complete(path, records)
    records = _chosen(path, records, options.records, notes)
    frf = [r for r in records if r.fields.get("func_type") == FUNC_FRF and (r.tag is None or r.tag.quantity == "frf")]
    time = [r for r in records if r.fields.get("func_type") == FUNC_TIME and r.tag is None]
    extra = [r for r in records if r.tag is not None and r.tag.quantity != "frf"]
    spectra = [r for r in records if r.tag is None and frf and is_force_spectrum(r.fields)]
    skipped = [r for r in records if r not in frf and r not in time and r not in extra and r not in spectra]
    if not frf and not time:
        _refuse_no_function(path, records)
    if skipped:
        notes.append(f"skipped records {', '.join(str(r.number) for r in skipped)} (function types "
                     f"{', '.join(sorted({str(r.fields.get('func_type')) for r in skipped}))}: "
                     "neither FRF nor time history nor a force spectrum beside FRFs)")
    _check_one_reference(path, frf)
    runs = _frf_runs(path, frf, options, units, notes, {r.fields.get("load_case_id", 0) for r in spectra})
    attach_force_spectra(path, runs, [(r.number, r.fields) for r in spectra], units, notes)
    if time:
        runs.append(random_run_from_time_histories(path, [(r.number, r.fields) for r in time], options, units,
                                                   notes))
    _attach_line_quantities(path, runs, extra, units, frf)
    return [in_sweep_order(r) for r in runs], records, notes


def _chosen(path: str, records: list[Record], wanted: list[int] | None, notes: list[str]) -> list[Record]:
    """The dataset 58 records ``--records`` names (all without it); a number that is none of them is refused."""
    if not wanted:
        return records
    numbers = [r.number for r in records]
    missing = [n for n in wanted if n not in numbers]
    if missing:
        raise InputError(f"record {missing[0]} is not a dataset 58 record of the file (its dataset 58 records: "
                         f"{', '.join(map(str, numbers)) or 'none'})", path, "--records")
    left = [n for n in numbers if n not in wanted]
    if left:
        notes.append(f"records {', '.join(map(str, left))} left out (--records)")
    return [r for r in records if r.number in wanted]


def _refuse_no_function(path: str, records: list[Record]) -> None:
    """No FRF and no time history among the (chosen) dataset 58 records -- there is one at least (read_records):
    say what the first is instead, in a whole sentence."""
    first = records[0]
    code = int(first.fields.get("func_type", 0))
    why = {9: "a PSD has neither phase nor a force to divide by, so it gives no receptance",
           10: "an ESD has neither phase nor a force to divide by, so it gives no receptance"}.get(
        code, "it gives no receptance")
    others = "" if len(records) == 1 else f", and neither is any other of its {len(records)} records"
    raise InputError(f"function type {code} is {function_name(code)}, not an FRF (4) or a time history (1): "
                     f"{why}{others}; export FRFs or time histories of force and responses", path,
                     first.where("func_type"))


def _reference(record: Record) -> tuple[int, int]:
    return int(record.fields.get("ref_node", 0)), int(record.fields.get("ref_dir", 0))


def _check_one_reference(path: str, frf: list[Record]) -> None:
    """Other systems' FRFs of one load case make one run, which has one excitation: a file with several
    references (a roving hammer) is refused first for that, with the records of each reference to pick."""
    by_case: dict = {}
    for r in frf:
        if r.tag is None:
            by_case.setdefault(r.fields.get("load_case_id", 0), {}).setdefault(_reference(r), []).append(r)
    for references in by_case.values():
        if len(references) < 2:
            continue
        groups = "; ".join(f"node {node}{'-' if d < 0 else '+'}{abs(d)}: record{'s' if len(rs) > 1 else ''} "
                           f"{', '.join(str(r.number) for r in rs)}" for (node, d), rs in references.items())
        second = list(references.values())[1][0]
        example = ",".join(str(r.number) for r in list(references.values())[0])
        raise InputError(f"the FRFs have {len(references)} different references ({groups}) -- a roving-hammer or "
                         "multi-reference measurement; a run has one excitation: import the records of one "
                         f"reference (e.g. --records {example}), one import per reference", path,
                         second.where("ref_node"))


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


FORCE_TYPES = {t: "force" for t in FORCES}
AXIS_TYPES = {"ordinate": "displacement (8), velocity (11) or acceleration (12)", "orddenom": "a force (13 or 9)"}
AXIS_NAMES = {"ordinate": "ordinate", "orddenom": "ordinate denominator"}


def _axis(path: str, record: Record, axis: str, allowed: dict, units: FileUnits | None) -> tuple[int, Scaled]:
    """A record axis's specific data type (one of ``allowed``) and the factor of its unit label to SI."""
    f = record.fields
    kind = int(f.get(f"{axis}_spec_data_type", 0))
    if kind not in allowed:
        what = AXIS_TYPES[axis] if axis == "orddenom" or allowed is RESPONSES else " or ".join(
            f"{name} ({t})" for t, name in allowed.items())
        label = str(f.get(f"{axis}_axis_units_lab", "")).strip()
        shown = f" (unit label {label!r}; the type decides, never the label)" if label.upper() not in ("", "NONE") \
            else ""
        raise InputError(f"{AXIS_NAMES[axis]} specific data type {kind} ({data_type_name(kind)}) is not {what}"
                         f"{shown}", path, record.where(f"{axis}_spec_data_type"))
    return kind, unit_factor(kind, f.get(f"{axis}_axis_units_lab", ""), path, record.where(f"{axis}_axis_units_lab"),
                             file_default(units, f, axis))


def _line_factor(path: str, record: Record, units: FileUnits | None) -> float:
    """The factor to SI of a contactid per-line record, after checking its types and unit labels are those
    export writes for its quantity (a standard deviation of receptance, a force, or a ratio)."""
    quantity = record.tag.quantity
    if quantity == "frf_std":
        _, num = _axis(path, record, "ordinate", {DISPLACEMENT: "displacement"}, units)
        _, den = _axis(path, record, "orddenom", FORCE_TYPES, units)
        return num.factor / den.factor
    if quantity == "force_amplitude":
        return _axis(path, record, "ordinate", FORCE_TYPES, units)[1].factor
    label = str(record.fields.get("ordinate_axis_units_lab", "")).strip()
    if quantity == "force_phase":                       # an angle: radians, as export writes it
        if label != "rad":
            raise InputError(f"unit {label!r} is not rad for force_phase", path,
                             record.where("ordinate_axis_units_lab"))
        return 1.0
    if label.upper() not in ("", "NONE", "1"):
        raise InputError(f"unit {label!r} is not a ratio (1) for {quantity}", path,
                         record.where("ordinate_axis_units_lab"))
    return 1.0


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
    # the types and unit labels are checked in contactid's own records too: the tags name the run and the DOFs,
    # never what the numbers are
    kind, num = _axis(path, record, "ordinate", RESPONSES, units)
    _, den = _axis(path, record, "orddenom", FORCE_TYPES, units)
    if num.assumed or den.assumed:
        notes.append(f"record {record.number}: no unit label and no units dataset 164; SI assumed")
    if record.tag is not None:
        response, excitation, sign = record.tag.response, record.tag.reference, 1.0
    else:
        response, s1 = _dof(path, record, "rsp_node", "rsp_dir", options, None)
        excitation, s2 = _dof(path, record, "ref_node", "ref_dir", options, options.excitation)
        sign = s1 * s2
    scale = num.factor / den.factor
    check_axis(x, path, record.where("x"))
    check_values(data, path, record.where("data"))
    keep = x > 0
    if not keep.all():
        notes.append(f"record {record.number}: the line at 0 Hz is left out")
    return FrfEntry(record, response, excitation, x[keep], to_receptance(sign * scale * data[keep], x[keep], kind))


def _run_key(record: Record) -> tuple:
    return ("tag", record.tag.run) if record.tag is not None else ("load case", record.fields.get("load_case_id", 0))


def _frf_runs(path: str, frf: list[Record], options: SourceOptions, units: FileUnits | None,
              notes: list[str], measured_force: set) -> list[ImportedRun]:
    """One run per load case (per tagged run); ``measured_force``: load cases with a force spectrum, whose
    level may come from it."""
    groups: dict[tuple, list[FrfEntry]] = {}
    for record in frf:
        groups.setdefault(_run_key(record), []).append(_frf_entry(path, record, options, units, notes))
    return [_run_from_entries(path, entries, options, measured_force) for entries in groups.values()]


def _run_from_entries(path: str, entries: list[FrfEntry], options: SourceOptions,
                      measured_force: set) -> ImportedRun:
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
    for e in entries[1:]:
        _same_run(path, e.record, first.record)
    if tag is not None:
        kind, force, direction, name, status = tag.kind, tag.force, tag.direction, tag.run, tag.status
        load_case = None
    else:
        kind = KINDS[options.kind or "sine"]
        load_case = first.record.fields.get("load_case_id", 0)
        force = options.force
        if force is None and load_case in measured_force:
            force = 0.0                        # set from the force spectrum (attach_force_spectra)
        if force is None:
            what = "force level of its stepped-sine" if kind == "stepped_sine" else "rms force of its random"
            raise InputError(f"the file does not say the {what} FRFs: give it (--force-amplitude N)", path,
                             first.record.where("force"))
        direction = "none" if kind == "random" else sweep_direction(first.frequency, options.direction)
        name = "random" if kind == "random" else sine_run_name(force, direction)
        status = "complete"
    run = ImportedRun(name, kind, float(force), direction, first.excitation, first.frequency, frf, status=status,
                      source=path, records=[e.record.number for e in entries], load_case=load_case)
    if tag is not None and tag.sample_rate:
        run.sample_rate, run.segment_length = tag.sample_rate, tag.segment_length
    if tag is not None:
        run.control = tag.control
        problem = run.control and control_dof_problem(run.control.mode, run.control.dof, frf, first.excitation)
        if problem:         # the rule of every door (analysis/common/quantities.py)
            raise InputError(f"at= {problem}", path, first.record.where("id3"))
    return run


def _same_run(path: str, record: Record, first: Record) -> None:
    """Records of one contactid run state its level, status and control alike (idlines.disagreement)."""
    if record.tag is None or first.tag is None:
        return
    differ = disagreement(record.tag, first.tag)
    if differ:
        key, line = differ
        shown = [" ".join(control_words(c, path)) or "control=force" if key == "control" and c is not None else c
                 for c in (getattr(record.tag, key), getattr(first.tag, key))]     # the tags as written
        raise InputError(f"{key} {shown[0]!r} differs from {shown[1]!r} in record "
                         f"{first.number} of the same run {first.tag.run}: the file is damaged or edited; nothing "
                         "imported", path, record.where(line))


def _attach_line_quantities(path: str, runs: list[ImportedRun], extra: list[Record],
                            units: FileUnits | None, frf: list[Record]) -> None:
    by_name = {r.name: r for r in runs}
    first_of = {r.tag.run: r for r in reversed(frf) if r.tag is not None}     # each run's first FRF record
    for record in extra:
        tag = record.tag
        run = by_name.get(tag.run)
        if run is None:
            raise InputError(f"{tag.quantity} of run {tag.run}, which has no FRF record in the file", path,
                             record.where("id1"))
        first_of.setdefault(tag.run, record)
        _same_run(path, record, first_of[tag.run])
        values = np.asarray(record.fields["data"], float) * _line_factor(path, record, units)
        if len(values) != len(run.frequency):
            raise InputError(f"{len(values)} lines, but run {tag.run} has {len(run.frequency)}", path,
                             record.where("num_pts"))
        check_values(values, path, record.where("data"))
        key, stored_units = LINE_QUANTITIES[tag.quantity]
        if key == "force_phase" and phases_outside(values).any():     # (analysis/common/quantities.py)
            line = int(np.flatnonzero(phases_outside(values))[0])
            raise InputError(f"line {line}: {phase_problem(float(values[line]))}", path, record.where("data"))
        run.arrays[key.format(dof=tag.response)] = (stored_units, values)
        run.records.append(record.number)
