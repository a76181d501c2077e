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
  remaining one, as the structure jumps. A long sweep is solved at all its lines at once and checked to be that
  march, line by line (:func:`_speculative_sweep`): the march's result without a Python step per line.
- :func:`predict_sweeps` -- the same in several directions over the same lines in one batch: where the
  response is multivalued the up and down sweeps give its two stable branches (the jump-robust error).
- :func:`continue_response` -- pseudo-arclength continuation in (y, w) that passes folds and returns the
  whole response curve, unstable parts marked.

Several harmonics (and the mean) by alternating frequency-time evaluation of the laws' own forces, where harmonics
matter (bilinear, gap, contact), are :mod:`analysis.prediction.multiharmonic`'s; it solves with
:func:`_quasi_newton`, defined here beside :func:`_newton`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..common.interrupt import check_stop
from ..mechanics.elements import Element
from ..mechanics.structures import Structure

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
    return _each_element(kbar_fns, X, w)


def _each_element(kbar_fns: Sequence[KbarFunction], X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """kbar of element i at amplitudes X[:, i] and lines w, shape of X (complex)."""
    k = np.zeros(X.shape, complex)
    for i, fn in enumerate(kbar_fns):
        k[:, i] = fn(X[:, i], w)
    return k


def _residual(y, w, G, gF, kbar_fns, floor):
    return y + (G @ (_kbar(kbar_fns, y, w, floor) * y)[..., None])[..., 0] - gF   # matmul: less overhead


def _residual_jacobian(y, w, G, kbar_fns, floor) -> np.ndarray:
    """d[Re R; Im R] / d[Re y; Im y] of :func:`_residual`, shape (B, 2r, 2r).

    With u_i = k_i(|y_i|) y_i:  du_i/dRe y_i = k_i + y_i k_i' Re y_i / |y_i|,
    du_i/dIm y_i = j k_i + y_i k_i' Im y_i / |y_i|, and k_i' = dk_i/dX by one difference in X.
    """
    X = np.maximum(np.abs(y), floor[:, None])
    h = 1e-6
    # kbar at X and at X (1 + h) in one call per element (the calls, not the arithmetic, cost here)
    B = len(w)
    both = np.concatenate([X, X * (1 + h)])
    kk = _each_element(kbar_fns, both, np.concatenate([w, w]))
    k = kk[:B]
    dk = (kk[B:] - k) / (X * h)
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


def _newton(fun: Callable[[np.ndarray, np.ndarray], np.ndarray], jac: Callable[[np.ndarray, np.ndarray], np.ndarray],
            z0: np.ndarray, tol: float = 1e-11, max_iter: int = 30, stalled_tol: float = 0.0,
            needless: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Damped Newton for a batch of independent real systems ``fun(z) = 0``, z of shape (B, m).

    ``fun(z, idx)`` and ``jac(z, idx)`` (shape (len(idx), m, m)) evaluate the items ``idx`` of the batch at
    their unknowns ``z``: only the items still iterating are evaluated, so a batch of many lines costs what its
    slowest items cost, not that times the batch. A backtracking line search keeps each item's residual norm
    decreasing; an item it cannot improve stops there. Returns (z, converged): converged where the residual norm
    is at most ``tol``, or at most ``stalled_tol`` where no step lowers it any more (``fun``'s own rounding is
    reached before ``tol``).

    ``needless(converged)``, where given, names the items (mask) whose answer no longer matters once the items
    ``converged`` have converged; they stop where they are (their flags say where they were left).
    """
    z = z0.copy()
    R = fun(z, np.arange(len(z)))
    norm = np.linalg.norm(R, axis=1)
    stuck = np.zeros(len(z), bool)
    dropped = np.zeros(len(z), bool)
    for _ in range(max_iter):
        check_stop()            # one Newton pass of the batch: where a stop asked for is heard
        if needless is not None:
            dropped |= needless((norm <= tol) | (stuck & (norm <= stalled_tol)))
        active = np.flatnonzero((norm > tol) & ~stuck & ~dropped)
        if not len(active):
            break
        improved = _line_search(fun, z, R, norm, active, _direction(jac(z[active], active), R[active]), 12)
        # an item no step improves is finished: the same unknowns would give the same step again
        stuck[active[~improved]] = True
    return z, (norm <= tol) | (stuck & (norm <= stalled_tol))


def _direction(J: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The Newton step ``-J^-1 R`` of each item (J (B, m, m), R (B, m)); where a Jacobian is singular (exactly at
    a fold), the least-norm step."""
    try:
        return np.linalg.solve(J, -R[..., None])[..., 0]
    except np.linalg.LinAlgError:
        return np.einsum("bij,bj->bi", np.linalg.pinv(J), -R)


_HALVINGS_AT_ONCE = (1, 3)
"""How many of the halved steps :func:`_line_search` tries in one evaluation, round by round (the rest in the last
round): a residual's call costs more than an item of it, and most items take the full step or one of the next few."""


def _line_search(fun, z: np.ndarray, R: np.ndarray, norm: np.ndarray, active: np.ndarray, dz: np.ndarray,
                 halvings: int, taken: Callable | None = None) -> np.ndarray:
    """Backtracking along ``dz`` for the items ``active``: each item takes the first of the steps ``dz``,
    ``dz / 2``, ... (``halvings`` of them) that lowers its residual norm. ``z``, ``R`` and ``norm`` are updated in
    place where one does; ``taken(items, step, change)`` hears of each step taken before that. Returns which of
    ``active`` improved.

    The steps are tried in rounds of several at once (:data:`_HALVINGS_AT_ONCE`), each item's in one call of
    ``fun``: the same step is taken as one tried after the other would take, in fewer calls."""
    improved = np.zeros(len(active), bool)
    first = 0
    for size in _HALVINGS_AT_ONCE + (halvings,):
        tried = np.arange(first, min(first + size, halvings))
        left = np.flatnonzero(~improved)
        if not len(tried) or not len(left):
            break
        first += len(tried)
        items = active[left]
        n, k = len(left), len(tried)
        alpha = np.tile(0.5 ** tried, n)                                     # item by item, its steps in order
        rows = np.repeat(np.arange(n), k)
        z_try = z[items[rows]] + alpha[:, None] * dz[left[rows]]
        R_try = fun(z_try, items[rows])
        n_try = np.linalg.norm(R_try, axis=1)
        lower = (n_try < norm[items[rows]]).reshape(n, k)
        ok = lower.any(axis=1)
        pick = np.flatnonzero(ok) * k + lower[ok].argmax(axis=1)             # each item's first step that lowers
        take = items[ok]
        if taken is not None:
            taken(take, z_try[pick] - z[take], R_try[pick] - R[take])
        z[take], R[take], norm[take] = z_try[pick], R_try[pick], n_try[pick]
        improved[left[ok]] = True
    return improved


def _quasi_newton(fun: Callable[[np.ndarray, np.ndarray], np.ndarray],
                  jac: Callable[[np.ndarray, np.ndarray], np.ndarray], z0: np.ndarray, tol: float,
                  stalled_tol: float, max_iter: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_newton` (its ``fun``, ``jac``, tolerances and result) for systems whose Jacobian costs many
    residuals (a difference Jacobian): Broyden's update of each item's Jacobian after every step taken, and a
    fresh ``jac`` only where a step from an updated one does not lower the residual norm; an item whose fresh
    Jacobian gives no such step stops there.

    Broyden's ("good") update makes the Jacobian map the step taken ``s`` to the residual change ``y`` and
    leaves it unchanged across ``s``: ``J += (y - J s) s^T / (s^T s)``."""
    z = z0.copy()
    B = len(z)
    R = fun(z, np.arange(B))
    norm = np.linalg.norm(R, axis=1)
    J = np.zeros((B,) + z.shape[1:] * 2)
    fresh = norm > tol
    first = np.flatnonzero(fresh)
    if len(first):
        J[first] = jac(z[first], first)
    stuck = np.zeros(B, bool)

    def broyden(take, step, change):
        J[take] += np.einsum("bi,bj->bij", change - np.einsum("bij,bj->bi", J[take], step), step) \
            / np.einsum("bi,bi->b", step, step)[:, None, None]
        fresh[take] = False

    for _ in range(max_iter):
        check_stop()            # one pass of the batch: where a stop asked for is heard
        active = np.flatnonzero((norm > tol) & ~stuck)
        if not len(active):
            break
        improved = _line_search(fun, z, R, norm, active, _direction(J[active], R[active]), 8, broyden)
        failed = active[~improved]
        stuck[failed[fresh[failed]]] = True
        renew = failed[~fresh[failed]]
        if len(renew):
            J[renew] = jac(z[renew], renew)
            fresh[renew] = True
    return z, (norm <= tol) | (stuck & (norm <= stalled_tol))


# --------------------------------------------------------------------------- stepped-sine prediction
@dataclass
class SweepPrediction:
    """Predicted stepped-sine response.

    Attributes
    ----------
    w : ndarray, shape (L,)
        Lines, rad/s (in the caller's order, whatever the sweep direction).
    force : ndarray, shape (B,) or (L, B)
        Force amplitudes, N, as given: one per level, or one per line and level (the measured force).
    y : ndarray, shape (L, B, r)
        Element displacement phasors, m or rad.
    receptance : ndarray, shape (L, B, n)
        ``x_p / F`` at every DOF of the structure, m/N.
    converged : ndarray of bool, shape (L, B)
    stable : ndarray of bool, shape (L, B)
        The balance Jacobian at the solution has a positive determinant (not on the saddle branch between two
        folds; :class:`ResponseCurve`).
    """

    w: np.ndarray
    force: np.ndarray
    y: np.ndarray
    receptance: np.ndarray
    converged: np.ndarray
    stable: np.ndarray

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
    force : float or array_like, shape (B,) or (L, B)
        Force amplitude(s), N; every level is swept independently (batched). Shape (L, B): each line at its own
        force (a controller's measured force per line, which is not the nominal level).
    direction : {"up", "down"}
        Sweep direction: decides which branch is followed where the response is multivalued.
    kbar_fns : optional, one ``f(X, w) -> kbar`` per element (default: the elements' laws).
    system : optional precomputed :func:`condense` result for the same lines.
    """
    return predict_sweeps(structure, elements, excitation_dof, w, force, [direction], kbar_fns, system)[0]


def predict_sweeps(structure: Structure, elements: Sequence[Element], excitation_dof: str, w, force,
                   directions: Sequence[str] = ("up", "down"), kbar_fns: Sequence[KbarFunction] | None = None,
                   system: CondensedSystem | None = None,
                   near: NearStart | None = None) -> list[SweepPrediction]:
    """:func:`predict_sweep` for several sweep directions over the same lines, solved in one batch (every
    direction and force level advances one line per step): one prediction per direction.

    Where the response is multivalued the two directions follow different stable branches, so the up and
    down sweeps together give every stable solution a stepped sine can measure there.

    ``near``, where given, holds a prediction of the same lines, forces and directions (items: each direction's
    levels in turn) for describing functions a hair away, a finite difference's step: each sweep converged and
    stable at every line there is solved at all its lines at once from it, on its branches, and swept only where
    that fails (:func:`_from_near`).
    """
    for direction in directions:
        if direction not in ("up", "down"):
            raise ValueError(f"direction must be 'up' or 'down', got {direction!r}")
    w = np.atleast_1d(np.asarray(w, float))
    F1 = np.asarray(force, float)
    per_line = line_forces(F1, len(w))                                               # (L, B)
    sys_ = system if system is not None else condense(structure, elements, excitation_dof, w)
    fns = list(kbar_fns) if kbar_fns is not None else element_kbar_functions(elements)
    D = len(directions)
    F = np.tile(per_line, (1, D))                                                    # (L, D B)
    orders = np.repeat(np.stack([np.argsort(w) if d == "up" else np.argsort(-w) for d in directions]),
                       per_line.shape[1], axis=0)                                    # (D B, L)
    y, converged = _sweep(sys_, fns, F, orders, near)
    L, B, r = len(w), F.shape[1], len(fns)
    floor = 1e-9 * np.abs(sys_.g[:, None, :] * F[:, :, None]).max(axis=2).reshape(-1)
    kb = _kbar(fns, y.reshape(L * B, r), np.repeat(w, B), floor).reshape(L, B, r)
    x = (sys_.Hq[:, None, :] * F[:, :, None] - np.einsum("lnr,lbr->lbn", sys_.HE, kb * y)) / F[:, :, None]
    J = _residual_jacobian(y.reshape(L * B, r), np.repeat(w, B), np.repeat(sys_.G, B, axis=0), fns, floor)
    stable = (np.linalg.det(J) > 0).reshape(L, B) if r else np.ones((L, B), bool)
    n = per_line.shape[1]
    F1 = np.atleast_1d(F1)
    part = [slice(k * n, (k + 1) * n) for k in range(D)]
    return [SweepPrediction(w, F1, y[:, p], x[:, p], converged[:, p], stable[:, p]) for p in part]


def line_forces(force, n_lines: int) -> np.ndarray:
    """Force amplitudes (L, B) of every line and level from one per level (B,) or one per line (L, B)."""
    F = np.asarray(force, float)
    if F.ndim < 2:
        return np.broadcast_to(np.atleast_1d(F)[None, :], (n_lines, np.atleast_1d(F).size)).copy()
    if F.shape[0] != n_lines:
        raise ValueError(f"a force per line needs shape (lines, levels) = ({n_lines}, B), got {F.shape}")
    return F



MARCHED_STEPS = 8      # a sweep of at most this many lines is marched line by line (benchmarks/prediction_march.py)
COARSENING = 8        # the guess of a speculative sweep comes from the sweep over every so many lines
SPECULATIVE_ITERATIONS = 8   # a line of the batch solves not converged in as many is left to the march
IN_STEP = 1e-8         # two solutions of a line closer than this (relative to its linear response) are one;
# a residual this small where Newton can lower it no further is a solution: a placed contact's describing
# function is only as exact as its own balance (1e-10 of X, analysis/mechanics/surroundings.py), and Newton's
# 1e-11 lies below that


@dataclass
class _LineBalances:
    """The balance at a batch of (line, force) items, each scaled by its linear response ``max |g F|`` so that
    Newton's tolerance is relative: ``residual(z, idx)`` and ``jacobian(z, idx)`` of the items ``idx``."""

    G: np.ndarray        # (N, r, r)
    gF: np.ndarray       # (N, r)
    w: np.ndarray        # (N,)
    scale: np.ndarray    # (N,)
    fns: Sequence[KbarFunction]

    @classmethod
    def at(cls, sys_: CondensedSystem, fns, lines: np.ndarray, force: np.ndarray) -> "_LineBalances":
        gF = sys_.g[lines] * force[:, None]
        return cls(sys_.G[lines], gF, sys_.w[lines], np.maximum(np.abs(gF).max(axis=1), 1e-300), fns)

    def residual(self, z, idx):
        scale = self.scale[idx, None]
        y = _to_complex(z) * scale
        return _to_real(_residual(y, self.w[idx], self.G[idx], self.gF[idx], self.fns, 1e-9 * scale[:, 0]) / scale)

    def jacobian(self, z, idx):
        scale = self.scale[idx]
        return _residual_jacobian(_to_complex(z) * scale[:, None], self.w[idx], self.G[idx], self.fns, 1e-9 * scale)

    def solve(self, start: np.ndarray, items: np.ndarray, max_iter: int = 30,
              needless: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Newton for the items ``items`` from the phasors ``start`` (len(items), r): (phasors, converged);
        ``needless`` as for :func:`_newton`."""
        scale = self.scale[items, None]
        z, conv = _newton(lambda zz, i: self.residual(zz, items[i]), lambda zz, i: self.jacobian(zz, items[i]),
                          _to_real(start / scale), max_iter=max_iter, stalled_tol=IN_STEP, needless=needless)
        return _to_complex(z) * scale, conv


@dataclass(frozen=True)
class NearStart:
    """The element phasors ``y`` (L, B, r) of a prediction a hair away and where they are converged and stable,
    ``ok`` (L, B): where :func:`predict_sweeps` starts a finite difference's step."""

    y: np.ndarray
    ok: np.ndarray


def _sweep(sys_: CondensedSystem, fns, F, orders, near: NearStart | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Newton along each batch item's own line order ``orders[b]`` (B, S), each line at its force ``F`` (L, B) and
    started from the previous line's solution: the element phasors (L, B, r) and convergence flags (L, B), at the
    lines of ``orders``.

    A short sweep is marched line by line. A long one is solved at all its lines at once and then checked to be
    what the march gives (:func:`_speculative_sweep`): the same solutions, without a Python step per line.
    ``near``: items solved at every line from a prediction a hair away (:func:`_from_near`), the rest swept."""
    B, S = orders.shape
    y = np.zeros((len(sys_.w), B, len(fns)), complex)
    converged = np.zeros((len(sys_.w), B), bool)
    if near is not None:
        rest = np.flatnonzero(~_from_near(sys_, fns, F, near, y, converged))
        if len(rest):
            y[:, rest], converged[:, rest] = _sweep(sys_, fns, F[:, rest], orders[rest])
        return y, converged
    if S <= MARCHED_STEPS:
        for step in range(S):
            _march_step(sys_, fns, F, orders, step, np.arange(B), y, converged)
    else:
        _speculative_sweep(sys_, fns, F, orders, y, converged)
    return y, converged


def _from_near(sys_: CondensedSystem, fns, F, near: NearStart, y, converged) -> np.ndarray:
    """The items (mask (B,)) whose solution a hair away converged and was stable at every line and from which
    Newton converges at every line again; ``y`` and ``converged`` are set there.

    A step of a finite difference moves each solution by about the step, so Newton from it converges in a few
    iterations at every line at once, and stays on the branch the prediction it was taken at follows: the
    difference is the derivative along those branches, not a jump moved to the next line by the step."""
    L, B = F.shape
    items = np.flatnonzero(near.ok.all(axis=0))
    done = np.zeros(B, bool)
    if not len(items):
        return done
    lines, which = np.repeat(np.arange(L), len(items)), np.tile(items, L)
    balances = _LineBalances.at(sys_, fns, lines, F[lines, which])
    sol, ok = balances.solve(near.y[lines, which], np.arange(len(lines)), SPECULATIVE_ITERATIONS)
    whole = ok.reshape(L, len(items)).all(axis=0)
    taken = items[whole]
    y[:, taken] = sol.reshape(L, len(items), -1)[:, whole]
    converged[:, taken] = True
    done[taken] = True
    return done


def _march_step(sys_: CondensedSystem, fns, F, orders, step: int, items: np.ndarray, y, converged) -> None:
    """One line of the march for the batch items ``items``: Newton from the previous line's solution, then
    from the restarts of :func:`_restarts` for those that did not converge, each taking the first restart
    in that order that converges; ``y`` and ``converged`` are set.

    The restarts of all items are solved as one batch: the answer is what trying them one after the other
    gives, at the cost of one Newton solve instead of one per restart."""
    line = orders[items, step]
    balances = _LineBalances.at(sys_, fns, line, F[line, items])
    if step == 0:
        sol, ok = balances.solve(balances.gF, np.arange(len(items)))
        y[line, items], converged[line, items] = sol, ok
        return
    previous = y[orders[items, step - 1], items]
    sol, ok = balances.solve(previous, np.arange(len(items)))    # kept, flagged, where no restart converges
    todo = np.flatnonzero(~ok)
    if len(todo):
        starts = _restarts(previous[todo], balances.gF[todo])                  # (A, len(todo), r)
        # where the previous line had no solution either (e.g. friction holding), one more attempt from the
        # linear response is all that is worth trying
        hopeless = ~converged[orders[items[todo], step - 1], items[todo]]
        tried = np.ones(starts.shape[:2], bool)
        tried[1:, hopeless] = False
        attempt, which = np.nonzero(tried)                      # attempt by attempt, so in order per item
        rsol, rok = balances.solve(starts[attempt, which], todo[which], needless=_after_the_first(which))
        won = np.flatnonzero(rok)
        winners, first = np.unique(which[won], return_index=True)             # each item's first that converged
        sol[todo[winners]], ok[todo[winners]] = rsol[won[first]], True
    y[line, items], converged[line, items] = sol, ok


def _after_the_first(which: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """For attempts of items ``which`` (in order per item): the attempts that come after one of their item's that
    has converged. Only an item's first converged attempt is taken, so these need not be solved on: an attempt
    before it may still converge and is solved to its end, and the answer is what solving them all gives."""
    def needless(converged: np.ndarray) -> np.ndarray:
        first = np.full(which.max() + 1, len(which))
        np.minimum.at(first, which[converged], np.flatnonzero(converged))
        return np.arange(len(which)) > first[which]
    return needless


def _restarts(previous, linear) -> np.ndarray:
    """Starting points (A, B, r) for lines of a sweep that did not converge from the previous line's solution:
    the linear solution, then the previous one scaled and turned through the quadrants -- for a jump off a fold
    where the branch ends, the other branch has another amplitude and phase."""
    turns = [a * np.exp(1j * phi) for a in (1.0, 3.0) for phi in (np.pi / 2, np.pi, -np.pi / 2)]
    return np.stack([linear, 3.0 * previous] + [previous * t for t in turns])


def _speculative_sweep(sys_: CondensedSystem, fns, F, orders, y, converged) -> None:
    """The march of :func:`_sweep`, its lines solved all at once.

    The sweep over every other line (recursively) gives a guess at every line, by interpolation in w. Newton
    at every line from the guess at the line before gives ``first``; Newton at every line from ``first`` at
    the line before gives ``second``. Where the march's solution at a line is ``first`` there (within
    :data:`IN_STEP`), its next line is Newton from the same start as ``second``'s, so the march takes ``second``
    there if it converged; elsewhere -- past a jump the guess put on another branch, lines with no solution --
    it is marched line by line until it is back in step with ``first``.
    """
    B, S = orders.shape
    coarse = np.unique(np.r_[np.arange(0, S, COARSENING), S - 1])
    y_coarse, _ = _sweep(sys_, fns, F, orders[:, coarse])
    guess = _interpolated(sys_.w, orders, coarse, y_coarse)
    balances = _LineBalances.at(sys_, fns, orders.reshape(-1),
                                F[orders, np.arange(B)[:, None]].reshape(-1))        # item b S + s
    first, _ = _from_line_before(balances, guess)
    second, conv = _from_line_before(balances, first)
    scale = balances.scale.reshape(B, S)
    close = np.abs(second - first).max(axis=2) <= IN_STEP * scale
    _reconcile(sys_, fns, F, orders, first, second, conv, close, scale, y, converged)


def _interpolated(w, orders, coarse, y_coarse) -> np.ndarray:
    """Guesses (B, S, r) at every step of the sweeps ``orders`` from their solutions ``y_coarse`` (by line)
    at the steps ``coarse``: linear in w between the coarse steps on either side."""
    B, S = orders.shape
    steps = np.arange(S)
    hi = np.searchsorted(coarse, steps)                         # the coarse step at or after each step
    lo = hi - (coarse[hi] != steps)
    a, c = coarse[lo], coarse[hi]
    ws = w[orders]                                              # (B, S)
    span = ws[:, c] - ws[:, a]
    t = np.where(span != 0, (ws - ws[:, a]) / np.where(span != 0, span, 1.0), 0.5)
    ys = y_coarse[orders, np.arange(B)[:, None]]               # (B, S, r); set at the coarse steps only
    return ys[:, a] + t[..., None] * (ys[:, c] - ys[:, a])


def _from_line_before(balances: _LineBalances, before: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Newton at every step from ``before`` (B, S, r) at the step before (the first step from the linear
    response, as the march starts): (phasors (B, S, r), converged (B, S))."""
    B, S, r = before.shape
    start = np.concatenate([balances.gF.reshape(B, S, r)[:, :1], before[:, :-1]], axis=1)
    sol, conv = balances.solve(start.reshape(B * S, r), np.arange(B * S), SPECULATIVE_ITERATIONS)
    return sol.reshape(B, S, r), conv.reshape(B, S)


def _reconcile(sys_, fns, F, orders, first, second, conv, close, scale, y, converged) -> None:
    """The march over the steps of ``orders``, taking ``second`` wherever it is what the march computes
    (:func:`_speculative_sweep`): an item in step at step s - 1 (its solution is ``first`` there) takes
    ``second`` at step s if that converged, and stays in step if it is ``close`` to ``first``."""
    B, S = orders.shape
    items = np.arange(B)
    leaves = ~conv
    leaves[:, 1:] |= ~close[:, :-1]
    events = np.flatnonzero(leaves.any(axis=0))             # the steps where some item may leave the batch's
    in_step = np.ones(B, bool)
    s = 0
    while s < S:
        if in_step.all() and conv[:, s].all():              # every item takes the batch's solutions up to the next event
            end = events[np.searchsorted(events, s, side="right")] if events.size and events[-1] > s else S
            lines = orders[:, s:end].T
            y[lines, items] = second[:, s:end].transpose(1, 0, 2)
            converged[lines, items] = True
            in_step = close[:, end - 1].copy()
            s = end
            continue
        take = in_step & conv[:, s]
        y[orders[take, s], items[take]] = second[take, s]
        converged[orders[take, s], items[take]] = True
        if not take.all():
            _march_step(sys_, fns, F, orders, s, np.flatnonzero(~take), y, converged)
        in_step = np.abs(y[orders[:, s], items] - first[:, s]).max(axis=1) <= IN_STEP * scale[:, s]
        s += 1


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
        False where the Jacobian of the balance at fixed w has a negative determinant: an odd number of real
        eigenvalues of the slow flow have crossed zero, the saddle-node instability of the middle branch
        between two folds. The fold points themselves count as stable (a sweep reaches them). Other
        instabilities (Hopf, quasi-periodic) are not detected.
    folds : ndarray of int
        Indices of the fold (turning) points, located to 1e-9 of the arclength.
    force : float
    complete : bool
        Whether the curve reached ``w_stop`` (not stopped by ``max_points``, by turning back out of the span or,
        asked to, at its first fold).
    """

    w: np.ndarray
    y: np.ndarray
    stable: np.ndarray
    folds: np.ndarray
    force: float
    complete: bool = True

    @property
    def fold_frequencies(self) -> np.ndarray:
        """w at the folds, rad/s."""
        return self.w[self.folds]


class _Balance:
    """The condensed single-harmonic balance at one force level as a function of scaled unknowns
    ``v = [Re y / ys, Im y / ys, w / ws]``, for continuation."""

    def __init__(self, structure, elements, excitation_dof, force, kbar_fns, y_scale, w_scale):
        self.structure, self.force, self.fns = structure, float(force), kbar_fns
        self.E, self.loads = _element_loads(structure, elements, excitation_dof)
        self.ys, self.ws = y_scale, w_scale
        self.r = len(kbar_fns)
        self.floor = np.array([1e-9 * y_scale.max()])

    def _system(self, w):
        resp = self.structure.response([w], self.loads)[0]
        return self.E.T @ resp[:, :-1], self.E.T @ resp[:, -1] * self.force

    def unknowns(self, y, w) -> np.ndarray:
        return np.r_[y.real / self.ys, y.imag / self.ys, w / self.ws]

    def phasors(self, v) -> np.ndarray:
        return (v[: self.r] + 1j * v[self.r: 2 * self.r]) * self.ys

    def residual(self, v) -> np.ndarray:
        G, gF = self._system(v[-1] * self.ws)
        R = _residual(self.phasors(v)[None], np.array([v[-1] * self.ws]), G[None], gF[None], self.fns, self.floor)
        return _to_real(R[0] / self.ys)

    def jacobian(self, v) -> tuple[np.ndarray, np.ndarray]:
        """Residual and its Jacobian (2r, 2r + 1): analytic in y, one difference in w."""
        w = v[-1] * self.ws
        G, gF = self._system(w)
        y = self.phasors(v)
        R = _to_real(_residual(y[None], np.array([w]), G[None], gF[None], self.fns, self.floor)[0] / self.ys)
        Jy = _residual_jacobian(y[None], np.array([w]), G[None], self.fns, self.floor)[0]
        Jy = Jy * np.r_[self.ys, self.ys][None, :] / np.r_[self.ys, self.ys][:, None]
        h = 1e-7 * max(abs(v[-1]), 1e-3)
        vp = v.copy()
        vp[-1] += h
        return R, np.column_stack([Jy, (self.residual(vp) - R) / h])

    def solve_at(self, y0, w, tol=1e-11) -> tuple[np.ndarray, bool]:
        """Newton at fixed w from ``y0``."""
        v = self.unknowns(y0, w)
        for _ in range(30):
            R, J = self.jacobian(v)
            if np.linalg.norm(R) < tol:
                return self.phasors(v), True
            v[:-1] -= np.linalg.lstsq(J[:, :-1], R, rcond=None)[0]
        return self.phasors(v), bool(np.linalg.norm(self.residual(v)) < 1e3 * tol)


def _tangent(J, previous) -> np.ndarray:
    """Unit tangent of the solution curve: the null vector of J, oriented along ``previous`` (Keller's
    bordered system ``[J; t_prev] t = [0; 1]``), which keeps the direction of travel through folds."""
    t = np.linalg.solve(np.vstack([J, previous]), np.r_[np.zeros(J.shape[0]), 1.0])
    return t / np.linalg.norm(t)


def _arclength_correct(balance, v_prev, t, ds, tol=1e-10, max_iter=8):
    """Newton on the residual plus the arclength condition ``t . (v - v_prev) = ds`` from the tangent
    prediction; returns (v, converged, iterations)."""
    v = v_prev + ds * t
    for it in range(1, max_iter + 1):
        R, J = balance.jacobian(v)
        full_R = np.r_[R, t @ (v - v_prev) - ds]
        if np.linalg.norm(full_R) < tol:
            return v, True, it
        try:
            v = v - np.linalg.solve(np.vstack([J, t]), full_R)
        except np.linalg.LinAlgError:
            return v, False, it
        if not np.isfinite(v).all():
            return v, False, it
    return v, bool(np.linalg.norm(np.r_[balance.residual(v), t @ (v - v_prev) - ds]) < tol), max_iter


def _amplitude_scale(structure, elements, excitation_dof, force, w_start, w_stop, fns) -> np.ndarray:
    """Per-element amplitude scale of the continuation: the largest amplitude either sweep direction reaches
    over the span, so the amplitude and the frequency parts of the arclength are both O(1). (The linear
    response is no scale: undamped, its peak is unbounded.)"""
    grid = np.linspace(min(w_start, w_stop), max(w_start, w_stop), 80)
    system = condense(structure, elements, excitation_dof, grid)
    amp = np.zeros(len(fns))
    for direction in ("up", "down"):
        pred = predict_sweep(structure, elements, excitation_dof, grid, force, direction, fns, system)
        amp = np.maximum(amp, np.abs(pred.y[:, 0, :]).max(axis=0))
    return np.maximum(amp, 1e-6 * max(amp.max(), 1e-300))


def continue_response(structure: Structure, elements: Sequence[Element], excitation_dof: str, force: float,
                      w_start: float, w_stop: float, step: float | None = None, max_points: int = 5000,
                      kbar_fns: Sequence[KbarFunction] | None = None, y_start=None,
                      until_fold: bool = False) -> ResponseCurve:
    """Trace the single-harmonic response from ``w_start`` to ``w_stop`` (rad/s, either order) through folds.

    The unknowns are the element phasors scaled by the largest amplitude either sweep reaches in the span and
    w scaled by the span. Each step predicts along the tangent and corrects with Newton on the residual plus
    the arclength condition. A step is taken back and halved when Newton does not converge in 8 iterations or
    the tangent turns by more than 0.2 rad; it grows by 1.5 after easy steps, up to ``step`` (default 0.02 of
    the scaled curve). Folds are located where the tangent's w component changes sign (secant on the arclength
    to 1e-9), and the curve ends exactly at ``w_stop``. It also ends, ``complete`` False, after ``max_points``
    or if it turns back out of the span. ``y_start`` (element phasors at ``w_start``) picks the branch to
    start on; default: a sweep's solution at ``w_start``. ``until_fold``: the curve ends, ``complete`` False, at
    the first fold (where a sweep's branch ends: all a jump needs; past it the curve can wind through the span
    for hundreds of steps).
    """
    fns = list(kbar_fns) if kbar_fns is not None else element_kbar_functions(elements)
    sgn = 1.0 if w_stop > w_start else -1.0
    span = abs(w_stop - w_start)
    ys = _amplitude_scale(structure, elements, excitation_dof, force, w_start, w_stop, fns)
    bal = _Balance(structure, elements, excitation_dof, force, fns, ys, span)
    if y_start is None:
        y_start = predict_sweep(structure, elements, excitation_dof, [w_start], force,
                                "up" if sgn > 0 else "down", kbar_fns=fns).y[0, 0]
    y0, _ = bal.solve_at(np.asarray(y_start, complex), w_start)
    v = bal.unknowns(y0, w_start)
    ds_max = step if step is not None else 0.02
    ds = ds_max / 4
    J = bal.jacobian(v)[1]
    t = _tangent(J, np.r_[np.zeros(2 * bal.r), sgn])
    points, dets, folds, complete = [v.copy()], [np.linalg.det(J[:, :-1])], [], False
    lo, hi = min(w_start, w_stop) - span, max(w_start, w_stop) + span
    while len(points) <= max_points:
        v_new, ok, iters = _arclength_correct(bal, v, t, ds)
        if ok:
            J_new = bal.jacobian(v_new)[1]
            t_new = _tangent(J_new, t)
        if not ok or t_new @ t < np.cos(0.2):
            ds *= 0.5
            if ds < 1e-9:
                break
            continue
        if np.sign(t_new[-1]) != np.sign(t[-1]) and t[-1] != 0:
            folds.append(len(points))
            points.append(_locate_fold(bal, v, t, ds))
            dets.append(0.0)
            if until_fold:
                break
        w_new = v_new[-1] * span
        if sgn * (w_new - w_stop) >= 0:                        # past the end: the last point exactly at w_stop
            frac = (w_stop / span - v[-1]) / (v_new[-1] - v[-1])
            y_end, _ = bal.solve_at(bal.phasors(v + frac * (v_new - v)), w_stop)
            points.append(bal.unknowns(y_end, w_stop))
            dets.append(np.linalg.det(bal.jacobian(points[-1])[1][:, :-1]))
            complete = True
            break
        v, t = v_new, t_new
        points.append(v.copy())
        dets.append(np.linalg.det(J_new[:, :-1]))
        if not lo < w_new < hi or w_new <= 0:
            break
        ds = min(ds * (1.5 if iters <= 3 else 1.0), ds_max)
    P = np.array(points)
    y = (P[:, : bal.r] + 1j * P[:, bal.r: 2 * bal.r]) * ys[None, :]
    stable = np.array(dets) >= 0                               # the folds (0) count as stable
    return ResponseCurve(P[:, -1] * span, y, stable, np.array(folds, int), float(force), complete)


def _locate_fold(balance, v, t, ds, tol=1e-9):
    """The point between ``v`` (tangent ``t``) and the arclength ``ds`` further where the tangent's w
    component is zero: bracketed secant (Illinois) on the arclength."""
    def tw(s):
        p, ok, _ = _arclength_correct(balance, v, t, s)
        return p, _tangent(balance.jacobian(p)[1], t)[-1]

    a, fa = 0.0, t[-1]
    b = ds
    p_b, fb = tw(b)
    p = p_b
    for _ in range(60):
        s = b - fb * (b - a) / (fb - fa) if fb != fa else 0.5 * (a + b)
        if not min(a, b) < s < max(a, b):
            s = 0.5 * (a + b)
        p, fs = tw(s)
        if abs(fs) < tol or abs(b - a) < tol:
            break
        if np.sign(fs) == np.sign(fb):
            fa *= 0.5                      # Illinois: the end kept twice is halved, so both ends move
        else:
            a, fa = b, fb
        b, fb = s, fs
    return p

