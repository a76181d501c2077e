"""A session's measurements as the analysis sees them (analysis never opens files itself)."""
from __future__ import annotations

import numpy as np

from analysis.common.errors import InputError
from analysis.signals.frf_noise import smoothness_noise
from analysis.common.measurements import Control, Measurements, PhaseRun, RandomRun, SineRun, UnresolvedLines

from app.session.writer import RunData, Session
from app.session.checks import check_format, check_run, check_run_count

NOISE_FLOOR = 1e-9     # relative to the largest FRF value of the run


def measurements_from_session(session: Session, include_incomplete: bool = True) -> Measurements:
    """Collect the stepped-sine and random runs of a session, after checking what they hold
    (:mod:`app.session.checks`: InputError naming file, run and dataset for impossible contents).

    Aborted or incomplete stepped-sine runs are used up to their last whole line (each line was measured
    whole) and listed in ``Measurements.unfinished``; ``include_incomplete=False`` leaves them out. Nothing of
    ``/provenance`` is read. ``session`` may also be anything with ``runs()`` (the GUI's live lines).
    """
    source = None
    if isinstance(session, Session):
        source = str(session.path)
        check_format(session.attrs, source)
        check_run_count(session.run_names(), source)
    sine, random, unfinished, phase, unresolved = [], None, [], [], []
    random_name = ""                  # the random run taken, to name beside a second one
    for checked in (check_run(run, source) for run in session.runs()):
        if not checked.lines or (checked.run.incomplete and not include_incomplete):
            continue
        if checked.unfinished:
            unfinished.append(checked.note())
        run, dofs, n = checked.run, checked.sensor_dofs, checked.lines
        keep = np.ones(n, bool) if checked.unresolved is None else ~checked.unresolved
        if not keep.all():
            unresolved.append(UnresolvedLines(run.name, int((~keep).sum()), n))
            if not keep.any():
                continue
        arrays = {k: v[:n][keep] for k, v in run.arrays.items()}
        frequency = run.frequency[:n][keep]
        H = np.stack([run.frf[d][:n][keep] for d in dofs], axis=1)
        if run.kind == "phase_resonance":
            phase.append(_phase_run(run, arrays, _sine_run(run, dofs, frequency, H, arrays, checked.control)))
            continue
        if run.kind == "random":
            if random is not None:      # the reference is one run: taking one of two would be a silent choice
                raise InputError(f"runs {random_name} and {run.name} are both random runs: the analysis takes one "
                                 "random run as the low-level reference; keep one in the session", source,
                                 f"/runs/{run.name}")
            random_name = run.name
            random = RandomRun(run.excitation_dof, dofs, frequency, H,
                               _stack(arrays, "coherence", dofs), _stack(arrays, "random_error", dofs),
                               run.force, _welch_resolution(run.attrs))
            continue
        sine.append(_sine_run(run, dofs, frequency, H, arrays, checked.control))
    return Measurements(sine, random, unfinished, phase, unresolved)


def _sine_run(run: RunData, dofs: list[str], frequency: np.ndarray, H: np.ndarray, arrays: dict,
              control: Control) -> SineRun:
    thd = [displacement_distortion(arrays[f"harmonics/acc:{d}"]) for d in dofs if f"harmonics/acc:{d}" in arrays]
    std = _stack(arrays, "frf_std", dofs)
    if std is not None:
        # a noise-free (simulated) record has zero residual: floor at the round-off of the data
        std = np.maximum(std, NOISE_FLOOR * np.abs(H).max())
    distortion = np.max(np.stack(thd), axis=0) if thd else arrays.get("distortion")   # imported: as stored
    return SineRun(run.name, run.force, run.direction, run.excitation_dof, dofs, frequency, H,
                   std if std is not None else smoothness_noise(frequency, H),
                   arrays.get("force_amplitude"), distortion, noise_estimated=std is None,
                   control=control)


def _phase_run(run: RunData, arrays: dict, lines: SineRun) -> PhaseRun:
    """A phase-resonance run's locked points (``lines``, as lines for the identification too), the displacement
    at the locked DOF from its acceleration's fundamental, the lag from its receptance there."""
    dof, frequency = str(run.attrs["phase_dof"]), lines.frequency_hz
    displacement = np.abs(arrays[f"harmonics/acc:{dof}"][:, 1]) / (2 * np.pi * frequency) ** 2
    lag = None if dof not in lines.sensor_dofs else \
        np.degrees(-np.angle(lines.receptance[:, lines.sensor_dofs.index(dof)])) % 360.0
    return PhaseRun(run.name, dof, float(run.attrs["target_phase"]), frequency, arrays["force_amplitude"],
                    displacement, arrays["lock_converged"].astype(bool), run.excitation_dof, lag, lines)


def _welch_resolution(attrs: dict) -> float | None:
    """The random run's Welch resolution (Hz) from its segment length and sample rate, where it has them."""
    if "segment_length" in attrs and "sample_rate" in attrs and attrs["segment_length"] > 0:
        return float(attrs["sample_rate"]) / float(attrs["segment_length"])
    return None


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
