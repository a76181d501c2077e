"""Amplitude-dependent natural frequency and damping: measured per response level, predicted from a model.

**Measured.** A response-controlled stepped-sine level holds one response amplitude at every line, so the joint
sits at (nearly) one amplitude and the FRF is that of a linear structure: a single-mode fit around its peak
(:func:`analysis.signals.modal_fit.fit_modes`) gives the natural frequency and damping ratio at that amplitude.

**Predicted: the describing-function eigenproblem** (docs/method.md section 7). At a response amplitude ``a`` of
``quantity`` at the DOF ``p`` the nonlinear mode is taken as the linear mode of the structure with each element
replaced by its describing function at the amplitude the mode gives it::

    (K + sum_i kbar_i(X_i, w) e_i e_i^T + lambda C + lambda^2 M) phi = 0,
    phi scaled so that |phi_p| w^k = a     (k = 0, 1, 2: displacement, velocity, acceleration),
    X_i = |e_i^T phi|,   w = Im lambda,

solved by fixed-point iteration from the linear mode nearest the requested frequency (the mode is followed by
its shape: the eigenvector most parallel to the last one). The natural frequency is ``|lambda| / 2 pi`` and the
damping ratio ``-Re lambda / |lambda|`` -- the pole a single-mode fit of a measured FRF at that amplitude
estimates. It is the single-harmonic, single-nonlinear-mode limit of the extended periodic motion concept:
exact for the first harmonic of an isolated mode, blind to harmonics and to the coupling of close modes.

**Measured damping at phase resonance.** At a lag of 90 deg the force balances the damping force of the mode
(the power balance of the extended periodic motion concept): with the mass-normalised shape ``phi`` of the
mode of the model's linear structure nearest the lock, force ``F`` at DOF ``e`` and fundamental displacement
amplitude ``X_d`` at the locked DOF ``d``, ``zeta = F phi_e phi_d sin(lag) / (2 w^2 X_d)`` (``sin(lag)``: the
force's share in quadrature with the response, 1 at an exact lock). Exact for one mode of a structure with
proportional damping; close modes and non-proportional damping bias it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg

from ..common.errors import InputError
from ..common.measurements import CONTROL_UNITS, Measurements, PhaseRun, SineRun, response_amplitude
from ..identification.between_runs import GROUP, divided_difference, one_group
from ..mechanics.elements import Element
from ..mechanics.structures import Structure
from ..signals.modal_fit import fit_modes

METHOD = "describing-function eigenproblem (single nonlinear mode, first harmonic)"
POWER = {"displacement": 0, "velocity": 1, "acceleration": 2}    # response = displacement x w^k
TOLERANCE = 1e-10        # relative change of the eigenvalue that ends the fixed-point iteration
MAX_ITERATIONS = 200
FIT_BAND = 0.03          # the single-mode fit of a level uses the lines within this share of its peak frequency...
MIN_FIT_LINES = 8        # ...and at least this many lines nearest the peak (what the fit needs)


@dataclass(frozen=True)
class ModalPoint:
    """The natural frequency (Hz) and damping ratio of one mode at one response amplitude (in the units of the
    curve's quantity); ``converged`` says whether the iteration (prediction) or the fit (measurement) did."""

    amplitude: float
    frequency: float
    damping: float
    converged: bool = True


@dataclass
class Backbone:
    """Natural frequency and damping against response amplitude at ``dof``: ``source`` "measured" (a modal fit
    per response level, ``runs`` naming them) or "predicted" (``method``)."""

    dof: str
    quantity: str
    points: list[ModalPoint]
    source: str
    method: str = ""
    runs: tuple[str, ...] = ()

    @property
    def units(self) -> str:
        return CONTROL_UNITS[self.quantity]

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(amplitude, frequency Hz, damping ratio), ascending in amplitude."""
        pts = sorted(self.points, key=lambda p: p.amplitude)
        return tuple(np.array([getattr(p, k) for p in pts], float) for k in ("amplitude", "frequency", "damping"))

    def to_json(self) -> dict:
        return {"dof": self.dof, "quantity": self.quantity, "units": self.units, "source": self.source,
                "method": self.method, "runs": list(self.runs),
                "points": [{"amplitude": p.amplitude, "frequency_hz": p.frequency,
                            "damping_ratio": _number(p.damping), "converged": p.converged}
                           for p in sorted(self.points, key=lambda p: p.amplitude)]}


def _number(x: float) -> float | None:
    """A value for JSON: None where it is not known (a phase lock measures no damping ratio)."""
    return None if not np.isfinite(x) else float(x)


# --------------------------------------------------------------------------- measured
def measured_backbone(runs: Sequence[SineRun]) -> list[Backbone]:
    """One measured curve per (DOF, quantity) held by response-controlled runs: a single-mode fit of each run's
    FRF at the held DOF around its peak. Runs whose fit finds no mode are left out."""
    groups: dict[tuple[str, str], list[SineRun]] = {}
    for run in runs:
        if run.control.response and run.control.dof in run.sensor_dofs:
            groups.setdefault((run.control.dof, run.control.quantity), []).append(run)
    out = []
    for (dof, quantity), members in groups.items():
        points, names = [], []
        for run in members:
            point = level_modal_point(run)
            if point is not None:
                points.append(point)
                names.append(run.name)
        if points:
            out.append(Backbone(dof, quantity, points, "measured", "single-mode fit per response level",
                                tuple(names)))
    return out


def level_modal_point(run: SineRun) -> ModalPoint | None:
    """The natural frequency and damping of a response level: the single-mode fit of its FRFs on the lines within
    FIT_BAND of the peak at the held DOF (at least MIN_FIT_LINES of them; None for a shorter run), at the
    amplitude the level held (the median measured)."""
    p = run.sensor_dofs.index(run.control.dof)
    order = np.argsort(run.frequency_hz)          # a down sweep too: the fit wants its band low to high
    f = np.asarray(run.frequency_hz, float)[order]
    H = np.asarray(run.receptance)[order]
    force = run.force_per_line[order]
    if len(f) < MIN_FIT_LINES:
        return None
    distance = np.abs(f / f[np.argmax(np.abs(H[:, p]))] - 1.0)
    near = (distance <= FIT_BAND) | (distance <= np.sort(distance)[MIN_FIT_LINES - 1])
    fit = fit_modes(f[near], H[near], n_modes=1)
    if not len(fit.frequency):
        return None
    held = response_amplitude(H[near, p] * -(2 * np.pi * f[near]) ** 2 * force[near],
                              2 * np.pi * f[near], run.control.quantity)
    return ModalPoint(float(np.median(held)), float(fit.frequency[0]), float(fit.damping[0]))


def phase_resonance_backbone(run: PhaseRun, structure: Structure | None = None) -> Backbone:
    """A phase-resonance run's points as a measured curve: the locked frequency against the displacement
    amplitude at the locked DOF -- a lock at 90 deg is the natural frequency of an isolated mode -- and the
    damping ratio by the power balance (:func:`phase_resonance_damping`; NaN without a ``structure``)."""
    damping = phase_resonance_damping(run, structure) if structure is not None else \
        np.full(len(run.frequency_hz), np.nan)
    points = [ModalPoint(float(a), float(f), float(z), bool(c))
              for a, f, z, c in zip(run.amplitude, run.frequency_hz, damping, run.converged)]
    return Backbone(run.dof, "displacement", points, "measured", f"phase resonance ({run.target_phase:g} deg)",
                    (run.name,))


def phase_resonance_damping(run: PhaseRun, structure: Structure) -> np.ndarray:
    """Damping ratio of each point of a phase-resonance run, ``F phi_e phi_d sin(lag) / (2 w^2 X_d)`` (module
    docstring), ``phi`` the mass-normalised shape of the linear structure's mode nearest the lock at the smallest
    amplitude (the least nonlinear); NaN where the excitation DOF is not the structure's."""
    if run.excitation_dof not in structure.dofs or run.dof not in structure.dofs:
        return np.full(len(run.frequency_hz), np.nan)
    frequencies, shapes = structure.modes()
    phi = shapes[:, int(np.argmin(np.abs(frequencies - _least_nonlinear_hz(run))))]
    return power_balance_damping(run, phi[structure.index(run.excitation_dof)] * phi[structure.index(run.dof)])


def _least_nonlinear_hz(run: PhaseRun) -> float:
    """The frequency the run locked at at its smallest amplitude."""
    return float(run.frequency_hz[int(np.argmin(run.amplitude))])


def power_balance_damping(run: PhaseRun, modal_constant: float) -> np.ndarray:
    """``F A sin(lag) / (2 w^2 X_d)`` at each point, ``A = phi_e phi_d`` the mode's modal constant between the
    excitation and the locked DOF (mass-normalised shapes; from a model or a measured FRF)."""
    lag = np.full(len(run.frequency_hz), run.target_phase) if run.lag is None else np.asarray(run.lag, float)
    w = 2 * np.pi * np.asarray(run.frequency_hz, float)
    return (np.asarray(run.force, float) * modal_constant * np.sin(np.radians(lag))
            / (2 * w ** 2 * np.asarray(run.amplitude, float)))


def measured_modal_constant(run: PhaseRun, frequency_hz, receptance) -> float | None:
    """The modal constant ``phi_e phi_d`` of the mode a phase-resonance run locks on, from a measured receptance
    ``H_de`` of the same excitation and locked DOF taken where the structure is (nearly) linear -- the low-level
    random run, or a low level: the real part of the residue of the single-mode fit nearest the lock
    (:func:`analysis.signals.modal_fit.fit_modes`); None where no mode is found within 25 % of the lock. With it the
    power balance needs no model: what the lab reads live."""
    fit = fit_modes(frequency_hz, np.asarray(receptance)[:, None])
    if not len(fit.frequency):
        return None
    near = _least_nonlinear_hz(run)
    mode = int(np.argmin(np.abs(fit.frequency - near)))
    if abs(fit.frequency[mode] / near - 1.0) > 0.25:
        return None
    return float(fit.residues[mode, 0].real)


def measured_power_balance(measurements: Measurements, run: PhaseRun) -> np.ndarray | None:
    """Damping ratio of each point of ``run`` by the power balance with the modal constant measured in the same
    session (:func:`measured_modal_constant`): from the random run where it drives the run's excitation DOF and
    sees the locked DOF, else from the lowest force-controlled stepped-sine level that does. None where the
    session holds neither, or its FRF shows no mode near the lock."""
    e, d = run.excitation_dof, run.dof
    sources = []
    r = measurements.random
    if r is not None and r.excitation_dof == e and d in r.sensor_dofs:
        sources.append((r.frequency_hz, r.receptance[:, r.sensor_dofs.index(d)]))
    lowest = min((s for s in measurements.sine if s.control.mode == "force" and s.excitation_dof == e
                  and d in s.sensor_dofs and len(s.frequency_hz) >= MIN_FIT_LINES), key=lambda s: s.force, default=None)
    if lowest is not None:
        order = np.argsort(lowest.frequency_hz)          # a down sweep too: the fit wants its band low to high
        sources.append((lowest.frequency_hz[order], lowest.receptance[order, lowest.sensor_dofs.index(d)]))
    for f, h in sources:
        constant = measured_modal_constant(run, f, h)
        if constant is not None:
            return power_balance_damping(run, constant)
    return None


# --------------------------------------------------------------------------- predicted
def predict_backbone(structure: Structure, elements: Sequence[Element], dof: str, quantity: str,
                     amplitudes, near_hz: float) -> Backbone:
    """Natural frequency and damping of the mode nearest ``near_hz`` at each response ``amplitude`` of ``quantity``
    at ``dof`` (SI units), by the describing-function eigenproblem (module docstring). Amplitudes are followed
    in ascending order, each iteration starting from the mode found at the one before."""
    if quantity not in POWER:
        raise InputError(f"a backbone is predicted for a displacement, velocity or acceleration, not {quantity!r}")
    p = structure.index(dof)
    E = np.stack([el.vector(structure) for el in elements], axis=1) if elements else np.zeros((structure.n, 0))
    fns = [el.describing_function for el in elements]
    lam, phi = _linear_mode(structure, 2 * np.pi * near_hz)
    points = []
    for a in np.sort(np.asarray(amplitudes, float)):
        lam, phi, converged = _nonlinear_mode(structure, E, fns, p, POWER[quantity], float(a), lam, phi)
        points.append(ModalPoint(float(a), float(abs(lam) / (2 * np.pi)), float(-lam.real / abs(lam)), converged))
    return Backbone(dof, quantity, points, "predicted", METHOD)


def _linear_mode(structure: Structure, w_near: float) -> tuple[complex, np.ndarray]:
    """The pole (Im > 0) of the linear structure nearest ``w_near`` (rad/s) and its shape."""
    lam, vec = _poles(structure.K.astype(complex), structure.C, structure.M)
    i = int(np.argmin(np.abs(lam.imag - w_near)))
    return lam[i], vec[:, i]


def _poles(K: np.ndarray, C: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues with Im > 0 of ``(K + lambda C + lambda^2 M) phi = 0`` and their DOF shapes (state-space
    form: a complex K from the describing functions has no conjugate pairs to rely on)."""
    n = K.shape[0]
    # M is positive definite: the standard problem of M^-1 [K C] is many times faster than the generalised one
    MK, MC = np.split(scipy.linalg.solve(M, np.concatenate([K, C], axis=1), assume_a="pos"), 2, axis=1)
    lam, vec = scipy.linalg.eig(np.block([[np.zeros((n, n)), np.eye(n)], [-MK, -MC]]))
    keep = lam.imag > 0
    return lam[keep], vec[:n, keep]


def _nonlinear_mode(structure: Structure, E: np.ndarray, fns, p: int, power: int, amplitude: float,
                    lam: complex, phi: np.ndarray) -> tuple[complex, np.ndarray, bool]:
    """Fixed point of the describing-function eigenproblem at one amplitude, from the pole ``lam`` and shape
    ``phi`` of a neighbouring amplitude."""
    for _ in range(MAX_ITERATIONS):
        w = lam.imag
        scaled = phi * (amplitude / (abs(phi[p]) * w ** power))
        X = np.abs(E.T @ scaled)
        kbar = np.array([fn(np.array([x]), np.array([w]))[0] for fn, x in zip(fns, X)], complex)
        K = structure.K + (E * kbar) @ E.T
        poles, shapes = _poles(K, structure.C, structure.M)
        i = int(np.argmax(np.abs(shapes.conj().T @ phi) / np.linalg.norm(shapes, axis=0)))  # the same mode
        new, phi = poles[i], shapes[:, i]
        if abs(new - lam) <= TOLERANCE * abs(lam):
            return new, phi, True
        lam = new
    return lam, phi, False


# --------------------------------------------------------------------------- measured against predicted
CURVE_POINTS = 24        # predicted points drawn between the smallest and the largest measured amplitude


@dataclass
class BackboneComparison:
    """A measured curve, the model's prediction at its amplitudes (``predicted``) and on a finer grid
    (``curve``, for plots), with the relative errors of the prediction at each measured point."""

    measured: Backbone
    predicted: Backbone
    curve: Backbone

    @property
    def frequency_error(self) -> np.ndarray:
        return self.predicted.arrays()[1] / self.measured.arrays()[1] - 1.0

    @property
    def damping_error(self) -> np.ndarray:
        return self.predicted.arrays()[2] / self.measured.arrays()[2] - 1.0

    def text(self) -> list[str]:
        m = self.measured
        what = "response level(s)" if m.method.startswith("single-mode") else f"point(s) of {m.runs[0]}, {m.method}"
        out = [f"  {m.quantity} at {m.dof} ({len(m.points)} {what}); predicted by the {self.predicted.method}:",
               f"    {'amplitude [' + m.units + ']':>18} {'f meas [Hz]':>12} {'f model':>10} {'error':>8} "
               f"{'zeta meas':>10} {'zeta model':>10} {'error':>8}"]
        for pm, pp, ef, ez in zip(sorted(m.points, key=lambda p: p.amplitude), self.predicted.points,
                                  self.frequency_error, self.damping_error):
            flag = "" if pp.converged else "  (prediction not converged)"
            flag += "" if pm.converged else "  (lock not converged)"
            damping = f"{pm.damping:10.5f} {pp.damping:10.5f} {100 * ez:+7.2f}%" if np.isfinite(pm.damping) else \
                f"{'-':>10} {pp.damping:10.5f} {'-':>8}"
            out.append(f"    {pm.amplitude:18.4g} {pm.frequency:12.5f} {pp.frequency:10.5f} {100 * ef:+7.3f}% "
                       f"{damping}{flag}")
        return out

    def to_json(self) -> dict:
        return {"measured": self.measured.to_json(), "predicted": self.predicted.to_json(),
                "curve": self.curve.to_json(), "frequency_error": [float(e) for e in self.frequency_error],
                "damping_error": [_number(e) for e in self.damping_error]}


def compare_backbones(structure: Structure, elements: Sequence[Element], runs: Sequence[SineRun],
                      phase_runs: Sequence[PhaseRun] = ()) -> list[BackboneComparison]:
    """Measured natural frequency and damping -- of the response levels, and of the phase-resonance runs'
    points -- against the model's prediction."""
    out = []
    for measured in measured_backbones(structure, runs, phase_runs):
        a, f, _ = measured.arrays()
        grid = np.geomspace(a.min(), a.max(), CURVE_POINTS) if a.max() > a.min() else a
        curve = predict_backbone(structure, elements, measured.dof, measured.quantity, grid, float(f[0]))
        out.append(BackboneComparison(measured, _predicted_at(structure, elements, measured), curve))
    return out


def measured_backbones(structure: Structure, runs: Sequence[SineRun],
                       phase_runs: Sequence[PhaseRun] = ()) -> list[Backbone]:
    """Every measured curve: the response levels' and the phase-resonance runs' (damping from ``structure``)."""
    return measured_backbone(runs) + [phase_resonance_backbone(r, structure) for r in phase_runs]


def _predicted_at(structure: Structure, elements: Sequence[Element], measured: Backbone) -> Backbone:
    """The model's prediction at the measured amplitudes, from the mode nearest the first measured frequency."""
    a, f, _ = measured.arrays()
    return predict_backbone(structure, elements, measured.dof, measured.quantity, a, float(f[0]))


@dataclass(frozen=True)
class ModalError:
    """The error of a model's natural frequencies and damping ratios against the measured ones (every point of
    the response levels and the phase-resonance runs): the RMS relative error of each; NaN where nothing of it
    is measured."""

    frequency: float
    damping: float

    @property
    def measured(self) -> bool:
        return bool(np.isfinite(self.frequency))

    def to_json(self) -> dict:
        return {"backbone_error": _number(self.frequency), "damping_error": _number(self.damping)}


def modal_error(pairs: Sequence[tuple[Backbone, Backbone]]) -> ModalError:
    """RMS relative frequency and damping errors over (measured, predicted) curves; damping over the points
    where it is measured."""
    return ModalResiduals.of(pairs).error()


@dataclass(frozen=True)
class ModalResiduals:
    """The relative errors ``predicted / measured - 1`` of a model's natural frequencies (every measured point) and
    damping ratios (the points where it is measured), shape (points,) each: what :class:`ModalError` is the RMS
    of, kept apart so that the points of several predictions pool (the levels of several held-out folds, each
    predicted by the fit that did not see it)."""

    frequency: np.ndarray
    damping: np.ndarray

    @classmethod
    def of(cls, pairs: Sequence[tuple[Backbone, Backbone]]) -> "ModalResiduals":
        """Of (measured, predicted) curves."""
        if not pairs:
            return cls(np.zeros(0), np.zeros(0))
        ef = np.concatenate([p.arrays()[1] / m.arrays()[1] - 1.0 for m, p in pairs])
        ez = np.concatenate([p.arrays()[2] / m.arrays()[2] - 1.0 for m, p in pairs])
        return cls(ef, ez[np.isfinite(ez)])

    @classmethod
    def joined(cls, parts: Sequence["ModalResiduals"]) -> "ModalResiduals":
        return cls(np.concatenate([np.zeros(0)] + [p.frequency for p in parts]),
                   np.concatenate([np.zeros(0)] + [p.damping for p in parts]))

    def error(self) -> ModalError:
        """The RMS of each; NaN where nothing of it is measured."""
        return ModalError(_rms(self.frequency), _rms(self.damping))


def scatter_between_levels(curves: Sequence[Backbone]) -> ModalError:
    """How well the test repeats a mode's natural frequency and damping ratio from one level to the next, relative,
    from the measured curves themselves: a mode's frequency and damping are functions of its amplitude, so
    neighbouring points disagree beyond a smooth curve by what the test does not repeat (a joint that settles, the
    temperature, the fixture; on a real structure the mode moves by a fraction of a per cent between runs). Each
    curve's points, in order of ``u = ln amplitude``, are taken four at a time (every window of ``GROUP``
    consecutive points within a factor ``SPAN`` in amplitude), and the combination of their ``ln f`` (``ln zeta``)
    that vanishes for any quadratic in ``u`` (the third divided difference, ``|c| = 1``:
    :func:`analysis.identification.between_runs.divided_difference`, the scatter between runs of the kbar turned
    to the modes) leaves one point's scatter: the RMS over every window of every curve. NaN where no window is
    found (fewer than four points within a factor two)."""
    parts: tuple[list, list] = ([], [])
    for curve in curves:
        a, f, z = curve.arrays()
        u = np.log(a)
        for start in range(len(u) - GROUP + 1):
            nodes = u[start:start + GROUP]
            if not one_group(nodes):
                continue
            c = divided_difference(nodes)
            for out, values in zip(parts, (f, z)):
                window = values[start:start + GROUP]
                if np.all(window > 0):
                    out.append(float(c @ np.log(window)))
    return ModalError(_rms(np.array(parts[0])), _rms(np.array(parts[1])))


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else float("nan")


def model_modal_error(structure: Structure, elements: Sequence[Element], runs: Sequence[SineRun],
                      phase_runs: Sequence[PhaseRun] = ()) -> ModalError:
    """:func:`modal_error` of the model (predicted at the measured amplitudes only: no curve for plots)."""
    return modal_error([(m, _predicted_at(structure, elements, m))
                        for m in measured_backbones(structure, runs, phase_runs)])
