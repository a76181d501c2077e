"""What an import produces before anything is written: runs, options, DOF maps (docs/import.md)."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from analysis.common.errors import InputError
from analysis.common.measurements import Control
from analysis.common.quantities import dof_name_problem

KINDS = {"sine": "stepped_sine", "random": "random"}
DIRECTION_CODES = {"X": 1, "Y": 2, "Z": 3, "RX": 4, "RY": 5, "RZ": 6}
_DOF_MAP = re.compile(r"^(\d+)(?:([+-])(RX|RY|RZ|X|Y|Z|[1-6]))?=(\S+)$", re.IGNORECASE)


@dataclass(frozen=True)
class DofMap:
    """``--dof NODE[+DIR]=NAME``: a UFF node (and direction, signed) named as a model DOF."""

    node: int
    direction: int | None        # 1..6, signed; None: any direction of the node
    name: str

    def matches(self, node: int, direction: int) -> bool:
        return node == self.node and (self.direction is None or abs(direction) == abs(self.direction))

    def sign(self, direction: int) -> float:
        """-1 where the file's direction points against the mapped one (the FRF changes sign)."""
        wanted = 1 if self.direction is None else self.direction
        return -1.0 if (direction < 0) != (wanted < 0) else 1.0


def parse_dof_map(text: str) -> DofMap:
    """``3+Z=A.w``, ``3-RY=A.theta``, ``12=x2`` (node alone: any direction)."""
    m = _DOF_MAP.match(text.strip())
    if not m:
        raise InputError(f"--dof takes NODE[+DIR]=NAME with DIR one of X Y Z RX RY RZ or 1..6 (e.g. 3+Z=A.w), "
                         f"got {text!r}", field="--dof")
    node, sign, direction, name = m.groups()
    if dof_name_problem(name):          # the rule of every door (analysis/common/quantities.py)
        raise InputError(f"{text.strip()}: {dof_name_problem(name)}", field="--dof")
    if direction is None:
        return DofMap(int(node), None, name)
    code = int(direction) if direction.isdigit() else DIRECTION_CODES[direction.upper()]
    return DofMap(int(node), -code if sign == "-" else code, name)


@dataclass
class SourceOptions:
    """What the command line (or the GUI) says about one file, where the file does not say it."""

    kind: str | None = None              # "sine" | "random"; default: the file's tags, else sine
    force: float | None = None           # N
    direction: str | None = None         # "up" | "down"
    dofs: list[DofMap] = field(default_factory=list)
    excitation: str | None = None
    records: list[int] | None = None     # UFF records to import (numbers from 1 in file order); None: all
    force_sign: float = 1.0              # -1: the file's force is reversed against exp(+jwt) (docs/import.md)

    def __post_init__(self):
        if self.excitation is not None and dof_name_problem(self.excitation):     # the rule of every door
            raise InputError(dof_name_problem(self.excitation), field="--excitation")
        named: dict[tuple[int, int | None], str] = {}
        for m in self.dofs:
            earlier = named.setdefault((m.node, m.direction), m.name)
            if earlier != m.name:
                where = f"{m.node}" + ("" if m.direction is None else f"{'-' if m.direction < 0 else '+'}"
                                                                       f"{abs(m.direction)}")
                raise InputError(f"node {where} is mapped twice, to {earlier} and to {m.name}", field="--dof")

    def dof_name(self, node: int, direction: int) -> tuple[str, float] | None:
        """The mapped DOF name and the sign of a file's node and direction (None when not mapped)."""
        for m in self.dofs:
            if m.direction is not None and m.matches(node, direction):
                return m.name, m.sign(direction)
        for m in self.dofs:
            if m.matches(node, direction):
                return m.name, 1.0 if direction >= 0 else -1.0
        return None


@dataclass
class ImportedRun:
    """One run read from a file, ready for the session writer (all in SI, receptance m/N).

    ``arrays`` holds further per-line quantities by their session name (``frf_std/<dof>``, ``coherence/<dof>``,
    ``force_amplitude``, ``distortion``, ...) with their units."""

    name: str
    kind: str                            # "stepped_sine" | "random"
    force: float
    direction: str                       # "up" | "down" | "none"
    excitation_dof: str
    frequency: np.ndarray
    frf: dict[str, np.ndarray]
    arrays: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)
    status: str = "complete"
    source: str = ""
    records: list[int] = field(default_factory=list)
    raw: "RawRecord | None" = None
    sample_rate: float = 0.0             # Hz; with segment_length, a random run's Welch resolution
    segment_length: int = 0              # samples per Welch segment (0: not known)
    load_case: int | None = None         # the UFF load case of another system's FRFs (None: tagged or CSV)
    control: Control | None = None       # None: force control at ``force``


@dataclass
class RawRecord:
    """Time histories kept with a run imported from them."""

    channels: list[str]
    units: list[str]
    data: np.ndarray                     # (samples, channels)


@dataclass
class SourceFile:
    """Everything read from one file: its runs and what ``/provenance/import`` keeps of it."""

    path: str
    format: str
    size: int
    sha256: str
    id_lines: list[list[str]]
    runs: list[ImportedRun]
    notes: list[str]
    force_sign: float = 1.0              # applied to every FRF of the file (--force-sign)


def csv_float(text: str) -> float:
    """A CSV cell as a number, as ``float`` reads it but without digit groups: Python reads ``1_000`` as 1000,
    and no CSV writer means that. ValueError when it is no number."""
    if "_" in text:
        raise ValueError(text)
    return float(text)


def check_axis(x: np.ndarray, where: str, field_name: str) -> None:
    """Finite, positive, strictly monotonic frequencies (one direction), else an error naming the line."""
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise InputError(f"line {int(bad[0])} is {float(x[bad[0]])!r}, not a number", where, field_name)
    bad = np.flatnonzero(x < 0)
    if bad.size:
        raise InputError(f"line {int(bad[0])} is {float(x[bad[0]])!r} Hz, a negative frequency", where, field_name)
    if len(x) > 1:
        step = np.diff(x)
        wrong = np.flatnonzero(step * np.sign(step[0]) <= 0) if step[0] != 0 else np.array([0])
        if wrong.size:
            i = int(wrong[0])
            raise InputError(f"frequencies out of order at line {i + 1} ({float(x[i])!r} then {float(x[i + 1])!r} "
                             "Hz): lines must rise or fall strictly", where, field_name)


def check_values(values: np.ndarray, where: str, field_name: str) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputError(f"line {int(bad[0])} is {complex(values[bad[0]])!r}, not a finite number", where,
                         field_name)


def sweep_direction(x: np.ndarray, given: str | None) -> str:
    """The sweep direction: as given, else from the order of the lines (rising: up)."""
    if given:
        return given
    return "down" if len(x) > 1 and x[1] < x[0] else "up"


def in_sweep_order(run: ImportedRun) -> ImportedRun:
    """Lines in the order a sweep in ``run.direction`` measures them (an exporter may have sorted them)."""
    if run.kind != "stepped_sine" or len(run.frequency) < 2:
        return run
    rising = run.frequency[1] > run.frequency[0]
    if rising == (run.direction == "up"):
        return run
    run.frequency = run.frequency[::-1].copy()
    run.frf = {d: v[::-1].copy() for d, v in run.frf.items()}
    run.arrays = {k: (u, v[::-1].copy()) for k, (u, v) in run.arrays.items()}
    return run


def parse_records(text: str) -> list[int]:
    """``--records 1,3`` (record numbers from 1, in file order)."""
    words = [w.strip() for w in text.split(",")]
    if not words or not all(w.isdigit() and int(w) > 0 for w in words):
        raise InputError(f"--records takes record numbers from 1 separated by commas (e.g. 1,3), got {text!r}",
                         field="--records")
    return [int(w) for w in words]


def sine_run_name(force: float, direction: str) -> str:
    """The name an acquired session gives a stepped-sine run (docs/session-format.md)."""
    return f"sine_{force:g}N_{direction}"


UNIT_TOKENS = {"displacement": "m", "velocity": "mps", "acceleration": "mps2"}


def response_run_name(control: Control, direction: str) -> str:
    """The name of a response-controlled stepped-sine level: ``sine_x1_20mps2_up`` (docs/session-format.md)."""
    return f"sine_{control.dof}_{control.target:g}{UNIT_TOKENS[control.quantity]}_{direction}"
