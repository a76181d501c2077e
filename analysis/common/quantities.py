"""Quantities checked at more than one door, each declared once (docs/session-format.md, "Quantities").

The plan, the CSV and UFF imports and the session reader (app/session/checks.py) ask these functions, so that
what one door refuses every door refuses, in the same words:

* a **DOF name** is 1 to :data:`MAX_DOF_NAME` characters, letters, digits and ``_ . + -``, starting with a letter,
  a digit or ``_`` (``x1``, ``A.w``, ``O.theta``). It names an HDF5 dataset (``frf/<dof>``) and a channel
  (``acc:<dof>``): a ``/`` would make nested groups, ``.`` or ``..`` name a group itself, a space or a ``:``
  would not survive the formats;
* a **force amplitude** (N) lies from :data:`FORCE_RANGE`'s 1 uN to 1 MN: outside it no lab shaker drives and no
  force gauge reads, and the analysis of such numbers overflows (a force of 1e300 N) or underflows (1e-300 N);
* a **frequency** (Hz) -- a measured line, a modal structure's natural frequency -- lies from
  :data:`FREQUENCY_RANGE`'s 1 mHz to 1 MHz: beyond it is a damaged dataset or a typing slip, not a vibration;
* a **response target** -- the amplitude a response-controlled level holds -- lies within
  :data:`RESPONSE_RANGE` for its quantity (1 pm to 1 m, 1 nm/s to 1 km/s, 1 um/s^2 to 1e6 m/s^2): below, no
  sensor resolves it; above, no shaker reaches it (a plan holds it below its own ``max_acceleration`` too);
* a **phase** (rad) lies within +-:data:`MAX_PHASE` (2 pi: both the -pi..pi and the 0..2 pi conventions): a phase
  of 1e300 rad has no digit left below one turn;
* a **coherence** lies within :data:`COHERENCE_RANGE` (0 to 1; above 1 by :data:`COHERENCE_ROUNDING` at most);
* a **control DOF** is one the run measures: a response is held where a sensor measures it, a force where the
  excitation (its force gauge) or a sensor is;
* a **level** holds a force or a response, not both; the response's quantity and DOF come with its target
  (:func:`held_without_target`, :func:`force_and_response`: the plan's, the CSV's and the UFF tags' words);
* a **measured force** on a force level (held at its force, or open loop) within :data:`FORCE_LEVEL_FACTOR` of
  the level's force: a force 10^4 times the level's (3000 N on a 0.3 N level) may be real (a gauge's units, a
  level mislabelled) and is noted, not refused.

Each function returns why a value is refused (the words after the field), or None when it is fine.
"""
from __future__ import annotations

import math
import re

import numpy as np

MAX_DOF_NAME = 64
_DOF_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")
FORCE_RANGE = (1e-6, 1e6)       # N: the force amplitudes (and rms forces) a lab applies and measures
FREQUENCY_RANGE = (1e-3, 1e6)   # Hz: a measured line, a natural frequency
MAX_PHASE = 2 * math.pi         # rad: |phase| at most one turn
RESPONSE_RANGE = {              # SI: a response amplitude a level holds, by the quantity held
    "displacement": (1e-12, 1.0),       # m
    "velocity": (1e-9, 1e3),            # m/s
    "acceleration": (1e-6, 1e6),        # m/s^2
}
RESPONSE_UNITS = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}
FORCE_LEVEL_FACTOR = 10.0       # a force measured on a force level beyond level * or / this is noted
COHERENCE_RANGE = (0.0, 1.0)    # 1: an ordinary coherence, |Gxy|^2 / (Gxx Gyy)
COHERENCE_ROUNDING = 1e-9       # above 1 by at most this: the rounding of the spectra's ratio, not a fault


def dof_name_problem(name) -> str | None:
    """Why ``name`` is no DOF name, or None."""
    if not isinstance(name, str) or not name:
        return f"{name!r} is not a DOF name (such as x1 or A.w)"
    if len(name) > MAX_DOF_NAME:
        return f"a DOF name of {len(name)} characters ({name[:16]!r}...); at most {MAX_DOF_NAME}"
    if not _DOF_NAME.fullmatch(name):
        return (f"{name!r} is not a DOF name: letters, digits and _ . + - only, starting with a letter, a digit or _ "
                "(such as x1 or A.w)")
    return None


def force_problem(value) -> str | None:
    """Why ``value`` (N) is no force amplitude a lab applies, or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        return f"{value!r} is not a force amplitude in N"
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        return f"{value!r} is not a force amplitude > 0 N"
    lo, hi = FORCE_RANGE
    if not lo <= value <= hi:
        return f"{value:g} N is outside the forces a lab applies ({lo:g} to {hi:g} N)"
    return None


def forces_outside(values: np.ndarray) -> np.ndarray:
    """Mask of the finite, positive values (N) outside :data:`FORCE_RANGE` (the others are refused as no
    force amplitude at all)."""
    values = np.asarray(values, float)
    lo, hi = FORCE_RANGE
    with np.errstate(invalid="ignore"):
        return np.isfinite(values) & (values > 0) & ((values < lo) | (values > hi))



def response_target_problem(quantity: str, value) -> str | None:
    """Why ``value`` (SI units of ``quantity``: displacement, velocity or acceleration) is no response amplitude a
    level holds, or None (a quantity not among them is the caller's to refuse)."""
    number = _number(value)
    unit = RESPONSE_UNITS.get(quantity, "")
    if number is None or not math.isfinite(number) or number <= 0:
        return f"{value!r} is not a response amplitude > 0 {unit}".rstrip()
    if quantity not in RESPONSE_RANGE:
        return None
    lo, hi = RESPONSE_RANGE[quantity]
    if not lo <= number <= hi:
        return (f"{number:g} {unit} is outside the {quantity} amplitudes a lab holds ({lo:g} to {hi:g} {unit}: "
                "below, no sensor resolves it; above, no shaker reaches it)")
    return None


def _number(value) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        return None
    return float(value)


def frequency_problem(value) -> str | None:
    """Why ``value`` (Hz) is no frequency of a vibration measurement, or None; the words follow "is" (``line 2
    is -1.5 Hz, outside ...``)."""
    number = _number(value)
    lo, hi = FREQUENCY_RANGE
    if number is None:
        return f"{value!r}, not a frequency in Hz"
    if not math.isfinite(number):
        return f"{number!r} Hz, and a frequency must be finite"
    if not lo <= number <= hi:
        return f"{number:g} Hz, outside the frequencies of a vibration measurement ({lo:g} to {hi:g} Hz)"
    return None


def phase_problem(value) -> str | None:
    """Why ``value`` (rad) is no phase, or None."""
    number = _number(value)
    if number is None or not math.isfinite(number):
        return f"{value!r} is not a phase in rad"
    if abs(number) > MAX_PHASE:
        return f"{number:g} rad is not a phase (within -2 pi to 2 pi rad, one turn either way)"
    return None


def phases_outside(values: np.ndarray) -> np.ndarray:
    """Mask of the finite values (rad) beyond +-:data:`MAX_PHASE` (the non-finite ones are refused as no number)."""
    values = np.asarray(values, float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(values) & (np.abs(values) > MAX_PHASE)


def coherences_outside(values: np.ndarray) -> np.ndarray:
    """Mask of the finite values outside :data:`COHERENCE_RANGE` (beyond its rounding allowance)."""
    values = np.asarray(values, float)
    lo, hi = COHERENCE_RANGE
    with np.errstate(invalid="ignore"):
        return np.isfinite(values) & ((values < lo) | (values > hi + COHERENCE_ROUNDING))


def coherence_problem(value) -> str | None:
    """Why ``value`` is no coherence, or None."""
    number = _number(value)
    lo, hi = COHERENCE_RANGE
    if number is None or not math.isfinite(number):
        return f"{value!r} is not a coherence"
    if coherences_outside(np.array([number])).any():
        return f"{number:g} is not a coherence (from {lo:g} to {hi:g})"
    return None


def control_dof_problem(mode: str, dof: str, sensor_dofs, excitation_dof: str) -> str | None:
    """Why a level held (``mode``) at ``dof`` cannot be, by a run that measures ``sensor_dofs`` and has its force
    gauge at ``excitation_dof``, or None."""
    sensors = list(sensor_dofs)
    if mode == "response":
        if dof not in sensors:
            return (f"the response is held at {dof}, which no sensor of the run measures (sensors: "
                    f"{', '.join(sensors)})")
        return None
    if dof != excitation_dof and dof not in sensors:
        return (f"the level is held at {dof}, which the run does not measure (excitation {excitation_dof}, sensors: "
                f"{', '.join(sensors)})")
    return None


def force_level_note(measured: np.ndarray, level: float) -> str | None:
    """Where a force level's measured force (N per line) lies beyond :data:`FORCE_LEVEL_FACTOR` of the level:
    the words of a note, or None."""
    measured = np.asarray(measured, float)
    with np.errstate(all="ignore"):
        ratio = measured / float(level)
        far = np.flatnonzero(np.isfinite(ratio) & ((ratio > FORCE_LEVEL_FACTOR) | (ratio < 1 / FORCE_LEVEL_FACTOR)))
    if not far.size:
        return None
    i = int(far[np.argmax(np.abs(np.log(ratio[far])))])
    return (f"the force measured at {far.size} of {measured.size} line(s) is more than {FORCE_LEVEL_FACTOR:g} times "
            f"off the level's {float(level):g} N (line {i}: {measured[i]:g} N, {ratio[i]:.3g} times): check the "
            "force gauge's units and the level")


def held_without_target(give: str) -> str:
    """The words for a response's quantity, DOF or target given without the rest of it, ``give`` what is missing
    as the door names it (the plan's ``response = <amplitude>``, the CSV's ``control_target = <amplitude>``, the
    UFF tags' ``control=response``)."""
    return f"belongs to a response-controlled level: give {give} too"


def force_and_response(target: str) -> str:
    """The words for a level given both a force and a response target (``target`` as the door names it)."""
    return f"a level holds either a force or a response amplitude ({target}), not both"
