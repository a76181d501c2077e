"""Is an element linear? A chi-square test of kbar samples against their noise.

A linear element (or a linear error of the reference model) has a complex stiffness
that depends on frequency only: ``kbar(X, w) = kbar(w)``. Samples of one element
taken at several force levels must then agree, line by line, within their noise.
The test fits the linear hypothesis and compares the weighted residual with a
chi-square quantile at a stated false-alarm probability, so the threshold is always
relative to the noise.

Two forms of the linear hypothesis:

``per_line``
    One free complex constant per frequency line shared by two or more samples
    (different force levels at the same line). No assumption about the frequency
    dependence; lines with a single sample carry no information and are left out.
``polynomial``
    ``kbar = a + b w^2 + j (c w + d)``: a stiffness offset ``a``, a mass error
    ``-b``, a viscous ``c`` and a structural ``d`` term -- the ways a wrong linear
    reference model shows up at one element (docs/method.md §3). Used when no line is
    shared, e.g. a single force level, where amplitude and frequency dependence
    cannot be fully separated.

Noise: ``kbar_std`` is ``sqrt(E|delta kbar|^2)`` of circular complex noise (as
returned by :func:`analysis.identification.identify.identify_complex_stiffness`), so Re and Im
each have ``kbar_std / sqrt(2)``. Without it the noise is estimated from the scatter
between neighbouring lines of each force level (see :func:`scatter_std`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.stats

from ..common.errors import InputError
from ..common.wording import engineering

DEFAULT_FALSE_ALARM = 1.0e-3
SHARED_LINE_TOLERANCE = 1.0e-9   # relative: lines closer than this are the same line
SCATTER_WINDOW = 10             # half-width, in second differences, of the local noise estimate
SIGNIFICANT_SIGMA = 3.0          # when evidence calls an offset or a trend "significant"
TAIL_SIZES = (1, 2, 4, 8)        # the largest-amplitude samples tested together for a shift (:func:`_tail_shift`)


@dataclass
class ComponentTrend:
    """Change of Re or Im kbar with amplitude once the linear hypothesis is removed.

    Attributes
    ----------
    change : float
        Fitted change across the amplitude range, ``slope * ln(X_max / X_min)``, N/m,
        from adding a ``ln X`` term to the linear-hypothesis fit.
    sigma : float
        ``|change|`` in units of its own standard error (0 when the amplitudes do not vary).
    chi2 : float
        Weighted residual sum of squares of the linear-hypothesis fit.
    dof : int
        Its degrees of freedom.
    """

    change: float
    sigma: float
    chi2: float
    dof: int


@dataclass
class TailShift:
    """The shift of the ``count`` largest-amplitude samples of one component from the linear hypothesis."""

    component: str        # "Re" or "Im"
    count: int            # samples in the tail
    shift: float          # their common shift, N/m (generalised least squares)
    sigma: float          # |shift| over its standard error
    limit: float          # the sigma beyond which it is amplitude dependence
    amplitude: float      # the smallest amplitude of the tail, m

    @property
    def departs(self) -> bool:
        return self.sigma > self.limit


@dataclass
class LinearityVerdict:
    """Linear or nonlinear, with the numbers behind it.

    Attributes
    ----------
    linear : bool
        ``statistic <= threshold`` and neither component's trend beyond ``trend_limit`` sigma.
    statistic : float
        Chi-square of the linear-hypothesis fit, Re and Im together.
    dof : int
        Its degrees of freedom.
    threshold : float
        Chi-square quantile at ``1 - false_alarm / 2`` (per-line model; ``1 - 3 false_alarm / 4`` polynomial).
    p_value : float
        Probability of a statistic at least this large if the element is linear.
    false_alarm : float
        Probability of calling a linear element nonlinear.
    model : str
        ``"per_line"`` or ``"polynomial"`` (module docstring).
    samples_used : int
        Samples that entered the test.
    mean_kbar : complex
        Inverse-variance weighted mean of the samples used, N/m.
    mean_kbar_std : float
        Its standard deviation, ``sqrt(E|delta|^2)``, N/m.
    real, imag : ComponentTrend
        Per-component fit and trend with amplitude.
    amplitude_range : tuple of float
        Smallest and largest amplitude used, m.
    linear_correction : dict or None
        For the polynomial model: ``a`` (N/m), ``b`` (N·s^2/m), ``c`` (N·s/m), ``d`` (N/m).
    noise_estimated : bool
        The noise came from the scatter between lines, not from ``kbar_std``.
    evidence : str
        One paragraph saying what was found.
    trend_limit : float
        With the per-line model, the standard normal quantile at ``false_alarm / 16``: a trend of Re or Im with
        ln X across the levels of a line beyond this many sigma (either sign) is amplitude dependence. The
        chi-square sums every departure over all its degrees of freedom and so is weak against one steady trend
        (a quadratic damping beside a stiffness offset: 8 sigma in Im, p = 0.04 over 112 dof); the two
        tests share ``false_alarm`` with the tail's (``tail``). ``inf`` with
        the polynomial model, where a trend along one level is partly frequency dependence.
    tail : TailShift or None
        The largest shift of the largest-amplitude samples from the linear hypothesis fitted to the others
        (:func:`_tail_shift`); beyond its limit it is amplitude dependence. A law that grows fast with the
        amplitude (a quintic, a clearance that closes at the higher level's resonance) moves only the few
        samples at the largest amplitudes: the chi-square dilutes them over every degree of freedom and a
        trend in ln X hardly sees them (a quintic at 5 sigma on the largest sample, p = 0.57 in the
        chi-square, while its FRFs gained x28 with it). The false alarm is shared: a quarter to the tail's
        tests; with the per-line model half to the chi-square and an eighth to each component's trend, with the
        polynomial model three quarters to the chi-square.
    """

    linear: bool
    statistic: float
    dof: int
    threshold: float
    p_value: float
    false_alarm: float
    model: str
    samples_used: int
    mean_kbar: complex
    mean_kbar_std: float
    real: ComponentTrend
    imag: ComponentTrend
    amplitude_range: tuple[float, float]
    linear_correction: dict | None
    noise_estimated: bool
    evidence: str
    trend_limit: float = np.inf
    tail: TailShift | None = None


def linearity_verdict(X, w, kbar, kbar_std=None, *, level=None, false_alarm: float = DEFAULT_FALSE_ALARM,
                      model: str = "auto", stiffness_unit: str = "N/m", amplitude_unit: str = "m",
                      ) -> LinearityVerdict:
    """Decide whether one element's kbar depends on its amplitude.

    Parameters
    ----------
    X : array_like, shape (N,)
        Element displacement amplitude of each sample, m (rad on rotations), > 0.
    w : array_like, shape (N,)
        Angular frequency of each sample, rad/s, > 0.
    kbar : array_like, shape (N,), complex
        Identified equivalent complex stiffness, N/m. Leave out ill-conditioned lines.
    kbar_std : array_like, shape (N,), optional
        Its standard deviation ``sqrt(E|delta kbar|^2)``, N/m, > 0. When omitted the
        noise is estimated by :func:`scatter_std` along each force level; the
        chi-square threshold then holds only approximately.
    level : array_like, shape (N,), optional
        Force-level (run) label of each sample; needed to estimate the noise when
        several samples share a line.
    false_alarm : float
        Probability, under the linear hypothesis, of a "nonlinear" verdict.
    model : {"auto", "per_line", "polynomial"}
        Form of the linear hypothesis; "auto" takes per_line when some line has
        two or more samples, else polynomial.
    stiffness_unit, amplitude_unit : str
        Units printed in the evidence.

    Returns
    -------
    LinearityVerdict

    Raises
    ------
    InputError
        Mismatched shapes, non-finite or non-positive values, too few samples for
        the chosen model.
    """
    X, w, kbar = _samples(X, w, kbar)
    if not 0.0 < false_alarm < 1.0:
        raise InputError(f"false_alarm must lie in (0, 1), got {false_alarm}", field="false_alarm")
    if model not in ("auto", "per_line", "polynomial"):
        raise InputError(f"model must be 'auto', 'per_line' or 'polynomial', got {model!r}", field="model")
    line = line_labels(w)
    if kbar_std is None:
        std = scatter_std(w, kbar, level)
    else:
        std = np.asarray(kbar_std, float)
        if std.shape != X.shape or not (np.isfinite(std).all() and (std > 0).all()):
            raise InputError(f"kbar_std must be {X.size} finite values > 0", field="kbar_std")
    counts = np.bincount(line)
    shared = counts[line] >= 2
    if model == "auto":
        model = "per_line" if shared.any() else "polynomial"

    if model == "per_line":
        used = shared
        group = np.unique(line[used], return_inverse=True)[1]
    else:
        used = np.ones(X.size, bool)
        w_unit = w / w.max()     # scaled so the design is well conditioned
        base = {"real": np.stack([np.ones_like(w), w_unit**2], axis=1),
                "imag": np.stack([w_unit, np.ones_like(w)], axis=1)}
    X_used, k_used, sigma = X[used], kbar[used], std[used] / np.sqrt(2.0)
    log_X = np.log(X_used)
    fits = {}
    for part, values in (("real", k_used.real), ("imag", k_used.imag)):
        fits[part] = (_per_line_component(group, values, sigma, log_X) if model == "per_line"
                      else _component(base[part], values, sigma, log_X))
    dof = fits["real"][0].dof + fits["imag"][0].dof
    if dof < 1:
        raise InputError(f"{used.sum()} usable samples leave no degrees of freedom for the {model} model: "
                         "measure more lines or more force levels", field="kbar")
    statistic = fits["real"][0].chi2 + fits["imag"][0].chi2
    # the false alarm shared (LinearityVerdict.tail): a quarter to the tail's tests, half (per line; three
    # quarters, polynomial) to the chi-square, the rest to the trends
    threshold = float(scipy.stats.chi2.ppf(1.0 - (false_alarm / 2 if model == "per_line" else 0.75 * false_alarm),
                                           dof))
    # a trend across levels within lines is amplitude dependence and nothing else; along one level (polynomial)
    # it is partly the frequency dependence the polynomial leaves out, and the chi-square alone decides
    trend_limit = float(scipy.stats.norm.isf(false_alarm / 16)) if model == "per_line" else np.inf
    trended = max(fits["real"][0].sigma, fits["imag"][0].sigma) > trend_limit
    tail = _tail_shift(X, w, kbar, std / np.sqrt(2.0), false_alarm / 4)
    p_value = float(scipy.stats.chi2.sf(statistic, dof))

    weights = 1.0 / std[used] ** 2
    mean = complex(np.sum(weights * k_used) / weights.sum())
    mean_std = float(1.0 / np.sqrt(weights.sum()))
    correction = None
    if model == "polynomial":
        (a, b_unit), (c_unit, d) = fits["real"][1], fits["imag"][1]
        correction = {"a": float(a), "b": float(b_unit / w.max() ** 2), "c": float(c_unit / w.max()), "d": float(d)}
    verdict = LinearityVerdict(
        linear=statistic <= threshold and not trended and not (tail is not None and tail.departs),
        statistic=float(statistic), dof=int(dof), threshold=threshold,
        p_value=p_value, false_alarm=false_alarm, model=model, samples_used=int(used.sum()),
        mean_kbar=mean, mean_kbar_std=mean_std, real=fits["real"][0], imag=fits["imag"][0],
        amplitude_range=(float(X_used.min()), float(X_used.max())), linear_correction=correction,
        noise_estimated=kbar_std is None, evidence="", trend_limit=trend_limit, tail=tail)
    verdict.evidence = _evidence(verdict, stiffness_unit, amplitude_unit, int(np.unique(line[used]).size))
    return verdict


def scatter_std(w, kbar, level=None) -> np.ndarray:
    """Noise of kbar estimated from the scatter between neighbouring lines.

    Along each force level, sorted by frequency, the combination of three
    neighbouring samples that cancels any constant and any straight line in w
    leaves noise (and curvature); its mean square over ``SCATTER_WINDOW``
    neighbours on either side, scaled by the combination's noise gain, estimates
    ``E|delta kbar|^2`` locally (with the small-sample correction ``nu / (nu - 2)``
    so that ``1 / std^2`` is unbiased). Curvature of the true kbar along w makes the
    estimate too large, so the test then errs on the side of "linear"; and a
    statistic built on estimated noise has heavier tails than chi-square, so the
    false-alarm probability holds only approximately.

    Parameters
    ----------
    w : array_like, shape (N,)
        Angular frequencies, rad/s.
    kbar : array_like, shape (N,), complex
        Samples, N/m.
    level : array_like, shape (N,), optional
        Force-level label of each sample; default one level.

    Returns
    -------
    ndarray, shape (N,)
        ``sqrt(E|delta kbar|^2)`` at each sample, N/m.
    """
    w = np.asarray(w, float)
    kbar = np.asarray(kbar, complex)
    level = np.zeros(w.size, int) if level is None else np.asarray(level)
    if level.shape != w.shape:
        raise InputError(f"level must have one label per sample ({w.size}), got shape {level.shape}",
                         field="level")
    std = np.empty(w.size)
    for label in np.unique(level):
        members = np.flatnonzero(level == label)
        order = members[np.argsort(w[members], kind="stable")]
        ws, ks = w[order], kbar[order]
        if ws.size < 3:
            raise InputError(f"estimating the noise needs at least 3 lines per force level; level {label!r} "
                             f"has {ws.size} (or give kbar_std)", field="kbar_std")
        if (np.diff(ws) <= SHARED_LINE_TOLERANCE * ws.max()).any():
            raise InputError("samples of one force level share a frequency line: give level labels so the "
                             "noise can be estimated along each level (or give kbar_std)", field="level")
        h1, h2 = np.diff(ws)[:-1], np.diff(ws)[1:]
        coeffs = np.stack([h2, -(h1 + h2), h1], axis=1)
        combination = coeffs[:, 0] * ks[:-2] + coeffs[:, 1] * ks[1:-1] + coeffs[:, 2] * ks[2:]
        variance = np.abs(combination) ** 2 / np.sum(coeffs**2, axis=1)
        # mean over up to SCATTER_WINDOW neighbours on either side (fewer at the ends and on short levels)
        idx = np.arange(variance.size)
        lo, hi = np.maximum(idx - SCATTER_WINDOW, 0), np.minimum(idx + SCATTER_WINDOW + 1, variance.size)
        total = np.concatenate([[0.0], np.cumsum(variance)])
        count = (hi - lo).astype(float)
        local = (total[hi] - total[lo]) / count
        # A variance estimate with nu real degrees of freedom underestimates 1/sigma^2 on
        # average by nu / (nu - 2); correct it so the chi-square mean stays right.
        nu = 2.0 * count
        local = local * nu / np.maximum(nu - 2.0, 1.0)
        std[order] = np.sqrt(np.concatenate([local[:1], local, local[-1:]]))
    if not (std > 0).all():
        raise InputError("the estimated noise is zero somewhere (noise-free data?): give kbar_std",
                         field="kbar_std")
    return std


def _samples(X, w, kbar):
    X = np.asarray(X, float)
    w = np.asarray(w, float)
    kbar = np.asarray(kbar, complex)
    if X.ndim != 1 or X.shape != w.shape or X.shape != kbar.shape:
        raise InputError(f"X, w and kbar must be 1-D arrays of one length, got shapes {X.shape}, {w.shape}, "
                         f"{kbar.shape}", field="kbar")
    for name, values in (("X", X), ("w", w)):
        if not (np.isfinite(values).all() and (values > 0).all()):
            raise InputError(f"{name} must be finite and > 0 (drop ill-conditioned lines first)", field=name)
    if not np.isfinite(kbar).all():
        raise InputError("kbar must be finite (drop ill-conditioned lines first)", field="kbar")
    return X, w, kbar


def line_labels(w: np.ndarray) -> np.ndarray:
    """Integer label per sample, shape of ``w`` (N,): samples whose lines (rad/s) lie within
    ``SHARED_LINE_TOLERANCE`` of the largest, one after another, share a label -- one line measured by several runs,
    whose frequencies may differ in their last digits."""
    if not w.size:
        return np.zeros(0, int)
    order = np.argsort(w, kind="stable")
    new_line = np.diff(w[order]) > SHARED_LINE_TOLERANCE * w.max()
    labels = np.empty(w.size, int)
    labels[order] = np.concatenate([[0], np.cumsum(new_line)])
    return labels


def _component(base: np.ndarray, values: np.ndarray, sigma: np.ndarray, log_X: np.ndarray):
    """Weighted fit of one component; returns (ComponentTrend, coefficients of the base fit)."""
    weighted_base = base / sigma[:, None]
    target = values / sigma
    coef, *_ = np.linalg.lstsq(weighted_base, target, rcond=None)
    rank = np.linalg.matrix_rank(weighted_base) if base.shape[1] else 0
    chi2 = float(np.sum((weighted_base @ coef - target) ** 2))
    dof = values.size - rank
    # Trend: the ln X coefficient of the base fit extended by ln X, with its standard error.
    extended = np.column_stack([weighted_base, log_X / sigma])
    change = sigma_count = 0.0
    if dof >= 2 and np.linalg.matrix_rank(extended) > rank:
        ext_coef, *_ = np.linalg.lstsq(extended, target, rcond=None)
        covariance = np.linalg.pinv(extended.T @ extended)
        span = log_X.max() - log_X.min()
        slope, slope_se = ext_coef[-1], np.sqrt(covariance[-1, -1])
        change, sigma_count = float(slope * span), float(abs(slope) / slope_se)
    return ComponentTrend(change, sigma_count, chi2, int(dof)), coef


def _tail_shift(X, w, kbar, sigma, false_alarm: float) -> TailShift | None:
    """The largest common shift, in sigma, of the ``k`` largest-amplitude samples (``k`` in :data:`TAIL_SIZES`,
    at most a quarter of the samples, larger in amplitude than every other) from a quadratic in w fitted to the
    other samples (a linear element's kbar may change smoothly with the frequency), the fit's own uncertainty
    included (generalised least squares on the tail's residuals); ``false_alarm`` is shared by the tests of both
    components (two-sided). None with too few samples, or amplitudes too alike, for any test."""
    order = np.argsort(X, kind="stable")
    sizes = [k for k in TAIL_SIZES if 4 * k <= X.size and X.size - k >= 4 and X[order[-k]] > X[order[-k - 1]]]
    if not sizes:
        return None
    limit = float(scipy.stats.norm.isf(false_alarm / (4 * len(sizes))))
    w_unit = w / w.max()
    A = np.stack([np.ones_like(w), w_unit, w_unit ** 2], axis=1)
    best = None
    for k in sizes:
        tail, rest = order[-k:], order[:-k]
        # Re and Im share the weights, so the fit's design, covariance and the tail's C are the same for both
        Aw = A[rest] / sigma[rest, None]
        covariance = np.linalg.pinv(Aw.T @ Aw)
        C = np.diag(sigma[tail] ** 2) + A[tail] @ covariance @ A[tail].T
        Ci_1 = np.linalg.solve(C, np.ones(k))
        se = float(1.0 / np.sqrt(Ci_1.sum()))
        for name, values in (("Re", kbar.real), ("Im", kbar.imag)):
            coef, *_ = np.linalg.lstsq(Aw, values[rest] / sigma[rest], rcond=None)
            shift = float(np.linalg.solve(C, values[tail] - A[tail] @ coef).sum() / Ci_1.sum())
            found = TailShift(name, k, shift, abs(shift) / se, limit, float(X[tail].min()))
            if best is None or found.sigma > best.sigma:
                best = found
    return best


def _per_line_component(group: np.ndarray, values: np.ndarray, sigma: np.ndarray, log_X: np.ndarray):
    """:func:`_component` for the per-line base (one indicator column per line), in closed form: the fit is
    the weighted mean of each line, and the ln X trend beside it the weighted regression of what is left on
    ln X less its own line means (Frisch-Waugh-Lovell). Linear in the samples, where the dense least squares on
    a samples x lines design grows with the cube of the lines."""
    weight = sigma ** -2.0
    totals = np.bincount(group, weight)

    def line_means(v: np.ndarray) -> np.ndarray:
        return np.bincount(group, weight * v) / totals

    coef = line_means(values)
    residual = values - coef[group]
    chi2 = float(np.sum(weight * residual ** 2))
    rank = totals.size
    dof = values.size - rank
    centred = log_X - line_means(log_X)[group]
    spread = float(np.sum(weight * centred ** 2))
    change = sigma_count = 0.0
    # the extended design has a larger rank when ln X varies within some line (as matrix_rank would decide)
    if dof >= 2 and spread > (values.size * np.finfo(float).eps) ** 2 * float(np.sum(weight * log_X ** 2)):
        slope = float(np.sum(weight * centred * residual)) / spread
        change, sigma_count = slope * float(log_X.max() - log_X.min()), abs(slope) * np.sqrt(spread)
    return ComponentTrend(float(change), float(sigma_count), chi2, int(dof)), coef


def _evidence(v: LinearityVerdict, k_unit: str, x_unit: str, n_lines: int) -> str:
    compare = ("compared line by line across force levels at " if v.model == "per_line"
               else "fitted as a + b w^2 + j (c w + d) over ") + f"{n_lines} lines"
    within = "within" if v.statistic <= v.threshold else "exceeds"
    parts = [f"{'linear' if v.linear else 'nonlinear'}: chi-square {v.statistic:.4g} for {v.dof} dof {within} "
             f"{v.threshold:.4g} (false-alarm probability {v.false_alarm:g}, p = {v.p_value:.2g}), {compare}"]
    x_lo, x_hi = v.amplitude_range
    for name, trend in (("Re kbar", v.real), ("Im kbar", v.imag)):
        if trend.sigma == 0.0:
            parts.append(f"{name}: the amplitude does not vary enough to show a trend")
            continue
        direction = "rises" if trend.change > 0 else "falls"
        beyond = f", beyond the {v.trend_limit:.3g} of a linear element" if trend.sigma > v.trend_limit else ""
        parts.append(f"{name} {direction} by {engineering(abs(trend.change), k_unit)} ({trend.sigma:.1f} sigma"
                     f"{beyond}) over X {x_lo:.3g}..{x_hi:.3g} {x_unit}")
    if v.tail is not None and v.tail.departs:
        t = v.tail
        parts.append(f"{t.component} kbar of the {t.count} largest-amplitude sample(s) (X >= {t.amplitude:.3g} "
                     f"{x_unit}) departs from the linear hypothesis by {engineering(t.shift, k_unit)} ({t.sigma:.1f} "
                     f"sigma, beyond the {t.limit:.3g} of a linear element)")
    if v.linear_correction is not None:
        c = v.linear_correction
        parts.append(f"linear correction: stiffness {c['a']:.4g} {k_unit}, mass {-c['b']:.4g} {k_unit}·s^2, "
                     f"viscous {c['c']:.4g} {k_unit}·s, structural {c['d']:.4g} {k_unit}")
    if abs(v.mean_kbar) > SIGNIFICANT_SIGMA * v.mean_kbar_std:
        note = (" -- an amplitude-independent offset means the reference model is wrong at this element "
                "(a linear mis-model, not a nonlinearity)" if v.linear else "")
        parts.append(f"mean kbar {v.mean_kbar.real:.4g} {v.mean_kbar.imag:+.4g}j {k_unit} "
                     f"(+- {v.mean_kbar_std:.2g}){note}")
    if v.noise_estimated:
        parts.append("noise estimated from the scatter between neighbouring lines")
    return "; ".join(parts)
