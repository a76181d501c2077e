"""contactid's own per-run CSV (``export --csv``) read back, so that CSV export -> import gives the analysis the
same numbers (docs/import.md, "CSV export, read back").

Row 1 is a sentence for people; row 2 (``MARK``) holds ``key=value`` words -- run, kind, exact force, direction,
status, excitation, for a random run sample_rate and segment_length, and for a level not held at its force the
control words of the UFF id lines (:data:`.idlines.CONTROL_TAGS`); row 3 names the columns
``frequency [Hz]``, ``Re frf <dof> [m/N]`` / ``Im frf <dof> [m/N]`` and ``<quantity> [<unit>]`` (``Re``/``Im``
for complex ones). The FRFs and the per-line quantities a UFF export carries (:data:`.uff.LINE_QUANTITIES`)
are read; the other columns (the controller's own records) stay in the CSV, and the import lists them.
"""
from __future__ import annotations

import csv
import math
import re

import numpy as np

from analysis.common.errors import InputError

from .idlines import DIRECTIONS, KINDS, read_control
from .runs import ImportedRun, check_axis, csv_float

MARK = "# contactid-run"
KEYS = ("run", "kind", "force", "direction", "status", "excitation")
PER_LINE = re.compile(r"^(frf_std|coherence|random_error)/\S+$"
                      r"|^(force_amplitude|force_phase|force_phasor|distortion)$")
_COLUMN = re.compile(r"^(?:(Re|Im) )?(.+?) \[(.*)\]$")


def is_run_csv(path: str) -> bool:
    """True when the file's second row is contactid's run line (a CSV ``export --csv`` wrote)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = [row for _, row in zip(range(2), csv.reader(fh))]
    except (OSError, UnicodeDecodeError, csv.Error):
        return False
    return len(rows) == 2 and len(rows[1]) == 1 and rows[1][0].startswith(MARK + " ")


def _run_words(text: str, path: str) -> dict[str, str]:
    words = dict(w.split("=", 1) for w in text[len(MARK):].split() if "=" in w)
    for key in KEYS:
        if key not in words:
            raise InputError(f"the run line has no {key}=", path, "line 2")
    if words["kind"] not in KINDS or words["direction"] not in DIRECTIONS:
        raise InputError(f"kind={words['kind']} direction={words['direction']} are not a run's (kinds: "
                         f"{', '.join(KINDS)}; directions: {', '.join(DIRECTIONS)})", path, "line 2")
    return words


def _positive(words: dict, key: str, path: str, whole: bool = False) -> float:
    text = words[key]
    try:
        value = csv_float(text)
    except ValueError:
        raise InputError(f"{key}={text!r} is not a number", path, "line 2") from None
    if not (math.isfinite(value) and value > 0) or (whole and not text.isdigit()):
        raise InputError(f"{key}={text} is not {'a whole number' if whole else 'a number'} > 0", path, "line 2")
    return value


def _table(rows: list[list[str]], width: int, path: str, numbers: list[int]) -> np.ndarray:
    """The numbers below the column row, as floats (``numbers``: each row's line from 1 in the file)."""
    values = np.empty((len(rows), width))
    for i, row in enumerate(rows):
        line = numbers[i]
        if len(row) != width:
            raise InputError(f"{len(row)} fields, the column row has {width}", path, f"line {line}")
        for j, cell in enumerate(row):
            try:
                values[i, j] = csv_float(cell)
            except ValueError:
                raise InputError(f"{cell!r} is not a number", path, f"line {line}: column {j + 1}") from None
    return values


def read_csv_run(path: str) -> tuple[list[ImportedRun], list[str], list[str]]:
    """The run of one CSV written by ``export --csv``, its run line and notes."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            numbered = [(n, row) for n, row in enumerate(csv.reader(fh), start=1) if row]
        rows, numbers = [row for _, row in numbered], [n for n, _ in numbered]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"cannot be read as CSV ({exc})", path) from None
    if len(rows) < 4:
        raise InputError("has no line below its column row", path)
    words = _run_words(rows[1][0], path)
    force = _positive(words, "force", path)
    table = _table(rows[3:], len(rows[2]), path, numbers[3:])
    columns: dict[str, dict[str, tuple[int, str]]] = {}
    for j, name in enumerate(rows[2]):
        m = _COLUMN.match(name.strip())
        if not m:
            raise InputError(f"column {name!r} is not 'name [unit]'", path, f"line 3: column {j + 1}")
        part, quantity, unit = m.groups()
        columns.setdefault(quantity, {})[part or "value"] = (j, unit)
    if "frequency" not in columns:
        raise InputError("no column 'frequency [Hz]'", path, "line 3")
    frequency = table[:, columns.pop("frequency")["value"][0]]
    try:
        check_axis(frequency, path, "frequency [Hz]")
    except InputError:      # said again by the file line of the row, as every other CSV error is
        _refuse_axis(frequency, path, numbers[3:])
    frf, arrays, left = {}, {}, []
    for quantity, parts in columns.items():
        if quantity.startswith("frf "):
            frf[quantity[4:]] = _values(table, parts, path, quantity, numbers[3:])
        elif PER_LINE.match(quantity):
            arrays[quantity] = (next(iter(parts.values()))[1], _values(table, parts, path, quantity, numbers[3:]))
        else:
            left.append(quantity)
    if not frf:
        raise InputError("no FRF column ('Re frf <dof> [m/N]', 'Im frf <dof> [m/N]')", path, "line 3")
    run = ImportedRun(words["run"], words["kind"], force, words["direction"], words["excitation"], frequency, frf,
                      arrays, status=words["status"], source=path, records=[],
                      control=read_control(words, words["excitation"], force, path, "line 2"))
    if "sample_rate" in words or "segment_length" in words:
        run.sample_rate = _positive(words, "sample_rate", path)
        run.segment_length = int(_positive(words, "segment_length", path, whole=True))
    notes = [f"columns kept only in the CSV (not read by the analysis): {', '.join(left)}"] if left else []
    return [run], [rows[1][0]], notes


def _refuse_axis(frequency: np.ndarray, path: str, numbers: list[int]) -> None:
    """The frequency column's first fault (check_axis found one), named by its file line."""
    for k, hz in enumerate(frequency):
        if not np.isfinite(hz) or hz < 0:
            raise InputError(f"{float(hz)!r} is not a frequency in Hz", path, f"line {numbers[k]}: frequency [Hz]")
        if k and (hz - frequency[k - 1]) * (frequency[1] - frequency[0]) <= 0:
            raise InputError(f"{float(hz)!r} Hz after {float(frequency[k - 1])!r} Hz (line {numbers[k - 1]}): the "
                             "lines of a run rise or fall strictly", path, f"line {numbers[k]}: frequency [Hz]")
    raise InputError("the lines of a run rise or fall strictly", path, "frequency [Hz]")


def _values(table: np.ndarray, parts: dict, path: str, quantity: str, numbers: list[int]) -> np.ndarray:
    """One column, or a complex one from its Re and Im columns (both needed)."""
    if "value" in parts:
        values = table[:, parts["value"][0]]
    elif "Re" in parts and "Im" in parts:
        values = table[:, parts["Re"][0]] + 1j * table[:, parts["Im"][0]]
    else:
        raise InputError(f"{quantity} has {' and '.join(parts)} but not both Re and Im", path, "line 3")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(f"{complex(values[bad[0]]) if np.iscomplexobj(values) else float(values[bad[0]])!r} is not "
                         "a finite number", path, f"line {numbers[int(bad[0])]}: {quantity}")
    return values
