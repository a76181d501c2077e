"""The sign and unit conventions of imported FRFs, checked on the drive point (docs/import.md, "Conventions").

Under ``x = X sin wt`` (phasor ``exp(+jwt)``, docs/contracts.md §1) a passive structure takes energy from the
force at its drive point: the mean power ``w |F|^2 (-Im H) / 2`` is >= 0 at every line, so Im of a drive-point
receptance is negative (the phase about -pi/2 at a resonance). A file whose force sign is reversed (or whose
accelerance was stored as a receptance) has Im H > 0 throughout; a mobility stored as a receptance has
``Im V = w Re X``, positive below a resonance and negative above. The sign of Im H is judged over all lines,
weighted by |Im H| (noise at lines with little damping counts little). Nothing is guessed: the import refuses
with the flag that flips the sign (``--force-sign -1``) or the unit to check, and the sign applied is kept in the
session's import provenance.
"""
from __future__ import annotations

import numpy as np

from analysis.common.errors import InputError

from .runs import ImportedRun

# S = sum Im H / sum |Im H| over the lines: -1 for a receptance. Above +OUTWARD the energy flows out (a reversed
# force); between -MIXED and +OUTWARD it flows in at some lines and out at others (not a receptance)
OUTWARD = 0.5
MIXED = 0.5
# Im H smaller than this fraction of |H| at every line: the lines hold no damping to judge a sign by
SILENT_IM = 1e-3


def apply_force_sign(run: ImportedRun, sign: float) -> None:
    """The run as measured with the force's sign reversed (sign -1): every FRF changes sign, the force's phase
    turns by pi, its amplitude stays."""
    if sign == 1.0:
        return
    run.frf = {dof: -values for dof, values in run.frf.items()}
    if "force_phase" in run.arrays:
        unit, phase = run.arrays["force_phase"]
        run.arrays["force_phase"] = (unit, np.angle(np.exp(1j * (phase + np.pi))))
    if "force_phasor" in run.arrays:
        unit, phasor = run.arrays["force_phasor"]
        run.arrays["force_phasor"] = (unit, -phasor)


def energy_sign(h: np.ndarray) -> float | None:
    """``sum Im H / sum |Im H|``: -1 when energy flows into the structure at every line, +1 when out at every
    line; None when Im H is negligible at every line."""
    im = np.asarray(h).imag
    if np.abs(im).max(initial=0.0) <= SILENT_IM * np.abs(h).max(initial=0.0):
        return None
    return float(im.sum() / np.abs(im).sum())


def check_drive_point(run: ImportedRun, path: str, force_sign: float) -> None:
    """Refuse a drive-point receptance whose imaginary part says energy flows out of the structure, or flows in
    and out by turns (not a receptance); InputError naming the file, run and DOF, with the hint."""
    h = run.frf.get(run.excitation_dof)
    if h is None or len(h) < 2:
        return
    s = energy_sign(h)
    if s is None:
        return
    where = f"run {run.name}, frf {run.excitation_dof} (drive point)"
    peak = int(np.abs(h).argmax())
    at_peak = f"{float(run.frequency[peak]):.6g} Hz, phase {float(np.angle(h[peak])):+.2f} rad"
    flip = "import without --force-sign -1" if force_sign < 0 else "give --force-sign -1"
    if s > OUTWARD:
        raise InputError(f"Im of the drive-point receptance is > 0 (at its peak {at_peak}; about -pi/2 expected): "
                         f"energy would flow out of the structure under exp(+jwt); the force sign is reversed "
                         f"({flip}), or the FRF is not the quantity its label says (an accelerance read as a "
                         f"receptance, or the reverse)", path, where)
    if s > -MIXED:
        raise InputError(f"Im of the drive-point receptance changes sign across the lines (sum Im / sum |Im| = "
                         f"{s:+.2f}, -1 expected; at its peak {at_peak}): not a receptance -- a mobility "
                         f"(velocity/force) labelled as one? check the unit", path, where)
