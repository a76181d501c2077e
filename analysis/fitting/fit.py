"""Fitting element laws to equivalent complex-stiffness samples of one element.

Given samples ``kbar_k`` of one element's equivalent complex stiffness at amplitudes
``X_k`` and angular frequencies ``w_k`` (k = 1..N), :func:`fit_laws` finds the
parameters of any sum of laws (docs/contracts.md §2) that best explains them:

    kbar_model(X, w) = sum_j lin_j * B_j(X, w; shape)

where ``B`` stacks the basis functions of every law (:meth:`Law.basis`), ``lin``
are the parameters that enter linearly and ``shape`` the others. The fit is a
weighted least-squares fit of the real and imaginary parts, solved by variable
projection: for given shape parameters the linear ones follow from one exact
linear solve, so the nonlinear search runs over the shape parameters only (none
for most laws). docs/fitting.md states the definitions.
"""
from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from ..mechanics.elements import LawTerm
from ..common.errors import InputError
from ..common.statistics import OUTLIER_FALSE_ALARM, capped_chi_square, charged_criterion, outlier_limit, part_weight
from ..laws import Law, get_law
from ..laws.base import Param
from ..mechanics.surroundings import Surroundings, linear_part, placed_kbar

#: Singular values of the column-scaled weighted Jacobian below this fraction of
#: the largest one count as zero: the parameter combinations along them are not
#: determined by the data.
RANK_RTOL = 1e-8
# A parameter is reported non-identifiable when its squared component in the null
# space exceeds this (round-off and finite-difference noise stay far below it).
_NULL_WEIGHT = 1e-8
#: Two parameters whose estimates correlate beyond this (in magnitude) lie along a near-flat direction of the
#: fit: the samples determine a combination of them, not each one (docs/fitting.md, "Identifiability").
CORRELATION_LIMIT = 0.99
#: A parameter closer to zero than this many standard errors is "not determined by the data": its 95 %
#: interval holds zero, so the samples tell neither its size nor its sign.
UNDETERMINED_Z = 1.959964
# Huber's threshold (in standard deviations of a sample's residual) for the reweighted start of the
# outlier search, and the most reweighting / exclusion passes.
HUBER_LIMIT = 2.0
_ROBUST_ITERATIONS = 20
# Largest group of undetermined parameters whose determined combinations are searched for the sparsest basis
# (2^n small SVDs).
_SPARSE_LIMIT = 10
# Singular values (of orthonormal rows) below this count as zero there: the finite-difference Jacobian leaves
# the exact zeros at about 1e-8..1e-7.
_SPARSE_TOL = 1e-6
# Relative step of the central differences for the shape columns of the Jacobian
# (~ eps^(1/3): balances truncation against round-off).
_DIFF_STEP = 6e-6
# Start-range widening beyond the sampled amplitude range, factor each side.
_WIDEN = 3.0
# least_squares sets its first trust radius to |x0|: a start at the origin of the search
# coordinates would get a vanishing radius and stop at once. The coordinates (O(1) over
# the plausible range) are shifted by this much so that no start sits near the origin.
_SEARCH_OFFSET = 10.0
# A contact law placed in its surroundings: refits with the placement of the previous fit's values, at most
# this many, until its scaling parameter moves by less than _PLACED_TOLERANCE (relative)
_PLACED_REFITS = 8
_PLACED_TOLERANCE = 1e-3
# ... and where outliers are left out, one refit from the placement settled on every sample
_ROBUST_PLACED_REFITS = 1


# --------------------------------------------------------------------------- results
@dataclass
class TermFit:
    """The fitted values of one law term.

    Attributes
    ----------
    law : Law
        The law.
    label : str
        Name used in notes: the law's name, or ``name[i]`` (``i`` its position in
        the list of laws) when the same law appears twice.
    params : dict[str, float]
        Contract parameters (docs/contracts.md §2), in the law's units.
    stderr : dict[str, float]
        Standard errors of ``params``, same units; ``inf`` where the data do not
        determine the parameter (see :attr:`LawFit.degeneracies`).
    fit_params : dict[str, float]
        The same values in the law's fit parametrisation (linear, then shape).
    undetermined : tuple[str, ...]
        Contract parameters the samples do not determine: an infinite standard error, a 95 %
        interval that holds zero (``UNDETERMINED_Z``), or a member of a correlated pair
        (:attr:`LawFit.correlated`). Their values are not findings; print them as undetermined.
    surroundings : Surroundings or None
        Where a contact law was fitted placed in its structure (``fit_laws(surroundings=...)``): the
        structure around the element with the element's amplitude-independent laws; its kbar is placed there.
    """

    law: Law
    label: str
    params: dict[str, float]
    stderr: dict[str, float]
    fit_params: dict[str, float]
    undetermined: tuple[str, ...] = ()
    surroundings: Surroundings | None = None

    @property
    def size_unseen(self) -> bool:
        """Whether the samples leave the law's size open: every linear parameter (its force scale) has a 95 %
        interval that holds zero, or no finite error. Such a law fits nothing of the samples."""
        return all(not np.isfinite(self.stderr[n]) or abs(self.params[n]) < UNDETERMINED_Z * self.stderr[n]
                   for n in self.law.linear)

    def law_term(self) -> LawTerm:
        """The fitted term as a :class:`LawTerm` (e.g. to write a fitted model file)."""
        return LawTerm(self.law, dict(self.params))

    def describing_function(self, X, w) -> np.ndarray:
        """kbar of this term, complex, broadcast over X (m or rad) and w (rad/s)."""
        if self.surroundings is not None:
            return placed_kbar([(self.law, self.params)], X, w, self.surroundings)
        if not hasattr(self, "_term"):            # one validated LawTerm, reused by the solvers
            self._term = self.law_term()
        return self._term.describing_function(X, w)


@dataclass(frozen=True)
class Combination:
    """A linear combination of fit parameters that the samples do determine.

    Attributes
    ----------
    coefficients : dict[str, float]
        ``label.name`` -> coefficient; the largest coefficient magnitude is 1.
    value : float
        The combination evaluated at the fitted parameters.
    stderr : float
        Its standard error.
    """

    coefficients: dict[str, float]
    value: float
    stderr: float

    def __str__(self) -> str:
        parts = []
        for name, a in self.coefficients.items():
            sign = "-" if a < 0 else "+"
            magnitude = "" if f"{abs(a):.4g}" == "1" else f"{abs(a):.4g}*"
            parts.append(f"{sign} {magnitude}{name}")
        text = " ".join(parts)
        text = text[2:] if text.startswith("+ ") else text
        return f"{text} = {self.value:.6g} ± {self.stderr:.2g}"


@dataclass(frozen=True)
class Degeneracy:
    """A group of fit parameters that the samples do not determine separately.

    Attributes
    ----------
    parameters : tuple[str, ...]
        ``label.name`` of every fit parameter in the group; each has an infinite
        standard error.
    determined : tuple[Combination, ...]
        The combinations of them the samples still determine (e.g. ``k_pos + k_neg``
        for bilinear); empty when the samples say nothing about any of them.
    """

    parameters: tuple[str, ...]
    determined: tuple[Combination, ...]

    def __str__(self) -> str:
        names = ", ".join(self.parameters)
        if not self.determined:
            if len(self.parameters) == 1:
                return f"not identifiable from these samples: {names}"
            return f"not identifiable from these samples: {names} (no combination of them is determined)"
        return (f"not separately identifiable: {names}; the samples determine only "
                + "; ".join(str(c) for c in self.determined))

    def to_json(self) -> dict:
        return {"parameters": list(self.parameters),
                "determined": [{"combination": dict(c.coefficients), "value": c.value, "stderr": c.stderr}
                               for c in self.determined], "text": str(self)}


@dataclass(frozen=True)
class Correlation:
    """Two contract parameters the samples determine only together: their estimates correlate beyond
    ``CORRELATION_LIMIT`` (a near-flat direction of the fit, e.g. a linear spring beside an iwan ``kt`` on
    samples without macro-slip).

    Attributes
    ----------
    parameters : tuple[str, str]
        ``label.name`` of the two contract parameters.
    correlation : float
        The correlation of their estimates (-1..1).
    determined : Combination
        The combination of them the samples determine best, with its value and standard error.
    """

    parameters: tuple[str, ...]
    correlation: float
    determined: Combination

    def __str__(self) -> str:
        return (f"not determined separately (correlation {self.correlation:+.4f}): {' and '.join(self.parameters)}; "
                f"the samples determine {self.determined}")

    def to_json(self) -> dict:
        c = self.determined
        return {"parameters": list(self.parameters), "correlation": self.correlation,
                "combination": dict(c.coefficients), "value": c.value, "stderr": c.stderr, "text": str(self)}


@dataclass
class LawFit:
    """Result of :func:`fit_laws`.

    Attributes
    ----------
    terms : list[TermFit]
        One entry per law term, in the order given.
    residuals : ndarray, complex, shape (N,)
        ``kbar_model - kbar`` per sample, in the units of kbar (N/m or N·m/rad).
    normalized_residuals : ndarray, complex, shape (N,)
        Residual parts divided by their standard deviations,
        ``Re r / sigma_re + j Im r / sigma_im`` (equal to ``residuals`` when no
        sigma was given).
    chi_square : float
        Sum of squares of the normalized residual parts.
    dof : int
        Degrees of freedom, ``2 N - effective_parameters``.
    n_samples : int
        Number of complex samples N (2 N real observations).
    n_parameters : int
        Number of fit parameters (all laws, linear and shape).
    effective_parameters : int
        Numerical rank of the weighted Jacobian at the optimum: the number of
        parameter combinations the samples determine.
    aic, bic : float
        Akaike and Bayesian information criteria (docs/fitting.md); smaller is
        better, comparable between fits of the same samples with the same sigma.
    sigma_given : bool
        Whether sample standard deviations were given; if not, the standard errors
        are scaled by the reduced chi-square.
    fit_parameter_names : list[str]
        ``label.name`` of the fit parameters, the order of ``covariance``.
    covariance : ndarray, shape (n_parameters, n_parameters)
        Covariance of the fit parameters (pseudo-inverse on the determined
        subspace); a non-identifiable parameter has ``inf`` variance and ``nan``
        covariances.
    degeneracies : list[Degeneracy]
        Non-identifiable parameter groups.
    notes : list[str]
        Human-readable remarks: degeneracies, correlated groups, parameters that ended on a
        bound, a shape search that ran out of evaluations, samples left out as outliers.
    correlated : list[Correlation]
        Pairs of contract parameters the samples determine only together.
    excluded : ndarray of bool, shape (N,), or None
        With ``exclude_outliers``: the samples left out of the fit (their residuals are still
        reported); None otherwise.
    """

    terms: list[TermFit]
    residuals: np.ndarray
    normalized_residuals: np.ndarray
    chi_square: float
    dof: int
    n_samples: int
    n_parameters: int
    effective_parameters: int
    aic: float
    bic: float
    sigma_given: bool
    fit_parameter_names: list[str]
    covariance: np.ndarray
    degeneracies: list[Degeneracy] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    correlated: list[Correlation] = field(default_factory=list)
    excluded: np.ndarray | None = None

    @property
    def reduced_chi_square(self) -> float:
        """chi_square / dof (about 1 when the model is right and sigma is true)."""
        return self.chi_square / self.dof

    @property
    def identifiable(self) -> bool:
        """True when every fit parameter is determined by the samples."""
        return not self.degeneracies

    def law_terms(self) -> list[LawTerm]:
        """The fitted terms as :class:`LawTerm` objects."""
        return [t.law_term() for t in self.terms]

    def describing_function(self, X, w) -> np.ndarray:
        """kbar of the fitted sum of laws, complex, broadcast over X and w (rad/s)."""
        X, w = np.broadcast_arrays(np.asarray(X, float), np.asarray(w, float))
        return sum((t.describing_function(X, w) for t in self.terms), np.zeros(X.shape, complex))


# --------------------------------------------------------------------------- inputs
def _resolve_terms(laws, start) -> list[tuple[Law, dict[str, float]]]:
    """(law, starting values) per term from names, Law objects or LawTerms."""
    if isinstance(laws, (str, Law, LawTerm)):
        laws = [laws]
    try:
        laws = list(laws)
    except TypeError:
        raise InputError(f"must be a list of law names, Law or LawTerm objects, got {type(laws).__name__}",
                         None, "laws") from None
    if not laws:
        raise InputError("no law to fit: give at least one", None, "laws")
    if start is not None:
        start = list(start)
        if len(start) != len(laws):
            raise InputError(f"has {len(start)} entries for {len(laws)} laws", None, "start")
    terms = []
    for i, entry in enumerate(laws):
        where = f"laws[{i}]"
        if isinstance(entry, LawTerm):
            law, values = entry.law, dict(entry.values)
        elif isinstance(entry, Law):
            law, values = entry, {}
        elif isinstance(entry, str):
            law, values = get_law(entry, None, where), {}
        else:
            raise InputError(f"must be a law name, Law or LawTerm, got {type(entry).__name__}", None, where)
        if start is not None and start[i] is not None:
            if not isinstance(start[i], Mapping):
                raise InputError(f"must be a table of parameter values, got {type(start[i]).__name__}",
                                 None, f"start[{i}]")
            values.update(start[i])
        terms.append((law, law.check_params(values, field=where)))
    return terms


def _real_array(value, name: str, n: int | None = None) -> np.ndarray:
    """``value`` as a float array; with ``n``, a scalar or shape (n,) broadcast to (n,)."""
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise InputError("must be an array of real numbers", None, name) from None
    if n is None:
        return a
    if a.ndim > 1 or (a.ndim == 1 and a.size != n):
        raise InputError(f"shape {a.shape} does not match kbar's {(n,)}", None, name)
    return np.broadcast_to(a, (n,)).copy()


def _samples(X, w, kbar, sigma):
    """Validated samples X, w, kbar and per-part weights 1/std (real, imaginary), each shape (N,)."""
    try:
        kbar = np.asarray(kbar, complex)
    except (TypeError, ValueError):
        raise InputError("must be an array of complex numbers", None, "kbar") from None
    if kbar.ndim != 1 or kbar.size == 0:
        raise InputError(f"must be a non-empty 1-D array, got shape {kbar.shape}", None, "kbar")
    n = kbar.size
    X, w = _real_array(X, "X", n), _real_array(w, "w", n)
    for name, a in (("X", X), ("w", w), ("kbar", kbar)):
        bad = np.count_nonzero(~np.isfinite(a))
        if bad:
            raise InputError(f"{bad} of {n} values are not finite (NaN or inf)", None, name)
    if np.any(X <= 0):
        raise InputError("amplitudes must be > 0", None, "X")
    if sigma is None:
        return X, w, kbar, np.ones(n), np.ones(n)
    s = _real_array(sigma, "sigma")
    if s.ndim == 0:
        s = np.full(n, float(s))
    if s.shape == (n,):
        w_re = w_im = part_weight(s)          # std of the complex sample: each part carries half the variance
    elif s.shape == (n, 2):
        w_re, w_im = 1.0 / s[:, 0], 1.0 / s[:, 1]
    else:
        raise InputError(f"must be a scalar, shape (N,) or (N, 2) with N = {n}, got {s.shape}", None, "sigma")
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise InputError("standard deviations must be finite and > 0", None, "sigma")
    return X, w, kbar, w_re, w_im


# --------------------------------------------------------------------------- shape search
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


# --------------------------------------------------------------------------- the problem
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

    def __init__(self, terms, X, w, kbar, w_re, w_im, rank_rtol):
        self.X, self.w = X, w
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
                self.design_fixed[:, blk.linear] = self._weighted(blk.law.basis(X, w))

    def _weighted(self, basis: np.ndarray) -> np.ndarray:
        """Complex basis (p, N) -> weighted real design columns (2N, p)."""
        basis = np.asarray(basis, complex).reshape(-1, self.X.size)
        return np.concatenate([basis.real * self.w_re, basis.imag * self.w_im], axis=1).T

    def design(self, theta: np.ndarray) -> np.ndarray:
        """Weighted real design (2N, n_linear) for the shape vector theta (natural units)."""
        A = self.design_fixed.copy()
        for blk in self.blocks:
            if blk.law.shape:
                shape = dict(zip((p.name for p in blk.law.shape), theta[blk.shape]))
                A[:, blk.linear] = self._weighted(blk.law.basis(self.X, self.w, **shape))
        return A

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


def _column_norms(A: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(A, axis=0)
    return np.where(norms > 0, norms, 1.0)


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


# --------------------------------------------------------------------------- covariance
def _covariance(J: np.ndarray, rank_rtol: float):
    """Pseudo-inverse covariance (unscaled), rank, non-identifiable mask and groups.

    Columns are scaled to unit norm first so that the rank decision does not depend
    on the parameters' units. Each group is ``(indices, coefficient vectors)``: the
    coupled undetermined parameters and the combinations of them still determined
    (full-length coefficient vectors, largest magnitude 1).
    """
    P = J.shape[1]
    norms = _column_norms(J)
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)   # 2N > P: Vt is P x P
    keep = s > rank_rtol * s[0] if s[0] > 0 else np.zeros(P, bool)
    V = Vt.T
    cov = ((V[:, keep] / s[keep] ** 2) @ V[:, keep].T) / np.outer(norms, norms)
    null = V[:, ~keep]
    projector = null @ null.T        # independent of the basis chosen inside the null space
    involved = np.diag(projector) > _NULL_WEIGHT
    groups = []
    for group in _coupled_groups(projector, involved):
        # determined directions inside the group (in scaled parameters norm_j * theta_j)
        values, vectors = np.linalg.eigh(np.eye(len(group)) - projector[np.ix_(group, group)])
        combos = []
        for row in _sparse_basis(vectors[:, values > 0.5].T):
            coef = np.zeros(P)
            coef[group] = row * norms[group]
            combos.append(coef / coef[np.argmax(np.abs(coef))])
        groups.append((group, combos))
    return cov, int(np.count_nonzero(keep)), involved, groups


def _sparse_basis(rows: np.ndarray) -> np.ndarray:
    """The sparsest basis of the determined combinations (rows: a basis, in scaled parameters).

    Any basis of the determined subspace is right; the sparse one is what can be read: where the samples fix
    ``k + kt`` beside a combination of the iwan shapes, it says so instead of two mixtures of all four. For
    each set of parameters to leave out (most first), a combination without them exists when the basis
    restricted to them has a one-dimensional left null space; such combinations are taken, sparsest first,
    while they add a dimension. Groups beyond ``_SPARSE_LIMIT`` parameters keep the given basis."""
    m, g = rows.shape
    if g > _SPARSE_LIMIT or m == 0:
        return rows
    chosen: list[np.ndarray] = []
    for n_zero in range(g - 1, -1, -1):
        for zero in itertools.combinations(range(g), n_zero):
            restricted = rows[:, list(zero)]
            _, sv, vt = np.linalg.svd(restricted.T, full_matrices=True) if n_zero else (None, np.zeros(0), np.eye(m))
            null = vt[np.count_nonzero(sv > _SPARSE_TOL):]
            if len(null) != 1:
                continue
            candidate = null[0] @ rows
            candidate[np.abs(candidate) < _SPARSE_TOL * np.abs(candidate).max()] = 0.0
            if np.linalg.matrix_rank(np.array(chosen + [candidate]), tol=_SPARSE_TOL) > len(chosen):
                chosen.append(candidate)
                if len(chosen) == m:
                    return np.array(chosen)
    return np.array(chosen) if len(chosen) == m else rows


def _coupled_groups(projector: np.ndarray, involved: np.ndarray) -> list[list[int]]:
    """Connected groups of involved parameters (coupled through the null-space projector)."""
    remaining = set(np.flatnonzero(involved).tolist())
    groups = []
    while remaining:
        group, frontier = [], [min(remaining)]
        remaining -= set(frontier)
        while frontier:
            i = frontier.pop()
            group.append(i)
            linked = {j for j in remaining if abs(projector[i, j]) > _NULL_WEIGHT}
            remaining -= linked
            frontier.extend(linked)
        groups.append(sorted(group))
    return groups


# --------------------------------------------------------------------------- entry point
def fit_laws(laws, X, w, kbar, sigma=None, start=None, *, grid_points: int = 7, grid_budget: int = 128,
             n_starts: int = 3, tolerance: float = 1e-12, max_evaluations: int = 60,
             rank_rtol: float = RANK_RTOL, exclude_outliers: bool = False,
             surroundings: Surroundings | None = None) -> LawFit:
    """Fit a sum of laws on one element to complex-stiffness samples.

    Parameters
    ----------
    laws : sequence of str, Law or LawTerm
        The law terms of the element. A LawTerm's (possibly partial) values are
        starting values for the shape parameters; linear parameters need none.
    X : array_like, shape (N,) or scalar
        Element amplitude per sample, m (or rad), > 0.
    w : array_like, shape (N,) or scalar
        Angular frequency per sample, rad/s.
    kbar : array_like, complex, shape (N,)
        Equivalent complex stiffness samples, N/m (or N·m/rad).
    sigma : array_like, optional
        Standard deviation per sample: scalar or shape (N,) for the complex sample
        (``sqrt(E|e|^2)``, shared equally by real and imaginary parts), or shape
        (N, 2) for the real and imaginary parts separately; same units as kbar.
        Without it every part is weighted alike and standard errors are scaled by
        the reduced chi-square.
    start : sequence of mapping, optional
        One entry per law (or None): starting values by contract parameter name,
        overriding those of a LawTerm.
    grid_points : int
        Starting values per shape parameter on the scan grid.
    grid_budget : int
        Upper bound on the number of grid points (with several shape parameters
        the points per parameter shrink, down to 2).
    n_starts : int
        Number of best grid points refined by the bounded local search; the
        user's starting values are refined in addition. 0 with starting values
        for every shape parameter skips the grid scan (a quick refit); 0 without
        them refines the best grid point only.
    tolerance : float
        ftol, xtol and gtol of :func:`scipy.optimize.least_squares`.
    max_evaluations : int
        Residual evaluations per local search (finite-difference Jacobians not
        counted). A well-posed search needs about 5-25; running out means a flat
        cost (shape parameters the samples hardly determine) and is noted.
    rank_rtol : float
        Relative singular-value cut of the column-scaled weighted Jacobian below
        which a parameter combination counts as not determined.
    exclude_outliers : bool
        Leave out the samples that do not follow the fitted laws (chi-square of the
        sample above :func:`outlier_limit`, from an iteratively reweighted start), and
        scale the standard errors by the reduced chi-square where it exceeds 1
        (docs/fitting.md, "Outliers"). :attr:`LawFit.excluded` says which.
    surroundings : Surroundings, optional
        The structure around the element (:mod:`analysis.mechanics.surroundings`): a contact law (``placed``) is
        fitted by its kbar placed there, the mean and harmonics it drives in the structure included
        (:func:`_fit_placed`); without it, or without such a law, by its describing function alone.

    Returns
    -------
    LawFit

    Raises
    ------
    InputError
        Unknown law, malformed starting values, arrays of the wrong shape, non-finite
        samples, amplitudes <= 0, sigma <= 0, or no more real observations (2N)
        than fit parameters.
    """
    terms = _resolve_terms(laws, start)
    X, w, kbar, w_re, w_im = _samples(X, w, kbar, sigma)
    opts = _Options(grid_points, grid_budget, n_starts, tolerance, max_evaluations, rank_rtol)
    data = _Samples(X, w, kbar, w_re, w_im, sigma is not None)
    fitter = _fit_robust if exclude_outliers else _fit_once
    if surroundings is None or not any(law.placed for law, _ in terms):
        return fitter(terms, data, opts)
    return _fit_placed(terms, data, opts, surroundings, fitter)


class _PlacedLaw:
    """A contact law whose basis is its kbar placed in ``around`` with its scaling parameter held at
    ``reference`` (and divided by it): the fit's linear parameter then rescales a fixed placement, and
    :func:`_fit_placed` refits until the two agree. Everything else is the law's own."""

    def __init__(self, law: Law, reference: float, around: Surroundings):
        self.law, self.reference, self.around = law, reference, around

    def __getattr__(self, name):
        return getattr(self.law, name)

    def basis(self, X, w, **shape):
        values = self.law.from_fit({self.law.linear[0]: self.reference}, shape)
        return placed_kbar([(self.law, values)], X, w, self.around)[None] / self.reference

    def kbar_function(self, **params):
        """kbar of this basis at the given values (what a fit in progress judges its samples by)."""
        linear, shape = self.law.to_fit(self.law.check_params(params, complete=True))
        scale = linear[self.law.linear[0]]
        return lambda X, w: scale * self.basis(np.asarray(X, float), np.asarray(w, float), **shape)[0]

    def describing_function(self, X, w, **params):
        return self.kbar_function(**params)(X, w)


def _scaling(law: Law, values: Mapping[str, float]) -> float:
    """The parameter scaling a placed law's force (its one linear parameter)."""
    return values[law.linear[0]]


def _fit_placed(terms, data: _Samples, opts: _Options, surroundings: Surroundings, fitter) -> LawFit:
    """The fit of ``terms`` with their contact laws placed in ``surroundings`` (:mod:`analysis.mechanics.surroundings`).

    The placed kbar depends on the law's scaling parameter (the contact's stiffness against the structure's),
    which the fit solves for linearly: from the fit of the describing function alone, the laws are placed at a
    reference value and refitted until the fitted value is the reference (:func:`_settle`), first on every sample
    and then, where outliers are left out, by ``fitter`` from there (a placement far off would leave out the very
    samples that show the contact)."""
    laws = [law for law, _ in terms]
    fit = _settle(laws, _fit_once(terms, data, opts), data, _quick(opts), surroundings, _fit_once, _PLACED_REFITS)
    if fitter is not _fit_once:
        fit = _settle(laws, fit, data, _quick(opts), surroundings, fitter, _ROBUST_PLACED_REFITS)
    around = _around(fit, surroundings)
    for t, law in zip(fit.terms, laws):
        placed = isinstance(t.law, _PlacedLaw)
        t.law = law
        t.surroundings = around if placed else None
    return fit


def _around(fit: LawFit, surroundings: Surroundings) -> Surroundings:
    """The surroundings with the fit's amplitude-independent laws in parallel."""
    return surroundings.with_parallel(linear_part([(t.law, t.params) for t in fit.terms]))


def _settle(laws: list[Law], fit: LawFit, data: _Samples, opts: _Options, surroundings: Surroundings, fitter,
            refits: int) -> LawFit:
    """Refits of ``fit``'s terms (laws ``laws``) with the contact laws placed at reference values until each fitted
    scaling parameter equals its reference (``_PLACED_TOLERANCE``), the references moved by secant steps on
    ``fitted - reference`` (a plain substitution converges slowly where the contact is as stiff as the
    structure); each refit refines from the last values. A contact whose
    scaling parameter is 0 has no force to place: the terms are then refitted by ``fitter`` as they are."""
    placed = [law.placed for law in laws]
    reference = np.array([_scaling(law, t.params) for t, law, m in zip(fit.terms, laws, placed) if m])
    previous = None
    for i in range(refits):
        if np.any(reference == 0.0):
            return fit if i else fitter([(law, dict(t.params)) for t, law in zip(fit.terms, laws)], data, opts)
        around = _around(fit, surroundings)
        refs = iter(reference)
        fit = fitter([(_PlacedLaw(law, next(refs), around) if m else law, dict(t.params))
                      for t, law, m in zip(fit.terms, laws, placed)], data, opts)
        fitted = np.array([_scaling(law, t.params) for t, law, m in zip(fit.terms, laws, placed) if m])
        gap = fitted - reference
        if np.all(np.abs(gap) <= _PLACED_TOLERANCE * np.abs(reference)):
            break
        following = fitted
        if previous is not None:
            with np.errstate(divide="ignore", invalid="ignore"):     # an unmoved reference: no slope, no secant
                slope = (gap - previous[1]) / (reference - previous[0])
            secant = reference - gap / np.where(slope < 0.0, slope, -1.0)
            # a secant step where the fitted value falls as the reference rises (the placement's own effect),
            # never across zero
            following = np.where((slope < 0.0) & (secant * reference > 0.0), secant, fitted)
        previous = (reference, gap)
        reference = following
    return fit


@dataclass(frozen=True)
class _Options:
    """The search settings of :func:`fit_laws`."""

    grid_points: int
    grid_budget: int
    n_starts: int
    tolerance: float
    max_evaluations: int
    rank_rtol: float


@dataclass(frozen=True)
class _Samples:
    """Validated samples with their per-part weights (1 / std); ``sigma_given`` False: unit weights."""

    X: np.ndarray
    w: np.ndarray
    kbar: np.ndarray
    w_re: np.ndarray
    w_im: np.ndarray
    sigma_given: bool

    def subset(self, keep: np.ndarray, weight: np.ndarray | None = None) -> "_Samples":
        """The kept samples, their stds divided by ``sqrt(weight)`` (iteratively reweighted fits)."""
        root = 1.0 if weight is None else np.sqrt(weight[keep])
        return _Samples(self.X[keep], self.w[keep], self.kbar[keep], self.w_re[keep] * root,
                        self.w_im[keep] * root, self.sigma_given)

    def distance(self, model: np.ndarray) -> np.ndarray:
        """sqrt of each sample's chi-square contribution (Re and Im together) against a model kbar."""
        r = model - self.kbar
        return np.hypot(r.real * self.w_re, r.imag * self.w_im)


def _fit_once(terms, data: _Samples, opts: _Options, inflate: bool = False) -> LawFit:
    """One weighted least-squares fit of ``terms`` to ``data`` (module docstring).

    ``inflate``: standard errors scaled by the reduced chi-square where it exceeds 1 (the samples scatter
    more than their sigma says: a fit after outliers were left out)."""
    X, w, kbar, w_re, w_im = data.X, data.w, data.kbar, data.w_re, data.w_im
    problem = _Problem(terms, X, w, kbar, w_re, w_im, opts.rank_rtol)
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


# --------------------------------------------------------------------------- outliers
def _robust_start(terms, data: _Samples, opts: _Options, plain: LawFit | None = None) -> LawFit:
    """Iteratively reweighted fit with Huber weights: a start that large outliers do not drag far (a plain
    least-squares start can sit so far off that the good samples look like the outliers). ``plain``: the plain
    fit of ``data``, where already made."""
    weight = np.ones(data.X.size)
    everything = np.ones(data.X.size, bool)
    fit = plain if plain is not None else _fit_once(terms, data, opts)
    for _ in range(_ROBUST_ITERATIONS):
        d = data.distance(fit.describing_function(data.X, data.w))
        new = np.minimum(1.0, HUBER_LIMIT / np.maximum(d, 1e-300))
        if np.allclose(new, weight, rtol=1e-3, atol=1e-6):
            break
        weight = new
        fit = _fit_once(_refit_terms(fit), data.subset(everything, weight), _quick(opts))
    return fit


def _refit_terms(fit: LawFit):
    """The fitted terms as starting values of a quick refit."""
    return [(t.law, dict(t.params)) for t in fit.terms]


def _quick(opts: _Options) -> _Options:
    """Refit from the previous values: no grid scan, only the local search."""
    return _Options(opts.grid_points, opts.grid_budget, 0, opts.tolerance, opts.max_evaluations, opts.rank_rtol)


def _fit_robust(terms, data: _Samples, opts: _Options) -> LawFit:
    """Fit, leaving out the samples that do not follow the fitted laws (docs/fitting.md, "Outliers").

    From a Huber start, the samples whose chi-square against the current fit exceeds :func:`outlier_limit`
    are left out and the rest refitted, until the set stops changing. The plain fit starts instead where it
    leaves the smaller capped chi-square (:func:`_capped_loss`): the Huber weights also drag a fit away from the
    few samples one law acts on alone (a clearance that closes only at the higher level's resonance came out at
    zero stiffness, its lines left out as outliers). Nor are samples left out whose leaving takes away what
    determines a law's size (its force scale): the lines a law acts on alone are its evidence, however far a
    describing function misses them (the same clearance's three highest lines, 37-390 sigma off the formula,
    left its stiffness without a finite error). Residuals are reported for every sample
    (normalised in the caller's weights); the chi-square, information criteria and standard errors are those
    of the kept samples, the standard errors scaled by the reduced chi-square where it exceeds 1."""
    given = data
    if not data.sigma_given:
        data = _with_scatter_sigma(terms, data, opts)
    n = data.X.size
    limit = outlier_limit(n)
    plain = _fit_once(terms, data, opts)
    fit = min((_robust_start(terms, data, opts, plain), plain), key=lambda f: _capped_loss(f, data))
    keep = np.ones(n, bool)
    for _ in range(_ROBUST_ITERATIONS):
        new = data.distance(fit.describing_function(data.X, data.w)) ** 2 <= limit
        if 2 * new.sum() <= sum(len(t.fit_params) for t in fit.terms):
            break                               # too few samples would be left: keep the last set
        changed = not np.array_equal(new, keep)
        refit = _fit_once(_refit_terms(fit), data.subset(new), _quick(opts), inflate=True)
        if _sizes_determined(refit) < _sizes_determined(fit):
            break                               # the samples left out were what determined a law's size
        fit, keep = refit, new
        if not changed:
            break
    model = fit.describing_function(data.X, data.w)
    fit.residuals = model - data.kbar
    # in the caller's weights (unit ones without sigma), as a plain fit of the same samples reports them
    fit.normalized_residuals = (model - data.kbar).real * given.w_re + 1j * (model - data.kbar).imag * given.w_im
    fit.excluded = ~keep
    if (~keep).any():
        fit.notes.append(f"{int((~keep).sum())} of {n} samples left out: their chi-square against the fitted laws "
                         f"exceeds {limit:.3g} (outliers at false-alarm {OUTLIER_FALSE_ALARM:g} per fit)")
    return fit


def _sizes_determined(fit: LawFit) -> int:
    """How many of the laws' size parameters (each law's ``linear``, its force scale) have a finite standard
    error."""
    return sum(int(np.isfinite(t.stderr.get(n, np.inf))) for t in fit.terms for n in t.law.linear)


def _capped_loss(fit: LawFit, data: _Samples) -> float:
    """What leaving samples out minimises: :func:`capped_chi_square` of ``fit`` on ``data``."""
    return capped_chi_square(data.distance(fit.describing_function(data.X, data.w)) ** 2)


def _with_scatter_sigma(terms, data: _Samples, opts: _Options) -> _Samples:
    """Unit weights replaced by the scatter of a Huber fit (median of the chi-square with 2 dof: 2 ln 2)."""
    fit = _robust_start(terms, data, opts)
    r = fit.describing_function(data.X, data.w) - data.kbar
    s = math.sqrt(float(np.median(np.abs(r) ** 2)) / (2 * math.log(2))) or 1.0
    ones = np.full(data.X.size, 1.0 / s)
    return _Samples(data.X, data.w, data.kbar, ones, ones, True)


def _information_criteria(chi_square: float, rank: int, n_obs: int, sigma_given: bool) -> tuple[float, float]:
    """AIC and BIC (docs/fitting.md): -2 ln L up to a model-independent constant, plus the penalty."""
    if sigma_given:
        fit_term, k = chi_square, rank
    else:
        # Gaussian likelihood with the variance estimated as chi^2 / n: one more parameter
        fit_term = n_obs * math.log(chi_square / n_obs) if chi_square > 0 else -math.inf
        k = rank + 1
    return fit_term + 2 * k, charged_criterion(fit_term, k, n_obs)


def _term_fits(problem: _Problem, fit_values: np.ndarray, cov: np.ndarray,
               unidentified: np.ndarray) -> tuple[list[TermFit], list[str], np.ndarray]:
    """Contract parameters and their standard errors per law term (through ``Law.fit_jacobian``), with the
    names (``label.name``) and covariance of all contract parameters (undetermined rows and columns NaN)."""
    out, names, blocks_G, blocks_idx = [], [], [], []
    for blk in problem.blocks:
        law = blk.law
        idx = [*range(blk.linear.start, blk.linear.stop),
               *(problem.n_linear + j for j in range(blk.shape.start, blk.shape.stop))]
        fit_names = [*law.linear, *(p.name for p in law.shape)]
        values = dict(zip(fit_names, fit_values[idx].tolist()))
        lin = {name: values[name] for name in law.linear}
        shp = {p.name: values[p.name] for p in law.shape}
        params = {name: float(value) for name, value in law.from_fit(lin, shp).items()}
        G = law.fit_jacobian(lin, shp)
        free = ~unidentified[idx]
        block_cov = cov[np.ix_(idx, idx)][np.ix_(free, free)]
        var = np.einsum("ij,jk,ik->i", G[:, free], block_cov, G[:, free])
        # a contract parameter that depends on an undetermined fit parameter is undetermined
        scale = np.max(np.abs(G), axis=1, keepdims=True)
        depends_on_unidentified = np.any(np.abs(G[:, ~free]) > 1e-12 * scale, axis=1)
        stderr = np.where(depends_on_unidentified, np.inf, np.sqrt(np.maximum(var, 0.0)))
        out.append(TermFit(law, blk.label, params, dict(zip(law.param_names, stderr.tolist())), values,
                           tuple(n for n, bad in zip(law.param_names, depends_on_unidentified) if bad)))
        names += [f"{blk.label}.{n}" for n in law.param_names]
        blocks_G.append(np.where(depends_on_unidentified[:, None], np.nan, G))
        blocks_idx += idx
    G_all = np.zeros((len(names), len(blocks_idx)))
    row = col = 0
    for G in blocks_G:
        G_all[row:row + G.shape[0], col:col + G.shape[1]] = G
        row, col = row + G.shape[0], col + G.shape[1]
    sub = cov[np.ix_(blocks_idx, blocks_idx)]
    sub = np.where(np.isfinite(sub), sub, 0.0)              # undetermined rows of G are NaN already
    return out, names, G_all @ sub @ G_all.T


def _correlated_pairs(terms: list[TermFit], names: list[str], cov: np.ndarray) -> list[Correlation]:
    """Pairs of contract parameters whose estimates correlate beyond ``CORRELATION_LIMIT`` (a near-flat
    direction of the fit), each with the combination of the two the samples determine best.

    For standard errors s_i, s_j and correlation r that combination is ``p_i / s_i - sign(r) p_j / s_j``
    (the smaller eigenvalue's direction of the pair's correlation matrix), scaled so that its largest
    coefficient is 1: ``k + kt`` for a linear spring beside an iwan kt."""
    values = np.array([v for t in terms for v in t.params.values()])
    std = np.sqrt(np.abs(np.diag(cov)))
    usable = np.isfinite(std) & (std > 0)
    out = []
    for i, j in zip(*np.triu_indices(len(names), k=1)):
        if not (usable[i] and usable[j]):
            continue
        r = cov[i, j] / (std[i] * std[j])
        if not abs(r) > CORRELATION_LIMIT:
            continue
        a = np.array([1.0 / std[i], -math.copysign(1.0, r) / std[j]])
        a /= a[np.argmax(np.abs(a))]
        pair = [i, j]
        variance = a @ cov[np.ix_(pair, pair)] @ a
        combo = Combination({names[i]: float(a[0]), names[j]: float(a[1])}, float(a @ values[pair]),
                            float(np.sqrt(max(variance, 0.0))))
        out.append(Correlation((names[i], names[j]), float(r), combo))
    return out


def _mark_undetermined(terms: list[TermFit], correlated: list[Correlation]) -> None:
    """Mark the contract parameters the samples do not determine: no finite standard error, a 95 % interval
    that holds zero (``abs(value) < UNDETERMINED_Z * stderr``), or a member of a correlated pair."""
    in_group = {name for g in correlated for name in g.parameters}
    for t in terms:
        marked = set(t.undetermined)
        for name, value in t.params.items():
            err = t.stderr[name]
            if (not math.isfinite(err) or abs(value) < UNDETERMINED_Z * err
                    or f"{t.label}.{name}" in in_group):
                marked.add(name)
        t.undetermined = tuple(n for n in t.law.param_names if n in marked)
