"""The statistics every judgement shares (analysis/common/statistics.py), against independent truth: sampled
circular noise, the chi-square distribution's own tail, and the formulas written out."""
import math

import numpy as np
import scipy.stats

from analysis.common.statistics import (OUTLIER_FALSE_ALARM, capped_chi_square, charged_criterion,
                                        chi_square_noise_bound, chi_square_shares, falls_above_noise, noise_scale,
                                        outlier_limit, part_weight)


def test_a_share_of_circular_noise_is_a_chi_square_of_two_degrees_of_freedom():
    rng = np.random.default_rng(7)
    std = np.full(200_000, 3.0)
    noise = (rng.normal(size=std.size) + 1j * rng.normal(size=std.size)) * std / math.sqrt(2)   # E|n|^2 = std^2
    shares = chi_square_shares(noise, std)
    assert abs(shares.mean() - 2.0) < 0.02 and abs(shares.var() - 4.0) < 0.1
    assert scipy.stats.kstest(shares[:5000], scipy.stats.chi2(2).cdf).pvalue > 1e-3
    np.testing.assert_allclose(part_weight(std[:3]), math.sqrt(2) / 3.0)
    np.testing.assert_allclose(chi_square_shares(np.array([3 + 4j])), [25.0])      # no std: unweighted


def test_the_outlier_limit_loses_one_clean_sample_in_a_hundred_sets():
    for n in (1, 97, 5000):
        limit = outlier_limit(n)
        # P(chi2_2 > L) = exp(-L / 2), so a clean set of n loses a sample with probability ~ n exp(-L / 2)
        assert math.isclose(n * scipy.stats.chi2(2).sf(limit), OUTLIER_FALSE_ALARM, rel_tol=1e-9)
    assert math.isclose(outlier_limit(97), 18.4, abs_tol=0.05)
    z = np.array([1.0, 2.0, 1e6])
    assert capped_chi_square(z) == 3.0 + outlier_limit(3)


def test_the_criterion_and_the_noise_bound_are_the_formulas():
    assert math.isclose(charged_criterion(50.0, 3, 100, scale=2.0), 25.0 + 3 * math.log(100))
    assert math.isclose(chi_square_noise_bound(2.0, 3, 0.01), 2.0 * scipy.stats.chi2.ppf(0.99, 3))
    assert chi_square_noise_bound(1.0, 0, 0.01) == chi_square_noise_bound(1.0, 1, 0.01)       # at least one
    assert noise_scale(10.0, 20, 2) == 1.0 and math.isclose(noise_scale(90.0, 20, 2), 5.0)
    bound = chi_square_noise_bound(1.0, 2, 0.01)
    assert falls_above_noise(100.0, 100.0 - bound * 1.01, 2, 1.0, 0.01)
    assert not falls_above_noise(100.0, 100.0 - bound * 0.99, 2, 1.0, 0.01)
