"""Linear / nonlinear verdict: calibrated against its own null distribution and known laws."""
import numpy as np
import pytest

from analysis import InputError
from analysis.identification.identify import identify_complex_stiffness
from analysis.identification.linearity import SCATTER_WINDOW, linearity_verdict, scatter_std

LINES = np.linspace(10.0, 30.0, 40)          # rad/s
LEVELS = np.array([0.2, 0.5, 1.0])            # N


def campaign(kbar_of, seed, noise=1.0, lines=LINES, levels=LEVELS):
    """Samples at every (level, line): amplitude from a resonance-like curve, noisy kbar.

    ``noise`` is the rms of ``|delta kbar|`` in N/m, varied by a factor 3 across samples.
    """
    rng = np.random.default_rng(seed)
    w = np.tile(lines, levels.size)
    level = np.repeat(np.arange(levels.size), lines.size)
    X = levels[level] * 2e-3 / np.abs(1 - (w / 20.0) ** 2 + 0.2j)
    std = noise * rng.uniform(0.5, 1.5, w.size)
    circular = (rng.normal(size=w.size) + 1j * rng.normal(size=w.size)) / np.sqrt(2)
    return X, w, kbar_of(X, w) + std * circular, std, level


def viscous(X, w):
    return 500.0 + 2.0j * w + 0 * X


def cubic(X, w):
    return 0.75 * 2e7 * X**2 + 0j * w


def coulomb(X, w):
    return 1j * 4 * 0.02 / (np.pi * X) + 0 * w


@pytest.mark.slow
def test_linear_element_passes_and_false_alarm_rate_is_as_stated():
    verdicts = [linearity_verdict(*campaign(viscous, seed)[:4]) for seed in range(20)]
    assert all(v.linear for v in verdicts)
    assert all(v.model == "per_line" and v.dof == 2 * (3 - 1) * LINES.size for v in verdicts)
    # Under the linear hypothesis the statistic is chi-square: check the rate at 10 %.
    rate = np.mean([not linearity_verdict(*campaign(viscous, seed)[:4], false_alarm=0.1).linear
                    for seed in range(100, 400)])
    assert 0.05 <= rate <= 0.16
    mean_stat = np.mean([linearity_verdict(*campaign(viscous, seed)[:4]).statistic for seed in range(400, 500)])
    assert abs(mean_stat / verdicts[0].dof - 1) < 0.05


def test_cubic_spring_is_nonlinear_with_rising_real_part():
    v = linearity_verdict(*campaign(cubic, 1)[:4])
    assert not v.linear and v.p_value < 1e-12
    assert v.real.change > 0 and v.real.sigma > 20
    assert v.imag.sigma < 4
    assert v.evidence.startswith("nonlinear")
    assert "Re kbar rises by" in v.evidence and "sigma" in v.evidence


def test_friction_is_nonlinear_with_falling_imaginary_part():
    v = linearity_verdict(*campaign(coulomb, 2)[:4])
    assert not v.linear
    assert v.imag.change < 0 and v.imag.sigma > 20
    assert v.real.sigma < 4
    assert "Im kbar falls by" in v.evidence


def test_a_steady_trend_the_chi_square_dilutes_is_amplitude_dependence():
    # quadratic damping, Im kbar = (8 / 3 pi) c2 w^2 X (its describing function), small beside the viscous part:
    # over 240 degrees of freedom the chi-square stays below its threshold, the trend of Im with ln X does not
    lines = np.linspace(10.0, 30.0, 120)
    v = linearity_verdict(*campaign(lambda X, w: 500.0 + 2.0j * w + 1j * 8 / (3 * np.pi) * 0.4 * w ** 2 * X, 6,
                                    lines=lines)[:4])
    assert v.statistic <= v.threshold and v.imag.sigma > v.trend_limit > 3.5 and v.real.sigma < 3
    assert not v.linear and v.imag.change > 0
    assert f"sigma, beyond the {v.trend_limit:.3g} of a linear element" in v.evidence
    # a single level has no trend across levels within a line: the chi-square alone decides
    one = linearity_verdict(*campaign(cubic, 1, levels=LEVELS[:1])[:4])
    assert one.model == "polynomial" and one.trend_limit == np.inf


def test_a_law_acting_at_the_largest_amplitudes_only_is_amplitude_dependence():
    # a clearance that closes at the higher level's resonance only (the two largest of 80 samples, a few sigma
    # each): the chi-square over 80 dof and the trend in ln X stay quiet, the tail's shift does not
    def gap(X, w, k=4000.0, clearance=0.0094):
        u = np.minimum(clearance / X, 1.0)
        return k * (1 - 2 / np.pi * (np.arcsin(u) + u * np.sqrt(1 - u ** 2))) + 0j * w
    X, w, k, std, _ = campaign(gap, 7, noise=12.0, levels=np.array([0.2, 1.0]))
    assert np.count_nonzero(gap(X, w).real) == 2
    v = linearity_verdict(X, w, k, std)
    assert v.statistic <= v.threshold and max(v.real.sigma, v.imag.sigma) <= v.trend_limit
    assert not v.linear and v.tail.component == "Re" and v.tail.departs and v.tail.shift > 0
    assert "largest-amplitude sample(s)" in v.evidence
    # the same samples without the law: linear, and so is a kbar that changes smoothly with the frequency only
    for kbar_of in (lambda X, w: 0j * X, lambda X, w: 4.0 * w + 0.02j * w ** 2):
        X, w, k, std, _ = campaign(kbar_of, 7, noise=12.0, levels=np.array([0.2, 1.0]))
        v = linearity_verdict(X, w, k, std)
        assert v.linear and not v.tail.departs, v.evidence


def test_amplitudes_all_alike_at_the_top_have_no_tail_to_test():
    # two levels, each at one amplitude (response control): the largest samples are a level, not a tail
    w = np.tile(LINES, 2)
    X = np.repeat([1e-3, 4e-3], LINES.size)
    v = linearity_verdict(X, w, 100.0 + 0j * w + 0.1 * np.random.default_rng(0).normal(size=w.size), np.ones(w.size))
    assert v.tail is None


def test_constant_offset_is_linear_and_named_as_offset():
    v = linearity_verdict(*campaign(lambda X, w: 200.0 + 5.0j + 0 * X, 3)[:4])
    assert v.linear
    assert abs(v.mean_kbar - (200.0 + 5.0j)) < 5 * v.mean_kbar_std
    assert "offset" in v.evidence and "mean kbar 200" in v.evidence


def test_single_level_uses_the_linear_correction_model():
    def mis_modelled(X, w):
        return 300.0 - 0.5 * w**2 + 1j * (0.8 * w + 20.0) + 0 * X

    X, w, k, std, _ = campaign(mis_modelled, 4, noise=0.05, levels=np.array([1.0]))
    v = linearity_verdict(X, w, k, std)
    assert v.model == "polynomial" and v.linear and v.dof == 2 * LINES.size - 4
    c = v.linear_correction
    np.testing.assert_allclose([c["a"], c["b"], c["c"], c["d"]], [300.0, -0.5, 0.8, 20.0], rtol=0.02)
    assert "linear correction: stiffness 300" in v.evidence
    X, w, k, std, _ = campaign(cubic, 4, levels=np.array([1.0]))
    assert not linearity_verdict(X, w, k, std).linear


def test_estimated_noise_matches_the_true_noise_and_decides():
    lines = np.linspace(10.0, 30.0, 120)
    X, w, k, std, level = campaign(viscous, 5, noise=2.0, lines=lines)
    estimated = scatter_std(w, k, level)
    assert abs(np.sqrt(np.mean(estimated**2)) / np.sqrt(np.mean(std**2)) - 1) < 0.1
    false_alarms = sum(not linearity_verdict(*campaign(viscous, seed, lines=lines)[:3], level=level).linear
                       for seed in range(20))
    assert false_alarms <= 2
    v = linearity_verdict(*campaign(cubic, 6, lines=lines)[:3], level=level)
    assert not v.linear and v.noise_estimated and "scatter" in v.evidence


@pytest.mark.parametrize("cubic_stiffness, linear", [(0.0, True), (4e7, False)])
def test_end_to_end_with_identification(cubic_stiffness, linear):
    """Three-DOF chain, element grounded at x0 (not measured), force at x2, three levels.

    For a single element the response is explicit in the element amplitude X
    (docs/method.md §4): choose X, then kbar(X), then Hbar, then the force F = X / |hbar_e|.
    """
    rng = np.random.default_rng(7)
    M = np.diag([1.0, 1.5, 2.0])
    K = 1e4 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    C = 1e-4 * K
    w = np.linspace(20.0, 200.0, 60)
    Z = K[None] - w[:, None, None] ** 2 * M[None] + 1j * w[:, None, None] * C[None]
    H = np.linalg.inv(Z)
    samples = []
    for X_level in (1e-4, 3e-4, 1e-3):
        kbar = 0.75 * cubic_stiffness * X_level**2 + 500.0 + 0.5j * w   # plus a linear spring-damper
        Delta = np.zeros_like(Z)
        Delta[:, 0, 0] = kbar
        Hbar = np.linalg.inv(Z + Delta)
        force = X_level / np.abs(Hbar[:, 0, 2])
        clean = Hbar[:, [1, 2], 2]
        std = 1e-3 * np.abs(clean)
        noisy = clean + std * (rng.normal(size=clean.shape) + 1j * rng.normal(size=clean.shape)) / np.sqrt(2)
        result = identify_complex_stiffness(H, noisy, [1, 2], 2, [0], force=force, noise_std=std)
        keep = ~result.ill_conditioned
        samples.append((result.amplitude[keep, 0], w[keep], result.kbar[keep, 0], result.kbar_std[keep, 0]))
    X, ws, k, s = (np.concatenate(parts) for parts in zip(*samples))
    v = linearity_verdict(X, ws, k, s)
    assert v.linear == linear, v.evidence
    if not linear:
        assert v.real.change > 0 and "Re kbar rises" in v.evidence


@pytest.mark.parametrize("kwargs, message", [
    (dict(X=np.ones(3)), "X, w and kbar must be 1-D arrays of one length"),
    (dict(X=-np.ones(120)), "X must be finite and > 0"),
    (dict(kbar_std=np.zeros(120)), "kbar_std must be 120 finite values > 0"),
    (dict(false_alarm=1.5), "false_alarm must lie in"),
    (dict(model="spline"), "model must be"),
    (dict(kbar_std=None), "share a frequency line: give level labels"),
])
def test_bad_input_is_one_line_error(kwargs, message):
    X, w, k, std, _ = campaign(viscous, 0)
    args = dict(X=X, w=w, kbar=k, kbar_std=std)
    args.update(kwargs)
    with pytest.raises(InputError, match=message) as info:
        linearity_verdict(args.pop("X"), args.pop("w"), args.pop("kbar"), args.pop("kbar_std"), **args)
    assert "\n" not in str(info.value)


def test_too_few_samples_for_the_model_is_an_error():
    X, w, k, std, _ = campaign(viscous, 0, lines=LINES[:2], levels=np.array([1.0]))
    with pytest.raises(InputError, match="no degrees of freedom for the polynomial model"):
        linearity_verdict(X, w, k, std)
    with pytest.raises(InputError, match="per_line model"):
        linearity_verdict(X, w, k, std, model="per_line")


def test_scatter_noise_on_a_level_shorter_than_its_window():
    """A force level with fewer lines than the averaging window still gets one estimate per line."""
    rng = np.random.default_rng(3)
    n = SCATTER_WINDOW + 2                      # fewer combinations than the 2 * SCATTER_WINDOW + 1 window
    w = np.linspace(10.0, 12.0, n)
    kbar = 1e4 + 0.0j + 50.0 * (rng.normal(size=n) + 1j * rng.normal(size=n))
    std = scatter_std(w, kbar)
    assert std.shape == (n,) and np.all(np.isfinite(std)) and np.all(std > 0)
    assert np.allclose(std, std[0])             # every combination lies in every line's window


def test_the_per_line_fit_in_closed_form_is_the_dense_least_squares():
    """The per-line component against the dense weighted least squares on the indicator design (and its ln X
    extension with pinv's standard error) it replaces."""
    from analysis.identification.linearity import _component, _per_line_component

    rng = np.random.default_rng(5)
    group = np.repeat(np.arange(40), 3)[rng.permutation(120)]
    values = rng.normal(size=120) + 0.3 * group
    sigma = rng.uniform(0.5, 2.0, size=120)
    log_X = np.log(rng.uniform(1e-4, 1e-2, size=120))
    fast, coef = _per_line_component(group, values, sigma, log_X)
    dense, dense_coef = _component(np.eye(40)[group], values, sigma, log_X)
    np.testing.assert_allclose(coef, dense_coef, rtol=1e-10)
    assert fast.dof == dense.dof == 80
    np.testing.assert_allclose([fast.chi2, fast.change, fast.sigma], [dense.chi2, dense.change, dense.sigma],
                               rtol=1e-9)
    flat, _ = _per_line_component(group, values, sigma, np.log(np.full(120, 1e-3)))
    assert flat.sigma == flat.change == 0.0                 # no amplitude spread: no trend, as the dense rank says
