"""Harmonic balance with several harmonics and the mean, the element forces by alternating frequency-time (AFT)
evaluation of the laws' own time-domain forces (docs/method.md §4; docs/workbench.md, "Where one harmonic is not
enough"): needed where harmonics matter (bilinear, gap, contact, friction that sticks).

With ``E`` the element vectors, ``q`` the excitation DOF and the structure's receptance ``H`` at each harmonic
``k w``, the element phasors ``Y_k`` (k = 0 the mean, 1 the fundamental, ..., H) solve

    R_k = Y_k + G_k F_k(Y) - delta_k1 g F = 0,      G_k = E^T H(k w) E,  g = E^T H(w) e_q,

``F_k`` the harmonics of the element forces marched along the motion ``Y``. Phasors follow docs/contracts.md §1.

- :func:`predict_multiharmonic` -- the balance at every line, all lines at once where each starts from its own
  single-harmonic solution (:class:`_MultiharmonicLines`);
- :func:`predict_multiharmonic_converged` -- the same, each line with the harmonics its motion needs
  (:func:`omitted_harmonics`: what those left out would drive);
- :func:`single_harmonic_distortion` -- the harmonics a single-harmonic solution implies (which lines need this);
- :class:`_AFT` -- the element forces' harmonics of a batch of motions, each force jump placed where it happens
  (:func:`_jump_correction`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.optimize
from ..common.compiled import njit

from ..common.interrupt import check_stop
from ..mechanics.elements import Element
from ..mechanics.structures import Structure
from .harmonic_balance import _element_loads, _quasi_newton, predict_sweep


@dataclass
class MultiharmonicResponse:
    """Multi-harmonic steady state at each line.

    Attributes
    ----------
    w : ndarray, shape (L,)
    harmonics : ndarray, shape (L, H + 1, n)
        Complex amplitude of harmonic k (k = 0 is the mean, real) of every DOF, in the phasor convention
        ``Im(X_k e^{j k w t})``.
    converged : ndarray of bool, shape (L,)
    element_harmonics, element_forces : ndarray, shape (L, H + 1, r)
        The same of every element's relative displacement and of its force: ``element_forces[:, 1] /
        element_harmonics[:, 1]`` is the fundamental's force over the fundamental's motion, what the closed-form
        identification measures as kbar where the motion is not sinusoidal.
    n_used : ndarray of int, shape (L,), or None
        The harmonics each line was balanced with, where lines differ (:func:`predict_multiharmonic_converged`;
        the arrays above are zero beyond them); None: all H.
    """

    w: np.ndarray
    harmonics: np.ndarray
    converged: np.ndarray
    element_harmonics: np.ndarray
    element_forces: np.ndarray
    n_used: np.ndarray | None = None

    def receptance(self, force) -> np.ndarray:
        """Fundamental receptance ``X_1 / F``, shape (L, n); ``force`` one amplitude or one per line (L,)."""
        return self.harmonics[:, 1, :] / np.reshape(np.asarray(force, float), (-1, 1))


def element_force_history(element: Element, y: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Time-domain force of an element's laws along (y, v), from rest; 1-D arrays."""
    total = np.zeros_like(y)
    for term in _time_domain_laws(element):
        total += term.law.force(y, v, **term.values)
    return total


def element_force_periodic(element: Element, y: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The force of an element's laws over one period of each periodic motion ``y``, ``v`` (B, T), on its closed
    loop (:meth:`analysis.laws.base.Law.march_periodic`)."""
    total = np.zeros(y.shape)
    for term in _time_domain_laws(element):
        total += term.law.march_periodic(y, v, term.law.parameter_vector(**term.values))
    return total


def _time_domain_laws(element: Element):
    """The element's laws, whose time-domain forces sum to its force. An element with a non-parametric part has
    no time-domain force (:mod:`analysis.mechanics.nonparametric`): refused, never half a force."""
    if not element.time_domain:
        raise ValueError(f"element {element.name!r} has a non-parametric part: it has no time-domain force, so it "
                         "cannot be marched nor predicted with harmonics")
    return element.laws


#: A force change across the sampling interval of a sign change of the velocity or the displacement counts as a
#: jump (friction; velocity stiffness) when, less the neighbours' mean change, it exceeds this many times the
#: neighbours' changes (a step: O(n) times larger).
JUMP_RATIO = 2.0


class _AFT:
    """Alternating frequency-time evaluation of the elements' forces for harmonics 0..H: the laws' time-domain
    kernels are marched over two periods of the trial motion (so hysteretic laws start their second cycle on
    the closed loop) and the second period is transformed, with each force jump at a sign change of the
    velocity or the displacement placed where the sign changes (:func:`_jump_correction`)."""

    def __init__(self, elements: Sequence[Element], n_harmonics: int, n_time: int):
        self.elements, self.n_time = elements, n_time
        self.theta = 2 * np.pi * np.arange(n_time) / n_time
        self.k = np.arange(n_harmonics + 1)
        self.S, self.C = np.sin(np.outer(self.theta, self.k)), np.cos(np.outer(self.theta, self.k))

    def forces(self, Yk: np.ndarray, w: float) -> np.ndarray:
        """Element force phasors (H+1, r) of the motion with element phasors ``Yk`` (H+1, r) at w."""
        return self.forces_rows(Yk[None], np.array([w], float))[0]

    def forces_rows(self, Yk: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Element force phasors (B, H+1, r) of B motions with element phasors ``Yk`` (B, H+1, r) at lines ``w``
        (B,): one compiled march per element for the whole batch, in (B, r, n) order so that the transforms are
        one matrix product each."""
        S, C, k, n = self.S, self.C, self.k, self.n_time
        B, r = Yk.shape[0], Yk.shape[2]
        A = np.swapaxes(Yk, 1, 2).reshape(B * r, -1)                        # (B r, H+1)
        re, im = A[:, 1:].real, A[:, 1:].imag
        y_t = (A[:, :1].real + re @ S[:, 1:].T + im @ C[:, 1:].T).reshape(B, r, n)
        v_t = (np.repeat(w, r)[:, None] * (re @ (C[:, 1:] * k[1:]).T - im @ (S[:, 1:] * k[1:]).T)).reshape(B, r, n)
        f = np.empty((B, r, n))
        for i, el in enumerate(self.elements):
            f[:, i] = element_force_periodic(el, y_t[:, i], v_t[:, i])
        flat = f.reshape(B * r, n)
        Fk = (2.0 / n * (flat @ S + 1j * (flat @ C))).reshape(B, r, -1)
        Fk[:, :, 0] = flat.mean(axis=1).reshape(B, r)
        return np.swapaxes(Fk, 1, 2) + _jump_correction(f, y_t, v_t, self.theta, k)


def _jump_correction(f: np.ndarray, y: np.ndarray, v: np.ndarray, theta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """What moving each force jump from the middle of its sampling interval (where the sum over the samples puts
    it) to where it is adds to the force phasors (B, H+1, r) of the B motions ``f``, ``y``, ``v`` (B, r, n). The
    laws' forces jump where the velocity changes sign (friction) or the displacement does (velocity stiffness,
    ``|x'| sgn(x)``).

    The plain sum over ``n`` samples places a jump on the sampling grid, so the phasors move in steps of about
    ``jump / n`` as the sign change crosses a sample: the balance residual is discontinuous, and Newton stalls
    at that size without a root (the 2-DOF Anderson-Ferri rig: residuals of 1e-4 to 3e-3 at half its lines, 7
    harmonics, 512 points). The sign change of ``u`` (v or y) lies at the fraction ``s = u_m / (u_m - u_{m+1})``
    of its interval (linear interpolation); the jump is the change of force across the interval less the mean
    change across its neighbours (what a smooth force changes by); held over ``(1/2 - s)`` of the interval it
    adds ``(2/n) jump (1/2 - s) (sin k theta + j cos k theta)`` at its middle (half that for the mean). The
    phasors are then continuous in the motion to O(1/n^2). Only a jump larger than ``JUMP_RATIO`` times the
    changes across the two neighbouring intervals counts: a continuous force that bends there (a Jenkins
    slider sticking, quadratic damping) changes by about as much beside it and is left as sampled.

    Compiled (:func:`_placed_jumps`): it runs at every AFT evaluation, and as numpy calls on a few sign changes it
    cost more than the laws' own forces."""
    return _placed_jumps(f, y, v, theta, k, JUMP_RATIO)


@njit(cache=True)
def _placed_jumps(f, y, v, theta, k, ratio):
    """:func:`_jump_correction`'s sum, motion by motion and element by element: each interval where the
    velocity, or else the displacement, changes sign, its jump placed where the sign changes; (B, len(k), r)
    complex."""
    B, r, n = f.shape
    out = np.zeros((B, k.size, r), np.complex128)
    for q in range(B):
        for c in range(r):
            for which in range(2):
                u = v[q, c] if which == 0 else y[q, c]
                for m in range(n):
                    a, b = u[m], u[(m + 1) % n]
                    if not a * b < 0:
                        continue
                    if which == 1 and v[q, c, m] * v[q, c, (m + 1) % n] < 0:
                        continue                                  # an interval's jump is placed once
                    fc = f[q, c]
                    before = fc[m] - fc[(m - 1) % n]
                    beyond = fc[(m + 2) % n] - fc[(m + 1) % n]
                    jump = fc[(m + 1) % n] - fc[m] - 0.5 * (before + beyond)
                    if not abs(jump) > ratio * (abs(before) + abs(beyond)):
                        continue                                  # a force that only bends there: left alone
                    held = jump * (0.5 - a / (a - b)) / n
                    mid = theta[m] + np.pi / n
                    out[q, 0, c] += held
                    for h in range(1, k.size):
                        out[q, h, c] += 2 * held * complex(np.sin(mid * k[h]), np.cos(mid * k[h]))
    return out


def single_harmonic_distortion(structure: Structure, elements: Sequence[Element], excitation_dof: str, w,
                               force, y, n_harmonics: int = 5, n_time: int = 64) -> np.ndarray:
    """The harmonics a single-harmonic solution implies: the elements' forces along the harmonic motion ``y``
    (L, r) at lines ``w`` (L,) (``force``: one amplitude or one per line) put through the structure at 0 and 2..H
    times w. Returns the total harmonic
    distortion of every DOF's displacement, shape (L, n): ``sqrt(sum_{k != 1} |X_k|^2) / |X_1|``.

    All lines at once: their two-period motions are marched one after another in one call per element (the
    first period of each line re-seats hysteretic laws)."""
    w = np.atleast_1d(np.asarray(w, float))
    y = np.atleast_2d(np.asarray(y, complex))
    L, H = len(w), n_harmonics
    aft = _AFT(elements, H, n_time)
    S1, C1 = aft.S[:, 1], aft.C[:, 1]
    E, loads = _element_loads(structure, elements, excitation_dof)
    y_t = S1[None, :, None] * y.real[:, None, :] + C1[None, :, None] * y.imag[:, None, :]        # (L, N, r)
    v_t = w[:, None, None] * (C1[None, :, None] * y.real[:, None, :] - S1[None, :, None] * y.imag[:, None, :])
    f = np.empty((L, n_time, len(elements)))
    for i, el in enumerate(elements):
        twice = element_force_history(el, np.tile(y_t[:, :, i], 2).ravel(), np.tile(v_t[:, :, i], 2).ravel())
        f[:, :, i] = twice.reshape(L, 2 * n_time)[:, n_time:]
    Fk = 2.0 / n_time * (np.einsum("nk,lnr->lkr", aft.S, f) + 1j * np.einsum("nk,lnr->lkr", aft.C, f))
    Fk[:, 0] = f.mean(axis=1)
    resp = _at_harmonics(structure, loads, w, aft.k)
    Xk = -np.einsum("lknr,lkr->lkn", resp[..., :-1], Fk)
    X1 = resp[:, 1, :, -1] * np.broadcast_to(np.asarray(force, float), w.shape)[:, None] + Xk[:, 1]
    Xk[:, 1] = 0.0
    return np.sqrt(np.sum(np.abs(Xk) ** 2, axis=1)) / np.maximum(np.abs(X1), 1e-300)


def predict_multiharmonic(structure: Structure, elements: Sequence[Element], excitation_dof: str, w, force,
                          n_harmonics: int = 5, n_time: int = 256, direction: str = "up",
                          y_start=None) -> MultiharmonicResponse:
    """Harmonic balance with ``n_harmonics`` harmonics and the mean, forces by AFT (:class:`_AFT`), at one
    force amplitude or one per line (``force`` shape (L,)).

    With ``y_start`` (single-harmonic element phasors, (L, r), or harmonics 0..H0 of them, (L, H0 + 1, r))
    every line starts from its own, which picks the branch where the response is multivalued, and the lines are
    independent: they are solved all at once by Broyden's method from a difference Jacobian (:func:`_quasi_newton`,
    :class:`_MultiharmonicLines`), and a line that does not converge so is solved on its own by scipy's ``hybr``
    from the same start. A batch where none of the :data:`PROBED_LINES` lines nearest a balance at their start
    converges is left there, unconverged. Without it Newton (``hybr``) runs at each line from the previous line's
    solution, the first started from the single-harmonic solution.
    """
    w = np.atleast_1d(np.asarray(w, float))
    H = int(n_harmonics)
    if H < 1 or n_time < 4 * H + 2:
        raise ValueError("need n_harmonics >= 1 and n_time >= 4 n_harmonics + 2")
    forces = np.broadcast_to(np.asarray(force, float), w.shape)
    lines = _MultiharmonicLines(structure, elements, excitation_dof, w, forces, H, n_time)
    z = np.zeros((len(w), lines.size))
    if y_start is not None:
        start = np.zeros((len(w), H + 1, len(elements)), complex)
        given = np.asarray(y_start, complex)
        if given.ndim == 2:
            start[:, 1] = given
        else:
            start[:, :given.shape[1]] = given[:, :H + 1]
        z = lines.pack(start, np.arange(len(w)))
        # a batch that meets no line at all meets a force with no smooth balance at these motions (a law that
        # sticks): the lines whose single-harmonic start is nearest a balance show that as well as all of them,
        # and a retry from the same start would repeat the search line by line; a few lines left are local
        probe = np.sort(np.argsort(np.linalg.norm(lines.residual(z, np.arange(len(w))), axis=1),
                                   kind="stable")[:PROBED_LINES])
        if _balanced(lines, z, probe).any():
            _balanced(lines, z, np.setdiff1d(np.arange(len(w)), probe))
            left = np.linalg.norm(lines.residual(z, np.arange(len(w))), axis=1) >= MULTIHARMONIC_CONVERGED
            for line in np.flatnonzero(left):
                check_stop()        # one line: where a stop asked for is heard
                z[line] = lines.solve_one(line, start[line])
    else:
        order = np.argsort(w) if direction == "up" else np.argsort(-w)
        start = np.zeros((H + 1, len(elements)), complex)
        start[1] = predict_sweep(structure, elements, excitation_dof, w[order[:1]], forces[order[0]],
                                 direction).y[0, 0]
        for line in order:
            check_stop()
            z[line] = lines.solve_one(line, start)
            start = lines.unpack(z[line:line + 1], np.array([line]))[0]
    return lines.response(z)


HARMONIC_TRUNCATION = 1e-3
"""A line's balance has harmonics enough where those it leaves out move its elements' fundamental by at most this
share of it (:func:`predict_multiharmonic_converged`), unless told a coarser share: a tenth of the percent a good
model's prediction misses measured FRFs by, so that what the truncation adds to an error is below what the
comparison tells apart."""


def predict_multiharmonic_converged(structure: Structure, elements: Sequence[Element], excitation_dof: str, w,
                                    force, y_start, n_harmonics: int, n_time: int, most_harmonics: int,
                                    truncation: float = HARMONIC_TRUNCATION) -> MultiharmonicResponse:
    """:func:`predict_multiharmonic` from ``y_start`` (L, r), each line with as many harmonics as its motion needs.
    First ``n_harmonics``; then, at the lines whose fundamental the harmonics left out would move by more than
    ``truncation`` of it (:func:`omitted_harmonics`, an estimate), twice as many, started from the solution before;
    and twice as many again, up to ``most_harmonics``, wherever the last doubling moved the elements' fundamental
    by more than that share (convergence in harmonics: what doubling did not move, doubling again moves less, the
    forces' harmonics falling off). A force with a kink or a jump (a
    contact, friction) has harmonics that fall off slowly, and where one of them meets a mode the truncated
    balance misses the fundamental by percents; elsewhere a few harmonics suffice, and more would only cost. A
    line whose balance with more harmonics does not converge keeps the one before. The result holds harmonics up
    to the most any line took (zero above a line's own, ``n_used``). ``n_time`` bounds the harmonics a line can
    take: the forces' samples must resolve them (``n_time >= 4 H + 2``)."""
    w = np.atleast_1d(np.asarray(w, float))
    forces = np.broadcast_to(np.asarray(force, float), w.shape)
    H, tolerance = int(n_harmonics), float(truncation)
    most_harmonics = min(int(most_harmonics), (n_time - 2) // 4)
    mh = predict_multiharmonic(structure, elements, excitation_dof, w, forces, H, n_time, y_start=y_start)
    kept = [(np.arange(len(w)), mh)]
    pending, before = np.flatnonzero(mh.converged), mh.element_harmonics[mh.converged]
    if H < most_harmonics and len(pending):
        needs = omitted_harmonics(structure, elements, excitation_dof, w[pending], before,
                                  min(2 * H, most_harmonics), n_time) > tolerance
        pending, before = pending[needs], before[needs]
    while H < most_harmonics and len(pending):
        H = min(2 * H, most_harmonics)
        mh = predict_multiharmonic(structure, elements, excitation_dof, w[pending], forces[pending], H, n_time,
                                   y_start=before)
        ok = mh.converged
        if ok.any():
            kept.append((pending[ok], _rows(mh, ok)))
        after = mh.element_harmonics[ok]
        moved = _relative(after[:, 1] - before[ok, 1], after[:, 1]) > tolerance
        pending, before = pending[ok][moved], after[moved]
    return _merged(w, kept)


def omitted_harmonics(structure: Structure, elements: Sequence[Element], excitation_dof: str, w, Yk, up_to: int,
                      n_time: int) -> np.ndarray:
    """What the harmonics a balance leaves out would change in its fundamental, per line, to first order: with the
    balance's motion ``Yk`` (L, H+1, r) at lines ``w`` (L,), harmonics H+1..``up_to`` of its forces drive the
    motion ``-G_k F_k`` that the balance leaves out; added to the motion, it changes the forces' fundamental by
    ``dF_1``, which moves the elements' fundamental by ``-G_1 dF_1``. Returns that move relative to the
    fundamental, the largest over the elements; shape (L,). The motion left out alone would overstate it wherever
    the fundamental depends little on it (a stiff contact, whose harmonics are large against its own small motion);
    the estimate leaves out how the balance's own harmonics take up the change, so it errs towards more harmonics
    (docs/workbench.md, "Each line its own harmonics")."""
    w = np.atleast_1d(np.asarray(w, float))
    L, H, r = Yk.shape[0], Yk.shape[1] - 1, Yk.shape[2]
    aft = _AFT(elements, up_to, n_time)
    padded = np.zeros((L, up_to + 1, r), complex)
    padded[:, :H + 1] = Yk
    E, loads = _element_loads(structure, elements, excitation_dof)
    G = np.einsum("ni,lknj->lkij", E, _at_harmonics(structure, loads[:, :-1], w,
                                                    np.concatenate([[1], np.arange(H + 1, up_to + 1)])))
    before = aft.forces_rows(padded, w)
    moved = padded.copy()
    moved[:, H + 1:] = -(G[:, 1:] @ before[:, H + 1:, :, None])[..., 0]
    fundamental = (G[:, 0] @ (aft.forces_rows(moved, w) - before)[:, 1, :, None])[..., 0]
    return _relative(fundamental, Yk[:, 1])


def _at_harmonics(structure: Structure, loads: np.ndarray, w: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The structure's response to ``loads`` (n, m) at harmonics ``k`` (K,) of lines ``w`` (L,); (L, K, n, m)."""
    return structure.response((k[None, :] * w[:, None]).ravel(), loads).reshape(len(w), len(k), structure.n, -1)


def _relative(change: np.ndarray, fundamental: np.ndarray) -> np.ndarray:
    """The largest over the elements of a change of their fundamental (L, r) relative to it; (L,)."""
    return (np.abs(change) / np.maximum(np.abs(fundamental), 1e-300)).max(axis=1, initial=0.0)


def _rows(mh: MultiharmonicResponse, rows: np.ndarray) -> MultiharmonicResponse:
    return MultiharmonicResponse(mh.w[rows], mh.harmonics[rows], mh.converged[rows], mh.element_harmonics[rows],
                                 mh.element_forces[rows])


def _merged(w: np.ndarray, kept: list[tuple[np.ndarray, MultiharmonicResponse]]) -> MultiharmonicResponse:
    """One response at lines ``w`` from balances at some of them, each (lines, response); a later balance of a
    line replaces an earlier one. Harmonics above a balance's own are zero; ``n_used`` says how many it had."""
    most = max(mh.harmonics.shape[1] for _, mh in kept) - 1
    n, r = kept[0][1].harmonics.shape[2], kept[0][1].element_harmonics.shape[2]
    out = MultiharmonicResponse(w, np.zeros((len(w), most + 1, n), complex), np.zeros(len(w), bool),
                                np.zeros((len(w), most + 1, r), complex), np.zeros((len(w), most + 1, r), complex),
                                np.zeros(len(w), int))
    for lines, mh in kept:              # each balance of a line has more harmonics than the one before
        h = mh.harmonics.shape[1]
        out.harmonics[lines, :h] = mh.harmonics
        out.element_harmonics[lines, :h] = mh.element_harmonics
        out.element_forces[lines, :h] = mh.element_forces
        out.converged[lines] = mh.converged
        out.n_used[lines] = h - 1
    return out


def _balanced(lines: "_MultiharmonicLines", z: np.ndarray, items: np.ndarray) -> np.ndarray:
    """The lines ``items`` solved by :func:`_quasi_newton` from their unknowns in ``z`` (L, size), updated in
    place; which of them converged."""
    if not len(items):
        return np.zeros(0, bool)
    z[items], converged = _quasi_newton(lambda zz, i: lines.residual(zz, items[i]),
                                        lambda zz, i: lines.jacobian(zz, items[i]), z[items],
                                        MULTIHARMONIC_TOLERANCE, MULTIHARMONIC_CONVERGED)
    return converged


PROBED_LINES = 8
"""A batch of more lines is first solved at this many, those whose single-harmonic start is nearest a balance
(the least residual): where none converges, none of the others is solved (:func:`predict_multiharmonic`)."""
MULTIHARMONIC_TOLERANCE = 1e-12
"""Residual norm (relative to the line's linear response) where the batched multi-harmonic Newton stops."""
MULTIHARMONIC_CONVERGED = 1e-8
"""Residual norm below which a multi-harmonic line counts as converged (a friction force's sampled jumps leave
a residual of about their rounding)."""
_AFT_BATCH_VALUES = 4_000_000
"""Samples of trial motion marched per batch of AFT evaluations (memory: a few arrays of this many floats)."""


class _MultiharmonicLines:
    """The multi-harmonic balance of lines ``w`` in real unknowns scaled by each line's linear response:
    ``z = [Y_0, Re Y_1..H, Im Y_1..H] / scale`` (r element phasors each), and the residual

        R_k = Y_k + G_k F_k(Y) - delta_k1 g F,      G_k = E^T H(k w) E,  g = E^T H(w) e_q,

    with ``F_k`` the element forces' harmonics by AFT. Rows of a batch name their line (``idx``), so the
    solver evaluates any set of lines, each as often as it needs."""

    def __init__(self, structure: Structure, elements: Sequence[Element], excitation_dof: str, w: np.ndarray,
                 forces: np.ndarray, H: int, n_time: int):
        self.w, self.forces, self.H, self.r = w, forces, H, len(elements)
        self.size = self.r * (2 * H + 1)
        E, loads = _element_loads(structure, elements, excitation_dof)
        self.aft = _AFT(elements, H, n_time)
        resp = _at_harmonics(structure, loads, w, self.aft.k)
        self.HE, self.Hq = resp[..., :-1], resp[..., -1]                  # (L, H+1, n, r), (L, H+1, n)
        self.G = np.einsum("ni,lknj->lkij", E, self.HE)                   # (L, H+1, r, r)
        self.gF = np.einsum("ni,ln->li", E, self.Hq[:, 1]) * forces[:, None]
        self.scale = np.maximum(np.abs(self.gF).max(axis=1, initial=0.0), 1e-300)
        self._rows = max(1, _AFT_BATCH_VALUES // (2 * n_time * max(self.r, 1)))

    def unpack(self, z: np.ndarray, idx: np.ndarray) -> np.ndarray:
        B, H, r = len(z), self.H, self.r
        Yk = np.zeros((B, H + 1, r), complex)
        Yk[:, 0] = z[:, :r]
        Yk[:, 1:] = (z[:, r:r + H * r] + 1j * z[:, r + H * r:]).reshape(B, H, r)
        return Yk * self.scale[idx, None, None]

    def pack(self, Yk: np.ndarray, idx: np.ndarray) -> np.ndarray:
        Yk = Yk / self.scale[idx, None, None]
        B = len(Yk)
        return np.concatenate([Yk[:, 0].real, Yk[:, 1:].real.reshape(B, -1), Yk[:, 1:].imag.reshape(B, -1)], axis=1)

    def element_forces(self, Yk: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """AFT forces of the rows (B, H+1, r), in batches of at most ``_AFT_BATCH_VALUES`` samples."""
        out = np.empty_like(Yk)
        for a in range(0, len(Yk), self._rows):
            out[a:a + self._rows] = self.aft.forces_rows(Yk[a:a + self._rows], self.w[idx[a:a + self._rows]])
        return out

    def residual(self, z: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """R of the rows ``z`` (B, size) at their lines ``idx`` (B,), scaled as z."""
        Yk = self.unpack(z, idx)
        R = Yk + (self.G[idx] @ self.element_forces(Yk, idx)[..., None])[..., 0]
        R[:, 1] -= self.gF[idx]
        return self.pack(R, idx)

    def jacobian(self, z: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """dR/dz of the rows by forward differences, every row and its perturbations in one batch; (B, size,
        size)."""
        B, m = z.shape
        h = _DIFFERENCE_STEP * np.maximum(np.abs(z), 1.0)
        trial = np.repeat(z[:, None, :], m + 1, axis=1)
        trial[:, 1:] += h[:, :, None] * np.eye(m)[None]
        R = self.residual(trial.reshape(B * (m + 1), m), np.repeat(idx, m + 1)).reshape(B, m + 1, m)
        return np.swapaxes((R[:, 1:] - R[:, :1]) / h[:, :, None], 1, 2)

    def solve_one(self, line: int, start: np.ndarray) -> np.ndarray:
        """The unknowns of one line by scipy's ``hybr`` from the element phasors ``start`` (H+1, r)."""
        idx = np.array([line])
        sol = scipy.optimize.root(lambda z: self.residual(z[None], idx)[0], self.pack(start[None], idx)[0],
                                  method="hybr", options={"xtol": 1e-12})
        return sol.x

    def response(self, z: np.ndarray) -> MultiharmonicResponse:
        idx = np.arange(len(z))
        converged = np.linalg.norm(self.residual(z, idx), axis=1) < MULTIHARMONIC_CONVERGED
        Yk = self.unpack(z, idx)
        Fk = self.element_forces(Yk, idx)
        drive = np.zeros((len(z), self.H + 1))
        drive[:, 1] = self.forces
        out = self.Hq * drive[:, :, None] - (self.HE @ Fk[..., None])[..., 0]
        return MultiharmonicResponse(self.w, out, converged, Yk, Fk)


_DIFFERENCE_STEP = 1.5e-8
"""Forward-difference step of the multi-harmonic Jacobian, relative to an unknown (and to the line's linear
response where the unknown is smaller): the square root of the double's rounding."""
