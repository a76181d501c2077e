"""The non-parametric element part: kbar as a smooth function of the amplitude, and of the frequency where the
data show it (docs/nonparametric.md).

Where no law of the library explains an element's kbar (:mod:`analysis.missing.unexplained`), the samples themselves can
still predict the FRFs: ``kbar(X, w) = s(ln X) + p(ln w)``, added to whatever laws the element carries (it models
what they leave; with no laws it is the whole kbar).

- ``s`` is a natural cubic spline in ``ln X`` through complex values at ``KNOTS`` knots evenly spaced in ``ln X``
  over the measured amplitudes. It is fitted to the samples by weighted least squares (weights ``1 / std``) with
  a penalty on the second differences of the knot values (a P-spline), the smoothing parameter chosen by
  generalised cross-validation. Why this form: kbar is smooth in ``ln X`` over decades of amplitude (every law
  of the library is), the penalised spline bends only as far as the data demand (no order to choose, no
  ringing of a global polynomial), the fit is linear (one solve per smoothing value) and the result is a
  short table of knots and values that a model file carries and a reader can check by eye.
- ``p`` is a natural cubic spline in ``ln w`` through ``W_KNOTS`` knots, zero at the lowest, kept only where
  the F test of :func:`_frequency_dependent` says the frequency explains more of the samples than the noise
  would at ``FREQUENCY_FALSE_ALARM`` (the F test, not a chi-square, so that a misestimated noise level does
  not decide it).

Outside the knot range both splines are held at their end value (the argument is clamped): no trend is
extrapolated. :meth:`NonParametric.outside` tells which amplitudes were clamped, so a prediction can say so.

The part has a describing function only. It has no time-domain force -- nothing says how the force moves
within a cycle, nor what hysteresis produced the measured Im kbar -- so an element carrying one cannot be
simulated nor predicted with harmonics (:func:`analysis.prediction.multiharmonic.element_force_history` refuses it):
it is not a law class (analysis/laws/base.py requires a kernel) but a second kind of element part.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..common.errors import InputError
from ..common.statistics import part_weight
from ..common.tables import Fields
from ..laws.base import broadcast

NAME = "nonparametric"          # how --add and the model file name it
KNOTS = 16                      # knots in ln X (fewer where the samples have fewer distinct amplitudes)
W_KNOTS = 3                     # knots in ln w of the frequency part
FREQUENCY_FALSE_ALARM = 1e-3    # of the F test that keeps the frequency part
_LAMBDAS = np.logspace(-6, 4, 41)   # smoothing values tried (relative to the data's scale)
TOML_KEYS = ("X", "re", "im", "w", "w_re", "w_im")


def _spline(knots: np.ndarray, values: np.ndarray) -> "CubicSpline | None":
    """Natural cubic spline through (knots, values) along axis 0; None for a single knot (a constant)."""
    from scipy.interpolate import CubicSpline    # here, not at the top: the command line starts without scipy

    return CubicSpline(knots, values, bc_type="natural") if len(knots) > 1 else None


def _basis(knots: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Values at ``u`` of the splines through the unit vectors: column k is the spline that is 1 at knot k and 0
    at the others, so ``_basis @ values`` is the spline through ``values`` (u already clamped)."""
    spline = _spline(knots, np.eye(len(knots)))
    return np.ones((len(u), 1)) if spline is None else spline(u)


@dataclass
class NonParametric:
    """kbar(X, w) = s(ln X) + p(ln w), natural cubic splines through complex values at knots (module docstring).

    Attributes
    ----------
    X_knots : ndarray, increasing, m (rad)
    values : ndarray complex, kbar at the amplitude knots, N/m (N·m/rad)
    w_knots, w_values : ndarray or None
        Frequency knots (rad/s) and the frequency part there (0 at the first knot); None: no frequency part.
    """

    X_knots: np.ndarray
    values: np.ndarray
    w_knots: np.ndarray | None = None
    w_values: np.ndarray | None = None

    def __post_init__(self):
        self.X_knots = np.asarray(self.X_knots, float)
        self.values = np.asarray(self.values, complex)
        self._s = _spline(np.log(self.X_knots), self.values)
        self._p = None
        if self.w_knots is not None:
            self.w_knots = np.asarray(self.w_knots, float)
            self.w_values = np.asarray(self.w_values, complex)
            self._p = _spline(np.log(self.w_knots), self.w_values)

    @property
    def frequency_dependent(self) -> bool:
        return self.w_knots is not None

    @property
    def X_range(self) -> tuple[float, float]:
        return float(self.X_knots[0]), float(self.X_knots[-1])

    def describing_function(self, X, w) -> np.ndarray:
        """kbar of the part at amplitudes X and lines w (broadcast), clamped to the knot ranges."""
        X, w = broadcast(np.asarray(X, float), np.asarray(w, float))
        u = np.clip(np.log(np.maximum(X, 1e-300)), *np.log(self.X_range))
        out = np.full(X.shape, self.values[0]) if self._s is None else self._s(u)
        if self._p is not None:
            out = out + self._p(np.clip(np.log(np.maximum(w, 1e-300)), *np.log(self.w_knots[[0, -1]])))
        return out

    def outside(self, X) -> np.ndarray:
        """Which amplitudes lie outside the knot range (where the part is held constant)."""
        X = np.asarray(X, float)
        lo, hi = self.X_range
        return (X < lo * (1 - 1e-9)) | (X > hi * (1 + 1e-9))

    def describe(self, amplitude_unit: str = "m") -> str:
        lo, hi = self.X_range
        return (f"{NAME}({len(self.X_knots)} knots over X = {lo:.3g}..{hi:.3g} {amplitude_unit}, held constant "
                f"outside" + (f"; frequency part over {self.w_knots[0] / (2 * np.pi):.3g}.."
                              f"{self.w_knots[-1] / (2 * np.pi):.3g} Hz" if self.frequency_dependent else "") + ")")

    # ------------------------------------------------------------------ model file
    def to_toml(self) -> dict:
        """The part as the ``nonparametric`` table of a model file's ``[[element]]``."""
        out = {"X": [float(x) for x in self.X_knots], "re": [float(v.real) for v in self.values],
               "im": [float(v.imag) for v in self.values]}
        if self.frequency_dependent:
            out.update({"w": [float(x) for x in self.w_knots], "w_re": [float(v.real) for v in self.w_values],
                        "w_im": [float(v.imag) for v in self.w_values]})
        return out

    @classmethod
    def from_toml(cls, table, source: str | None, where: str) -> "NonParametric":
        f = Fields(table, source, where)
        f.unknown_keys(set(TOML_KEYS))
        X = _knot_list(f, "X")
        re, im = _value_list(f, "re", len(X)), _value_list(f, "im", len(X))
        if f.has("w") != f.has("w_re") or f.has("w") != f.has("w_im"):
            raise f.error("w", "give all of w, w_re and w_im, or none")
        if not f.has("w"):
            return cls(X, re + 1j * im)
        w = _knot_list(f, "w")
        return cls(X, re + 1j * im, w, _value_list(f, "w_re", len(w)) + 1j * _value_list(f, "w_im", len(w)))


def _knot_list(f: Fields, key: str) -> np.ndarray:
    raw = f.require(key)
    if not isinstance(raw, list) or not raw:
        raise f.error(key, "must be a non-empty list of numbers")
    knots = np.array([f.check_number(key, v, positive=True) for v in raw])
    if np.any(np.diff(knots) <= 0):
        raise f.error(key, "knots must increase strictly")
    return knots


def _value_list(f: Fields, key: str, n: int) -> np.ndarray:
    raw = f.require(key)
    if not isinstance(raw, list) or len(raw) != n:
        raise f.error(key, f"must be a list of {n} numbers (one per knot)")
    return np.array([f.check_number(key, v) for v in raw])


# ---------------------------------------------------------------------- fitting
@dataclass
class FrequencyTest:
    """The F test of a frequency part: the drop of the residual sum of squares it brings against its
    parameters, over the residual variance of the larger model."""

    statistic: float
    threshold: float
    dependent: bool

    def text(self) -> str:
        return (f"F = {self.statistic:.3g} against {self.threshold:.3g} at {FREQUENCY_FALSE_ALARM:g} false alarm: "
                + ("kbar depends on the frequency" if self.dependent else "no frequency dependence shown"))


@dataclass
class NonParametricFit:
    """A fitted non-parametric part with how it was chosen."""

    model: NonParametric
    chi_square: float                # weighted residual sum of squares (both parts), as fit_laws counts it
    effective_parameters: float      # trace of the hat matrix (real parameters)
    smoothing: float
    frequency: FrequencyTest | None  # None where the samples span too little frequency to test


@dataclass
class _Solved:
    coefficients: np.ndarray
    rss: float
    edf: float


def _solve(A: np.ndarray, y: np.ndarray, P: np.ndarray, lam: float) -> _Solved:
    """Penalised weighted least squares with a real design and complex data (Re and Im share the design)."""
    M = A.T @ A + lam * P
    Minv = np.linalg.pinv(M)
    c = Minv @ (A.T @ y)
    r = A @ c - y
    edf = 2 * float(np.trace(A @ Minv @ A.T))         # each complex coefficient carries two real parameters
    return _Solved(c, float(np.sum(np.abs(r) ** 2)), edf)


def _gcv(A: np.ndarray, y: np.ndarray, P: np.ndarray) -> tuple[float, _Solved]:
    """The smoothing value that minimises generalised cross-validation, and its solution."""
    n = 2 * len(y)
    scale = np.trace(A.T @ A) / max(np.trace(P), 1e-300)
    best = None
    for lam in _LAMBDAS * scale:
        s = _solve(A, y, P, lam)
        score = n * s.rss / max(n - s.edf, 1.0) ** 2
        if best is None or score < best[0]:
            best = (score, lam, s)
    return best[1], best[2]


def _amplitude_knots(X: np.ndarray) -> np.ndarray:
    """Knots evenly spaced in ln X over the samples: ``KNOTS``, fewer where there are few distinct amplitudes."""
    lx = np.log(X)
    distinct = len(np.unique(np.round(lx, 6)))
    n = min(KNOTS, max(1, distinct // 3)) if np.ptp(lx) > 1e-6 else 1
    return np.exp(np.linspace(lx.min(), lx.max(), n)) if n > 1 else np.array([float(np.exp(lx.mean()))])


def _frequency_dependent(rss_without: float, fitted: _Solved, n_obs: int, added: int) -> FrequencyTest:
    """F test: does the frequency part drop the residual more than noise would, at FREQUENCY_FALSE_ALARM?"""
    dof = max(n_obs - fitted.edf, 1.0)
    statistic = ((rss_without - fitted.rss) / added) / max(fitted.rss / dof, 1e-300)
    import scipy.stats    # here, not at the top: scipy.stats alone takes ~0.5 s to import

    threshold = float(scipy.stats.f.ppf(1 - FREQUENCY_FALSE_ALARM, added, dof))
    return FrequencyTest(float(statistic), threshold, bool(statistic > threshold))


def fit_nonparametric(X, w, kbar, kbar_std=None) -> NonParametricFit:
    """Fit the non-parametric part to kbar samples (module docstring); ``kbar_std`` None weighs them equally."""
    X, w, kbar = np.asarray(X, float), np.asarray(w, float), np.asarray(kbar, complex)
    if len(X) < 3:
        raise InputError(f"a non-parametric element needs at least 3 kbar samples, got {len(X)}")
    weight = np.ones(len(X)) if kbar_std is None else part_weight(kbar_std)
    knots = _amplitude_knots(X)
    u = np.clip(np.log(X), np.log(knots[0]), np.log(knots[-1]))
    B = _basis(np.log(knots), u)
    K = B.shape[1]
    D = np.diff(np.eye(K), 2, axis=0) if K > 2 else np.zeros((0, K))
    P = D.T @ D
    y = weight * kbar
    A = weight[:, None] * B
    lam, solved = _gcv(A, y, P)
    model = NonParametric(knots, solved.coefficients)
    test = None
    lw = np.log(w)
    if np.ptp(lw) > 0.05 and len(X) > K + 2 * W_KNOTS:
        w_knots = np.exp(np.linspace(lw.min(), lw.max(), W_KNOTS))
        G = _basis(np.log(w_knots), lw)[:, 1:]            # zero at the first knot: s carries the constant
        Pw = np.zeros((K + W_KNOTS - 1,) * 2)
        Pw[:K, :K] = P
        with_w = _solve(np.hstack([A, weight[:, None] * G]), y, Pw, lam)
        test = _frequency_dependent(solved.rss, with_w, 2 * len(X), 2 * (W_KNOTS - 1))
        if test.dependent:
            c = with_w.coefficients
            model = NonParametric(knots, c[:K], w_knots, np.concatenate([[0.0], c[K:]]))
            solved = with_w
    return NonParametricFit(model, solved.rss, solved.edf, float(lam), test)
