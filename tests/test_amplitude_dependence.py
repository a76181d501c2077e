"""A law's own signature found where the omnibus linearity test sees none (analysis.search.discovery.amplitude_dependence),
and the verdict it overrules (analysis.loop.workbench._overruled)."""

import numpy as np
import pytest

from analysis.missing.diagnosis import ElementSamples
from analysis.search.discovery import AmplitudeDependence, amplitude_dependence
from analysis.laws import LAWS
from analysis.identification.linearity import linearity_verdict
from analysis.loop.workbench import _overruled

F = np.linspace(3.0, 10.0, 50)


def _samples(c3: float, seed: int, std: float = 25.0) -> ElementSamples:
    """Two levels on interleaved lines (no line shared: the verdict's polynomial model), the motion peaking at
    8 Hz; cubic damping by its analytic describing function i 3/4 c3 w^3 X^2 beside a linear offset."""
    rng = np.random.default_rng(seed)
    f2 = F + 0.07
    w = 2 * np.pi * np.concatenate([F, f2])
    X = np.concatenate([5e-4 * (1 + 4 * np.exp(-((F - 8) / 0.4) ** 2)),
                        2e-3 * (1 + 3 * np.exp(-((f2 - 8) / 0.4) ** 2))])
    kbar = -40.0 + 0.2j * w + 0.75j * c3 * w ** 3 * X ** 2
    kbar = kbar + std / np.sqrt(2) * (rng.standard_normal(X.size) + 1j * rng.standard_normal(X.size))
    return ElementSamples("b", X, w, kbar, np.full(X.size, std), np.repeat([0.5, 2.0], 50), False)


@pytest.mark.slow
def test_a_damping_law_is_found_on_every_draw_where_the_verdict_misses_some():
    verdicts, found = [], []
    for seed in range(8):
        s = _samples(9.0, seed)
        verdicts.append(linearity_verdict(s.X, s.w, s.kbar, s.kbar_std, level=s.level).linear)
        found.append(amplitude_dependence(s))
    assert any(verdicts)                  # the omnibus test calls some of these elements linear
    assert all(d is not None and LAWS[d.law].kind == LAWS["cubic_damping"].kind for d in found)
    assert all(d.chi_square_drop > d.threshold for d in found)


@pytest.mark.slow
def test_no_law_is_found_on_a_linear_element():
    assert all(amplitude_dependence(_samples(0.0, seed)) is None for seed in range(40))


def test_the_verdict_overruled_says_why_and_a_verdict_not_overruled_is_unchanged():
    s = _samples(9.0, 3)
    verdict = linearity_verdict(s.X, s.w, s.kbar, s.kbar_std, level=s.level)
    assert _overruled(verdict, None) is verdict
    found = AmplitudeDependence("cubic_damping", 23.0, 15.5, 11)
    out = _overruled(verdict, found)
    assert not out.linear and out.statistic == verdict.statistic
    assert out.evidence.startswith(verdict.evidence) and "cubic_damping beside a linear law" in out.evidence
