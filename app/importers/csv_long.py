"""The CSV long format: one row per line, force level and DOF (docs/import.md).

A header row names the columns ``frequency_hz, force_n, dof, re, im`` (receptance X/F, m/N, exp(+jwt)) and
optionally ``std`` (its standard deviation sqrt(E|n|^2), m/N), ``direction`` (up/down), the force measured at
each line (``force_amplitude_n``, N; ``force_phase_rad``) and, for a response-controlled level, the response
held (``control_dof``, ``control_quantity``, ``control_target`` in SI units; ``force_n`` may then be empty).
Lines starting with ``#`` before the header are comments. Rows of one level (and direction) form one run, in
the order given; every DOF of a run must have the same lines.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field

import numpy as np

from analysis.common.errors import InputError
from analysis.common.measurements import CONTROL_UNITS, Control
from analysis.common.quantities import (control_dof_problem, dof_name_problem, force_and_response, force_problem, frequency_problem,
                                       held_without_target, phase_problem, response_target_problem)

from .runs import (KINDS, ImportedRun, SourceOptions, csv_float, in_sweep_order, response_run_name,
                   sine_run_name, sweep_direction)

REQUIRED = ("frequency_hz", "force_n", "dof", "re", "im")
OPTIONAL = ("std", "direction", "force_amplitude_n", "force_phase_rad", "control_dof", "control_quantity",
            "control_target", "status")
STATUSES = ("complete", "failed", "aborted", "running")   # a session's run statuses (running: stored aborted)
RESPONSE_QUANTITIES = tuple(q for q in CONTROL_UNITS if q != "force")


@dataclass
class _Lines:
    """The rows of one DOF in one run."""

    first_row: int
    frequency: list[float] = field(default_factory=list)
    value: list[complex] = field(default_factory=list)
    std: list[float] = field(default_factory=list)
    force_amplitude: list[float] = field(default_factory=list)
    force_phase: list[float] = field(default_factory=list)
    status: str | None = None                 # the ``status`` column's word (None: the column is absent)
    status_row: int = 0
    rows: list[int] = field(default_factory=list)      # the file line (from 1) of each line, for messages
    cells: list[str] = field(default_factory=list)     # the ``dof`` cell of each as written (spaces kept)


def _number(text: str, path: str, row: int, column: str) -> float:
    try:
        value = csv_float(text)
    except ValueError:
        raise InputError(f"{text!r} is not a number", path, f"line {row}: {column}") from None
    if not np.isfinite(value):
        raise InputError(f"{text!r} is not a finite number", path, f"line {row}: {column}")
    return value


def _header(rows, path: str) -> tuple[int, list[str]]:
    for number, row in rows:
        if row and not row[0].lstrip().startswith("#"):
            columns = [c.strip().lower() for c in row]
            twice = sorted({c for c in columns if columns.count(c) > 1})
            if twice:
                raise InputError(f"column {', '.join(twice)} is named twice", path, f"line {number}: header")
            missing = [c for c in REQUIRED if c not in columns]
            unknown = [c for c in columns if c not in REQUIRED + OPTIONAL]
            if missing or unknown:
                raise InputError(f"the header must name the columns {', '.join(REQUIRED)} (optional: "
                                 f"{', '.join(OPTIONAL)}); " + (f"missing {', '.join(missing)}" if missing else
                                                               f"unknown {', '.join(unknown)}"),
                                 path, f"line {number}: header")
            return number, columns
    raise InputError("no header row", path)


def read_csv_long(path: str, options: SourceOptions) -> tuple[list[ImportedRun], list[str], list[str]]:
    """The runs of one CSV file, its header row and notes."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:     # Excel's "CSV UTF-8" starts with a BOM
            rows = list(enumerate(csv.reader(fh), start=1))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"cannot be read as CSV ({exc})", path) from None
    header_row, columns = _header(rows, path)
    if options.excitation is None:
        raise InputError("a CSV file does not name the excitation: give --excitation NAME", path, "--excitation")
    runs: dict[tuple[Control, str | None], dict[str, _Lines]] = {}
    for number, row in rows[header_row:]:
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(columns):
            raise InputError(f"{len(row)} fields, the header has {len(columns)}", path, f"line {number}")
        cell = dict(zip(columns, (c.strip() for c in row)))
        written_dof = row[columns.index("dof")]
        control = _control(cell, path, number, options.excitation)
        direction = cell.get("direction") or None
        if direction not in (None, "up", "down"):
            raise InputError(f"{direction!r} is not up or down", path, f"line {number}: direction")
        if not cell["dof"]:
            raise InputError("no DOF name", path, f"line {number}: dof")
        if dof_name_problem(cell["dof"]):      # at its row, before it is compared with any other
            raise InputError(dof_name_problem(cell["dof"]), path, f"line {number}: dof")
        lines = runs.setdefault((control, direction), {}).setdefault(cell["dof"], _Lines(number))
        hz = _number(cell["frequency_hz"], path, number, "frequency_hz")
        if hz > 0 and frequency_problem(hz):   # (0 Hz and below: refused in the words of a receptance line)
            raise InputError(f"{cell['frequency_hz']} is {frequency_problem(hz)}", path, f"line {number}: frequency_hz")
        lines.frequency.append(hz)
        lines.rows.append(number)
        lines.cells.append(written_dof)
        lines.value.append(complex(_number(cell["re"], path, number, "re"), _number(cell["im"], path, number, "im")))
        _status(cell, lines, path, number)
        if cell.get("std"):                # an empty cell: a run without standard deviations (all its rows)
            std = _number(cell["std"], path, number, "std")
            if std < 0:         # the session's rule (app/session/checks.py): 0 where a line shows no scatter
                raise InputError(f"{std!r} is not a standard deviation >= 0", path, f"line {number}: std")
            lines.std.append(std)
        _measured_force(cell, lines, path, number)
    if not runs:
        raise InputError("no data rows after the header", path, f"line {header_row}")
    for (control, direction), dofs in runs.items():
        for dof, lines in dofs.items():
            _check_lines(path, dof, control.label(), lines)
    _check_levels(path, runs)
    out = [_run(path, control, direction, dofs, options) for (control, direction), dofs in runs.items()]
    return [in_sweep_order(r) for r in out], [",".join(rows[header_row - 1][1])], []


def _key(hz: float) -> str:
    return f"{hz:.12g}"          # one line, as the DOFs of a level are compared (to 1e-12)


def _check_lines(path: str, dof: str, level: str, lines: _Lines) -> None:
    """The lines of one DOF at one level, each named by its file line: above 0 Hz, each once, rising or falling
    strictly (the order of the rows is the order measured)."""
    seen: dict[str, int] = {}
    for k, (hz, row) in enumerate(zip(lines.frequency, lines.rows)):
        if hz <= 0:
            raise InputError(f"{hz!r} Hz: receptance lines must be above 0 Hz", path, f"line {row}: frequency_hz")
        if _key(hz) in seen:
            first = seen[_key(hz)]
            spelt = {repr(c) for c in (lines.cells[k], lines.cells[lines.rows.index(first)]) if c != dof}
            note = f" (the dof cell {' and '.join(sorted(spelt))} is read as {dof!r}: spaces around a name are " \
                   "dropped)" if spelt else ""
            raise InputError(f"dof {dof} at {level} has {hz!r} Hz on line {first} already{note}: one row a line, DOF "
                             "and level", path, f"line {row}: frequency_hz")
        seen[_key(hz)] = row
        if k >= 2 and (hz - lines.frequency[k - 1]) * (lines.frequency[1] - lines.frequency[0]) < 0:
            raise InputError(f"{hz!r} Hz after {lines.frequency[k - 1]!r} Hz (line {lines.rows[k - 1]}) among the rows "
                             f"of dof {dof} at {level}, which {'rise' if lines.frequency[1] > lines.frequency[0] else 'fall'}"
                             ": the lines of a run rise or fall strictly (a row out of place?)", path,
                             f"line {row}: frequency_hz")


def _check_levels(path: str, runs: dict) -> None:
    """Every DOF of a level has the same lines. A line one DOF lacks that it has at another level is a row
    whose level columns split its level: that row is named, with the column that differs."""
    for (control, direction), dofs in runs.items():
        union = {}
        for dof, lines in dofs.items():
            for hz, row in zip(lines.frequency, lines.rows):
                union.setdefault(_key(hz), (hz, dof, row))
        for dof, lines in dofs.items():
            have = {_key(hz) for hz in lines.frequency}
            lacking = [v for k, v in union.items() if k not in have]
            if not lacking:
                continue
            hz, other, other_row = lacking[0]
            for (control2, direction2), dofs2 in runs.items():
                elsewhere = dofs2.get(dof)
                if elsewhere is None or (control2, direction2) == (control, direction):
                    continue
                rows = [r for f, r in zip(elsewhere.frequency, elsewhere.rows) if _key(f) == _key(hz)]
                if rows:
                    column = "direction" if control2 == control else \
                        "force_n" if control.mode == control2.mode == "force" else "control_target"
                    theirs, its = control.label(), control2.label()
                    if direction2 != direction:
                        theirs, its = f"{theirs} ({direction or 'no direction'})", f"{its} ({direction2 or 'none'})"
                    raise InputError(f"the row of dof {dof} at {hz!r} Hz holds level {its}, while the other rows of its "
                                     f"run hold {theirs} -- where dof {dof} then has no row at {hz!r} Hz and dof "
                                     f"{other} has one (line {other_row}): a row's level columns must be its run's",
                                     path, f"line {rows[0]}: {column}")
            raise InputError(f"dof {dof} at {control.label()} has no row at {hz!r} Hz, which dof {other} has: every "
                             "DOF of a level has the same lines (a row missing?)", path, f"line {other_row}: dof")


def _control(cell: dict, path: str, row: int, excitation: str) -> Control:
    """The level of a row: a force level (``force_n``), or the response held where ``control_target`` is given."""
    if not cell.get("control_target"):
        held = [c for c in ("control_quantity", "control_dof") if cell.get(c)]
        if held:                # the words of every door (analysis/common/quantities.py)
            raise InputError(held_without_target("control_target = <amplitude>"), path, f"line {row}: {held[0]}")
        if not cell["force_n"]:
            raise InputError("no force level", path, f"line {row}: force_n")
        force = _number(cell["force_n"], path, row, "force_n")
        if force <= 0:
            raise InputError(f"{cell['force_n']!r} is not a force amplitude > 0 N", path, f"line {row}: force_n")
        if force_problem(force):       # the plan's words, at the row that gives it
            raise InputError(force_problem(force), path, f"line {row}: force_n")
        return Control("force", excitation, "force", force)
    if cell["force_n"]:
        raise InputError(force_and_response("control_target"), path, f"line {row}: force_n")
    target = _number(cell["control_target"], path, row, "control_target")
    if target <= 0:
        raise InputError(f"{cell['control_target']!r} is not an amplitude > 0", path, f"line {row}: control_target")
    quantity = cell.get("control_quantity", "").lower()
    if quantity not in RESPONSE_QUANTITIES:
        raise InputError(f"{quantity!r} is not one of {', '.join(RESPONSE_QUANTITIES)} (the response held)", path,
                         f"line {row}: control_quantity")
    if response_target_problem(quantity, target):      # the range of every door (quantities.py)
        raise InputError(response_target_problem(quantity, target), path, f"line {row}: control_target")
    dof = cell.get("control_dof", "")
    if not dof:
        raise InputError("no DOF named for the response held", path, f"line {row}: control_dof")
    if not cell.get("force_amplitude_n"):
        raise InputError("a response-controlled level needs the force measured at each line", path,
                         f"line {row}: force_amplitude_n")
    return Control("response", dof, quantity, target)


def _status(cell: dict, lines: _Lines, path: str, row: int) -> None:
    """The run's status from the optional ``status`` column: one word for every row of a run."""
    if "status" not in cell:
        return
    word = cell["status"].lower() or "complete"
    if word not in STATUSES:
        raise InputError(f"{cell['status']!r} is not one of {', '.join(STATUSES)}", path, f"line {row}: status")
    if lines.status is not None and word != lines.status:
        raise InputError(f"status {word} differs from {lines.status} at line {lines.status_row} of the same run: "
                         "one status a run", path, f"line {row}: status")
    if lines.status is None:
        lines.status, lines.status_row = word, row


def _measured_force(cell: dict, lines: _Lines, path: str, row: int) -> None:
    """The force measured at the row's line (optional columns): amplitude > 0 N and its phase."""
    if cell.get("force_amplitude_n"):
        amplitude = _number(cell["force_amplitude_n"], path, row, "force_amplitude_n")
        if amplitude <= 0:
            raise InputError(f"{cell['force_amplitude_n']!r} is not a force amplitude > 0 N", path,
                             f"line {row}: force_amplitude_n")
        if force_problem(amplitude):         # the rules of every door (analysis/common/quantities.py)
            raise InputError(force_problem(amplitude), path, f"line {row}: force_amplitude_n")
        lines.force_amplitude.append(amplitude)
    if cell.get("force_phase_rad"):
        phase = _number(cell["force_phase_rad"], path, row, "force_phase_rad")
        if phase_problem(phase):
            raise InputError(phase_problem(phase), path, f"line {row}: force_phase_rad")
        lines.force_phase.append(phase)


def _run(path: str, control: Control, direction: str | None, dofs: dict[str, _Lines],
         options: SourceOptions) -> ImportedRun:
    first_dof, first = next(iter(dofs.items()))
    freq = np.array(first.frequency)
    frf, arrays = {}, {}
    level = control.label()
    for dof, lines in dofs.items():
        f = np.array(lines.frequency)      # each DOF's lines are checked, by file line, in _check_lines
        if len(f) != len(freq) or not np.allclose(f, freq, rtol=1e-12):
            raise InputError(f"dof {dof} at {level} has other lines than dof {first_dof} (line "
                             f"{first.first_row}): a level or line is missing", path,
                             f"line {lines.first_row}: frequency_hz")
        frf[dof] = np.array(lines.value)
        if lines.std and len(lines.std) != len(lines.frequency):
            raise InputError(f"dof {dof} at {level}: std is given on {len(lines.std)} of its {len(lines.frequency)} "
                             "lines; give it on every line or none", path, f"line {lines.first_row}: std")
        if lines.std:
            arrays[f"frf_std/{dof}"] = ("m/N", np.array(lines.std))
    problem = control_dof_problem(control.mode, control.dof, dofs, options.excitation)
    if problem:
        raise InputError(problem, path, f"line {first.first_row}: control_dof")
    statuses = {lines.status for lines in dofs.values()}
    if len(statuses) > 1:
        raise InputError(f"the DOFs at {level} give different statuses ({', '.join(sorted(map(str, statuses)))}): "
                         "one status a run", path, f"line {first.first_row}: status")
    status = statuses.pop() or "complete"
    arrays.update(_force_arrays(path, dofs, level))
    force = control.target
    if control.mode == "response":
        force = float(np.median(arrays["force_amplitude"][1]))
    kind = KINDS[options.kind or "sine"]
    if (freq <= 0).any():
        raise InputError("a line at 0 Hz or below: receptance lines must be above 0 Hz", path,
                         f"line {first.first_row}: frequency_hz")
    direction = "none" if kind == "random" else sweep_direction(freq, direction or options.direction)
    if kind == "random":
        name = "random"
    elif control.mode == "response":
        name = response_run_name(control, direction)
    else:
        name = sine_run_name(force, direction)
    return ImportedRun(name, kind, force, direction, options.excitation, freq, frf, arrays, status=status,
                       source=path, records=[lines.first_row for lines in dofs.values()], control=control)


def _force_arrays(path: str, dofs: dict[str, _Lines], level: str) -> dict[str, tuple[str, np.ndarray]]:
    """``force_amplitude`` (N) and ``force_phase`` (rad) per line, where the rows give them: every row of a line
    (one per DOF) gives the same force, it being one force."""
    out = {}
    for name, column, unit in (("force_amplitude", "force_amplitude_n", "N"), ("force_phase", "force_phase_rad",
                                                                                "rad")):
        given = [(dof, getattr(lines, name)) for dof, lines in dofs.items()]
        if not any(values for _, values in given):
            continue
        first_dof, first = given[0]
        for dof, values in given:
            lines = dofs[dof]
            if len(values) != len(lines.frequency):
                raise InputError(f"dof {dof} at {level}: {column} is given on {len(values)} of its "
                                 f"{len(lines.frequency)} lines; give it on every line or none", path,
                                 f"line {lines.first_row}: {column}")
            differ = np.flatnonzero(~np.isclose(values, first, rtol=1e-9, atol=0))
            if differ.size:
                k = int(differ[0])
                raise InputError(f"dof {dof} at {level} has {column} {values[k]!r}, dof {first_dof} {first[k]!r} (line "
                                 f"{dofs[first_dof].rows[k]}) at {lines.frequency[k]!r} Hz: one force a line", path,
                                 f"line {lines.rows[k]}: {column}")
        out[name] = (unit, np.array(first, float))
    return out
