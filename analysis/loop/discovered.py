"""The laws discovery found, checked by the whole model once they are fitted (docs/workbench.md §5, steps 1 and 2):
a law the model refitted without it predicts the FRFs as well is taken back (near the noise, on data without
harmonics), and a law whose model predicts the levels its fits did not see no better than the model without it.
"""
from __future__ import annotations

from typing import Callable, Iterator

from ..missing.diagnosis import RankingRules
from ..missing.modal_judge import ModalRules
from ..prediction.comparison import Comparison
from ..search.discovery import ElementDiscovery
from .cross_check import HeldOut, as_fitted, held_out_of_each, predicts_no_better
from .records import AutoStep
from .workbench import Workbench


def predicting_no_better(wb: Workbench, found: list[ElementDiscovery], checked: Callable[[], HeldOut],
                         min_gain: float = RankingRules().min_gain, modal: ModalRules | None = ModalRules()
                         ) -> Iterator[tuple[AutoStep, HeldOut]]:
    """Each law discovery found kept only where the model with it predicts every held-out fold better than the
    model refitted without it: the rule every law the loop adds meets (:func:`predicts_no_better`). Discovery
    chooses a set by its kbar and by the FRFs of the lines the set was fitted to; a law that only bends the fit to
    those lines -- a stiffness law standing in for the structure's misfit at another element, one law writing
    another's curvature again -- predicts the levels its fit did not see no better, or worse. Of an element's
    laws that fail, the one whose absence predicts best is taken back first and the rest weighed again
    (``checked``: the current model's held-out error). Yields each take-back with the held-out error of the
    model after it."""
    for element in found:
        while laws := wb.law_names(element.element):
            current = checked()
            if not current.judges:
                return
            failing = []
            starts = []
            for law in laws:
                with wb.without(element.element, law):
                    starts.append(as_fitted(wb))
            alones = held_out_of_each(wb, starts)      # every law's folds at once
            for law, alone in zip(laws, alones):
                why = predicts_no_better(alone, current, min_gain, modal)
                if why:
                    failing.append((alone.error, law, alone, why))
            if not failing:
                break
            _, law, alone, why = min(failing, key=lambda f: f[0])
            error = wb.history[-1].error
            after = wb.take_back(element.element, law).error
            yield AutoStep("take back", element.element, (law,), error, after, why), alone


def near_the_noise(comp: Comparison, near: float) -> bool:
    """Whether the model predicts the FRFs within ``near`` times the noise (:attr:`Comparison.times_the_noise`):
    only then does a law's share of the error say what it brings. Where another law is missing the model's error
    is mostly that law's misfit, and refitting an element without a right law can even lower it, its other
    parameters taking up part of that misfit. Friction that sticks leaves a right model several times the
    noise."""
    ratio = comp.times_the_noise
    return ratio is not None and ratio <= near


def unneeded(wb: Workbench, found: list[ElementDiscovery], min_gain: float,
                near: float) -> Iterator[AutoStep]:
    """On data without harmonics, each discovered law that the whole model, refitted without it, does not miss by
    ``min_gain``, taken back (one step each; of several, the one whose absence costs least first), where the model
    is near the noise (:func:`near_the_noise`). Discovery judges a set at its kbar fit, the others by their
    stand-ins, and steps from the set taken before; the model's own fit takes out the bias its harmonics put in
    the kbar (:meth:`Workbench.fit`), so the model is the fairer judge of what a law brings. The walk can end on
    a set larger than the data need while the smaller set within it never competed, and the model refitted
    without the extra law then predicts the FRFs as well. The loop adds a law only for ``min_gain``; a law that
    brings less is not kept either."""
    if not wb.harmonics_blind:
        return
    for element in found:
        if not near_the_noise(wb.compare(), near):
            return
        while len(laws := wb.law_names(element.element)) >= 2:
            error = wb.history[-1].error
            law, without = min(((law, wb.error_without(element.element, law)) for law in laws),
                               key=lambda pair: pair[1])
            if not without <= min_gain * error:
                break
            after = wb.take_back(element.element, law).error
            yield AutoStep("take back", element.element, (law,), error, after,
                           f"the model refitted without it predicts the FRFs within x{min_gain:g} of the model with "
                           f"it ({without:.3g} against {error:.3g}): discovery's set held more than the data need")
