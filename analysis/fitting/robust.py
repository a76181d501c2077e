"""Fits that leave out the samples that do not follow the fitted laws (docs/fitting.md, "Outliers"): a Huber
start that large outliers do not drag far (:func:`_robust_start`), then samples whose chi-square share exceeds the
outlier limit (:func:`analysis.common.statistics.outlier_limit`) left out and the rest refitted until the set stops
changing (:func:`_fit_robust`), never leaving out what determines a law's size: a pass that would leave a law's
size unseen that was seen, or leave out every sample a law acts on, is not made.
"""
from __future__ import annotations

import math

import numpy as np

from ..common.statistics import OUTLIER_FALSE_ALARM, capped_chi_square, outlier_limit
from .projection import _fit_once
from .results import LawFit
from .samples import _Options, _Samples


# Huber's threshold (in standard deviations of a sample's residual) for the reweighted start of the
# outlier search, and the most reweighting / exclusion passes.
HUBER_LIMIT = 2.0
_ROBUST_ITERATIONS = 20
# The reweighted start has settled when a pass moves no sample's distance from the fit by more than this share
# of the misfit's scale (:func:`_settled`). Reweighting converges only linearly: to weights equal within 1e-3 it
# took all its passes for the law sets that miss the samples by tens of standard deviations.
HUBER_SETTLED = 0.01


def _robust_start(terms, data: _Samples, opts: _Options, plain: LawFit | None = None) -> LawFit:
    """Iteratively reweighted fit with Huber weights: a start that large outliers do not drag far (a plain
    least-squares start can sit so far off that the good samples look like the outliers). ``plain``: the plain
    fit of ``data``, where already made."""
    weight = np.ones(data.X.size)
    everything = np.ones(data.X.size, bool)
    fit = plain if plain is not None else _fit_once(terms, data, opts)
    before = None
    for _ in range(_ROBUST_ITERATIONS):
        d = data.distance(fit.describing_function(data.X, data.w))
        new = np.minimum(1.0, HUBER_LIMIT / np.maximum(d, 1e-300))
        if np.allclose(new, weight, rtol=1e-3, atol=1e-6) or (before is not None and _settled(d, before)):
            break
        weight, before = new, d
        fit = _fit_once(_refit_terms(fit), data.subset(everything, weight), _quick(opts))
    return fit


def _settled(distance: np.ndarray, before: np.ndarray) -> bool:
    """Whether a pass of the reweighted start moved every sample's distance from the fit by at most
    :data:`HUBER_SETTLED` of the larger of one standard deviation and the fit's rms distance: the outlier
    search that follows judges samples against the fit's own misfit, so for laws that miss the samples by many
    standard deviations the start needs no finer precision than that misfit."""
    scale = max(1.0, float(np.sqrt(np.mean(distance ** 2))))
    return float(np.max(np.abs(distance - before))) <= HUBER_SETTLED * scale


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
        if _sizes_determined(refit) < _sizes_determined(fit) or _acts_only_on(fit, data, ~new):
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
    """How many of the laws have a size the samples determine: some force scale (the law's ``linear``) beyond its
    95 % interval of zero (:attr:`analysis.fitting.results.TermFit.size_unseen`, the test every judgement of a
    law's size uses). A finite standard error alone is not enough: leaving out the lines a law acts on alone can
    leave it a finite error about a size indistinguishable from none, or of the other sign."""
    return sum(not t.size_unseen for t in fit.terms)


def _acts_only_on(fit: LawFit, data: _Samples, left_out: np.ndarray) -> bool:
    """Whether some law of ``fit`` acts on samples ``left_out`` and on none of the others: its describing function
    is zero at every sample kept (a clearance open at all of them). Leaving those out leaves nothing of the law in
    the fit, whatever its size was."""
    if not left_out.any():
        return False
    for t in fit.terms:
        kbar = t.describing_function(data.X, data.w)
        if np.any(kbar[left_out] != 0) and not np.any(kbar[~left_out] != 0):
            return True
    return False


def _capped_loss(fit: LawFit, data: _Samples) -> float:
    """What leaving samples out minimises: :func:`capped_chi_square` of ``fit`` on ``data``."""
    return capped_chi_square(data.distance(fit.describing_function(data.X, data.w)) ** 2)


def _with_scatter_sigma(terms, data: _Samples, opts: _Options) -> _Samples:
    """Unit weights replaced by the scatter of a Huber fit (median of the chi-square with 2 dof: 2 ln 2)."""
    fit = _robust_start(terms, data, opts)
    r = fit.describing_function(data.X, data.w) - data.kbar
    s = math.sqrt(float(np.median(np.abs(r) ** 2)) / (2 * math.log(2))) or 1.0
    ones = np.full(data.X.size, 1.0 / s)
    return data.reweighted(ones, ones, True)
