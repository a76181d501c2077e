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
(:class:`analysis.prediction.backbone.ModalError`); below a floor -- what a phase lock or a single-mode fit resolves -- two
errors are the same.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..common.measurements import Measurements
from ..mechanics.model import Model
from ..prediction.backbone import ModalError, model_modal_error
from .diagnosis import Candidate


@dataclass(frozen=True)
class ModalRules:
    """Floors of the two errors: a difference below them is the measurement's resolution, not the model's."""

    frequency_floor: float = 2e-4    # relative; a lock within 0.5 deg of 90 deg at 1 % damping places the
                                     # frequency within ~1e-4 of the mode's
    damping_floor: float = 0.02      # relative; a single-mode fit or a power balance resolves the damping ratio
                                     # to a few per cent


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
