"""Interchange formats: UFF dataset 58 (via pyuff) and CSV, from a session file.

UFF58 (docs/import.md has the full description):

* one file per run, ``<stem>_<run><suffix>`` beside the named file (the default) -- what modal software that
  stacks a file's FRF records into one array (sdypy-EMA's ``read_uff``) needs when runs differ in length -- or
  every run in the named file (``per_run=False``, ``--one-file``); each file is opened by a dataset 151 header
  that states the quantity and the phase convention;
* binary records (58b, doubles) by default: an ASCII record's six digits do not hold every frequency a
  session measures (a random run's 0.150004 Hz spacing); ``binary=False`` (``--ascii``) writes ASCII;
* one FRF record (function type 4) per sensor DOF: receptance, ordinate displacement (specific data type 8,
  length exponent 1, "m"; "rad" with exponent 0 on a rotation) over excitation force (type 13, force exponent 1,
  "N"), abscissa in Hz, lines in rising frequency (a down sweep too); evenly spaced lines (a random run) are
  written as even, others as x/y pairs;
* contactid's per-line quantities after the FRFs as tagged records -- ``frf_std`` and ``random_error``, the
  measured ``force_amplitude`` and ``force_phase`` (rad; the import rebuilds ``force_phasor`` from the two) and
  the displacement ``distortion`` as general functions (type 0), ``coherence`` as type 6 -- so an import gives
  the analysis the same numbers (``frf_only`` leaves them out); the other per-line datasets of a run (a
  campaign's own records: ``force_target``, ``settle_time``, harmonics, ...) have no UFF record and are named in
  :attr:`UffExport.left_out`, as are phase-resonance runs (their locks carry attributes and harmonics a UFF58
  record cannot; the import would refuse them);
* node numbers: the session's stations (a DOF name up to its dot: ``A`` of ``A.w``, ``x1``) in natural sort
  order, numbered from 1; direction 3 (+Z) for ``*.w``, 5 (+Y rotation) for ``*.theta``, 1 (+X) otherwise;
  the DOF names themselves, the run name, force level and sweep direction (and a random run's sample rate and
  Welch segment length, and how a level not held at its force was held) are in the id lines
  (:mod:`app.importers.idlines`);
* the phase convention is exp(+jwt): a driving-point receptance has Im < 0.

An ASCII record writes uneven abscissae with 6 significant digits (E13.5) and even spacing's start and step
likewise: a frequency that does not survive that format is refused (binary UFF keeps uneven abscissae exact).
NaN or infinite frequencies or FRFs are refused, naming run and line. Every output is written under a
temporary name and moved into place only when complete (app/outputs.py).
"""
from __future__ import annotations

import csv
import re
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyuff

from analysis.common.errors import InputError
from analysis.common.measurements import Control

from .importers.csv_runs import MARK as CSV_RUN_MARK
from .importers.idlines import RecordTag, control_words, encode
from app.session import (RunData, Session, atomic_output, check_format, check_output, check_run, check_run_count,
                         displacement_distortion, open_session, require_free_space)
from app.session.checks import CheckedRun, refuse_saw_nothing

FUNC_GENERAL, FUNC_FRF, FUNC_COHERENCE = 0, 4, 6
DATA_UNKNOWN, DATA_DISPLACEMENT, DATA_FORCE, DATA_FREQUENCY = 0, 8, 13, 18
ASCII_DIGITS = "%.5e"                 # the E13.5 of a UFF58 ASCII abscissa
FORMAT_TOLERANCE = 1e-12              # relative: a frequency "survives" the format within this
BYTES_PER_POINT, BYTES_PER_HEADER = 64, 1500     # generous size estimate for the free-space check


@dataclass
class UffExport:
    """What :func:`export_uff` wrote."""

    files: list[Path]
    records: int
    left_out: list[str] = field(default_factory=list)      # what no record carries: runs, "<run>: <datasets>"
    # what a record would carry and ``frf_only`` (``--frf-only``) chose to leave out: "<run>: <datasets>"
    left_out_by_choice: list[str] = field(default_factory=list)


@dataclass
class _Axis:
    """How a record's abscissa is written."""

    quantity: str          # ordinate label and units
    units: str
    length_exp: int
    force_exp: int
    data_type: int


def _natural_key(text: str):
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", text)]


def _station(dof: str) -> str:
    return dof.partition(".")[0]


def node_numbers(dofs) -> dict[str, int]:
    """Station -> UFF node: the stations of all DOFs in natural sort order, from 1."""
    return {st: i for i, st in enumerate(sorted({_station(d) for d in dofs}, key=_natural_key), start=1)}


def direction_code(dof: str) -> int:
    """UFF direction of a DOF: 3 (+Z) for ``*.w``, 5 (+Y rotation) for ``*.theta``, 1 (+X) otherwise."""
    return {"w": 3, "theta": 5}.get(dof.partition(".")[2], 1)


def _response_axis(dof: str) -> _Axis:
    if direction_code(dof) == 5:
        return _Axis("Rotation", "rad", 0, 0, DATA_DISPLACEMENT)
    return _Axis("Displacement", "m", 1, 0, DATA_DISPLACEMENT)


FORCE_AXIS = _Axis("Force", "N", 0, 1, DATA_FORCE)
NO_AXIS = _Axis("NONE", "NONE", 0, 0, DATA_UNKNOWN)
ONE_AXIS = _Axis("Ratio", "1", 0, 0, DATA_UNKNOWN)
PHASE_AXIS = _Axis("Phase", "rad", 0, 0, DATA_UNKNOWN)


def _survives(x: np.ndarray) -> np.ndarray:
    written = np.array([float(ASCII_DIGITS % v) for v in x])
    return np.abs(written - x) <= FORMAT_TOLERANCE * np.abs(x)


def _abscissa(freq: np.ndarray, run: str, binary: bool, even_allowed: bool) -> dict:
    """pyuff fields of the abscissa: even where the lines are evenly spaced and start and step survive the
    header's E13.5, else x/y pairs (refused in ASCII where a frequency would be rounded).

    A run of one line is written evenly spaced (pyuff needs a second abscissa for x/y pairs, and a step for the
    header): its frequency is then the header's E13.5 start, and a frequency that does not survive it is
    refused by name rather than rounded."""
    if len(freq) == 1:
        if not _survives(freq)[0]:
            raise InputError(f"its one line at {float(freq[0])!r} Hz does not survive the 6 significant digits of "
                             f"the UFF58 header that holds a one-line record's frequency ({ASCII_DIGITS % freq[0]}); "
                             "export it with --csv-long or --csv", f"run {run}", "frequency")
        return {"abscissa_spacing": 1, "x": np.array([float(freq[0]), float(freq[0]) + 1.0])}
    if even_allowed and len(freq) > 1:
        start, step = float(ASCII_DIGITS % freq[0]), float(ASCII_DIGITS % (freq[1] - freq[0]))
        if np.allclose(start + step * np.arange(len(freq)), freq, rtol=FORMAT_TOLERANCE, atol=0):
            return {"abscissa_spacing": 1, "x": start + step * np.arange(len(freq))}
    if not binary:
        bad = np.flatnonzero(~_survives(freq))
        if bad.size:
            i = int(bad[0])
            raise InputError(f"line {i} at {float(freq[i])!r} Hz does not survive the 6 significant digits of an ASCII "
                             f"UFF58 abscissa ({ASCII_DIGITS % freq[i]}); export binary UFF (the default, or --binary)",
                             f"run {run}", "frequency")
    return {"abscissa_spacing": 0, "x": freq}


def _line_quantities(run: RunData) -> list[tuple[str, str, np.ndarray, _Axis, _Axis, int]]:
    """(quantity, response DOF, values, ordinate, denominator, function type) of the run's per-line records."""
    out = []
    dofs = run.sensor_dofs
    for d in dofs:
        if f"frf_std/{d}" in run.arrays:
            out.append(("frf_std", d, run.arrays[f"frf_std/{d}"], _response_axis(d), FORCE_AXIS, FUNC_GENERAL))
        if f"coherence/{d}" in run.arrays:
            out.append(("coherence", d, run.arrays[f"coherence/{d}"], ONE_AXIS, NO_AXIS, FUNC_COHERENCE))
        if f"random_error/{d}" in run.arrays:
            out.append(("random_error", d, run.arrays[f"random_error/{d}"], ONE_AXIS, NO_AXIS, FUNC_GENERAL))
    if "force_amplitude" in run.arrays:
        out.append(("force_amplitude", run.excitation_dof, run.arrays["force_amplitude"], FORCE_AXIS, NO_AXIS,
                    FUNC_GENERAL))
    if "force_phase" in run.arrays:
        out.append(("force_phase", run.excitation_dof, run.arrays["force_phase"], PHASE_AXIS, NO_AXIS, FUNC_GENERAL))
    distortion = _distortion(run)
    if distortion is not None:
        out.append(("distortion", run.excitation_dof, distortion, ONE_AXIS, NO_AXIS, FUNC_GENERAL))
    return out


def _not_carried(run: RunData, frf_only: bool = False) -> list[str]:
    """The run's per-line datasets no UFF record of :func:`_line_quantities` carries (``force_phasor`` is: the
    import rebuilds it from ``force_amplitude`` and ``force_phase``); with ``frf_only`` also those the records
    would carry and ``--frf-only`` leaves out (:func:`frf_only_drops` tells the two apart)."""
    carried = {"force_amplitude", "force_phase", "distortion", "force_phasor"} if not frf_only else set()
    if not frf_only:
        carried |= {f"{q}/{d}" for q in ("frf_std", "coherence", "random_error") for d in run.sensor_dofs}
        if "force_phase" not in run.arrays or "force_amplitude" not in run.arrays:
            carried.discard("force_phasor")
    return sorted(name for name in run.arrays if name not in carried)


def frf_only_drops(run: RunData) -> list[str]:
    """What the default UFF export carries of the run and ``--frf-only`` leaves out by the user's choice: its
    per-line records, and the displacement ``distortion`` the analysis reads where it comes from the harmonics."""
    dropped = sorted(set(_not_carried(run, True)) - set(_not_carried(run)))
    if "distortion" not in dropped and _distortion(run) is not None:
        dropped.append("distortion")
    return dropped


def attributes_not_carried(run: RunData) -> list[str]:
    """The run's attributes no interchange format carries, as a note names them: why it failed or was aborted
    (``end_reason``) and that its writer died during it (``incomplete``); the import stores the status alone."""
    out = []
    if run.attrs.get("end_reason"):
        out.append(f"end_reason {str(run.attrs['end_reason'])!r}")
    if run.attrs.get("incomplete"):
        out.append("incomplete (its writer stopped during the run)")
    return out


def welch_segment(run: RunData) -> tuple[float | None, int | None]:
    """A random run's sample rate (Hz) and Welch segment length (samples), which set the resolution the
    analysis allows for leakage; (None, None) for other runs or where the session does not hold them."""
    fs, segment = run.attrs.get("sample_rate", 0), run.attrs.get("segment_length", 0)
    if run.kind != "random" or not (fs and fs > 0 and segment and segment > 0):
        return None, None
    return float(fs), int(segment)


def _distortion(run: RunData) -> np.ndarray | None:
    """The per-line displacement THD the analysis uses (from the harmonics, or as imported)."""
    if "distortion" in run.arrays:
        return run.arrays["distortion"]
    thd = [displacement_distortion(run.arrays[f"harmonics/acc:{d}"]) for d in run.sensor_dofs
           if f"harmonics/acc:{d}" in run.arrays]
    return np.max(np.stack(thd), axis=0) if thd else None


@dataclass
class _RecordContext:
    """What every record of one run shares."""

    run: RunData
    control: Control
    load_case: int
    nodes: dict[str, int]
    created: str
    software: str
    binary: bool
    records: int | None = None          # records of the run (set when they are made)


def _record(ctx: _RecordContext, quantity: str, dof: str, values, ordinate: _Axis, denominator: _Axis,
            func_type: int) -> dict:
    run = ctx.run
    tag = RecordTag(run.name, quantity, dof, run.excitation_dof, run.kind, run.force, run.direction, run.status,
                    ctx.records, *welch_segment(run), ctx.control)
    freq = np.asarray(run.frequency, float)
    values = np.asarray(values)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(f"line {int(bad[0])}: {quantity} is not finite; nothing exported", f"run {run.name}",
                         f"{quantity}/{dof}")
    axis = _abscissa(freq, run.name, ctx.binary, even_allowed=run.kind == "random")
    record = pyuff.prepare_58(
        binary=int(ctx.binary), **encode(tag, ctx.created, ctx.software, f"run {run.name}"),
        func_type=func_type, load_case_id=ctx.load_case,
        rsp_ent_name=dof[:10], rsp_node=ctx.nodes[_station(dof)], rsp_dir=direction_code(dof),
        ref_ent_name=run.excitation_dof[:10], ref_node=ctx.nodes[_station(run.excitation_dof)],
        ref_dir=direction_code(run.excitation_dof),
        abscissa_spacing=axis["abscissa_spacing"], abscissa_spec_data_type=DATA_FREQUENCY,
        abscissa_axis_units_lab="Hz",
        ordinate_spec_data_type=ordinate.data_type, ordinate_len_unit_exp=ordinate.length_exp,
        ordinate_force_unit_exp=ordinate.force_exp, ordinate_axis_units_lab=ordinate.units,
        orddenom_spec_data_type=denominator.data_type, orddenom_len_unit_exp=denominator.length_exp,
        orddenom_force_unit_exp=denominator.force_exp, orddenom_axis_units_lab=denominator.units,
        data=values.astype(complex if func_type == FUNC_FRF else float), x=axis["x"])
    # the axis labels are written by pyuff but not taken by prepare_58
    record.update(abscissa_axis_lab="Frequency", ordinate_axis_lab=ordinate.quantity,
                  orddenom_axis_lab=denominator.quantity)
    return record


def _run_records(ctx: _RecordContext, frf_only: bool) -> list[dict]:
    run = ctx.run
    quantities = [] if frf_only else _line_quantities(run)
    ctx.records = len(run.sensor_dofs) + len(quantities)       # in every record's id5: a cut file is noticed
    records = [_record(ctx, "frf", d, run.frf[d], _response_axis(d), FORCE_AXIS, FUNC_FRF) for d in run.sensor_dofs]
    return records + [_record(ctx, *q) for q in quantities]


def _header(session_path: Path, software: str) -> dict:
    return pyuff.prepare_151(
        model_name=f"contactid session {session_path.name}"[:80],
        description="receptance X/F in m/N (rad/N); phase exp(+jwt): Im < 0 at a driving point",
        db_app="contactid", program=f"contactid {software}"[:80])


def _runs_to_export(s: Session) -> list[CheckedRun]:
    """The runs with lines, after the checks the analysis makes (:mod:`app.session.checks`): a session the
    analysis would refuse is not exported either (InputError naming the file, run and dataset)."""
    source = str(s.path)
    check_format(s.attrs, source)
    check_run_count(s.run_names(), source)
    return [check_run(r, source) for r in s.runs() if len(r.frequency)]


def _exportable(runs: list[CheckedRun]) -> tuple[list[CheckedRun], list[str]]:
    """The runs the UFF and CSV exports write, and those they leave out (named, with why): a phase-resonance
    run's points hang on its lock attributes and per-point harmonics, which neither format carries and which
    the import needs -- written, it would be refused on the way back."""
    kept = [c for c in runs if c.run.kind != "phase_resonance"]
    return kept, [f"{c.run.name} (phase resonance: not carried by the format)" for c in runs
                  if c.run.kind == "phase_resonance"]


def rising(run: RunData) -> RunData:
    """The run with its lines in rising frequency: modal tools take a record's abscissa as rising (sdypy-EMA's
    band cut finds no line in a falling one). A down sweep's measured order comes back on import, from its
    direction (app/importers/runs.py, ``in_sweep_order``)."""
    if len(run.frequency) < 2 or run.frequency[1] > run.frequency[0]:
        return run
    n = len(run.frequency)
    flip = {k: (v[::-1] if len(v) == n else v) for k, v in run.arrays.items()}
    return replace(run, frequency=run.frequency[::-1], frf={d: v[::-1] for d, v in run.frf.items()}, arrays=flip)


def run_file(uff_path: Path, run: str) -> Path:
    """Where the per-run export of ``run`` goes: ``<stem>_<run><suffix>`` beside ``uff_path``."""
    return uff_path.with_name(f"{uff_path.stem}_{run}{uff_path.suffix or '.uff'}")


def export_uff(session_path, uff_path, overwrite: bool = False, *, per_run: bool = True,
               binary: bool = True, frf_only: bool = False) -> UffExport:
    """Write the session's runs as UFF58: one file per run (see :func:`run_file`) or, with ``per_run=False``,
    all in ``uff_path``; binary records (58b, doubles) unless ``binary=False``. Nothing is written unless every
    record could be prepared."""
    session_path, uff_path = Path(session_path), Path(uff_path)
    if uff_path.resolve() == session_path.resolve():      # FILE names the session: a slip, whatever is written
        check_output(uff_path, inputs=[session_path], overwrite=overwrite, field="--uff")
    files: dict[Path, list[dict]] = {}
    with open_session(session_path) as s:
        software, created = s.attrs.get("software_version", ""), s.attrs.get("created", "")
        runs, left_out = _exportable(_runs_to_export(s))
        if not runs:
            raise InputError("has no measured FRF to export" + (f" (left out: {', '.join(left_out)})" if left_out
                                                                   else ""), str(session_path))
        for checked in runs:
            refuse_saw_nothing(checked, str(session_path), "UFF58")
        left_out += [f"{c.run.name}: {', '.join(names)}" for c in runs
                     for names in [_not_carried(c.run) + attributes_not_carried(c.run)] if names]
        chosen = [f"{c.run.name}: {', '.join(names)}" for c in runs for names in [frf_only_drops(c.run)]
                  if frf_only and names]
        nodes = node_numbers({d for c in runs for d in (c.run.excitation_dof, *c.run.sensor_dofs)})
        for load_case, checked in enumerate(runs, start=1):
            target = run_file(uff_path, checked.run.name) if per_run else uff_path
            ctx = _RecordContext(rising(checked.run), checked.control, load_case, nodes, created, software, binary)
            try:
                files.setdefault(target, []).extend(_run_records(ctx, frf_only))
            except InputError as exc:   # a record's fault names the run; the session holding it goes first
                raise InputError(exc.message, str(session_path), ": ".join(p for p in (exc.source, exc.field) if p)
                                 ) from None
    for target in files:
        check_output(target, inputs=[session_path], overwrite=overwrite, field="--uff")
    _write_uff_files(files, session_path, software, overwrite)
    return UffExport(list(files), sum(len(r) for r in files.values()), left_out, chosen)


def _write_uff_files(files: dict[Path, list[dict]], session_path: Path, software: str, overwrite: bool) -> None:
    """Write every file under a temporary name; all are moved into place only when all were written."""
    needed = sum(BYTES_PER_HEADER + BYTES_PER_POINT * len(r["data"]) for recs in files.values() for r in recs)
    require_free_space(next(iter(files)), needed, "export UFF58")
    with ExitStack() as stack:
        for target, records in files.items():
            temp = stack.enter_context(atomic_output(target, inputs=[session_path], overwrite=overwrite,
                                                     field="--uff"))
            try:
                pyuff.UFF(str(temp)).write_sets([_header(session_path, software)] + records, mode="add")  # a fresh file
            except Exception as exc:        # pyuff reports every write failure as a bare Exception
                raise OSError(f"{target}: writing the UFF file failed ({exc}); no export file was left") from exc


def export_csv(session_path, directory, overwrite: bool = False, left_out: list[str] | None = None) -> list[Path]:
    """One CSV per run: frequency, Re/Im of each FRF, and every per-line scalar quantity with its unit.
    Phase-resonance runs are left out (:func:`_exportable`) and named in ``left_out`` where it is given."""
    session_path, directory = Path(session_path), Path(directory)
    with open_session(session_path) as s:
        runs, skipped = _exportable(_runs_to_export(s))
    if left_out is not None:
        left_out += skipped + [f"{c.run.name}: {', '.join(names)}" for c in runs
                               for names in [attributes_not_carried(c.run)] if names]
    if not runs:
        raise InputError("has no measured FRF to export" + (f" (left out: {', '.join(skipped)})" if skipped else ""),
                         str(session_path))
    for checked in runs:
        refuse_saw_nothing(checked, str(session_path), "the per-run CSV")
    if directory.exists() and not directory.is_dir():
        raise InputError("is a file; --csv takes a folder (one CSV per run is written into it)", str(directory),
                         "--csv")
    created = not directory.exists()
    directory.mkdir(parents=True, exist_ok=True)
    try:
        paths = [directory / f"{c.run.name}.csv" for c in runs]
        for path in paths:
            check_output(path, inputs=[session_path], overwrite=overwrite, field="--csv")
        with ExitStack() as stack:
            for path, checked in zip(paths, runs):
                temp = stack.enter_context(atomic_output(path, inputs=[session_path], overwrite=overwrite,
                                                         field="--csv"))
                _write_run_csv(temp, checked)
    except BaseException:
        if created and not any(directory.iterdir()):
            directory.rmdir()                          # a failed export leaves no empty folder behind
        raise
    return paths


def run_line(run: RunData, control: Control) -> str:
    """The CSV's machine-readable second row: what ``import`` needs to make the run again (exact force, a random
    run's sample rate and Welch segment length, how the level was held), as ``key=value`` words like the UFF id
    lines."""
    words = [f"run={run.name}", f"kind={run.kind}", f"force={float(run.force)!r}", f"direction={run.direction}",
             f"status={run.status}", f"excitation={run.excitation_dof}"]
    fs, segment = welch_segment(run)
    if fs:
        words += [f"sample_rate={fs!r}", f"segment_length={segment}"]
    words += control_words(control, f"run {run.name}")
    return f"{CSV_RUN_MARK} " + " ".join(words)


def _write_run_csv(path: Path, checked: CheckedRun) -> None:
    run = checked.run
    columns = [("frequency [Hz]", run.frequency)]
    for dof, frf in run.frf.items():
        columns += [(f"Re frf {dof} [m/N]", frf.real), (f"Im frf {dof} [m/N]", frf.imag)]
    for name, values in sorted(run.arrays.items()):
        if values.ndim != 1 or len(values) != len(run.frequency):
            continue                                   # per-harmonic arrays stay in the HDF5 file
        unit = run.units.get(name, "")
        if np.iscomplexobj(values):
            columns += [(f"Re {name} [{unit}]", values.real), (f"Im {name} [{unit}]", values.imag)]
        else:
            columns.append((f"{name} [{unit}]", values.astype(float)))
    distortion = _distortion(run)
    if distortion is not None and "distortion" not in run.arrays:     # the THD the analysis uses, from harmonics
        columns.append(("distortion [1]", distortion))
    with path.open("w", newline="") as fh:
        out = csv.writer(fh)
        held = "" if checked.control.mode == "force" else f" (level {checked.control.label()})"
        out.writerow([f"# contactid run {run.name}: {run.kind}, force {run.force:g} N{held}, direction "
                      f"{run.direction}, status {run.status}, excitation {run.excitation_dof}"])
        out.writerow([run_line(run, checked.control)])
        out.writerow([name for name, _ in columns])
        for row in zip(*(values for _, values in columns)):
            out.writerow([repr(float(v)) for v in row])
