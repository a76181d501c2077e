"""Modal fit on synthetic FRFs with known poles."""
import numpy as np
import pytest

from analysis import load_structure
from analysis.signals.modal_fit import fit_modes


def beam():
    return load_structure({"type": "beam", "length": 0.6, "youngs_modulus": 211e9, "density": 7860.0,
                           "width": 0.04, "thickness": 0.005, "elements": 20, "left": "clamped", "right": "free",
                           "points": {"A": 0.15, "B": 0.3, "C": 0.45, "O": 0.6},
                           "springs": [{"dof": "O.w", "k": 4e5}, {"dof": "O.theta", "k": 152.0}],
                           "damping": {"stiffness_proportional": 2e-5}})


def test_beam_modes_are_recovered_from_noisy_frfs():
    s = beam()
    f = np.arange(5.0, 400.0, 0.25)
    H = s.frf(2 * np.pi * f, columns=["A.w"])[:, [s.index(d) for d in ("A.w", "B.w", "C.w")], 0]
    rng = np.random.default_rng(0)
    noisy = H * (1 + 0.01 * (rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape)))
    fit = fit_modes(f, noisy, n_modes=3)
    true_f = s.natural_frequencies()[:3]
    wn = 2 * np.pi * true_f
    true_zeta = 0.5 * 2e-5 * wn                       # stiffness-proportional: zeta = b w / 2
    np.testing.assert_allclose(fit.frequency, true_f, rtol=2e-4)
    np.testing.assert_allclose(fit.damping, true_zeta, rtol=0.05)
    assert fit.fit_error.max() < 0.03
    # shapes: the residue vector is proportional to the mode shape at the sensors
    _, phi = s.modes()
    for m in range(3):
        ref = phi[[s.index(d) for d in ("A.w", "B.w", "C.w")], m]
        ref = ref / ref[np.argmax(np.abs(ref))]
        assert np.abs(fit.shapes()[m] - ref).max() < 0.02


def test_single_sdof_pole_exact_without_noise():
    f = np.linspace(1, 30, 600)
    w, wr, zeta = 2 * np.pi * f, 2 * np.pi * 12.3, 0.02
    H = (0.7 / (wr**2 - w**2 + 2j * zeta * wr * w))[:, None]
    fit = fit_modes(f, H)
    assert fit.frequency[0] == pytest.approx(12.3, rel=1e-9)
    assert fit.damping[0] == pytest.approx(0.02, rel=1e-7)
    assert fit.residues[0, 0] == pytest.approx(0.7, rel=1e-7)


def test_no_peak_is_an_error():
    f = np.linspace(1, 10, 50)
    with pytest.raises(ValueError, match="no resonance"):
        fit_modes(f, 1.0 / (1000.0 + 0 * f))
