"""The measured natural frequency and damping against amplitude as a judge of the missing-effect loop.

Response-controlled levels and phase-resonance runs measure how the natural frequency and the damping ratio of a
mode change with amplitude (:mod:`analysis.prediction.backbone`). The FRF error does not see these curves well: a response
level holds one amplitude, so a linear spring fits its FRF as well as the cubic that bends the backbone, and the
locked points of a phase-resonance run are no sweep. So where a session measures them, the loop
(:mod:`analysis.loop.auto`) asks each candidate law what it does to them:

- **a veto.** A candidate significant by the FRFs that makes either curve worse by ``min_gain`` (the margin a law
  must bring) is not taken: the FRFs would trade the mode's physics for a better fit of the lines;
- **a second witness.** A candidate whose kbar supports it (positive evidence, the ranking's own test) that cuts
  either curve's error by ``min_gain``, makes neither worse by it, and does not make the FRF error worse, is
  significant although its FRF gain is below the margin: the curves measure the amplitude dependence the lines
  do not.

Each curve's error is the RMS relative error of the model's prediction at the measured points
(:class:`analysis.prediction.backbone.ModalError`); below a floor -- what a phase lock or a single-mode fit resolves,
or, where larger, how well the test repeats the mode from level to level (:class:`ModalYardstick`) -- two errors are
the same.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..common.measurements import Measurements
from ..mechanics.model import Model
from ..prediction.backbone import ModalError, measured_backbones, model_modal_error, scatter_between_levels
from .diagnosis import Candidate


@dataclass(frozen=True)
class ModalRules:
    """Floors of the two errors: a difference below them is the measurement's resolution, not the model's."""

    frequency_floor: float = 2e-4    # relative; a lock within 0.5 deg of 90 deg at 1 % damping places the
                                     # frequency within ~1e-4 of the mode's
    damping_floor: float = 0.02      # relative; a single-mode fit or a power balance resolves the damping ratio
                                     # to a few per cent


@dataclass(frozen=True)
class ModalYardstick:
    """What the measured modes are judged against: per curve, the larger of what a fit resolves (``resolution``)
    and how well the test repeats it from one level to the next (``scatter``,
    :func:`analysis.prediction.backbone.scatter_between_levels`). Two models' errors that differ below it differ by
    what the test does not repeat, which no law predicts: on a real structure the mode moves by a fraction of a
    per cent between runs, far beyond what a phase lock or a single-mode fit resolves, and a law judged against
    the resolution alone would be kept or refused by that drift."""

    resolution: ModalRules
    scatter: ModalError

    @classmethod
    def of(cls, model: Model, measurements: Measurements, resolution: ModalRules) -> "ModalYardstick":
        curves = measured_backbones(model.structure, measurements.sine, measurements.phase)
        return cls(resolution, scatter_between_levels(curves))

    @property
    def rules(self) -> ModalRules:
        """The floors the judgement uses."""
        return ModalRules(*(max(floor, scatter) if np.isfinite(scatter) else floor
                            for floor, scatter in self._pairs()))

    def _pairs(self) -> tuple[tuple[float, float], tuple[float, float]]:
        return ((self.resolution.frequency_floor, self.scatter.frequency),
                (self.resolution.damping_floor, self.scatter.damping))

    def _ruled_by(self) -> tuple[str, str]:
        return tuple("scatter_between_levels" if np.isfinite(scatter) and scatter > floor else "resolution"
                     for floor, scatter in self._pairs())

    def words(self) -> str:
        """``the measured modes judged against 0.00054 in frequency (the test's scatter between levels) and 0.02 in
        damping (what a fit resolves)``."""
        ruled = self._ruled_by()
        said = {"scatter_between_levels": "the test's scatter between levels", "resolution": "what a fit resolves"}
        rules = self.rules
        return (f"the measured modes judged against {rules.frequency_floor:.2g} in frequency ({said[ruled[0]]}) and "
                f"{rules.damping_floor:.2g} in damping ({said[ruled[1]]}), relative")

    def to_json(self) -> dict:
        ruled = self._ruled_by()
        rules = self.rules
        return {"frequency_floor": rules.frequency_floor, "frequency_ruled_by": ruled[0],
                "frequency_scatter": _number(self.scatter.frequency),
                "damping_floor": rules.damping_floor, "damping_ruled_by": ruled[1],
                "damping_scatter": _number(self.scatter.damping)}


def _number(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def measures_modes(measurements: Measurements) -> bool:
    """Whether the session measures natural frequency and damping against amplitude: a response level or a
    phase-resonance run."""
    return bool(measurements.phase) or any(r.control.response for r in measurements.sine)


def model_error(model: Model, measurements: Measurements) -> ModalError:
    """The model's natural frequency and damping errors against every measured point."""
    return model_modal_error(model.structure, model.elements, measurements.sine, measurements.phase)


def candidate_error(model: Model, measurements: Measurements, c: Candidate) -> ModalError | None:
    """The errors of the model with candidate ``c`` added (its element's laws as the candidate fitted them);
    None where the candidate has no fit."""
    if c.fit is None:
        return None
    elements = [replace(el, laws=c.fit.law_terms()) if el.name == c.element else el for el in model.elements]
    return model_modal_error(model.structure, elements, measurements.sine, measurements.phase)


@dataclass(frozen=True)
class ModalChange:
    """What a candidate does to the two curves: the gain of each (before / after, both floored; NaN where that
    curve is not measured)."""

    before: ModalError
    after: ModalError
    frequency_gain: float
    damping_gain: float

    @classmethod
    def of(cls, before: ModalError, after: ModalError, rules: ModalRules) -> "ModalChange":
        return cls(before, after, _gain(before.frequency, after.frequency, rules.frequency_floor),
                   _gain(before.damping, after.damping, rules.damping_floor))

    def _gains(self) -> np.ndarray:
        g = np.array([self.frequency_gain, self.damping_gain])
        return g[np.isfinite(g)]

    def worse(self, min_gain: float) -> bool:
        """Either curve worse by ``min_gain``."""
        return bool(np.any(self._gains() * min_gain <= 1.0))

    def better(self, min_gain: float) -> bool:
        """Either curve better by ``min_gain`` and neither worse by it."""
        return bool(np.any(self._gains() >= min_gain)) and not self.worse(min_gain)

    def words(self) -> str:
        """``backbone error 0.0242 -> 9.7e-05, damping error 0.0252 -> 0.00093``: the measured curves only."""
        parts = [f"backbone error {self.before.frequency:.3g} -> {self.after.frequency:.3g}"]
        if np.isfinite(self.before.damping) and np.isfinite(self.after.damping):
            parts.append(f"damping error {self.before.damping:.3g} -> {self.after.damping:.3g}")
        return ", ".join(parts)


def _gain(before: float, after: float, floor: float) -> float:
    if not (np.isfinite(before) and np.isfinite(after)):
        return float("nan")
    return max(before, floor) / max(after, floor)


def judge_by_modes(model: Model, measurements: Measurements, candidates: list[Candidate], min_gain: float,
                   rules: ModalRules = ModalRules()) -> None:
    """Apply the veto and the second witness (module docstring) to ranked candidates, in place: ``significant``
    changes, ``held_back`` says why a candidate was vetoed and ``by_modes`` why one was admitted. Candidates the
    model-form check or the loop already held back are left as they are."""
    before = model_error(model, measurements)
    if not before.measured:
        return
    for c in candidates:
        if c.model_form or c.held_back:
            continue
        if c.significant or (c.supported and c.gain >= 1.0):
            after = candidate_error(model, measurements, c)
            if after is None or not after.measured:
                continue
            change = ModalChange.of(before, after, rules)
            if c.significant and change.worse(min_gain):
                c.significant = False
                c.held_back = (f"it makes the measured natural frequency or damping against amplitude worse by "
                               f"more than x{min_gain:g}: {change.words()}")
            elif not c.significant and change.better(min_gain):
                c.significant = True
                c.by_modes = (f"the measured natural frequency and damping against amplitude call for it "
                              f"({change.words()}) where the FRF gain alone is below the x{min_gain:g} required")
