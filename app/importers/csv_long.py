"""The CSV long format: one row per line, force level and DOF (docs/import.md).

A header row names the columns ``frequency_hz, force_n, dof, re, im`` (receptance X/F, m/N, exp(+jwt)) and
optionally ``std`` (its standard deviation sqrt(E|n|^2), m/N) and ``direction`` (up/down); lines starting with
``#`` before the header are comments. Rows of one force level (and direction) form one run, in the order given;
every DOF of a run must have the same lines.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field

import numpy as np

from analysis.errors import InputError

from .runs import KINDS, ImportedRun, SourceOptions, check_axis, in_sweep_order, sine_run_name, sweep_direction

REQUIRED = ("frequency_hz", "force_n", "dof", "re", "im")
OPTIONAL = ("std", "direction")


@dataclass
class _Lines:
    """The rows of one DOF in one run."""

    first_row: int
    frequency: list[float] = field(default_factory=list)
    value: list[complex] = field(default_factory=list)
    std: list[float] = field(default_factory=list)


def _number(text: str, path: str, row: int, column: str) -> float:
    try:
        if "_" in text:                      # Python reads 1_000 as 1000; no CSV writer means that
            raise ValueError
        value = float(text)
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
    runs: dict[tuple[float, str | None], dict[str, _Lines]] = {}
    for number, row in rows[header_row:]:
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(columns):
            raise InputError(f"{len(row)} fields, the header has {len(columns)}", path, f"line {number}")
        cell = dict(zip(columns, (c.strip() for c in row)))
        if not cell["force_n"]:
            raise InputError("no force level", path, f"line {number}: force_n")
        force = _number(cell["force_n"], path, number, "force_n")
        if force <= 0:
            raise InputError(f"{cell['force_n']!r} is not a force amplitude > 0 N", path, f"line {number}: force_n")
        direction = cell.get("direction") or None
        if direction not in (None, "up", "down"):
            raise InputError(f"{direction!r} is not up or down", path, f"line {number}: direction")
        if not cell["dof"]:
            raise InputError("no DOF name", path, f"line {number}: dof")
        lines = runs.setdefault((force, direction), {}).setdefault(cell["dof"], _Lines(number))
        lines.frequency.append(_number(cell["frequency_hz"], path, number, "frequency_hz"))
        lines.value.append(complex(_number(cell["re"], path, number, "re"), _number(cell["im"], path, number, "im")))
        if "std" in cell:
            std = _number(cell["std"], path, number, "std")
            if std <= 0:
                raise InputError(f"{std!r} is not a standard deviation > 0", path, f"line {number}: std")
            lines.std.append(std)
    if not runs:
        raise InputError("no data rows after the header", path, f"line {header_row}")
    out = [_run(path, force, direction, dofs, options) for (force, direction), dofs in runs.items()]
    return [in_sweep_order(r) for r in out], [",".join(rows[header_row - 1][1])], []


def _run(path: str, force: float, direction: str | None, dofs: dict[str, _Lines],
         options: SourceOptions) -> ImportedRun:
    first_dof, first = next(iter(dofs.items()))
    freq = np.array(first.frequency)
    frf, arrays = {}, {}
    for dof, lines in dofs.items():
        f = np.array(lines.frequency)
        check_axis(f, path, f"line {lines.first_row}: frequency_hz (dof {dof}, force {force:g} N)")
        if len(f) != len(freq) or not np.allclose(f, freq, rtol=1e-12):
            raise InputError(f"dof {dof} at {force:g} N has other lines than dof {first_dof} (line "
                             f"{first.first_row}): a level or line is missing", path,
                             f"line {lines.first_row}: frequency_hz")
        frf[dof] = np.array(lines.value)
        if lines.std:
            arrays[f"frf_std/{dof}"] = ("m/N", np.array(lines.std))
    kind = KINDS[options.kind or "sine"]
    if (freq <= 0).any():
        raise InputError("a line at 0 Hz or below: receptance lines must be above 0 Hz", path,
                         f"line {first.first_row}: frequency_hz")
    direction = "none" if kind == "random" else sweep_direction(freq, direction or options.direction)
    name = "random" if kind == "random" else sine_run_name(force, direction)
    return ImportedRun(name, kind, force, direction, options.excitation, freq, frf, arrays, source=path,
                       records=[lines.first_row for lines in dofs.values()])
