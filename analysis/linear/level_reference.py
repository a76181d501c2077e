"""A reference structure from the lowest stepped-sine level, where there is no random run (docs/import.md).

Often the lowest level is the only linear data a test has, and one or two sensors see one mode. The modal fit of
:mod:`analysis.signals.modal_fit` on that level's FRFs gives natural frequencies, damping ratios, the residues and the
residual terms; with the drive point among the sensors the residues are mass-normalised shape entries
(``A_pq = phi_p phi_q``, so ``phi_q = sqrt(Re A_qq)``). They make a ``type = "modal"`` structure
(:class:`analysis.mechanics.structures.ModalStructure`), written as a model file with the joint element at the drive point
and no laws, for ``analyze`` to identify and fit.

The lowest level is the one with the smallest response (largest |H| F over its lines at the drive point): the
most linear. Whether it is linear enough is judged against the next level: a frequency that moves by more than
:data:`FREQUENCY_SHIFT` or a damping ratio that moves by more than :data:`DAMPING_SHIFT` between the two says the
structure is nonlinear already at these amplitudes, and the reference may hold part of the joint's effect at the
lowest level (the identified kbar is then relative to it).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..common.errors import InputError
from ..common.measurements import Measurements, SineRun
from ..laws.base import Origin
from ..mechanics.elements import Element
from ..mechanics.model import Model
from ..mechanics.structures import load_structure
from ..signals.modal_fit import ModalFit, fit_modes

FREQUENCY_SHIFT = 1e-3     # relative: the accuracy a reference frequency is wanted to
DAMPING_SHIFT = 0.05       # relative: the accuracy a reference damping ratio is wanted to
ELEMENT = "joint"


@dataclass
class LevelReference:
    """The modal reference fitted to one level, how well it fits, and what the next level says of it.

    Attributes
    ----------
    run : str
    drive : str
        The drive-point DOF (the excitation, measured), where the joint element goes.
    fit : ModalFit
    table : dict
        The ``[structure]`` table (``type = "modal"``).
    frf_error : float
        Relative FRF error of the modal structure against the level's FRFs over all its lines and sensors.
    next_run : str or None
        The level compared with; ``next_fit`` its modal fit.
    origin : Origin
        The joint's state the reference holds (:func:`origin_of`), where its laws are measured from.
    """

    run: str
    drive: str
    fit: ModalFit
    table: dict
    frf_error: float
    next_run: str | None = None
    next_fit: ModalFit | None = None
    origin: Origin | None = None

    @property
    def shifts(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Relative change of each mode's frequency and damping from this level to the next (None: no next)."""
        if self.next_fit is None or len(self.next_fit.frequency) != len(self.fit.frequency):
            return None
        return (self.next_fit.frequency / self.fit.frequency - 1, self.next_fit.damping / self.fit.damping - 1)

    @property
    def nonlinear(self) -> bool:
        s = self.shifts
        return s is not None and bool((np.abs(s[0]) > FREQUENCY_SHIFT).any() or (np.abs(s[1]) > DAMPING_SHIFT).any())

    def text(self) -> str:
        out = [f"reference from run {self.run} (modal, drive point {self.drive}):"]
        for r in range(len(self.fit.frequency)):
            lo, hi = self.fit.band[r]
            out.append(f"  mode {r + 1}: {self.fit.frequency[r]:.6g} Hz, damping {self.fit.damping[r]:.4g}, "
                       f"fit error {self.fit.fit_error[r]:.3g} on {lo:.5g}-{hi:.5g} Hz")
        out.append(f"  FRF error of the reference on its level: {self.frf_error:.3g}")
        if self.origin is not None:
            out.append(f"  the joint's laws measured from its state at this level's resonance: {self.origin.text()}")
        s = self.shifts
        if self.next_run is None:
            out.append("  no other level to judge its linearity by")
        elif s is None:
            out.append(f"  run {self.next_run} shows another number of modes: linearity not judged")
        else:
            moves = ", ".join(f"mode {r + 1} frequency {100 * s[0][r]:+.3g} %, damping {100 * s[1][r]:+.3g} %"
                              for r in range(len(s[0])))
            verdict = ("NONLINEAR already between the two lowest levels: the reference may hold part of the "
                       "joint's effect at this level" if self.nonlinear else
                       f"linear as far as the next level shows (within {100 * FREQUENCY_SHIFT:g} % in frequency "
                       f"and {100 * DAMPING_SHIFT:g} % in damping)")
            out.append(f"  next level {self.next_run}: {moves}; {verdict}")
        for p in self.fit.rejected:
            out.append(f"  peak at {p.frequency:.5g} Hz not taken: {p.reason}")
        return "\n".join(out)

    def model(self) -> Model:
        """The model: this structure and the joint element at the drive point, grounded, no laws (``analyze``
        finds them). The structure holds the joint's stiffness at this level, so the element is marked
        ``in_reference``: its laws are measured from its state at this level (:attr:`origin`)."""
        return Model(dict(self.table), load_structure(self.table),
                     [Element(ELEMENT, (self.drive,), [], in_reference=True, origin=self.origin)])


def origin_of(run: SineRun, fit: ModalFit, band=None) -> Origin:
    """The joint's state the reference holds: the drive point's amplitude at the resonance of the mode that
    responds most (within ``band``, Hz), at that mode's fitted frequency. The lines about a resonance decide the
    modal fit's damping and frequency; a level held at a constant acceleration has its largest displacement at its
    lowest line, not there. The joint element sits at the drive point, grounded: its amplitude is the drive
    point's."""
    k = run.sensor_dofs.index(run.excitation_dof)
    size = np.abs(run.receptance[:, k]) * run.force_per_line
    f = np.asarray(run.frequency_hz, float)
    lines = np.arange(f.size) if band is None else np.flatnonzero((f >= band[0]) & (f <= band[1]))
    peak = f[lines[np.argmax(size[lines])]]
    f0 = float(fit.frequency[np.argmin(np.abs(np.asarray(fit.frequency) - peak))])
    line = lines[np.argmin(np.abs(f[lines] - f0))]
    return Origin(float(size[line]), 2.0 * np.pi * f0)


def response_size(run: SineRun, drive: str) -> float:
    """The largest drive-point amplitude |H| F of a run, m: what orders levels from the most linear."""
    k = run.sensor_dofs.index(drive)
    return float(np.max(np.abs(run.receptance[:, k]) * run.force_per_line))


def _levels_by_size(measurements: Measurements) -> list[SineRun]:
    runs = [r for r in measurements.sine if r.excitation_dof in r.sensor_dofs]
    if not runs:
        raise InputError("no stepped-sine run measures its drive point (the excitation DOF among the sensors): a "
                         "modal reference needs it to scale the mode shapes")
    return sorted(runs, key=lambda r: response_size(r, r.excitation_dof))


def _fit(run: SineRun, band) -> ModalFit:
    order = np.argsort(run.frequency_hz)
    try:
        fit = fit_modes(np.asarray(run.frequency_hz)[order], run.receptance[order], band=band)
    except ValueError as exc:
        raise InputError(f"run {run.name}: no modal fit ({exc})", field="--band" if band else None) from None
    n = len(run.sensor_dofs)
    if len(fit.frequency) != n:
        raise InputError(f"run {run.name}: {len(fit.frequency)} mode(s) found for {n} sensor(s); a modal reference "
                         f"has as many modes as DOFs (choose the band with --band F1 F2)", field="--band")
    return fit


def _table(run: SineRun, fit: ModalFit) -> dict:
    """The ``[structure]`` table of the fitted modes, shapes scaled at the drive point."""
    q = run.sensor_dofs.index(run.excitation_dof)
    A = fit.residues.real                                               # (m, p): phi_r,p phi_r,q
    if (A[:, q] <= 0).any():
        raise InputError(f"run {run.name}: a mode's drive-point residue is not positive (Re A = "
                         f"{float(A[:, q].min()):.3g}): the FRF is not a receptance in the exp(+jwt) convention")
    phi_q = np.sqrt(A[:, q])
    shapes = A / phi_q[:, None]
    table = {"type": "modal", "dofs": list(run.sensor_dofs), "frequencies": [float(x) for x in fit.frequency],
             "damping": [float(x) for x in fit.damping], "shapes": shapes.tolist()}
    if len(fit.frequency) == 1:
        # one mode: its band's residual terms, known for the drive column (and by reciprocity its row)
        n = len(run.sensor_dofs)
        for key, values in (("residual_flexibility", fit.residuals[0, 0].real),
                            ("residual_inertia", fit.residuals[0, 1].real)):
            M = np.zeros((n, n))
            M[:, q] = M[q, :] = values
            table[key] = M.tolist()
    return table


def _frf_error(run: SineRun, table: dict) -> float:
    structure = load_structure(table)
    H = structure.frf(run.w, [run.excitation_dof])[:, :, 0]
    rows = [structure.index(d) for d in run.sensor_dofs]
    return float(np.linalg.norm(H[:, rows] - run.receptance) / np.linalg.norm(run.receptance))


def reference_from_level(measurements: Measurements, run: str | None = None, band=None) -> LevelReference:
    """The modal reference of the lowest level (or of ``run``), fitted on ``band`` (Hz) or all its lines."""
    levels = _levels_by_size(measurements)
    if run is not None:
        chosen = [r for r in measurements.sine if r.name == run]
        if not chosen:
            raise InputError(f"no stepped-sine run {run!r} (runs: {', '.join(r.name for r in measurements.sine)})",
                             field="--run")
        if chosen[0] not in levels:
            raise InputError(f"run {run} does not measure its drive point {chosen[0].excitation_dof}", field="--run")
        base = chosen[0]
    else:
        base = levels[0]
    fit = _fit(base, band)
    table = _table(base, fit)
    out = LevelReference(base.name, base.excitation_dof, fit, table, _frf_error(base, table),
                         origin=origin_of(base, fit, band))
    above = [r for r in levels if response_size(r, r.excitation_dof) > response_size(base, base.excitation_dof)
             * (1 + 1e-9) and r.control.key() != base.control.key()]
    if above:
        out.next_run = above[0].name
        try:
            out.next_fit = fit_modes(np.sort(above[0].frequency_hz),
                                     above[0].receptance[np.argsort(above[0].frequency_hz)], band=band)
        except ValueError:
            out.next_fit = None
    return out
