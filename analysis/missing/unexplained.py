"""Effects outside the library: an element whose kbar its laws do not explain, and what a non-parametric part
would gain there (docs/nonparametric.md).

A real contact follows no law of the library exactly. :func:`unexplained` decides whether an element's kbar
still departs from its fitted laws by much more than the noise:

- the statistic is the *trimmed chi-square* of the residual kbar: ``z_i = 2 |r_i|^2 / std_i^2`` per sample
  (chi-square with 2 degrees of freedom under the noise alone), the ``ceil(OUTLIER_FRACTION N)`` largest left
  out, so that a few outlier lines (a jump, a line that stuck) cannot raise the alarm alone;
- its distribution under the noise alone is exact up to one approximation: by Renyi's representation of
  exponential order statistics the sum of the ``N - m`` smallest of ``N`` exponentials is
  ``sum_j c_j Z_j`` with ``c_j = (N - m - j + 1) / (N - j + 1)`` and ``Z_j`` independent exponentials; it is
  taken as the gamma distribution with the same mean and variance, its mean scaled by ``(2N - k) / 2N`` for the
  ``k`` fitted parameters; the alarm threshold is its ``1 - false_alarm`` quantile;
- the departure must also be large: the residual's rms at least ``MIN_NOISE_RATIO`` times the noise (a
  statistically certain but small departure -- the model-form error of the single-harmonic balance, a noise
  level estimated 30 % low -- is not an effect outside the library).

The residual's signature -- how Re and Im of the residual move with X and w -- is the diagnosis' own
(:func:`analysis.missing.diagnosis.signature`, :func:`analysis.missing.diagnosis.signature_words`), completed by :class:`Trends`:
the slopes of Re and Im of the residual against ln X and ln w together (a plane fitted by weighted least
squares), with their significance, since the signature alone does not say how Re moves with w.

:func:`offer_nonparametric` fits the non-parametric part (:mod:`analysis.mechanics.nonparametric`) to what the laws leave
and predicts the FRFs with it: its error is what a better law could reach at best. ``above_noise`` says whether
that gain is more than the FRF noise explains (the FRF chi-square drop beyond its ``1 - FALSE_ALARM`` quantile for
the part's effective parameters), as the candidates' FRF test does.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import scipy.stats

from ..common.statistics import chi_square_shares, part_weight
from ..fitting.fit import LawFit
from ..laws.base import SignatureWords
from ..mechanics.nonparametric import NonParametric, NonParametricFit, fit_nonparametric
from ..prediction.comparison import (Comparison, Predictor, chi_square_falls, compare_predictions, gain_phrase,
                                     kbar_functions_with)
from .diagnosis import ElementSamples, Signature, signature, signature_words

FALSE_ALARM = 1e-3          # default probability that the noise alone raises the alarm
OUTLIER_FRACTION = 0.05     # largest per-sample chi-squares left out of the statistic
MIN_NOISE_RATIO = 2.0       # residual rms over the noise needed to speak of an effect
TREND_SIGMA = 3.0           # a trend is named in words above this many standard deviations


@dataclass
class Trends:
    """Slopes of the residual kbar against ln X and ln w (a weighted plane ``a + b ln X + c ln w`` per part),
    in kbar units per e-fold, with their significance in standard deviations (0 where w does not vary)."""

    re_X: float
    re_w: float
    im_X: float
    im_w: float
    re_X_sigma: float
    re_w_sigma: float
    im_X_sigma: float
    im_w_sigma: float

    def words(self) -> str:
        """The significant trends, e.g. "Re falls with X (12 sigma), Im rises with w (8 sigma)"."""
        out = []
        for part in ("re", "im"):
            for var in ("X", "w"):
                slope, sigma = getattr(self, f"{part}_{var}"), getattr(self, f"{part}_{var}_sigma")
                if abs(sigma) >= TREND_SIGMA:
                    out.append(f"{part.capitalize()} {'rises' if slope > 0 else 'falls'} with {var} "
                               f"({abs(sigma):.0f} sigma)")
        return ", ".join(out) or "no trend in X or w above the noise"


def _trends(samples: ElementSamples, residual: np.ndarray) -> Trends:
    lx, lw = np.log(samples.X), np.log(samples.w)
    w_varies = np.ptp(lw) > 0.05
    cols = [np.ones_like(lx), lx - lx.mean()] + ([lw - lw.mean()] if w_varies else [])
    weight = part_weight(samples.kbar_std)
    A = np.stack(cols, axis=1) * weight[:, None]
    cov = np.linalg.pinv(A.T @ A)
    out = {}
    for part, values in (("re", residual.real), ("im", residual.imag)):
        coef = cov @ (A.T @ (weight * values))
        # the slopes' scatter: the noise's, or the residual's own where it scatters more (a curved residual)
        scale = max(1.0, float(np.sum((A @ coef - weight * values) ** 2)) / max(len(lx) - len(cols), 1))
        sd = np.sqrt(np.diag(cov) * scale)
        # a variable that does not vary (one amplitude, one line) has no slope: 0 sigma
        sigma = np.divide(coef, sd, out=np.zeros_like(coef), where=sd > 0)
        out[f"{part}_X"], out[f"{part}_X_sigma"] = float(coef[1]), float(sigma[1])
        out[f"{part}_w"], out[f"{part}_w_sigma"] = (float(coef[2]), float(sigma[2])) if w_varies else (0.0, 0.0)
    return Trends(**out)


@dataclass
class Unexplained:
    """An element whose kbar departs from its laws by much more than the noise, and how (module docstring)."""

    element: str
    laws: tuple[str, ...]
    chi_square: float            # trimmed, over the samples kept
    expected: float              # its mean under the noise alone
    threshold: float             # its 1 - false_alarm quantile under the noise alone
    false_alarm: float
    n_samples: int
    left_out: int                # largest per-sample chi-squares left out (outlier lines)
    signature: Signature
    words: SignatureWords
    trends: Trends

    @property
    def noise_ratio(self) -> float:
        """rms of the residual kbar over the noise, over the samples kept."""
        return math.sqrt(self.chi_square / self.expected)

    def text(self) -> str:
        head = (f"is not explained by {' + '.join(self.laws)}: kbar departs" if self.laws else
                "has no law: kbar departs from 0")
        return (f"'{self.element}' {head} by {self.noise_ratio:.1f}x the noise "
                f"(trimmed chi-square {self.chi_square:.3g} against {self.threshold:.3g} at {self.false_alarm:g} "
                f"false alarm, {self.left_out} largest of {self.n_samples} lines left out); residual: "
                f"{self.words.re}; {self.words.im}; {self.trends.words()}")

    def to_json(self) -> dict:
        return {"element": self.element, "laws": list(self.laws), "noise_ratio": self.noise_ratio,
                "chi_square": self.chi_square, "expected": self.expected, "threshold": self.threshold,
                "false_alarm": self.false_alarm, "n_samples": self.n_samples, "left_out": self.left_out,
                "signature": asdict(self.signature), "trends": asdict(self.trends), "text": self.text()}


def trimmed_null(n: int, left_out: int, fitted: int, false_alarm: float) -> tuple[float, float]:
    """(mean, 1 - false_alarm quantile) of the trimmed chi-square under the noise alone (module docstring)."""
    j = np.arange(1, n - left_out + 1)
    c = (n - left_out - j + 1) / (n - j + 1)
    mean, var = float(np.sum(c)), float(np.sum(c ** 2))
    shrink = max(2 * n - fitted, 1) / (2 * n)
    shape, scale = mean ** 2 / var, shrink * var / mean
    return 2 * shrink * mean, 2 * float(scipy.stats.gamma.ppf(1 - false_alarm, shape, scale=scale))


def _departs(chi_square: float, expected: float, threshold: float) -> bool:
    """Above the noise at the false-alarm probability, and by much: ``MIN_NOISE_RATIO`` in rms."""
    return chi_square > threshold and chi_square >= MIN_NOISE_RATIO ** 2 * expected


def unexplained(samples: ElementSamples, fit: LawFit | None, false_alarm: float = FALSE_ALARM
                ) -> Unexplained | None:
    """The finding when ``samples.kbar`` departs from ``fit`` (the element's fitted laws; None: no laws, kbar
    against 0) by much more than the noise, else None. Without standard deviations there is no noise to judge
    against: None."""
    if samples.kbar_std is None or len(samples.X) < 4:
        return None
    model = fit.describing_function(samples.X, samples.w) if fit is not None else np.zeros(len(samples.X))
    residual = samples.kbar - model
    z = np.sort(chi_square_shares(residual, samples.kbar_std))
    n = len(z)
    left_out = math.ceil(OUTLIER_FRACTION * n)
    chi_square = float(z[: n - left_out].sum())
    expected, threshold = trimmed_null(n, left_out, 0 if fit is None else fit.effective_parameters, false_alarm)
    if not _departs(chi_square, expected, threshold):
        return None
    sig = signature(samples, model if fit is not None else None)
    return Unexplained(samples.name, tuple(t.law.name for t in fit.terms) if fit is not None else (), chi_square,
                       expected, threshold, false_alarm, n, left_out, sig, signature_words(sig, samples.units[0]),
                       _trends(samples, residual))


# ---------------------------------------------------------------------- what a non-parametric part gains
@dataclass
class NonParametricOffer:
    """The non-parametric part fitted to what an element's laws leave, and the FRF error it gives."""

    element: str
    fit: NonParametricFit
    error: float
    error_before: float
    extrapolated_lines: int      # predicted lines where the element's amplitude lies outside the knots
    above_noise: bool            # the FRF chi-square drops by more than the noise explains (module docstring)
    finding: Unexplained | None = None

    @property
    def gain(self) -> float:
        return self.error_before / self.error if self.error > 0 else float("inf")

    def text(self) -> str:
        clamp = (f"; {self.extrapolated_lines} predicted line(s) outside its amplitude range, held constant there"
                 if self.extrapolated_lines else "")
        gain = (f"a better law could gain up to x{self.gain:.3g}" if self.gain >= 1 else
                f"{gain_phrase(self.gain)}: the laws predict the FRFs better than the smoothed samples")
        if self.gain >= 1 and not self.above_noise:
            gain += " (no more than the FRF noise explains)"
        return (f"a non-parametric '{self.element}' (--add {self.element}:nonparametric) gives error "
                f"{self.error:.4g} against {self.error_before:.4g}: {gain}" + clamp)

    def to_json(self) -> dict:
        f = self.fit.frequency
        return {"element": self.element, "error": self.error, "error_before": self.error_before,
                "gain": self.gain, "extrapolated_lines": self.extrapolated_lines, "above_noise": self.above_noise,
                "frequency_dependent": self.fit.model.frequency_dependent,
                "frequency_test": None if f is None else asdict(f),
                "finding": None if self.finding is None else self.finding.to_json(), "text": self.text()}


def offer_nonparametric(predictor: Predictor, base: Comparison, index: int, samples: ElementSamples,
                        fit: LawFit | None, finding: Unexplained | None = None) -> NonParametricOffer:
    """Fit the non-parametric part of element ``index`` to ``samples`` minus its laws (``fit``), predict every run
    with it (single-harmonic, as ``base``) and return the error it reaches."""
    laws = fit.describing_function if fit is not None else None
    left = samples.kbar - (laws(samples.X, samples.w) if laws else 0.0)
    np_fit = fit_nonparametric(samples.X, samples.w, left, samples.kbar_std)
    fn = _with_part(laws, np_fit.model)
    elements = predictor.model.elements
    fns = kbar_functions_with(elements, {index: fn})
    predictions = predictor.predict(fns)
    comp = compare_predictions(predictor.runs, predictions)
    outside = sum(int(np_fit.model.outside(np.abs(p.y[:, index])).sum()) for p in predictions.values())
    return NonParametricOffer(samples.name, np_fit, comp.error, base.error, outside,
                              _frf_drop_above_noise(base, comp, np_fit.effective_parameters), finding)


def _frf_drop_above_noise(base: Comparison, comp: Comparison, parameters: float) -> bool:
    """Whether the FRF chi-square falls by more than its 1 - FALSE_ALARM quantile for the part's effective
    parameters (True where the measurement has no standard deviations: nothing to judge against)."""
    return chi_square_falls(base, comp, parameters, FALSE_ALARM)


def _with_part(laws, part: NonParametric):
    """kbar of the laws (None: none) plus the non-parametric part."""
    if laws is None:
        return part.describing_function
    return lambda X, w: laws(X, w) + part.describing_function(X, w)
