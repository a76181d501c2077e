"""Model against measurement: predicted stepped-sine FRFs and the error metric (docs/workbench.md).

The error of a model is the relative FRF error over every measured stepped-sine line and sensor:

    error = sqrt( sum |h_pred - h_meas|^2 / sum |h_meas|^2 )

summed over runs r, lines l and sensors p (0 = perfect). ``error_by_level`` restricts both sums to the runs at
one force level (both sweep directions), and the residual map gives the same ratio per run and line (sum over
sensors only), so where the model fails is visible, not only how much. When the measured receptances carry a
standard deviation, the chi-square ``sum |h_pred - h_meas|^2 / std^2`` is returned too; it decides whether an
improvement is larger than the noise explains.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .harmonic_balance import CondensedSystem, KbarFunction, condense, predict_sweep
from .measurements import Measurements, SineRun
from .model import Model


@dataclass
class Comparison:
    """How well a model predicts the measured stepped-sine FRFs.

    Attributes
    ----------
    error : float
        Relative FRF error over all runs (module docstring).
    error_by_level : list of (force N, error)
    residual_map : dict run name -> ndarray (L,)
        Relative error per line.
    predicted : dict run name -> ndarray (L, P) complex
        Predicted receptance at the sensors, m/N.
    converged : dict run name -> ndarray (L,) bool
        Whether the harmonic balance converged at each line.
    chi_square : float or None
        ``sum |residual|^2 / std^2`` when the measurement has standard deviations.
    n_observations : int
        Real numbers compared (2 per complex FRF value).
    """

    error: float
    error_by_level: list[tuple[float, float]]
    residual_map: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]
    converged: dict[str, np.ndarray]
    chi_square: float | None
    n_observations: int

    def to_json(self) -> dict:
        return {"error": self.error,
                "error_by_level": [{"force": f, "error": e} for f, e in self.error_by_level]}


class Predictor:
    """Predicts every stepped-sine run of a measurement set for a structure with elements at fixed places.

    The condensation (the expensive part for a beam) depends only on the structure and where the elements sit,
    so it is done once and reused for every set of laws tried -- the candidate ranking tries many.
    Runs sharing lines, excitation and direction are predicted together (force levels batched).
    """

    def __init__(self, model: Model, measurements: Measurements):
        self.model = model
        self.runs = list(measurements.sine)
        self._groups: dict[tuple, list[SineRun]] = {}
        for run in self.runs:
            key = (run.excitation_dof, run.direction, tuple(np.round(run.frequency_hz, 9)))
            self._groups.setdefault(key, []).append(run)
        self._systems: dict[tuple, CondensedSystem] = {}
        self._rows = {run.name: [model.structure.index(d) for d in run.sensor_dofs] for run in self.runs}

    def _system(self, key) -> CondensedSystem:
        if key not in self._systems:
            exc, _, freqs = key
            self._systems[key] = condense(self.model.structure, self.model.elements, exc, 2 * np.pi * np.array(freqs))
        return self._systems[key]

    def predict(self, kbar_fns: Sequence[KbarFunction] | None = None) -> tuple[dict, dict]:
        """Predicted sensor receptances and convergence flags per run, for the given element describing
        functions (default: the model elements' laws)."""
        fns = list(kbar_fns) if kbar_fns is not None else [e.describing_function for e in self.model.elements]
        predicted, converged = {}, {}
        for key, runs in self._groups.items():
            exc, direction, freqs = key
            system = self._system(key)
            forces = [r.force for r in runs]
            pred = predict_sweep(self.model.structure, self.model.elements, exc, system.w, forces,
                                 direction, kbar_fns=fns, system=system)
            for b, run in enumerate(runs):
                predicted[run.name] = pred.receptance[:, b, self._rows[run.name]]
                converged[run.name] = pred.converged[:, b]
        return predicted, converged

    def compare(self, kbar_fns: Sequence[KbarFunction] | None = None) -> Comparison:
        predicted, converged = self.predict(kbar_fns)
        return compare_predictions(self.runs, predicted, converged)


def compare_predictions(runs: Sequence[SineRun], predicted: dict, converged: dict) -> Comparison:
    """The error metric, per level and per line, from predicted receptances."""
    num = den = 0.0
    chi2 = 0.0
    have_std = all(r.receptance_std is not None for r in runs)
    by_level: dict[float, list[float]] = {}
    residual_map = {}
    n_obs = 0
    for run in runs:
        diff = predicted[run.name] - run.receptance
        line_num = np.sum(np.abs(diff) ** 2, axis=1)
        line_den = np.sum(np.abs(run.receptance) ** 2, axis=1)
        residual_map[run.name] = np.sqrt(line_num / line_den)
        rn, rd = float(line_num.sum()), float(line_den.sum())
        num, den = num + rn, den + rd
        acc = by_level.setdefault(round(run.force, 12), [0.0, 0.0])
        acc[0] += rn
        acc[1] += rd
        n_obs += 2 * diff.size
        if have_std:
            chi2 += float(np.sum(np.abs(diff) ** 2 / np.asarray(run.receptance_std) ** 2))
    return Comparison(float(np.sqrt(num / den)) if den else float("nan"),
                      [(f, float(np.sqrt(a / b))) for f, (a, b) in sorted(by_level.items())],
                      residual_map, predicted, converged, chi2 if have_std else None, n_obs)


def gain_phrase(gain: float) -> str:
    """An error ratio ``before / after`` as a test engineer reads it: "x3.20 better" or, below 1, "x1.02 worse"
    (the factor by which the error grew)."""
    if gain >= 1.0 or gain <= 0.0 or not np.isfinite(gain):
        return f"x{gain:.2f} better"
    return f"x{1.0 / gain:.2f} worse"


def kbar_functions_with(elements, replace: dict[int, Callable]) -> list[KbarFunction]:
    """The elements' describing functions with some replaced (index -> function)."""
    return [replace.get(i, el.describing_function) for i, el in enumerate(elements)]
