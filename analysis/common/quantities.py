"""Quantities checked at more than one door, each declared once (docs/session-format.md, "Quantities").

The plan, the CSV and UFF imports and the session reader (app/session/checks.py) ask these functions, so that
what one door refuses every door refuses, in the same words:

* a **DOF name** is 1 to :data:`MAX_DOF_NAME` characters, letters, digits and ``_ . + -``, starting with a letter,
  a digit or ``_`` (``x1``, ``A.w``, ``O.theta``). It names an HDF5 dataset (``frf/<dof>``) and a channel
  (``acc:<dof>``): a ``/`` would make nested groups, ``.`` or ``..`` name a group itself, a space or a ``:``
  would not survive the formats;
* a **force amplitude** (N) lies from :data:`FORCE_RANGE`'s 1 uN to 1 MN: outside it no lab shaker drives and no
  force gauge reads, and the analysis of such numbers overflows (a force of 1e300 N) or underflows (1e-300 N).

Each function returns why a value is refused (the words after the field), or None when it is fine.
"""
from __future__ import annotations

import math
import re

import numpy as np

MAX_DOF_NAME = 64
_DOF_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")
FORCE_RANGE = (1e-6, 1e6)       # N: the force amplitudes (and rms forces) a lab applies and measures


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
