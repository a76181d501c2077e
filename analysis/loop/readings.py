"""Discovery's other readings of an element's kbar, weighed by the whole model's prediction (docs/workbench.md §5,
step 4): where the loop would stop far above what the test allows, each set discovery chose among takes its
element's place in turn, the model is refitted and judged by its FRFs and by the levels its fits did not see, and
of every element's readings the simplest that predicts better replaces its element's laws.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from ..missing.modal_judge import ModalRules
from ..search.discovery import Discovery, ElementDiscovery
from ..common.parallel import map_tasks
from .cross_check import AsFitted, HeldOut, as_fitted, held_out_of_each, predicts_no_better
from .records import AutoStep
from .workbench import Workbench


@dataclass(frozen=True)
class _Reading:
    """A reading weighed by :func:`other_readings`: its element and laws, how many laws more than the element holds
    it has, the model's in-sample FRF error with it, its held-out error, and why it does not predict better (""
    where it does)."""
    element: str
    laws: tuple[str, ...]
    added: int
    error: float
    held: HeldOut
    why: str
    judged: bool        # the held-out levels judged it (:attr:`HeldOut.judges`, for it and the current model)


def other_readings(wb: Workbench, found: Discovery, min_gain: float, beyond: float, checked: Callable[[], HeldOut],
                    check: Callable[[Workbench, list[AsFitted]], list[HeldOut]] = held_out_of_each,
                    modal: ModalRules | None = ModalRules()) -> Iterator[tuple[AutoStep, HeldOut]]:
    """On data without harmonics, where the model stays farther above what the test allows
    (:attr:`Workbench.error_floor`) than a right model can be (``beyond`` times it, :func:`unfinished`), the
    searched elements' other readings of their kbar (:attr:`ElementDiscovery.readings`, the sets each walk chose
    among) weighed by what decides in the end: the whole model refitted with each, its FRFs, and the levels its
    fits did not see. The walk tries one set of each size, from the set it took before, with the other elements
    standing in by their measured kbar; a reading it passed on the way can describe the joint where the one it
    took does not, and only the model's prediction shows it. A reading qualifies where it cuts the error by
    ``min_gain`` for every law it adds (once for as many laws or fewer) and its model predicts the held-out levels
    better than the current one (:func:`predicts_no_better`, which judges nothing where a fold's fit saw too
    little to determine a law, as for the loop's laws); of those the simplest that no larger one out-predicts by
    the margin takes its element's place (:func:`_simplest_predicting`). A reading is a whole set judged anew: it
    may hold a law taken back from another set.

    Every element's readings are weighed against the same model and compared with one another, and one reading is
    taken at a time: where two elements' sets are wrong, a law at one of them can cut part of the misfit the other
    leaves, and weighed element by element the first element searched would take it before the other's own
    reading was asked. After a reading is taken, the elements not yet replaced are weighed again against the
    model with it, for as long as it stays unfinished.

    Nearer the floor the model may be right, and a reading would gain by taking up what one harmonic cannot
    represent, which two levels held out one by the other cannot refuse (each fold's fit sees one level, and a
    reading then needs to predict only one of them better). The distance is the FRF error's own, the measure a
    reading gains in: the chi-square's (:func:`analysis.loop.discovered.near_the_noise`) weighs every line alike
    and puts a right model with sticking friction tens of times the noise where its error is twice the floor.

    Where the data carry harmonics the kbar follows every line and judges the element's laws itself: an FRF
    misfit it does not show is no law's, and a law that takes it up describes the model's form, not the joint,
    at every level alike, so held-out levels cannot refuse it. Without harmonics the kbar fits leave out the
    lines where a contact closes or a friction sticks, and only the FRFs see a law acting there. ``checked``: the
    current model's held-out error; ``check``: the models' (:func:`analysis.loop.cross_check.held_out_of_each`;
    :data:`analysis.loop.cross_check.NOT_CHECKED` each where the loop checks none). Yields each step with the
    held-out error of the model after it."""
    left = list(found.elements)
    while left and unfinished(wb, beyond):
        error = wb.history[-1].error
        weighed = _weighed(wb, left, error, min_gain, checked, check, modal)
        best = _simplest_predicting(weighed, min_gain)
        if best is None:
            return
        current = wb.law_names(best.element)
        after = wb.replace_laws(best.element, best.laws).error
        yield AutoStep("replace", best.element, best.laws, error, after,
                       _reading_reason(best.element, current, weighed)), best.held
        left = [e for e in left if e.element != best.element]


def _weighed(wb: Workbench, elements: list[ElementDiscovery], error: float, min_gain: float,
             checked: Callable[[], HeldOut], check: Callable[[Workbench, list[AsFitted]], list[HeldOut]],
             modal: ModalRules | None = ModalRules()) -> list[_Reading]:
    """Each of ``elements``' readings other than its current set, with the model refitted with it: those that cut
    ``error`` by ``min_gain`` per law added (once for as many laws or fewer), with their held-out errors. The
    readings are fitted apart (:func:`analysis.common.parallel.map_tasks`: each from the model as it stands, which
    :meth:`Workbench.read_as` restores after each), and the folds of those that gain refitted at once
    (:func:`analysis.loop.cross_check.held_out_of_each`)."""
    asked = []
    for element in elements:
        current = wb.law_names(element.element)
        asked += [(element.element, laws, len(laws) - len(current)) for laws in element.readings
                  if set(laws) != set(current)]

    def fitted(j: int) -> tuple[float, AsFitted | None]:
        name, laws, added = asked[j]
        with wb.read_as(name, laws):
            after = wb.compare().error
            return after, as_fitted(wb) if error >= min_gain ** max(1, added) * after else None

    gaining = [(*reading, after, start) for reading, (after, start) in zip(asked, map_tasks(fitted, len(asked)))
               if start is not None]
    if not gaining:
        return []
    before = checked()                  # the current model's, once a reading gains the margin
    held = check(wb, [start for *_, start in gaining])
    return [_Reading(name, laws, added, after, h, predicts_no_better(before, h, min_gain, modal),
                     before.judges and h.judges)
            for (name, laws, added, after, _), h in zip(gaining, held)]


def unfinished(wb: Workbench, beyond: float) -> bool:
    """Whether, on data without harmonics, the model's FRF error stands more than ``beyond`` times what the test
    allows (:attr:`Workbench.error_floor`): farther than a right model can be, so the model lacks something the
    kbar did not show. With harmonics the kbar follows every line and judges the element's laws itself."""
    return bool(wb.harmonics_blind and wb.error_floor is not None
                and wb.history[-1].error > beyond * wb.error_floor.total)


def _simplest_predicting(weighed: list[_Reading], min_gain: float) -> _Reading | None:
    """Of the readings that predict the held-out levels better than the current model, the one that adds fewest
    laws to its element (then the best error), unless one that adds more predicts better by ``min_gain``: a law
    enters where it predicts data its fit did not see better by a margin, and a law the held-out levels do not call
    for is one the data do not determine. The error is the held-out one where the held-out levels judge both
    readings, else the in-sample one (:func:`_error_judging`). None where no reading qualifies."""
    qualified = sorted((r for r in weighed if not r.why),
                       key=lambda r: (r.added, not r.judged, _error_judging(r, r), r.error))
    best = qualified[0] if qualified else None
    for r in qualified[1:]:
        if r.added > best.added and min_gain * _error_judging(r, best) <= _error_judging(best, r):
            best = r
    return best


def _error_judging(r: _Reading, other: _Reading) -> float:
    """``r``'s error for a comparison with ``other``: held-out where the held-out levels judged both, else
    in-sample. A held-out error that does not judge (a fold's fit saw one level that does not show every law of
    the reading) measures what that fit could not determine, the same for every reading that holds the law, and
    would rank them by chance; the in-sample error is then all the data say."""
    return np.nan_to_num(r.held.error, nan=np.inf) if r.judged and other.judged else r.error


def _reading_reason(element: str, current: tuple[str, ...], weighed: list[_Reading]) -> str:
    was = "+".join(current) if current else "no law"
    each = "; ".join(f"{r.element}:{'+'.join(r.laws)}: in-sample {r.error:.3g}, held-out {r.held.error:.3g}"
                     f"{', predicts no better' if r.why else '' if r.judged else ', not judged by it'}"
                     for r in weighed)
    return (f"another reading of {element}'s kbar among those discovery chose from, in place of {was}: the model "
            "stayed far above what the test allows, and of the readings of the elements searched that cut its "
            "error by the margin a law must bring and are not refused by the held-out levels this one adds fewest "
            "laws, or predicts them better by the margin than those that add fewer (held-out levels judge nothing "
            f"where a fold's fit saw one level that does not show every law; {each})")
