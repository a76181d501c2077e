"""The structure around one element, and the describing function of a contact law placed in it.

A contact that closes has harmonics as large as its fundamental -- a one-sided one (:attr:`Law.placed`:
unilateral, and bilinear, its zero-clearance limit beside a linear spring) a mean and even harmonics, a two-sided
one (gap) odd harmonics. They move the structure: the mean to a
new static position, the harmonics to a response at 2w, 3w, ... And the element sees that motion, so how far
its contact closes over a cycle -- hence its fundamental, hence kbar -- depends on the structure around it, not
on the amplitude X alone. The plain describing function (``x = X sin wt`` at the element, nothing else) leaves
this out; for a contact whose stiffness is comparable to the structure's a one-sided one is off by 10-25 % in
Re kbar near resonance (tests/test_surroundings.py, against time integration).

Here the element is placed: its displacement is ``x = x0 + X sin(wt) + sum_{n=2..N} Re(x_n e^{jnwt})`` with
the fundamental given and the other harmonics balanced against the structure seen at the element,

    x_n = -R(n w) f_n        (n = 0, 2, 3, ..., N)

``R(W) = e^T Z(W)^-1 e`` the receptance of the rest at the element (the structure plus the element's own
amplitude-independent laws, springs and dampers in parallel), ``f_n`` the harmonics of the law's own
time-domain force. ``n = 0`` is the static balance ``x0 = -R(0) f0(x0, X)`` (the mean force against the static
compliance). The balance is solved by alternating frequency and time (AFT) with Newton steps (the law's tangent
stiffness along the cycle couples the harmonics; a contact as stiff as the structure near one of its modes needs
that coupling), only for the samples where the contact acts. kbar is then ``f_1 / X``. The fundamental is the
element's own (the identification measures it; the harmonic balance solves for it); the other elements'
harmonics, which the single-harmonic model has none of, are left out: a limit, stated in docs/method.md.
"""
from __future__ import annotations

import functools
import itertools
import os
import weakref
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from ..common.compiled import njit, njit_fixed
from ..common.parallel import task_scope
from ..common.recent import Recent
from ..common.small_solve import NOT_FINITE, SINGULAR, solve_small
from ..laws import Law
from ..laws.base import Origin, broadcast
from .structures import Structure

#: Harmonics balanced besides the fundamental (0, 2, ..., N). On a single mass 5 are within 0.01 % of the
#: converged kbar; a chain's higher modes can resonate with a harmonic, and 5 harmonics can then leave an error of
#: percents in Im kbar, which 9 take down a hundredfold.
N_HARMONICS = 9
# Samples per cycle of the AFT evaluation (well above 2 N + 1: the contact's kink is sampled finely)
N_TIME = 128
# Newton steps per sample. A balance converges in 2-3 steps (at most 7 on all but 3 of the 416 000 samples the
# paper-2dof discovery places); one that has not in 12 has none to find (a harmonic of a contact as stiff as the
# structure at one of its modes: its residual stalls at a few % of X however damped the steps), and keeps its
# last step (:func:`placed_kbar`).
_MAX_ITERATIONS = 12
# Newton steps from the balance last solved at the same samples before a sample starts again from no harmonics:
# a nearby solution converges in 2-3 (one step where the contact's closed part over the cycle is unchanged)
_WARM_ITERATIONS = 4
# Sets of samples whose last balance is kept
_STARTS_KEPT = 8
# Relative change of the harmonics (to X) below which the balance has converged
_TOLERANCE = 1e-10
# The balance's sums may be reordered (vectorised): its answer is converged to _TOLERANCE, far above their rounding
_REASSOCIATE = {"reassoc", "contract"}
# The Newton kernel's ``fundamental`` argument where it is to leave the force's fundamental alone
_NO_KBAR = np.empty((0, 2))


@dataclass
class Surroundings:
    """The rest of the structure as an element sees it: ``receptance(W) = e^T Z(W)^-1 e`` (m/N), W in rad/s.

    ``parallel(W)`` adds the element's own amplitude-independent laws (a dynamic stiffness in parallel)."""

    structure: Structure
    vector: np.ndarray
    parallel: Callable[[np.ndarray], np.ndarray] | None = None
    _receptances: "_Receptances" = field(default_factory=lambda: _Receptances(), repr=False, compare=False)
    _at_harmonics: tuple | None = field(default=None, repr=False, compare=False)
    # the balances last solved at a few sets of samples (placed_kbar), shared with the copies of with_parallel: a
    # fit asks the same samples again and again, at parameters a step apart
    starts: "_Starts" = field(default_factory=lambda: _Starts(), repr=False, compare=False)
    # the structure was made from a measured level and holds the element's small-amplitude stiffness: the
    # element's laws are measured from their small-amplitude state (analysis.laws.base.Law.relative), or from
    # ``origin`` where the reference records the element's state at the level it was made from
    in_reference: bool = False
    origin: Origin | None = None

    def receptance(self, W) -> np.ndarray:
        """R(W) for angular frequencies W (any shape), complex; NaN at a frequency that is not finite. Each
        frequency's R is computed once and kept (:class:`_Receptances`)."""
        W = np.asarray(W, float)
        R = self._receptances.at(W.ravel(), self._response).reshape(W.shape)
        if self.parallel is None:
            return R
        return R / (1.0 + R * self.parallel(W))

    def _response(self, W: np.ndarray) -> np.ndarray:
        """R(W) of the structure alone, computed (W 1-D)."""
        return self.structure.response(W, self.vector[:, None])[:, :, 0] @ self.vector

    def at_harmonics(self, w: np.ndarray, cycle: "_Cycle") -> np.ndarray:
        """R at the harmonics balanced (:attr:`_Cycle.harmonics`) of the lines ``w``, shape (S, H) complex, the static
        one real; the last lines asked are kept (a fit asks the same samples' lines many times)."""
        key = (w.tobytes(), cycle.harmonics.tobytes(), id(self.parallel))
        if self._at_harmonics is None or self._at_harmonics[0] != key:
            R = np.array(self.receptance(w[:, None] * cycle.harmonics[None, :]), complex)
            R[:, 0] = R[:, 0].real
            self._at_harmonics = (key, R)
        return self._at_harmonics[1]

    def with_parallel(self, stiffness: Callable[[np.ndarray], np.ndarray] | None) -> "Surroundings":
        """The same place with the element's amplitude-independent laws ``stiffness(W)`` in parallel (sharing
        the structure's receptances)."""
        return Surroundings(self.structure, self.vector, stiffness, self._receptances, starts=self.starts,
                            in_reference=self.in_reference, origin=self.origin)


class _Receptances:
    """The receptances a place has computed, ``R`` at the frequencies ``W`` sorted, shared by its copies
    (:meth:`Surroundings.with_parallel`) and looked up by bisection: a dictionary looked up once per sample and
    harmonic in Python cost about 1 % of a loop on measured data."""

    __slots__ = ("W", "R")

    def __init__(self):
        self.W, self.R = np.empty(0), np.empty(0, complex)

    def at(self, W: np.ndarray, compute: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """R at the frequencies ``W`` (1-D), those not kept yet computed by ``compute`` and kept; NaN at a frequency
        that is not finite (never computed nor kept)."""
        where, found = self._lookup(W)
        missing = np.unique(W[~found & np.isfinite(W)])
        if missing.size:
            order = np.argsort(np.concatenate([self.W, missing]), kind="stable")
            self.W = np.concatenate([self.W, missing])[order]
            self.R = np.concatenate([self.R, compute(missing)])[order]
            where, found = self._lookup(W)
        return np.where(found, self.R[where] if self.R.size else 0.0, complex(np.nan))

    def _lookup(self, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where each frequency of ``W`` stands among the kept ones (its index, clipped to the last), and whether it
        is one of them."""
        if not self.W.size:
            return np.zeros(W.shape, int), np.zeros(W.shape, bool)
        where = np.minimum(np.searchsorted(self.W, W), self.W.size - 1)
        return where, self.W[where] == W


class _Starts:
    """The balances a place last solved (:func:`placed_kbar`), kept per task of the analysis
    (:func:`analysis.common.parallel.task_scope`): a task starts from what it solved itself, never from what another
    left, so its answer does not depend on which tasks its process ran before it. Shared by a place's copies
    (:meth:`Surroundings.with_parallel`); it crosses a pipe as a reference, and comes back from a worker as the
    one of the process that forked the worker, where that holds it (a fit placed in the caller's structure)."""

    def __init__(self):
        self.token = (os.getpid(), next(_STARTS_MADE))
        self._by_task: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        _LIVE_STARTS[self.token] = self

    def of_task(self) -> Recent:
        """The balances the task under way solved here last."""
        scope = task_scope()
        kept = self._by_task.get(scope)
        if kept is None:
            kept = self._by_task[scope] = Recent(_STARTS_KEPT)
        return kept

    def __reduce__(self):
        return _starts_of, (self.token,)


_STARTS_MADE = itertools.count()
_LIVE_STARTS: "weakref.WeakValueDictionary[tuple, _Starts]" = weakref.WeakValueDictionary()


def _starts_of(token: tuple) -> _Starts:
    """The live :class:`_Starts` of ``token`` in this process, or new ones."""
    return _LIVE_STARTS.get(token) or _Starts()


def surroundings_of(structure: Structure, vector: np.ndarray, in_reference: bool = False,
                    origin: Origin | None = None) -> Surroundings:
    """The structure around the element of element vector ``vector`` (``x_element = vector @ x``);
    ``in_reference``: it holds the element's small-amplitude stiffness, or its state at ``origin``
    (:attr:`Surroundings.in_reference`)."""
    return Surroundings(structure, np.asarray(vector, float), in_reference=in_reference, origin=origin)


def linear_part(terms) -> Callable[[np.ndarray], np.ndarray] | None:
    """The dynamic stiffness ``W -> sum kbar(W)`` of the amplitude-independent terms among ``terms`` ((law,
    values) pairs with complete values), which act in parallel with the structure at every harmonic; None
    without any."""
    parts = [(law, dict(values)) for law, values in terms
             if not law.amplitude_dependent and not law.placed]
    if not parts:
        return None
    return _LinearPart(tuple(law.kbar_function(**values) for law, values in parts))


class _LinearPart:
    """``W -> sum kbar(W)`` of :func:`linear_part`'s terms. A class, not a closure, so that a fit that holds one
    can come back from another process (:mod:`analysis.common.parallel`)."""

    __slots__ = ("functions",)

    def __init__(self, functions: tuple):
        self.functions = functions

    def __call__(self, W):
        W = np.asarray(W, float)
        return sum((f(np.ones(W.shape), W) for f in self.functions), np.zeros(W.shape, complex))


def placed_kbar(terms: Sequence[tuple[Law, Mapping[str, float]]], X, w, around: Surroundings,
                n_harmonics: int = N_HARMONICS, n_time: int = N_TIME) -> np.ndarray:
    """kbar of the sum of ``terms`` ((law, contract values) pairs: the placed laws of one element, which share its
    mean and harmonics) at element amplitudes X and lines w, placed in ``around`` (module docstring); complex,
    broadcast over X and w. A sample whose balance has no solution (``_MAX_ITERATIONS``) keeps the kbar of its
    last step, far from any measured one: a fit moves away from where its model has no balance. (Given the
    contact alone's kbar there instead, the fits settled where the balance fails, every evaluation paying the
    full count of steps: several times the Newton work.)"""
    X, w = broadcast(np.asarray(X, float), np.asarray(w, float))
    shape = X.shape
    X, w = X.ravel(), w.ravel()
    p = [(law, law.parameter_vector(**values)) for law, values in terms]
    cycle = _cycle(n_harmonics, n_time)
    balance = _Balance(p, cycle, around.at_harmonics(w, cycle), X)
    key = (X.tobytes(), w.tobytes(), n_harmonics, n_time)
    starts = around.starts.of_task()
    z, left = starts.get(key), None
    if z is not None:
        # a balance solved at these samples before (a fit's evaluations differ by a step of its parameters) is
        # where this one starts; a sample it does not bring to convergence within a few steps starts again from
        # no harmonics, and so does every sample where a step fails, so that a balance's answer never depends on
        # which evaluation came before
        z = z.copy()
        left = balance.solve(z, np.ones(X.size, bool), _WARM_ITERATIONS)
        if left is None:
            z = None
        elif left.any():
            z[left] = 0.0
            left = balance.solve(z, left, _MAX_ITERATIONS)
    if z is None:
        z = np.zeros((X.size, cycle.size))
        left = balance.solve(z, np.ones(X.size, bool), _MAX_ITERATIONS)
    if left is None:
        # a contact pulling (k < 0) as hard as the structure holds it: no static balance, no kbar
        return np.full(shape, np.nan, complex)
    starts.keep(key, np.where(np.isfinite(z), z, 0.0))     # a NaN sample starts again from none
    return balance.kbar(z).reshape(shape)


class _Balance:
    """The balance of :func:`placed_kbar` at S samples: the placed laws (kernel parameter vectors), the cycle,
    the receptance ``R`` (S, H) at the harmonics balanced and the element's amplitude ``X`` (S,) of its
    fundamental ``X sin(theta)``."""

    def __init__(self, laws: list[tuple[Law, np.ndarray]], cycle: "_Cycle", R: np.ndarray, X: np.ndarray):
        self.cycle = cycle
        self.R = np.ascontiguousarray(R.real), np.ascontiguousarray(R.imag)
        self.X = X
        self.scale = np.maximum(X, 1e-300)
        self.p = np.concatenate([vector for _, vector in laws]).astype(float)
        self._newton = _newton_of(tuple(law.kernel for law, _ in laws), tuple(len(vector) for _, vector in laws))
        self.steps = np.zeros(X.size, np.int64)      # Newton steps each sample took in the last solve

    def solve(self, z: np.ndarray, active: np.ndarray, iterations: int) -> np.ndarray | None:
        """At most ``iterations`` Newton steps for the samples ``active`` (S,), ``z`` (S, size) updated in place
        from where it stands. Returns the samples not converged (S,) bool, None where a Jacobian is singular."""
        left = active.copy()
        return None if self._run(z, left, iterations, self.steps, _NO_KBAR) else left

    def kbar(self, z: np.ndarray) -> np.ndarray:
        """kbar of every sample at harmonics ``z`` (S, size): its force's fundamental over X, (S,) complex."""
        out = np.empty((z.shape[0], 2))
        self._run(z, np.zeros(z.shape[0], bool), 0, np.zeros(z.shape[0], np.int64), out)
        return (out[:, 0] + 1j * out[:, 1]) / self.scale

    def _run(self, z, left, iterations, steps, fundamental) -> bool:
        c = self.cycle
        return self._newton(self.p, c.Phi, c.P, c.trig, c.first, c.first_sign, c.second, c.second_sign,
                            *self.R, self.X, c.sin, c.cos, self.scale, z, left, iterations, _TOLERANCE, steps,
                            fundamental)


@functools.lru_cache(maxsize=None)
def _newton_of(kernels: tuple, sizes: tuple):
    """The Newton loop of the balance, sample by sample, compiled with the placed laws' kernels fixed, and
    disk-cached per set of laws as analysis.laws.base._marcher is (compiling costs 1-4 s). One sample's step, on
    its unknowns z (size,):

        x = X sin(theta) + Phi z,   r = z + R P f(x),   (I + R P diag(f'(x)) Phi) dz = r,   z -= dz

    ``f'`` by central differences (h = 1e-7 X); where the contact never touches over the cycle (f' = 0) the
    Jacobian is I. A sample stops when max|dz| <= tolerance X; ``left[i]`` stays True for one that has not within
    ``iterations``; ``steps[i]`` counts its steps. Returns True where a Jacobian was singular (the others then
    stand where they are). Per sample, not per batch: the solver's calls are mostly of a handful of samples,
    where a batch's array operations cost far more than the arithmetic.

    ``fundamental`` (S, 2), unless it is :data:`_NO_KBAR`: afterwards each sample's force's fundamental phasor
    at its z, ``(A, B)`` of ``f ~ A sin + B cos`` (docs/contracts.md §1: kbar = (A + j B) / X), from the same
    compiled force (a second pass over the samples in Python would cost more than the balance's last step)."""
    force = _summed(kernels, sizes)

    @njit_fixed(fastmath=_REASSOCIATE)
    def newton(p, Phi, P, trig, first, first_sign, second, second_sign, R_re, R_im, X, sin, cos, scale, z, left,
               iterations, tolerance, steps, fundamental):
        n_time, size = Phi.shape
        state = np.zeros(1)
        f, t, x = np.empty(n_time), np.empty(n_time), np.empty(n_time)
        pf, r, dz, coefficients = np.empty(size), np.empty(size), np.empty(size), np.empty(trig.shape[1])
        block, jacobian = np.empty((size, size)), np.empty((size, size))
        for i in range(z.shape[0]):
            steps[i] = 0
            if not left[i]:
                continue
            h = 1e-7 * scale[i]
            for _ in range(iterations):
                steps[i] += 1
                plain = True            # no harmonics yet: x is the fundamental alone
                for j in range(size):
                    plain = plain and z[i, j] == 0.0
                acting = False
                for n in range(n_time):
                    xn = X[i] * sin[n]
                    if not plain:
                        for j in range(size):
                            xn += Phi[n, j] * z[i, j]
                    x[n] = xn
                    f[n] = force(xn, p, state)
                    acting = acting or f[n] != 0.0
                if plain and not acting:
                    # a contact that never acts over the cycle: no force, no harmonics, r = 0 -- the balance holds
                    # as it stands (most samples of a clearance are open; their tangents would cost two forces
                    # more per instant and change nothing)
                    left[i] = False
                    break
                touching = False
                for n in range(n_time):
                    t[n] = (force(x[n] + h, p, state) - force(x[n] - h, p, state)) / (2.0 * h)
                    touching = touching or t[n] != 0.0
                for j in range(size):
                    harmonic = 0.0
                    for n in range(n_time):
                        harmonic += P[j, n] * f[n]
                    pf[j] = harmonic
                _receptance_times(R_re[i], R_im[i], pf.reshape(size, 1), r.reshape(size, 1))
                for j in range(size):
                    r[j] += z[i, j]
                if touching:
                    _tangent_block(t, trig, first, first_sign, second, second_sign, coefficients, block)
                    _receptance_times(R_re[i], R_im[i], block, jacobian)    # I + R block
                    for k in range(size):
                        jacobian[k, k] += 1.0
                    status = solve_small(jacobian, r, dz, size)
                    if status == SINGULAR:
                        return True
                    for j in range(size):       # element by element: a slice copy compiles numba's
                        r[j] = dz[j] if status != NOT_FINITE else np.nan    # shape-error message, seconds a process
                largest = 0.0
                for j in range(size):
                    z[i, j] -= r[j]
                    if not abs(r[j]) <= largest:        # NaN wins: a sample of bad numbers stops, NaN
                        largest = abs(r[j])
                if not largest > tolerance * scale[i]:
                    left[i] = False
                    break
        if fundamental.shape[0] == z.shape[0]:
            for i in range(z.shape[0]):
                a = 0.0
                b = 0.0
                for n in range(n_time):
                    xn = X[i] * sin[n]
                    for j in range(size):
                        xn += Phi[n, j] * z[i, j]
                    fn = force(xn, p, state)
                    a += fn * sin[n]
                    b += fn * cos[n]
                fundamental[i, 0] = 2.0 / n_time * a
                fundamental[i, 1] = 2.0 / n_time * b
        return False

    return newton


def _summed(kernels: tuple, sizes: tuple):
    """One compiled force ``f(x, p, state)`` of placed laws (no velocity, no state) acting together, ``p`` their
    parameter vectors end to end."""
    head, n = kernels[0], sizes[0]
    if len(kernels) == 1:
        @njit
        def one(x, p, state):
            return head(x, 0.0, p, state)
        return one
    rest = _summed(kernels[1:], sizes[1:])

    @njit
    def both(x, p, state):
        return head(x, 0.0, p[:n], state) + rest(x, p[n:], state)
    return both


@njit(cache=True)
def _receptance_times(R_re, R_im, v, out):
    """``out = R v`` for the receptance at the harmonics balanced (H,) acting on the columns of ``v`` (size, m),
    rows [mean, Re, Im of harmonic 2, ...]: the static one on the mean, each other one as the complex product on
    its pair (Re x_n + j Im x_n = R(n w) (Re f_n + j Im f_n))."""
    for c in range(v.shape[1]):
        out[0, c] = R_re[0] * v[0, c]
        for j in range(1, R_re.shape[0]):
            a, b = v[2 * j - 1, c], v[2 * j, c]
            out[2 * j - 1, c] = R_re[j] * a - R_im[j] * b
            out[2 * j, c] = R_im[j] * a + R_re[j] * b


@njit(cache=True)
def _tangent_block(t, trig, first, first_sign, second, second_sign, coefficients, out):
    """``P diag(t) Phi`` for one tangent t (T,) into ``out`` (size, size): each entry a sum of two Fourier
    coefficients of t (:func:`_trig_products`), ``coefficients = t trig`` the means of t cos k theta and
    t sin k theta (``trig``: :attr:`_Cycle.trig`), instead of a (size, T) by (T, size) product."""
    coefficients[:] = 0.0
    for n in range(t.shape[0]):
        if t[n] != 0.0:                 # a contact's tangent is zero where it is open
            for k in range(trig.shape[1]):
                coefficients[k] += trig[n, k] * t[n]
    for a in range(out.shape[0]):
        for b in range(out.shape[1]):
            out[a, b] = (first_sign[a, b] * coefficients[first[a, b]]
                         + second_sign[a, b] * coefficients[second[a, b]])


@functools.lru_cache(maxsize=8)
def _cycle(n_harmonics: int, n_time: int) -> "_Cycle":
    return _Cycle(n_harmonics, n_time)


class _Cycle:
    """The sampled cycle and the real form of the harmonics balanced: unknowns ``z = [x0, Re x2, Im x2, ...]``,
    displacement ``x = X sin(theta) + Phi z``, harmonics of a force ``P f`` (``P Phi = I``)."""

    def __init__(self, n_harmonics: int, n_time: int):
        self.harmonics = np.array([0] + list(range(2, n_harmonics + 1)))
        self.theta = 2 * np.pi * np.arange(n_time) / n_time
        self.sin, self.cos = np.sin(self.theta), np.cos(self.theta)
        n = self.harmonics[1:, None] * self.theta[None, :]
        # Re(x_n e^{jn theta}) = Re x_n cos - Im x_n sin
        self.Phi = np.column_stack([np.ones(n_time)] + [c for pair in zip(np.cos(n), -np.sin(n)) for c in pair])
        self.P = np.vstack([np.full(n_time, 1.0 / n_time)]
                           + [r for pair in zip(2.0 / n_time * np.cos(n), -2.0 / n_time * np.sin(n)) for r in pair])
        self.size = self.Phi.shape[1]
        # the means of t cos k theta, then of t sin k theta, k = 0 .. twice the highest harmonic, as ``t @ trig``;
        # and where each entry of ``P diag(t) Phi`` takes its two (:func:`_tangent_block`)
        k = self.theta[:, None] * np.arange(2 * self.harmonics[-1] + 1)[None, :]
        self.trig = np.hstack([np.cos(k), np.sin(k)]) / n_time
        (self.first, self.first_sign), (self.second, self.second_sign) = _trig_products(self.harmonics)


def _trig_products(harmonics: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Where each entry of ``P diag(t) Phi`` (:func:`_tangent_block`) takes its two Fourier coefficients of
    t, and with which factors: indices into ``[c_0 .. c_K, s_0 .. s_K]`` (c_k, s_k the means of t cos k theta and
    t sin k theta, K twice the highest harmonic), from the row's and the column's function by

        cos a cos b = (cos(a-b) + cos(a+b))/2,   sin a sin b = (cos(a-b) - cos(a+b))/2,
        sin a cos b = (sin(a+b) + sin(a-b))/2,   cos a sin b = (sin(a+b) - sin(a-b))/2."""
    K = 2 * int(harmonics[-1])
    # each unknown: (factor of its row of P times the mean, factor of its column of Phi, harmonic, is sine)
    functions = [(1.0, 1.0, 0, False)] + [f for h in harmonics[1:] for f in ((2.0, 1.0, h, False),
                                                                            (-2.0, -1.0, h, True))]
    size = len(functions)
    index = np.zeros((2, size, size), int)
    sign = np.zeros((2, size, size))

    def coefficient(k: int, sine: bool) -> tuple[int, float]:
        if not sine:
            return abs(k), 1.0
        return K + 1 + abs(k), float(np.sign(k))          # sin(-k) = -sin(k); sin 0 = 0

    for i, (row, _, a, row_sine) in enumerate(functions):
        for j, (_, column, b, column_sine) in enumerate(functions):
            if row_sine and column_sine:
                terms = [(a - b, False, 0.5), (a + b, False, -0.5)]
            elif row_sine or column_sine:
                terms = [(a + b, True, 0.5), (a - b if row_sine else b - a, True, 0.5)]
            else:
                terms = [(a - b, False, 0.5), (a + b, False, 0.5)]
            for n, (k, sine, half) in enumerate(terms):
                at, sign_k = coefficient(k, sine)
                index[n, i, j], sign[n, i, j] = at, row * column * half * sign_k
    return (index[0], sign[0]), (index[1], sign[1])

