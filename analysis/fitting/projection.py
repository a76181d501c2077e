"""The weighted least-squares fit of a sum of laws by variable projection (docs/fitting.md):

    min over shape of  || W (B(X, w; shape) lin(shape) - kbar) ||^2,  lin(shape) = the linear solve for that shape

``B`` stacks every law's basis functions (shape (N, n_linear) per part), ``W`` the per-part weights. For given shape
parameters the linear ones follow from one exact (bounded) linear solve, so the nonlinear search runs over the shape
parameters only, on coordinates scaled to the data (:class:`_ShapeCoordinate`): a grid scan, then bounded local
searches from its best points (:func:`_search_shape`). :func:`_fit_once` is one such fit with its uncertainty.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from ..common.errors import InputError
from ..common.interrupt import check_stop
from ..laws import Law
from ..laws.base import Param
from .results import Combination, Degeneracy, LawFit
from .samples import _Bases, _Options, _Samples
from .uncertainty import (_column_norms, _correlated_pairs, _covariance, _information_criteria, _mark_undetermined,
                          _term_fits)


#: Singular values of the column-scaled weighted Jacobian below this fraction of
#: the largest one count as zero: the parameter combinations along them are not
#: determined by the data.
RANK_RTOL = 1e-8
# Relative step of the central differences for the shape columns of the Jacobian
# (~ eps^(1/3): balances truncation against round-off).
_DIFF_STEP = 6e-6
# Start-range widening beyond the sampled amplitude range, factor each side.
_WIDEN = 3.0
# least_squares sets its first trust radius to |x0|: a start at the origin of the search
# coordinates would get a vanishing radius and stop at once. The coordinates (O(1) over
# the plausible range) are shifted by this much so that no start sits near the origin.
_SEARCH_OFFSET = 10.0
_UNIT_FACTOR = re.compile(r"\{([FL])\}(?:\^\(?(-?\d+(?:\.\d+)?)\)?)?")


def unit_exponents(unit: str) -> tuple[float, float]:
    """Exponents of force and length in a unit template, e.g. ``"{F}/{L}^3" -> (1, -3)``.

    Used to derive the scale of a shape parameter from the data.
    """
    exponents = {"F": 0.0, "L": 0.0}
    for i, part in enumerate(unit.split("/")):
        sign = 1.0 if i == 0 else -1.0
        for symbol, power in _UNIT_FACTOR.findall(part):
            exponents[symbol] += sign * (float(power) if power else 1.0)
    return exponents["F"], exponents["L"]


@dataclass(frozen=True)
class _ShapeCoordinate:
    """How one shape parameter is searched.

    Positive parameters without an upper bound are searched in ``z = ln(theta/scale)``
    (their plausible values span decades), the others in ``z = theta/scale``; both
    shifted by ``_SEARCH_OFFSET``.
    """

    param: Param
    scale: float           # typical magnitude from the data (> 0)
    log: bool
    grid_range: tuple[float, float]  # natural units (magnitudes when signed)
    signed: bool = False   # may change sign: log-spaced starts of both signs and zero

    def to_search(self, theta: float) -> float:
        return (math.log(theta / self.scale) if self.log else theta / self.scale) + _SEARCH_OFFSET

    def to_natural(self, z: float) -> float:
        z = z - _SEARCH_OFFSET
        return self.scale * math.exp(z) if self.log else self.scale * z

    def lowest(self) -> float:
        """The smallest admissible value (a margin above an open lower bound)."""
        lo = self.param.lower
        return lo + 1e-9 * max(abs(lo), self.scale) if self.param.lower_open else lo

    def search_bounds(self) -> tuple[float, float]:
        lo, hi = self.lowest(), self.param.upper
        if self.log:
            # 30 decades either side of the data's scale: beyond, exp() would underflow to an
            # inadmissible 0 or overflow, and no sample could tell the difference anyway
            lo = math.log(max(lo, self.scale * 1e-30) / self.scale)
            hi = math.log(min(hi, self.scale * 1e30) / self.scale)
        else:
            lo, hi = lo / self.scale, hi / self.scale
        return lo + _SEARCH_OFFSET, hi + _SEARCH_OFFSET

    def clip(self, theta: float) -> float:
        """theta moved strictly inside the bounds (least_squares needs a feasible start)."""
        margin = 1e-9 * self.scale
        theta = max(theta, self.lowest() + margin)
        return min(theta, self.param.upper - margin)

    def grid(self, n: int) -> np.ndarray:
        """n >= 2 starting values (search coordinates) spread over the plausible range."""
        a, b = self.grid_range
        if self.log:
            values = np.geomspace(a, b, n)
        elif self.signed:
            # zero and n log-spaced magnitudes a..b of either sign: the size of a sign-changing
            # parameter (a clearance or a preload) is as uncertain as that of a positive one, and a
            # clearance that closes near the largest amplitude is found only from a start within a few
            # times of it ((n - 1) // 2 a side left one magnitude, the smallest, at the screening's n = 4)
            half = np.geomspace(a, b, n)
            values = np.concatenate([-half[::-1], [0.0], half])
        else:
            values = np.linspace(a, b, n)
        return np.array([self.to_search(self.clip(v)) for v in values])


def _shape_coordinate(param: Param, example: float | None, X: np.ndarray, force_scale: float) -> _ShapeCoordinate:
    """Scale-aware search range of one shape parameter for the sampled amplitudes.

    A parameter with a length in its unit gets the range its unit implies over the
    sampled amplitudes (e.g. a slip displacement from min(X)/3 to 3 max(X), a
    1/length from 1/(3 max X) to 3/min(X)); a force unit is scaled by the median
    |kbar| X; a dimensionless one spans a decade either side of the law's example.
    """
    e_force, e_length = unit_exponents(param.unit)
    lo, hi = param.lower, param.upper
    if e_length != 0:
        ends = sorted(force_scale**e_force * np.array([X.min(), X.max()]) ** e_length)
        a, b = ends[0] / _WIDEN, ends[1] * _WIDEN
    else:
        typical = force_scale**e_force if e_force != 0 else (abs(example) if example else 1.0)
        a, b = typical / 10.0, typical * 10.0
    log = lo >= 0 and math.isinf(hi)
    if log:
        a, b = max(a, lo), max(b, 10.0 * lo)
        scale = math.sqrt(a * b)
    elif math.isfinite(lo) and math.isfinite(hi):
        # a bounded parameter: spread the starts over its whole interval, ends excluded
        step = (hi - lo) / 8.0
        a, b = lo + step, hi - step
        scale = max(abs(lo), abs(hi))
    else:
        # may change sign (e.g. a preload): magnitudes a..b of either sign (clipped to the bounds)
        return _ShapeCoordinate(param, b, False, (a, b), signed=True)
    return _ShapeCoordinate(param, scale, log, (a, b))


def _at_bound(value: float, param: Param, scale: float) -> bool:
    tol = 1e-6 * scale
    return value - param.lower <= tol or param.upper - value <= tol


@dataclass
class _Block:
    """Where one term's parameters sit in the stacked fit vectors."""

    law: Law
    label: str
    linear: slice              # columns of the design / entries of the linear vector
    shape: slice               # entries of the shape vector
    start: dict[str, float]    # starting values of the shape parameters given by the user


class _Problem:
    """Weighted variable-projection problem of one element's samples."""

    def __init__(self, terms, X, w, kbar, w_re, w_im, rank_rtol, bases: _Bases, rows: np.ndarray | None):
        self.X, self.w = X, w
        self.bases, self.rows = bases, rows
        self.w_re, self.w_im = w_re, w_im
        self.rank_rtol = rank_rtol
        self.b = np.concatenate([kbar.real * w_re, kbar.imag * w_im])
        counts = {}
        for law, _ in terms:
            counts[law.name] = counts.get(law.name, 0) + 1
        self.blocks: list[_Block] = []
        n_lin = n_shape = 0
        for i, (law, values) in enumerate(terms):
            label = law.name if counts[law.name] == 1 else f"{law.name}[{i}]"
            p, q = len(law.linear), len(law.shape)
            self.blocks.append(_Block(law, label, slice(n_lin, n_lin + p), slice(n_shape, n_shape + q),
                                      _shape_start(law, values)))
            n_lin, n_shape = n_lin + p, n_shape + q
        self.n_linear, self.n_shape = n_lin, n_shape
        self.linear_names = [f"{b.label}.{n}" for b in self.blocks for n in b.law.linear]
        self.shape_names = [f"{b.label}.{p.name}" for b in self.blocks for p in b.law.shape]
        self.linear_lower, self.linear_upper, self.linear_lower_open = _linear_bounds(self.blocks, n_lin)
        # Columns of laws without shape parameters never change: build them once.
        self.design_fixed = np.zeros((2 * X.size, n_lin))
        for blk in self.blocks:
            if not blk.law.shape:
                self.design_fixed[:, blk.linear] = self._columns(blk, np.zeros(0))

    def _weighted(self, basis: np.ndarray) -> np.ndarray:
        """Complex basis (p, N) -> weighted real design columns (2N, p)."""
        basis = np.asarray(basis, complex).reshape(-1, self.X.size)
        return np.concatenate([basis.real * self.w_re, basis.imag * self.w_im], axis=1).T

    def design(self, theta: np.ndarray) -> np.ndarray:
        """Weighted real design (2N, n_linear) for the shape vector theta (natural units)."""
        A = self.design_fixed.copy()
        for blk in self.blocks:
            if blk.law.shape:
                A[:, blk.linear] = self._columns(blk, theta[blk.shape])
        return A

    def _columns(self, blk: _Block, shape: np.ndarray) -> np.ndarray:
        """A block's weighted design columns at its shape values, its basis taken from those the fit's samples
        keep (:class:`analysis.fitting.samples._Bases`): a finite-difference step or a grid point moves one law's
        shape at a time, and a pass of a reweighted or outlier fit starts where the last ended, so the other
        laws' bases, a harmonic balance each for a placed contact, would otherwise be built again unchanged."""
        return self._weighted(self.bases.at(blk.law, shape, self.rows))

    def solve_linear(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted linear least squares for the linear parameters; (values, at_bound mask).

        Columns are scaled to unit norm so the rank cut treats them alike; a
        rank-deficient design gets the minimum-norm solution (in scaled columns).
        Only if that breaks a parameter bound is the bounded problem solved.
        """
        norms = _column_norms(A)
        As = A / norms
        x = np.linalg.lstsq(As, self.b, rcond=self.rank_rtol)[0]
        c = x / norms
        lo, hi, is_open = self.linear_lower, self.linear_upper, self.linear_lower_open
        if np.all(np.where(is_open, c > lo, c >= lo) & (c <= hi)):
            return c, np.zeros(c.size, bool)
        # an open lower bound (a stiffness that must be > 0) is replaced by a value whose
        # contribution to the model is 1e-12 of the data: the law is then practically absent
        lower = lo * norms + np.where(is_open, max(1e-12 * np.linalg.norm(self.b), 1e-300), 0.0)
        x = lsq_linear(As, self.b, bounds=(lower, hi * norms), method="bvls").x
        x = np.clip(x, lower, hi * norms)
        return x / norms, (x <= lower) | (x >= hi * norms)

    def projected_residual(self, theta: np.ndarray) -> np.ndarray:
        """Weighted residual (2N,) with the linear parameters solved for, at theta."""
        check_stop()            # one evaluation of a fit: where a stop asked for is heard (analysis.common.interrupt)
        A = self.design(theta)
        if not np.all(np.isfinite(A)):
            # outside the law's domain: a finite residual far worse than "no model"
            return -10.0 * self.b - 10.0
        c, _ = self.solve_linear(A)
        return A @ c - self.b

    def jacobian(self, theta: np.ndarray, c: np.ndarray, coords: list[_ShapeCoordinate]) -> np.ndarray:
        """d(weighted residual)/d(linear, shape) at the optimum, shape (2N, n_linear + n_shape).

        Linear columns are the design itself; shape columns are central
        differences of ``A(theta) c`` in natural units (one-sided at a bound).
        """
        A = self.design(theta)
        J = np.empty((A.shape[0], self.n_linear + self.n_shape))
        J[:, : self.n_linear] = A
        for i, coord in enumerate(coords):
            t = theta[i]
            h = _DIFF_STEP * max(abs(t), coord.scale)

            def model(value):
                shifted = theta.copy()
                shifted[i] = value
                return self.design(shifted) @ c

            lo, hi = coord.lowest(), coord.param.upper
            if t - h >= lo and t + h <= hi:
                column = (model(t + h) - model(t - h)) / (2 * h)
            else:
                s = 1.0 if t - h < lo else -1.0   # second-order one-sided, away from the bound
                column = s * (-3 * model(t) + 4 * model(t + s * h) - model(t + 2 * s * h)) / (2 * h)
            J[:, self.n_linear + i] = column
        return J


def _shape_start(law: Law, values: Mapping[str, float]) -> dict[str, float]:
    """User starting values of the law's shape parameters (from contract values)."""
    if all(n in values for n in law.param_names):
        return law.to_fit(values)[1]
    return {p.name: values[p.name] for p in law.shape if p.name in values}


def _linear_bounds(blocks: list[_Block], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower, upper bound and open-lower mask of the linear fit parameters.

    A linear fit parameter that is a contract parameter has its bounds; others are free.
    """
    lower, upper, lower_open = np.full(n, -np.inf), np.full(n, np.inf), np.zeros(n, bool)
    for blk in blocks:
        known = {p.name: p for p in blk.law.params}
        for j, name in zip(range(blk.linear.start, blk.linear.stop), blk.law.linear):
            if name in known:
                p = known[name]
                lower[j], upper[j], lower_open[j] = p.lower, p.upper, p.lower_open
    return lower, upper, lower_open


def _start_points(coords: list[_ShapeCoordinate], grid_points: int, grid_budget: int) -> np.ndarray:
    """Tensor grid of starting points in search coordinates, shape (n, m), at most ~grid_budget rows."""
    per_axis = max(2, min(grid_points, int(grid_budget ** (1.0 / len(coords)))))
    mesh = np.meshgrid(*(c.grid(per_axis) for c in coords), indexing="ij")
    return np.stack([g.ravel() for g in mesh], axis=1)


def _search_shape(problem: _Problem, coords: list[_ShapeCoordinate], user: dict[int, float],
                  grid_points: int, grid_budget: int, n_starts: int, tolerance: float,
                  max_evaluations: int) -> tuple[np.ndarray, bool]:
    """Best shape vector (natural units) and whether its local search converged.

    Grid scan, then bounded local refinement of the best starts and the user's start.
    """
    def natural(z):
        return np.array([c.to_natural(v) for c, v in zip(coords, z)])

    def residual(z):
        return problem.projected_residual(natural(z))

    def cost(z):
        r = residual(z)
        return float(r @ r)

    chosen = []
    if n_starts > 0 or len(user) < len(coords):     # else: a refit from known values, no scan
        starts = _start_points(coords, grid_points, grid_budget)
        costs = np.array([cost(z) for z in starts])
        chosen = [starts[i] for i in np.argsort(costs, kind="stable")[:max(n_starts, 1)]]
    if user:
        # the user's values, with the unspecified parameters taken from the best grid point
        base = chosen[0] if chosen else np.zeros(len(coords))
        pinned = np.array([coords[i].to_search(coords[i].clip(user[i])) if i in user else base[i]
                           for i in range(len(coords))])
        chosen = [pinned] + chosen[:n_starts]
    lower, upper = np.array([c.search_bounds() for c in coords]).T
    best, best_cost = None, math.inf
    for z0 in chosen:
        sol = least_squares(residual, np.clip(z0, lower, upper), bounds=(lower, upper), method="trf",
                            ftol=tolerance, xtol=tolerance, gtol=tolerance, max_nfev=max_evaluations)
        if 2.0 * sol.cost < best_cost:
            best, best_cost = sol, 2.0 * sol.cost
    return natural(best.x), best.status > 0


def _fit_once(terms, data: _Samples, opts: _Options, inflate: bool = False) -> LawFit:
    """One weighted least-squares fit of ``terms`` to ``data`` (module docstring).

    ``inflate``: standard errors scaled by the reduced chi-square where it exceeds 1 (the samples scatter
    more than their sigma says: a fit after outliers were left out)."""
    X, w, kbar, w_re, w_im = data.X, data.w, data.kbar, data.w_re, data.w_im
    problem = _Problem(terms, X, w, kbar, w_re, w_im, opts.rank_rtol, data.bases, data.rows)
    n, P = X.size, problem.n_linear + problem.n_shape
    if 2 * n <= P:
        raise InputError(f"{n} complex samples ({2 * n} real values) cannot determine {P} parameters "
                         f"with a degree of freedom left: need at least {P // 2 + 1} samples", None, "kbar")

    force_scale = float(np.median(np.abs(kbar) * X)) or 1.0
    coords, user = [], {}
    for blk in problem.blocks:
        for p in blk.law.shape:
            if p.name in blk.start:
                user[len(coords)] = blk.start[p.name]
            coords.append(_shape_coordinate(p, blk.law.example.get(p.name), X, force_scale))
    theta, converged = np.zeros(0), True
    if coords:
        theta, converged = _search_shape(problem, coords, user, opts.grid_points, opts.grid_budget,
                                         opts.n_starts, opts.tolerance, opts.max_evaluations)
    A = problem.design(theta)
    c, linear_at_bound = problem.solve_linear(A)
    r = A @ c - problem.b
    chi_square = float(r @ r)

    names = problem.linear_names + problem.shape_names
    cov, rank, unidentified, groups = _covariance(problem.jacobian(theta, c, coords), opts.rank_rtol)
    dof = 2 * n - rank
    if not data.sigma_given:
        cov = cov * (chi_square / dof)
    elif inflate:
        cov = cov * max(1.0, chi_square / dof)
    fit_values = np.concatenate([c, theta])
    degeneracies = [
        Degeneracy(tuple(names[i] for i in group),
                   tuple(Combination({names[i]: float(a[i]) for i in group if abs(a[i]) > 1e-9},
                                     float(a @ fit_values), float(np.sqrt(max(a @ cov @ a, 0.0))))
                         for a in combos))
        for group, combos in groups]
    # no finite variance or covariance exists along an undetermined direction
    cov[unidentified, :] = np.nan
    cov[:, unidentified] = np.nan
    cov[unidentified, unidentified] = np.inf

    notes = [str(d) for d in degeneracies]
    if not converged:
        notes.append(f"the search for {', '.join(problem.shape_names)} stopped after {opts.max_evaluations} "
                     "evaluations on a flat cost: the samples hardly determine them")
    at_bound = [(name, value) for name, value, hit in zip(problem.linear_names, c, linear_at_bound) if hit]
    at_bound += [(name, t) for name, coord, t in zip(problem.shape_names, coords, theta)
                 if _at_bound(t, coord.param, coord.scale)]
    notes += [f"{name} = {value:.6g} ended on its bound; its standard error assumes it free"
              for name, value in at_bound]

    term_fits, contract_names, contract_cov = _term_fits(problem, fit_values, cov, unidentified)
    correlated = _correlated_pairs(term_fits, contract_names, contract_cov)
    _mark_undetermined(term_fits, correlated)
    notes += [str(g) for g in correlated]
    aic, bic = _information_criteria(chi_square, rank, 2 * n, data.sigma_given)
    return LawFit(terms=term_fits,
                  residuals=r[:n] / w_re + 1j * r[n:] / w_im, normalized_residuals=r[:n] + 1j * r[n:],
                  chi_square=chi_square, dof=dof, n_samples=n, n_parameters=P, effective_parameters=rank,
                  aic=aic, bic=bic, sigma_given=data.sigma_given, fit_parameter_names=names,
                  covariance=cov, degeneracies=degeneracies, notes=notes, correlated=correlated)
