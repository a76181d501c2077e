"""Nonlinear forced response by harmonic balance (docs/method.md §4).

The structure is condensed onto its nonlinear elements (Tanrikulu et al., AIAA J. 31, 1993). With
``E`` the element vectors (``y = E^T x``, element displacements) and ``q`` the excitation DOF:

    x = H(w) e_q F - H(w) E f(y),        y = E^T x

so with the describing functions ``f_i = kbar_i(|y_i|, w) y_i`` the complex element amplitudes solve

    R(y) = y + G(w) (kbar(|y|, w) * y) - g(w) F = 0,      G = E^T H E,  g = E^T H e_q.

``kbar`` depends on ``|y|``, so ``R`` is not holomorphic: Newton works on the ``2r`` real unknowns.
Phasors follow docs/contracts.md §1: a signal ``Im(Y e^{jwt})``, so ``x = X sin(wt)`` has ``Y = X``.

Three solvers work on the condensed system:
- :func:`predict_sweep` -- what a stepped-sine sweep measures: Newton at each line starting from the previous
  line's solution, for all force levels at once. Past a fold the old branch ends and the solver lands on the
  remaining one, as the structure jumps.
- :func:`continue_response` -- pseudo-arclength continuation in (y, w) that passes folds and returns the
  whole response curve, unstable parts marked.
- :func:`predict_multiharmonic` -- several harmonics (and the mean) by alternating frequency-time (AFT)
  evaluation of the laws' own time-domain forces; needed where harmonics matter (bilinear, gap, contact).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.optimize

from .elements import Element
from .structures import Structure

KbarFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


# --------------------------------------------------------------------------- condensation
@dataclass
class CondensedSystem:
    """The structure seen from its nonlinear elements at the lines ``w``.

    Attributes
    ----------
    w : ndarray, shape (L,)
        Lines, rad/s.
    G : ndarray, shape (L, r, r)
        Element-to-element receptance ``E^T H E``.
    g : ndarray, shape (L, r)
        Excitation-to-element receptance ``E^T H e_q``.
    HE : ndarray, shape (L, n, r)
        DOF response to unit element forces, ``H E``.
    Hq : ndarray, shape (L, n)
        DOF response to a unit excitation force, ``H e_q``.
    """

    w: np.ndarray
    G: np.ndarray
    g: np.ndarray
    HE: np.ndarray
    Hq: np.ndarray


def condense(structure: Structure, elements: Sequence[Element], excitation_dof: str, w) -> CondensedSystem:
    """Condense ``structure`` onto ``elements`` at lines ``w`` (rad/s) for excitation at ``excitation_dof``."""
    w = np.atleast_1d(np.asarray(w, float))
    E, loads = _element_loads(structure, elements, excitation_dof)
    resp = structure.response(w, loads)
    HE, Hq = resp[:, :, :-1], resp[:, :, -1]
    return CondensedSystem(w, np.einsum("ni,lnj->lij", E, HE), np.einsum("ni,ln->li", E, Hq), HE, Hq)


def _element_loads(structure: Structure, elements: Sequence[Element], excitation_dof: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Element vectors ``E``, shape (n, r), and the loads ``[E, e_q]``, shape (n, r + 1), whose responses
    ``H [E, e_q]`` condense the structure onto its elements."""
    E = np.stack([el.vector(structure) for el in elements], axis=1) if elements else np.zeros((structure.n, 0))
    return E, np.concatenate([E, np.eye(structure.n)[:, [structure.index(excitation_dof)]]], axis=1)


def element_kbar_functions(elements: Sequence[Element]) -> list[KbarFunction]:
    """The describing function of each element's laws, as ``f(X, w) -> kbar``."""
    return [el.describing_function for el in elements]


def _kbar(kbar_fns: Sequence[KbarFunction], y: np.ndarray, w: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """kbar of every element at amplitudes |y| (B, r), lines w (B,); ``floor`` keeps X > 0 (1/X laws)."""
    X = np.maximum(np.abs(y), floor[:, None])
    return np.stack([fn(X[:, i], w) for i, fn in enumerate(kbar_fns)], axis=1) if kbar_fns else np.zeros_like(y)


def _residual(y, w, G, gF, kbar_fns, floor):
    return y + np.einsum("bij,bj->bi", G, _kbar(kbar_fns, y, w, floor) * y) - gF


def _residual_jacobian(y, w, G, kbar_fns, floor) -> np.ndarray:
    """d[Re R; Im R] / d[Re y; Im y] of :func:`_residual`, shape (B, 2r, 2r).

    With u_i = k_i(|y_i|) y_i:  du_i/dRe y_i = k_i + y_i k_i' Re y_i / |y_i|,
    du_i/dIm y_i = j k_i + y_i k_i' Im y_i / |y_i|, and k_i' = dk_i/dX by one difference in X.
    """
    X = np.maximum(np.abs(y), floor[:, None])
    k = _kbar(kbar_fns, y, w, floor)
    h = 1e-6
    dk = (np.stack([fn(X[:, i] * (1 + h), w) for i, fn in enumerate(kbar_fns)], axis=1) - k) / (X * h)
    du_re = k + y * dk * (y.real / X)
    du_im = 1j * k + y * dk * (y.imag / X)
    r = y.shape[1]
    eye = np.eye(r)[None]
    dR_re = eye + G * du_re[:, None, :]          # column j: d R / d Re y_j
    dR_im = 1j * eye + G * du_im[:, None, :]
    top = np.concatenate([dR_re.real, dR_im.real], axis=2)
    bottom = np.concatenate([dR_re.imag, dR_im.imag], axis=2)
    return np.concatenate([top, bottom], axis=1)


# --------------------------------------------------------------------------- batched Newton
def _to_real(y):
    return np.concatenate([y.real, y.imag], axis=-1)


def _to_complex(z):
    r = z.shape[-1] // 2
    return z[..., :r] + 1j * z[..., r:]


def _newton(fun: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, tol: float = 1e-11,
            max_iter: int = 30, jac: Callable[[np.ndarray], np.ndarray] | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Damped Newton for a batch of independent real systems ``fun(z) = 0``, z of shape (B, m).

    The Jacobian is ``jac(z)`` (B, m, m) when given, else forward differences (the residual is not analytic
    in z); a backtracking line search keeps each item's residual norm decreasing. Returns (z, converged).
    """
    z = z0.copy()
    B, m = z.shape
    R = fun(z)
    norm = np.linalg.norm(R, axis=1)
    for _ in range(max_iter):
        active = norm > tol
        if not active.any():
            break
        if jac is not None:
            J = jac(z)
        else:
            J = np.empty((B, m, m))
            h = 1e-7 * np.maximum(np.abs(z), 1e-3)
            for j in range(m):
                zp = z.copy()
                zp[:, j] += h[:, j]
                J[:, :, j] = (fun(zp) - R) / h[:, j, None]
        try:
            dz = np.linalg.solve(J, -R[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular Jacobian (exactly at a fold): least-norm step
            dz = np.einsum("bij,bj->bi", np.linalg.pinv(J), -R)
        dz[~active] = 0.0
        alpha = np.ones(B)
        improved = np.zeros(B, bool)
        for _ in range(12):
            z_try = z + alpha[:, None] * dz
            R_try = fun(z_try)
            n_try = np.linalg.norm(R_try, axis=1)
            ok = (n_try < norm) | ~active
            take = ok & ~improved
            z[take], R[take], norm[take] = z_try[take], R_try[take], n_try[take]
            improved |= ok
            if improved.all():
                break
            alpha[~improved] *= 0.5
        if not improved[active].any():
            break
    return z, norm <= tol


# --------------------------------------------------------------------------- stepped-sine prediction
@dataclass
class SweepPrediction:
    """Predicted stepped-sine response.

    Attributes
    ----------
    w : ndarray, shape (L,)
        Lines, rad/s (in the caller's order, whatever the sweep direction).
    force : ndarray, shape (B,)
        Force amplitudes, N.
    y : ndarray, shape (L, B, r)
        Element displacement phasors, m or rad.
    receptance : ndarray, shape (L, B, n)
        ``x_p / F`` at every DOF of the structure, m/N.
    converged : ndarray of bool, shape (L, B)
    """

    w: np.ndarray
    force: np.ndarray
    y: np.ndarray
    receptance: np.ndarray
    converged: np.ndarray

    @property
    def amplitude(self) -> np.ndarray:
        """Element amplitudes |y|, shape (L, B, r)."""
        return np.abs(self.y)


def predict_sweep(structure: Structure, elements: Sequence[Element], excitation_dof: str, w, force,
                  direction: str = "up", kbar_fns: Sequence[KbarFunction] | None = None,
                  system: CondensedSystem | None = None) -> SweepPrediction:
    """Single-harmonic response along a stepped-sine sweep at one or more force levels.

    Parameters
    ----------
    structure, elements : the reference structure and its nonlinear elements (with complete law values,
        unless ``kbar_fns`` supplies the describing functions).
    excitation_dof : str
        Where the force acts.
    w : array_like, shape (L,)
        Lines in rad/s.
    force : float or array_like, shape (B,)
        Force amplitude(s), N; every level is swept independently (batched).
    direction : {"up", "down"}
        Sweep direction: decides which branch is followed where the response is multivalued.
    kbar_fns : optional, one ``f(X, w) -> kbar`` per element (default: the elements' laws).
    system : optional precomputed :func:`condense` result for the same lines.
    """
    if direction not in ("up", "down"):
        raise ValueError(f"direction must be 'up' or 'down', got {direction!r}")
    w = np.atleast_1d(np.asarray(w, float))
    F = np.atleast_1d(np.asarray(force, float))
    sys_ = system if system is not None else condense(structure, elements, excitation_dof, w)
    fns = list(kbar_fns) if kbar_fns is not None else element_kbar_functions(elements)
    L, B, r = len(w), len(F), len(fns)
    order = np.argsort(w) if direction == "up" else np.argsort(-w)
    y = np.zeros((L, B, r), complex)
    converged = np.zeros((L, B), bool)
    prev_line = None
    for line in order:
        gF = sys_.g[line][None, :] * F[:, None]                                     # (B, r)
        scale = np.maximum(np.abs(gF).max(axis=1), 1e-300)                          # (B,)
        G = np.broadcast_to(sys_.G[line], (B, r, r))
        wl = np.full(B, w[line])

        def fun(z, G=G, gF=gF, wl=wl, scale=scale):
            yy = _to_complex(z) * scale[:, None]
            return _to_real(_residual(yy, wl, G, gF, fns, 1e-9 * scale) / scale[:, None])

        def jac(z, G=G, wl=wl, scale=scale):
            return _residual_jacobian(_to_complex(z) * scale[:, None], wl, G, fns, 1e-9 * scale)

        # where the previous line had no solution either (e.g. friction holding), one more attempt from the
        # linear response is all that is worth trying
        starts = [gF] if prev_line is None else _restarts(y[prev_line], gF)
        ok = np.zeros(B, bool)
        hopeless = np.zeros(B, bool) if prev_line is None else ~converged[prev_line]
        for attempt, start in enumerate(starts):
            todo = np.flatnonzero(~ok & ~(hopeless & (attempt > 1)))
            if not len(todo):
                break
            z, conv = _newton(lambda zz, t=todo: fun(_pad(zz, t, B))[t], _to_real(start[todo] / scale[todo, None]),
                              jac=lambda zz, t=todo: jac(_pad(zz, t, B))[t])
            sol = _to_complex(z) * scale[todo, None]
            if attempt == 0:
                y[line, todo] = sol  # kept, flagged, if no start converges
            y[line, todo[conv]] = sol[conv]
            ok[todo[conv]] = True
        converged[line] = ok
        prev_line = line
    floor = 1e-9 * np.abs(sys_.g[:, None, :] * F[None, :, None]).max(axis=2).reshape(-1)
    kb = _kbar(fns, y.reshape(L * B, r), np.repeat(w, B), floor).reshape(L, B, r)
    x = sys_.Hq[:, None, :] * F[None, :, None] - np.einsum("lnr,lbr->lbn", sys_.HE, kb * y)
    return SweepPrediction(w, F, y, x / F[None, :, None], converged)


def _restarts(previous, linear):
    """Starting points for one line of a sweep: the previous line's solution first (stay on the branch);
    then, for a jump off a fold where that branch ends, the linear solution and the previous one scaled and
    turned through the quadrants (the other branch has another amplitude and phase)."""
    turned = [previous * a * np.exp(1j * phi) for a in (1.0, 3.0) for phi in (np.pi / 2, np.pi, -np.pi / 2)]
    return [previous, linear, 3.0 * previous, *turned]


def _pad(z_subset, idx, batch):
    """A full batch with the items ``idx`` set (the others zero), for evaluating a subset."""
    full = np.zeros((batch, z_subset.shape[1]))
    full[idx] = z_subset
    return full


# --------------------------------------------------------------------------- continuation
@dataclass
class ResponseCurve:
    """A response curve traced by pseudo-arclength continuation at one force level.

    Attributes
    ----------
    w : ndarray, shape (S,)
        rad/s along the curve (not monotone where the curve folds).
    y : ndarray, shape (S, r)
        Element displacement phasors.
    stable : ndarray of bool, shape (S,)
        False on the parts between two folds (saddle-node turning points), where ``w`` runs backwards
        relative to the start of the curve. This is the single-harmonic fold criterion; other
        instabilities (Hopf, quasi-periodic) are not detected.
    folds : ndarray of int
        Indices of the points where ``w`` turns.
    force : float
    """

    w: np.ndarray
    y: np.ndarray
    stable: np.ndarray
    folds: np.ndarray
    force: float


def continue_response(structure: Structure, elements: Sequence[Element], excitation_dof: str, force: float,
                      w_start: float, w_stop: float, step: float | None = None, max_points: int = 5000,
                      kbar_fns: Sequence[KbarFunction] | None = None) -> ResponseCurve:
    """Trace the single-harmonic response from ``w_start`` to ``w_stop`` (rad/s) through folds.

    Unknowns are the scaled element phasors and w; each step predicts along the tangent of the solution curve
    and corrects with Newton on the residual plus the arclength condition; the step adapts to the number of
    Newton iterations.
    """
    fns = list(kbar_fns) if kbar_fns is not None else element_kbar_functions(elements)
    r = len(fns)
    E, loads = _element_loads(structure, elements, excitation_dof)
    w_scale = abs(w_stop - w_start)
    # unknowns scaled by the largest linear element response over the span, so a resonance peak is O(1)
    grid = np.linspace(w_start, w_stop, 400)
    y_scale = np.abs(condense(structure, elements, excitation_dof, grid).g).max() * force
    sgn = np.sign(w_stop - w_start)

    def residual(v):
        w = v[-1] * w_scale
        resp = structure.response([w], loads)[0]
        G, g = E.T @ resp[:, :-1], E.T @ resp[:, -1]
        yy = _to_complex(v[:-1]) * y_scale
        R = _residual(yy[None], np.array([w]), G[None], (g * force)[None], fns, np.array([1e-9 * y_scale]))[0]
        return _to_real(R) / y_scale

    def jacobian(v):
        R0 = residual(v)
        J = np.empty((2 * r, 2 * r + 1))
        for j in range(2 * r + 1):
            h = 1e-7 * max(abs(v[j]), 1e-3)
            vp = v.copy()
            vp[j] += h
            J[:, j] = (residual(vp) - R0) / h
        return R0, J

    def tangent(J, previous):
        t = np.linalg.svd(J)[2][-1]
        ref = previous if previous is not None else np.r_[np.zeros(2 * r), sgn]
        return t if t @ ref >= 0 else -t

    # first point: Newton at fixed w_start
    first = predict_sweep(structure, elements, excitation_dof, [w_start], force,
                          "up" if sgn > 0 else "down", kbar_fns=fns)
    v = np.r_[_to_real(first.y[0, 0] / y_scale), w_start / w_scale]
    ds = step if step is not None else 0.01
    points, t_prev = [v.copy()], None
    for _ in range(max_points):
        R0, J = jacobian(v)
        t = tangent(J, t_prev)
        for _attempt in range(20):
            v_new, ok, iters = _arclength_correct(residual, jacobian, v + ds * t, t, v, ds)
            if ok:
                break
            ds *= 0.5
        else:
            break
        v, t_prev = v_new, t
        points.append(v.copy())
        ds = min(ds * (1.5 if iters <= 3 else 1.0), 0.05)
        if sgn * (v[-1] * w_scale - w_stop) >= 0:
            break
    P = np.array(points)
    w_path = P[:, -1] * w_scale
    dw = np.diff(w_path) * sgn
    forward = np.r_[True, dw >= 0]
    folds = np.flatnonzero(np.diff(forward.astype(int)) != 0)
    return ResponseCurve(w_path, _to_complex(P[:, :-1]) * y_scale, forward, folds, float(force))


def _arclength_correct(residual, jacobian, v, t, v_prev, ds, tol=1e-10, max_iter=12):
    for it in range(1, max_iter + 1):
        R, J = jacobian(v)
        constraint = t @ (v - v_prev) - ds
        full_R = np.r_[R, constraint]
        if np.linalg.norm(full_R) < tol:
            return v, True, it
        full_J = np.vstack([J, t])
        try:
            v = v - np.linalg.solve(full_J, full_R)
        except np.linalg.LinAlgError:
            return v, False, it
    R = residual(v)
    return v, np.linalg.norm(np.r_[R, t @ (v - v_prev) - ds]) < tol * 100, max_iter


# --------------------------------------------------------------------------- multi-harmonic (AFT)
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
    """

    w: np.ndarray
    harmonics: np.ndarray
    converged: np.ndarray

    def receptance(self, force: float) -> np.ndarray:
        """Fundamental receptance ``X_1 / F``, shape (L, n)."""
        return self.harmonics[:, 1, :] / force


def element_force_history(element: Element, y: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Time-domain force of an element's laws along (y, v), from rest; 1-D arrays."""
    total = np.zeros_like(y)
    for term in element.laws:
        total += term.law.force(y, v, **term.values)
    return total


def predict_multiharmonic(structure: Structure, elements: Sequence[Element], excitation_dof: str, w, force: float,
                          n_harmonics: int = 5, n_time: int = 256, direction: str = "up") -> MultiharmonicResponse:
    """Harmonic balance with ``n_harmonics`` harmonics and the mean, forces by AFT.

    The laws' time-domain kernels are marched over two periods of the trial motion (so hysteretic laws start
    their second cycle on the closed loop) and the second period is transformed. Newton (scipy ``hybr``) runs
    at each line from the previous line's solution, starting from the single-harmonic solution.
    """
    w = np.atleast_1d(np.asarray(w, float))
    H = int(n_harmonics)
    if H < 1 or n_time < 4 * H + 2:
        raise ValueError("need n_harmonics >= 1 and n_time >= 4 n_harmonics + 2")
    r = len(elements)
    E, loads = _element_loads(structure, elements, excitation_dof)
    theta = 2 * np.pi * np.arange(n_time) / n_time
    k = np.arange(H + 1)
    S, C = np.sin(np.outer(theta, k)), np.cos(np.outer(theta, k))
    order = np.argsort(w) if direction == "up" else np.argsort(-w)
    # the single-harmonic solution starts the first line; later lines start from the previous one
    single = predict_sweep(structure, elements, excitation_dof, w[order[:1]], force, direction).y[0, 0]
    out = np.zeros((len(w), H + 1, structure.n), complex)
    converged = np.zeros(len(w), bool)
    previous = None
    for line in order:
        wl = w[line]
        resp = [structure.response([kk * wl], loads)[0] for kk in k]
        HE = np.stack([rsp[:, :-1] for rsp in resp])        # (H+1, n, r)
        Hq = np.stack([rsp[:, -1] for rsp in resp])          # (H+1, n)
        G = np.einsum("ni,knj->kij", E, HE)
        g1 = E.T @ Hq[1]
        scale = max(np.abs(g1).max() * force, 1e-300)

        def forces(Yk):                                      # Yk (H+1, r) complex phasors -> force phasors
            y_t = Yk[0].real[None, :] + S[:, 1:] @ Yk[1:].real + C[:, 1:] @ Yk[1:].imag
            v_t = wl * ((C[:, 1:] * k[1:]) @ Yk[1:].real - (S[:, 1:] * k[1:]) @ Yk[1:].imag)
            f = np.empty_like(y_t)
            for i, el in enumerate(elements):
                f[:, i] = element_force_history(el, np.tile(y_t[:, i], 2), np.tile(v_t[:, i], 2))[n_time:]
            a = 2.0 / n_time * S.T @ f
            b = 2.0 / n_time * C.T @ f
            Fk = a + 1j * b
            Fk[0] = f.mean(axis=0)
            return Fk

        def unpack(z):
            Yk = np.zeros((H + 1, r), complex)
            Yk[0] = z[:r]
            Yk[1:] = (z[r:r + H * r] + 1j * z[r + H * r:]).reshape(H, r)
            return Yk * scale

        def pack(Yk):
            Yk = Yk / scale
            return np.r_[Yk[0].real, Yk[1:].real.ravel(), Yk[1:].imag.ravel()]

        def residual(z):
            Yk = unpack(z)
            R = Yk + np.einsum("kij,kj->ki", G, forces(Yk))
            R[1] -= g1 * force
            return pack(R)

        if previous is None:
            start = np.zeros((H + 1, r), complex)
            start[1] = single
        else:
            start = previous
        sol = scipy.optimize.root(residual, pack(start), method="hybr", options={"xtol": 1e-12})
        Yk = unpack(sol.x)
        Fk = forces(Yk)
        out[line] = np.einsum("kn,k->kn", Hq, np.r_[0.0, force, np.zeros(H - 1)]) - np.einsum("knr,kr->kn", HE, Fk)
        converged[line] = sol.success and np.linalg.norm(residual(sol.x)) < 1e-8
        previous = Yk
    return MultiharmonicResponse(w, out, converged)
