"""UFF58 ordinates to receptance: specific data types, unit labels and the exp(+jwt) convention.

A response over force is converted to receptance X/F (m/N) by the unit labels' factors to SI and, for velocity
and acceleration, by ``V = jw X`` and ``A = -w^2 X``. A label the file leaves empty ("NONE") takes the file's
units dataset 164 with the record's length and force exponents, or SI without one (the import says which); a
label not in the tables is refused.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.common.errors import InputError

G = 9.80665
INCH = 0.0254
LBF = 4.4482216152605

DISPLACEMENT, VELOCITY, ACCELERATION = 8, 11, 12
FORCES = (9, 13)                       # reaction force, excitation force
RESPONSES = {DISPLACEMENT: "displacement", VELOCITY: "velocity", ACCELERATION: "acceleration"}
PREFIX = {DISPLACEMENT: "disp", VELOCITY: "vel", ACCELERATION: "acc"}
SI_UNITS = {DISPLACEMENT: "m", VELOCITY: "m/s", ACCELERATION: "m/s^2", 9: "N", 13: "N"}

_LENGTH = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "in": INCH, "rad": 1.0, "deg": np.pi / 180}
_SCALE = {
    DISPLACEMENT: _LENGTH,
    VELOCITY: {f"{u}/s": v for u, v in _LENGTH.items()},
    ACCELERATION: {**{f"{u}/s{p}": v for u, v in _LENGTH.items() for p in ("^2", "2", "**2", "²")},
                   "g": G, "g0": G, "gn": G},
    9: {"n": 1.0, "kn": 1e3, "lbf": LBF},
    13: {"n": 1.0, "kn": 1e3, "lbf": LBF},
}


@dataclass
class FileUnits:
    """A file's units (dataset 164): SI = value / factor for length and force."""

    length: float
    force: float

    def to_si(self, length_exp: int, force_exp: int) -> float:
        return float(self.length) ** -int(length_exp) * float(self.force) ** -int(force_exp)


def file_default(units: FileUnits | None, fields: dict, axis: str) -> float | None:
    """SI factor of a record's axis (``ordinate``, ``orddenom``) whose unit label is empty: the file's dataset
    164 with the axis's length and force exponents; None without a dataset 164."""
    if units is None:
        return None
    return units.to_si(fields.get(f"{axis}_len_unit_exp", 0), fields.get(f"{axis}_force_unit_exp", 0))


@dataclass
class Scaled:
    """A unit label read: its factor to SI and whether it was assumed."""

    factor: float
    assumed: bool


def unit_factor(data_type: int, label: str, where: str, field_name: str, default: float | None = None) -> Scaled:
    """Factor from the file's unit to SI for a specific data type (an empty label: ``default``, else SI)."""
    text = (label or "").strip()
    if text.upper() in ("", "NONE"):
        return Scaled(1.0 if default is None else default, default is None)
    table = _SCALE[data_type]
    key = text if text in table else text.lower()
    if key not in table:
        raise InputError(f"unit {text!r} not known for {RESPONSES.get(data_type, 'force')} "
                         f"(known: {', '.join(sorted(table))})", where, field_name)
    return Scaled(table[key], False)


def to_receptance(values: np.ndarray, frequency_hz: np.ndarray, data_type: int) -> np.ndarray:
    """Displacement, velocity or acceleration per force (SI) to receptance (exp(+jwt): V = jw X, A = -w^2 X)."""
    w = 2 * np.pi * np.asarray(frequency_hz, float)
    if data_type == VELOCITY:
        return values / (1j * w)
    if data_type == ACCELERATION:
        return values / -(w ** 2)
    return values
