"""Harmonic analysis: single-bin DFT on coherent records, IEEE 1057 sine fit, THD."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.signals.harmonics import (HarmonicProjector, coherent_length, harmonics, harmonics_at, sine_fit,
                                       total_harmonic_distortion)

FS = 1000.0


def synthesise(Y, frequency, n, fs=FS):
    """Y_0 + sum_k Im(Y_k exp(j k w t)) written out with sin and cos (independent of the module)."""
    t = np.arange(n) / fs
    y = np.full(n, np.real(Y[0]))
    for k in range(1, len(Y)):
        y += Y[k].real * np.sin(2 * np.pi * k * frequency * t) + Y[k].imag * np.cos(2 * np.pi * k * frequency * t)
    return y


amplitudes = st.lists(st.complex_numbers(max_magnitude=10.0, allow_nan=False, allow_infinity=False),
                      min_size=4, max_size=4)


@settings(max_examples=25, deadline=None)
@given(Y=amplitudes, mean=st.floats(-5, 5), periods=st.integers(1, 40))
def test_single_bin_dft_recovers_every_harmonic(Y, mean, periods):
    n = 2000
    frequency = periods * FS / n
    truth = np.array([mean, *Y])
    if 4 * frequency >= FS / 2:
        return
    h = harmonics(synthesise(truth, frequency, n), FS, frequency, 4)
    np.testing.assert_allclose(h.amplitudes, truth, atol=1e-9)
    assert h.residual_rms < 1e-9


def test_sine_convention_and_multichannel_ratio():
    n, frequency = 1000, 5.0
    t = np.arange(n) / FS
    x = 2.0 * np.sin(2 * np.pi * frequency * t)
    y = 3.0 * np.sin(2 * np.pi * frequency * t + 0.4)
    h = harmonics(np.column_stack([x, y]), FS, frequency, 2)
    assert h.fundamental[0] == pytest.approx(2.0)
    assert h.fundamental[1] / h.fundamental[0] == pytest.approx(1.5 * np.exp(0.4j))
    assert h.phase[1, 1] == pytest.approx(0.4)


def test_thd_of_known_distortion():
    Y = np.array([0.0, 1.0, 0.0, 0.3j, 0.0, 0.4])
    assert total_harmonic_distortion(Y) == pytest.approx(0.5)
    h = harmonics(synthesise(Y, 10.0, 1000), FS, 10.0, 5)
    assert h.thd == pytest.approx(0.5)
    assert total_harmonic_distortion(np.array([0.0, 0.0, 1.0])) == np.inf


def test_noise_variance_of_single_bin_dft():
    """White noise of variance s^2 gives E|dY|^2 = 4 s^2 / N (docs/method.md §5)."""
    rng = np.random.default_rng(3)
    n, sigma, frequency = 400, 0.5, 25.0
    errors = [harmonics(rng.normal(0, sigma, n), FS, frequency, 1).fundamental for _ in range(3000)]
    assert np.mean(np.abs(errors) ** 2) == pytest.approx(4 * sigma**2 / n, rel=0.08)


def test_incoherent_record_is_refused_and_coherent_length_fixes_it():
    with pytest.raises(ValueError, match="whole number"):
        harmonics(np.zeros(1000), FS, 7.3, 3)
    n, m = coherent_length(7.3, FS, 1000)
    assert n >= 1000 and m * FS / 7.3 == pytest.approx(n)
    harmonics(np.zeros(n), FS, 7.3, 3)
    with pytest.raises(ValueError, match="Nyquist"):
        harmonics(np.zeros(1000), FS, 100.0, 5)


def test_sine_fit_recovers_an_incoherent_tone_in_noise():
    rng = np.random.default_rng(1)
    n, frequency = 3000, 13.37123
    t = np.arange(n) / FS
    y = 1.7 * np.sin(2 * np.pi * frequency * t + 0.9) - 0.2 + rng.normal(0, 0.01, n)
    fit = sine_fit(y, FS)
    # Cramer-Rao scale of the frequency error: sigma sqrt(12) / (2 pi A T sqrt(N)) ~ 6e-5 Hz
    assert fit.frequency == pytest.approx(frequency, abs=5e-4)
    assert fit.amplitude == pytest.approx(1.7 * np.exp(0.9j), abs=3e-3)
    assert fit.offset == pytest.approx(-0.2, abs=1e-3)
    assert fit.residual_rms == pytest.approx(0.01, rel=0.1)


def test_harmonics_at_a_fitted_frequency_removes_leakage():
    n, frequency = 1234, 9.87654
    Y = np.array([0.1, 1.0 + 0.5j, 0.0, 0.2 - 0.1j])
    y = synthesise(Y, frequency, n)
    with pytest.raises(ValueError):
        harmonics(y, FS, frequency, 3)
    # the frequency comes from an undistorted reference channel (the force, on a rig)
    reference = np.sin(2 * np.pi * frequency * np.arange(n) / FS + 0.3)
    fit = sine_fit(reference, FS, frequency_guess=9.8)
    h = harmonics_at(y, FS, fit.frequency, 3)
    np.testing.assert_allclose(h.amplitudes, Y, atol=1e-7)


def test_sine_fit_refuses_flat_records():
    with pytest.raises(ValueError):
        sine_fit(np.ones(100), FS)
    assert math.isfinite(sine_fit(np.sin(np.arange(100)), FS).frequency)


def test_a_batch_of_records_gives_each_record_s_written_harmonics_and_residual():
    """Records of a fraction of a sample per period, written from known phasors plus a known noise: the batch's
    amplitudes are the written ones to the noise's size, and equal, record by record, what one record at a time
    gives (amplitudes and residual rms)."""
    rng = np.random.default_rng(3)
    f, n, B = 9.37, 213, 7
    Y = rng.normal(size=(B, 4, 2)) + 1j * rng.normal(size=(B, 4, 2))
    Y[:, 0] = Y[:, 0].real                                              # the offset is real
    noise = 1e-6 * rng.normal(size=(B, n, 2))
    records = np.stack([np.column_stack([synthesise(Y[b, :, c], f, n) for c in range(2)]) for b in range(B)]) + noise
    project = HarmonicProjector(f, FS, n, 3)
    amplitudes, rms = project.batch(records)
    assert amplitudes.shape == (B, 4, 2) and rms.shape == (B, 2)
    assert np.allclose(amplitudes, Y, atol=1e-6)
    for b in range(B):
        one = project(records[b])
        assert np.allclose(one.amplitudes, amplitudes[b], rtol=1e-12, atol=1e-15)
        assert np.allclose(one.residual_rms, rms[b], rtol=1e-9)
    assert np.all((rms > 0.5e-6) & (rms < 2e-6))
    with pytest.raises(ValueError):
        project.batch(records[:, :-1])
