"""What the automatic loop is told and what it returns (docs/workbench.md §5): its rules, each step it takes
and its result, shared by the loop's stages (analysis/loop/auto.py and the checks it runs).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..missing.diagnosis import Candidate, RankingRules
from ..missing.modal_judge import ModalRules, ModalYardstick
from ..prediction.backbone import ModalError
from ..prediction.comparison import gain_phrase
from ..search.discovery import Discovery, DiscoveryRules


@dataclass(frozen=True)
class AutoRules:
    """The thresholds of the loop."""

    max_steps: int = 6               # laws (or pairs) added at most, discovery and linear corrections not counted
    discovery: DiscoveryRules | None = DiscoveryRules()   # laws of the elements without any first (None: not)
    linear_corrections: bool = True  # apply the linear corrections first
    pairs: bool = True               # try pairs of laws on an element whose kbar is not explained
    pair_pool: int = 2               # the element's laws with the largest kbar evidence, each paired with every
                                     # other law of positive evidence
    unexplained_false_alarm: float = 1e-3   # of the test "the kbar is not explained by the element's laws"
    partial_min_gain: float = 5.0    # error cut a law must reach alone when its element's kbar stays unexplained
    modes: ModalRules | None = ModalRules()   # the measured backbone and damping judge candidates too (None: not)
    take_back_near_noise: float = 10.0   # a discovered law is weighed for taking back within this many times the
                                         # noise (:func:`analysis.loop.discovered.near_the_noise`)
    # discovery's other readings are weighed where the model's FRF error is more than this many times what the test
    # allows: nearer, sticking friction on data without harmonics can leave a right model
    # (:func:`analysis.loop.readings.other_readings`)
    readings_beyond_floor: float = 10.0
    ranking: RankingRules = RankingRules()
    # every step's model judged on levels its fit did not see (:func:`analysis.loop.cross_check.held_out`), and a
    # law kept only where its model predicts every held-out fold better than the model without it
    held_out: bool = True


@dataclass
class AutoStep:
    """One step of the loop: what was added, why, and the FRF error before and after."""

    action: str                      # "discover", "linear correction", "add", "add pair", "replace" or "take back"
    element: str | None              # the element (for a linear correction: the elements, comma-separated)
    laws: tuple[str, ...]
    error_before: float
    error_after: float
    reason: str
    # natural frequency and damping against the measured ones (response levels, phase resonance), where measured
    modal_before: ModalError | None = None
    modal_after: ModalError | None = None
    # the FRF error after the step on levels its fit did not see (NaN: not checked, or one level only), and per fold
    held_out: float = float("nan")
    held_out_folds: tuple[float, ...] = ()
    # whether those levels can judge the step's laws (:attr:`analysis.loop.cross_check.HeldOut.judges`; None: not
    # checked): where each fold's fit saw one level that does not show every law, the held-out error measures what
    # that fit could not determine, not the model
    held_out_judges: bool | None = None
    # natural frequency and damping of the held-out response levels, each predicted by the fit that did not see it
    # (None: not checked, or no mode measured)
    held_out_modal: ModalError | None = None

    @property
    def gain(self) -> float:
        return self.error_before / self.error_after if self.error_after > 0 else float("inf")

    def line(self) -> str:
        """One line: what was added and the error before and after."""
        what = f"at {self.element}" if self.action == "linear correction" else f"{self.element}:{'+'.join(self.laws)}"
        modal = ""
        if self.modal_after is not None and self.modal_after.measured:
            modal = (f"; backbone error {self.modal_before.frequency:.3g} -> {self.modal_after.frequency:.3g}, "
                     f"damping error {self.modal_before.damping:.3g} -> {self.modal_after.damping:.3g}")
        held = (f"; held-out {self.held_out:.3g} against in-sample {self.error_after:.3g}"
                f"{NOT_JUDGING if self.held_out_judges is False else ''}" if np.isfinite(self.held_out) else "")
        if held and self.held_out_modal is not None and self.held_out_modal.measured:
            held += (f" (held-out backbone error {self.held_out_modal.frequency:.3g}, damping error "
                     f"{self.held_out_modal.damping:.3g})")
        return (f"{self.action} {what}: error {self.error_before:.3g} -> {self.error_after:.3g} "
                f"({gain_phrase(self.gain)}){held}{modal}")

    def text(self) -> str:
        return f"{self.line()}\n     {self.reason}"

    def to_json(self) -> dict:
        return {"action": self.action, "element": self.element, "laws": list(self.laws),
                "error_before": self.error_before, "error_after": self.error_after, "gain": self.gain,
                "in_sample_error": self.error_after,
                "held_out_error": float(self.held_out) if np.isfinite(self.held_out) else None,
                "held_out_fold_errors": [float(e) if np.isfinite(e) else None for e in self.held_out_folds],
                "held_out_judges": self.held_out_judges,
                "reason": self.reason, **_modal_json(self.modal_before, "_before"),
                **_modal_json(self.modal_after, "_after"), **_modal_json(self.held_out_modal, "_held_out")}


def _modal_json(error: ModalError | None, suffix: str) -> dict:
    """``backbone_error_before``, ``damping_error_held_out`` etc.: null where nothing is measured."""
    values = {"backbone_error": None, "damping_error": None} if error is None else error.to_json()
    return {k + suffix: v for k, v in values.items()}


@dataclass
class AutoResult:
    """The steps taken and why the loop ended; ``candidates`` is the ranking it ended on; ``undone``: the step a
    stop by the user came inside of, undone ("" where the loop ended between steps)."""

    steps: list[AutoStep]
    stopped: str
    candidates: list[Candidate] = field(default_factory=list)
    discovery: Discovery | None = None
    undone: str = ""
    modal_yardstick: ModalYardstick | None = None   # what the measured modes were judged against, where measured

    def text(self) -> str:
        lines = [self.discovery.text()] if self.discovery is not None and self.discovery.elements else []
        lines += ["automatic loop:"]
        if self.modal_yardstick is not None:
            lines.append(f"  {self.modal_yardstick.words()}")
        lines += [f"  {i + 1}. {s.text()}" for i, s in enumerate(self.steps)]
        inside = f" during {self.undone}, which was undone" if self.undone else ""
        return "\n".join(lines + [f"  stopped: {self.stopped}{inside}"])

    def to_json(self) -> dict:
        return {"steps": [s.to_json() for s in self.steps], "stopped": self.stopped, "undone": self.undone,
                "discovery": None if self.discovery is None else self.discovery.to_json(),
                "modal_yardstick": None if self.modal_yardstick is None else self.modal_yardstick.to_json()}


#: What a step's line adds where its held-out levels cannot judge its laws (:attr:`AutoStep.held_out_judges`)
NOT_JUDGING = " (which cannot judge it: each fold's fit saw one level that does not show every law)"

STOPPED_BY_USER = "stopped by the user"
DISCOVERY = "discovery"             # AutoResult.undone of a stop inside discovery
