"""The statistics every judgement of the method shares, each formula written once (docs/fitting.md).

A complex sample ``z = x + jy`` with standard deviation ``std`` (``sqrt(E|delta z|^2)``, circular noise) carries
``std / sqrt(2)`` on each part, so its share of a chi-square has 2 degrees of freedom:

    share = |residual|^2 / (std^2 / 2) = 2 |residual|^2 / std^2

A set of ``p`` parameters fitted to ``N`` observations is charged ``p ln N`` on top of its chi-square (the
Schwarz criterion, with the chi-square scaled by ``s^2`` where the noise is only known up to a factor). A sample
whose share exceeds ``-2 ln(OUTLIER_FALSE_ALARM / N)`` is an outlier (Bonferroni over the ``N`` samples), and a
chi-square that falls by less than ``s^2 chi2_q(dof)`` falls by no more than the noise explains.
"""
import math

import numpy as np
import scipy.stats

#: Probability that a clean set of samples, with the right standard deviations, loses one as an outlier.
OUTLIER_FALSE_ALARM = 0.01
# The largest share of the samples a fit may leave out as outliers and still be a fit of the data. At the false
# alarm above a clean set loses a sample once in a hundred fits: outliers are rare lines a describing function
# cannot follow (a contact closing, friction sticking, a line the controller did not settle). When more than a
# tenth of the lines depart, they are not exceptions but the data, and the laws do not describe them.
OUTLIER_SHARE_LIMIT = 0.10

_TINY = 1e-300


def part_weight(std) -> np.ndarray:
    """The weight ``sqrt(2) / std`` of a complex sample's real and imaginary part, each carrying ``std / sqrt(2)``
    of its standard deviation ``std`` (any shape; a zero std weighs without bound, not as a division error)."""
    return 1.0 / (np.maximum(np.asarray(std, float), _TINY) / math.sqrt(2.0))


def chi_square_shares(residual, std=None) -> np.ndarray:
    """Each complex residual's share of the chi-square, ``2 |residual|^2 / std^2`` (2 degrees of freedom); with
    ``std`` None the unweighted ``|residual|^2``. Same shape as ``residual``."""
    if std is None:
        return np.abs(residual) ** 2
    return np.abs(np.asarray(residual) * part_weight(std)) ** 2


def charged_criterion(chi_square: float, n_parameters: float, n_observations: int, scale: float = 1.0) -> float:
    """``chi_square / scale + n_parameters ln(n_observations)``: the fit's chi-square (in units of ``scale``,
    s^2, where the noise is known only up to it) with each parameter charged ``ln N`` (Schwarz)."""
    return chi_square / scale + n_parameters * math.log(n_observations)


def outlier_limit(n: int) -> float:
    """The chi-square share (2 degrees of freedom: Re and Im) above which one of ``n`` samples is an outlier.

    Bonferroni: a clean set of ``n`` samples whose sigma is right loses a sample with probability
    ``OUTLIER_FALSE_ALARM``; the limit is ``-2 ln(OUTLIER_FALSE_ALARM / n)`` (18.4 for 97 samples, i.e. 4.3
    standard deviations)."""
    return -2.0 * math.log(OUTLIER_FALSE_ALARM / max(n, 1))


def capped_chi_square(z: np.ndarray) -> float:
    """The chi-square with every sample's share ``z`` capped at the outlier limit (:func:`outlier_limit`):
    where lines may depart from any describing function (data without harmonics), a set of laws neither wins by
    bending to the departing lines nor loses nothing by leaving a line out -- each costs the limit."""
    return float(np.sum(np.minimum(z, outlier_limit(len(z)))))


def noise_scale(chi_square: float, n_observations: int, n_parameters: int) -> float:
    """s^2: the reduced chi-square ``chi_square / (N - p)`` of a fit, at least 1. Where the noise is known only up
    to a factor (a kbar's line noise against the scatter real tests add), the fit's own misfit sets the unit."""
    return max(1.0, chi_square / max(n_observations - n_parameters, 1))


def falls_above_noise(before: float, after: float, added: int, scale: float, false_alarm: float) -> bool:
    """Whether a chi-square falls from ``before`` to ``after`` by more than the noise explains for ``added``
    parameters at the false-alarm rate (:func:`chi_square_noise_bound`)."""
    return bool(before - after > chi_square_noise_bound(scale, added, false_alarm))


def chi_square_noise_bound(scale: float, dof: float, false_alarm: float) -> float:
    """The drop of a chi-square that the noise explains at the false-alarm rate for ``dof`` parameters added
    (at least one), on a chi-square of scale ``scale`` (s^2: for the kbar the reduced chi-square of the best fit,
    at least 1; 1 for the FRFs, whose noise is measured): s^2 chi2_q."""
    return scale * scipy.stats.chi2.ppf(1 - false_alarm, max(dof, 1))
