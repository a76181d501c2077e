"""The noise of FRFs that came without it (analysis.signals.frf_noise), against noise of known size."""
import numpy as np

from analysis.signals.frf_noise import smoothness_noise


def test_the_estimated_noise_is_the_noise_added():
    rng = np.random.default_rng(0)
    f = np.linspace(1.0, 5.0, 3000)
    H = np.stack([1 / (9 - f ** 2 + 0.1j * f), 1 / (16 - f ** 2 + 0.2j * f)], axis=1)
    relative = 1e-3                                   # E|n|^2 = 2 relative^2 |H|^2 (circular complex)
    noisy = H * (1 + relative * (rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape)))
    std = smoothness_noise(f, noisy)
    ratio = np.sqrt(np.mean((std / np.abs(H)) ** 2, axis=0)) / (np.sqrt(2) * relative)   # rms: the median of a
    # variance estimate lies below its mean
    assert np.all(np.abs(ratio - 1) < 0.1), ratio


def test_a_down_sweep_gets_the_noise_of_its_lines():
    rng = np.random.default_rng(1)
    f = np.linspace(1.0, 5.0, 200)
    H = (1 / (9 - f ** 2 + 0.1j * f))[:, None] * (1 + 1e-3 * (rng.normal(size=(200, 1)) + 1j * rng.normal(size=(200, 1))))
    np.testing.assert_allclose(smoothness_noise(f[::-1], H[::-1])[::-1], smoothness_noise(f, H), rtol=1e-9)


def test_the_stacked_least_squares_is_lstsq_also_where_a_system_is_rank_deficient():
    from analysis.signals.frf_noise import _least_squares

    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 15, 6)) + 1j * rng.normal(size=(3, 15, 6))
    A[1, :, 5] = A[1, :, 4]                                  # two equal columns: rank 5
    b = rng.normal(size=(3, 15)) + 1j * rng.normal(size=(3, 15))
    expected = np.array([np.linalg.lstsq(A[i], b[i], rcond=None)[0] for i in range(3)])
    np.testing.assert_allclose(_least_squares(A, b), expected, atol=1e-12)
