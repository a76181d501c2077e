"""A systematic misfit: a run of same-sign residuals that noise does not explain is named, with where and how
large; noise alone is not."""
import numpy as np
import pytest

from analysis.missing.misfit import RUN_FALSE_ALARM, shortest_telling_run, systematic_misfits


def _samples(n=167, seed=0, std=0.01):
    rng = np.random.default_rng(seed)
    X = np.geomspace(1e-5, 7e-3, n)
    rng.shuffle(X)                                   # the order of the lines is not the order of amplitude
    law = (98 - 3e3 * X) + 1j * (0.3 + 800 * X)
    noise = std / np.sqrt(2) * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    return X, law, noise, np.full(n, std)


def test_the_run_length_bound_is_the_false_alarm_of_coin_flips():
    n = 167
    L = shortest_telling_run(n)
    assert n * 2.0 ** (1 - L) <= RUN_FALSE_ALARM < n * 2.0 ** (2 - L)


@pytest.mark.parametrize("seed", range(20))
def test_noise_alone_names_no_misfit(seed):
    X, law, noise, std = _samples(seed=seed)
    assert systematic_misfits("e", X, law + noise, law, std) == []


def test_a_law_above_the_data_at_small_amplitude_is_named_with_its_range_and_size():
    # the demo's tangential element: data about 0.2, law about 0.35 N·m/rad at the smallest amplitudes
    X, law, noise, std = _samples()
    small = X < 2e-4
    data = law + noise - 0.15j * small
    found = systematic_misfits("tangential", X, data, law, std, ("N·m/rad", "rad"))
    assert [m.part for m in found] == ["Im"]
    m = found[0]
    assert abs(m.count - small.sum()) <= 3            # a noise sample or two of the same sign may extend the run
    assert m.X_range[0] == X.min() and m.X_range[1] == pytest.approx(X[small].max(), rel=0.1)
    assert m.misfit == pytest.approx(-0.15, abs=0.01) and m.sigma > 10
    assert m.model_ends[0] - m.data_ends[0] == pytest.approx(0.15, abs=0.02)
    assert "tangential Im kbar: the data lie below the fitted laws at X 10 µrad.." in m.text()
    assert m.to_json()["part"] == "Im"


def test_a_run_within_the_noise_is_not_named():
    # a long run whose mean misfit is well inside its standard error: signs alone are not enough
    X, law, _, std = _samples(std=1.0)
    data = law - 1e-4 * (X < 1e-3)
    assert systematic_misfits("e", X, data, law, std) == []
