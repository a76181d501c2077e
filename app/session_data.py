"""A session's measurements as the analysis sees them (analysis never opens files itself)."""
from __future__ import annotations

import numpy as np

from analysis.frf_noise import smoothness_noise
from analysis.measurements import Measurements, RandomRun, SineRun

from .session import Session

NOISE_FLOOR = 1e-9     # relative to the largest FRF value of the run


def measurements_from_session(session: Session, include_incomplete: bool = True) -> Measurements:
    """Collect the stepped-sine and random runs of a session.

    Aborted or incomplete stepped-sine runs are used up to their last complete line (each line was measured
    whole); ``include_incomplete=False`` leaves them out. Nothing of ``/provenance`` is read.
    """
    sine, random = [], None
    for run in session.runs():
        if not len(run.frequency) or (run.incomplete and not include_incomplete):
            continue
        dofs = run.sensor_dofs
        H = np.stack([run.frf[d] for d in dofs], axis=1)
        if run.kind == "random":
            random = RandomRun(run.excitation_dof, dofs, run.frequency, H,
                               _stack(run.arrays, "coherence", dofs), _stack(run.arrays, "random_error", dofs),
                               run.force)
            continue
        thd = [displacement_distortion(run.arrays[f"harmonics/acc:{d}"]) for d in dofs
               if f"harmonics/acc:{d}" in run.arrays]
        std = _stack(run.arrays, "frf_std", dofs)
        if std is not None:
            # a noise-free (simulated) record has zero residual: floor at the round-off of the data
            std = np.maximum(std, NOISE_FLOOR * np.abs(H).max())
        distortion = np.max(np.stack(thd), axis=0) if thd else run.arrays.get("distortion")   # imported: as stored
        sine.append(SineRun(run.name, run.force, run.direction, run.excitation_dof, dofs, run.frequency, H,
                            std if std is not None else smoothness_noise(run.frequency, H),
                            run.arrays.get("force_amplitude"), distortion, noise_estimated=std is None))
    return Measurements(sine, random)


def _stack(arrays: dict, prefix: str, dofs: list[str]):
    keys = [f"{prefix}/{d}" for d in dofs]
    if not all(k in arrays for k in keys):
        return None
    return np.stack([arrays[k] for k in keys], axis=1)


def displacement_distortion(acceleration_harmonics: np.ndarray) -> np.ndarray:
    """THD of the displacement from the harmonics 0..K of an acceleration, shape (L, K + 1) -> (L,).

    Harmonic k of the displacement is that of the acceleration divided by (k w)^2, so the acceleration's THD
    overstates how far the motion is from harmonic -- which is what decides whether a describing function
    applies -- by up to k^2."""
    Y = np.asarray(acceleration_harmonics)
    k = np.arange(Y.shape[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.sqrt(np.sum(np.abs(Y[:, 2:] / k[2:] ** 2) ** 2, axis=1)) / np.abs(Y[:, 1])
    return np.where(np.abs(Y[:, 1]) > 0, ratio, 0.0)
