"""The missing-effect loop run automatically (docs/workbench.md §5): the product's own advice followed step by step.

From a started workbench: model discovery first -- every element without laws gets the set of laws its kbar
and the FRFs choose (:mod:`analysis.search.discovery`), one history step per element --, then the linear corrections (elements whose verdict is linear with a constant kbar
offset: a wrong reference, applied together), then rank, add the top significant candidate, refit, rank again,
until nothing significant is left. Where no single law is significant but an element's kbar is clearly not
explained by its laws, pairs of laws on that element are tried before giving up (two effects of one joint can
each look insignificant alone); and where the model then stays above what the test allows, the other readings of
each element's kbar that discovery chose among are weighed by the whole model's prediction of the FRFs and of
the levels its fits did not see (:func:`analysis.loop.readings.other_readings`), and then the best law the FRFs
call for by far where the kbar does not (:func:`_beyond_the_kbar`). Significance is that of the ranking
(:mod:`analysis.missing.diagnosis`), including the check against what the single-harmonic model cannot represent,
so the loop stops on the physics the data show.

This module holds the order of the steps and the ranking's holds; each stage that judges a model by the whole
model's fit or by the levels its fits did not see lives beside it, the loop importing them one way: the checks of
discovery's laws (:mod:`analysis.loop.discovered`), the held-out checks and their rule
(:mod:`analysis.loop.cross_check`), the other readings (:mod:`analysis.loop.readings`), and the records every
stage shares (:mod:`analysis.loop.records`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Iterator

import numpy as np

from ..common.interrupt import Interrupted, stoppable
from ..laws import LAWS
from ..missing.diagnosis import Candidate, check_model_form
from ..missing.modal_judge import ModalYardstick, judge_by_modes, measures_modes, model_error
from ..missing.unexplained import unexplained
from ..prediction.backbone import ModalError
from ..prediction.comparison import gain_phrase
from ..search.discovery import Discovery, ElementDiscovery, WalkStep
from .cross_check import NOT_CHECKED, HeldOut, held_out, held_out_of_each, predicts_no_better
from .discovered import predicting_no_better, unneeded
from .readings import other_readings, unfinished
from .records import DISCOVERY, STOPPED_BY_USER, AutoResult, AutoRules, AutoStep
from .workbench import ElementReport, Workbench


def kbar_unexplained(report: ElementReport, false_alarm: float = 1e-3) -> bool:
    """Whether an element's kbar is clearly not explained by its fitted laws (against zero without laws): the
    detector of effects outside the library (:func:`analysis.missing.unexplained.unexplained`, robust to a few outlier
    lines and blind to departures too small to matter) finds it."""
    return report.samples is not None and unexplained(report.samples, report.fit, false_alarm) is not None


def _hold_back_partial(wb: Workbench, candidates: list[Candidate], rules: AutoRules) -> None:
    """Take significance away from a candidate after which its element's kbar is still clearly not explained
    (:func:`analysis.missing.unexplained.unexplained` on the element's laws with it) and that cuts the error less than
    ``rules.partial_min_gain``: a law of the wrong kind can fit most of a kbar it does not describe (a constant
    spring beside a stiffness growing with frequency) and still gain x1.5 in the FRFs, and a law that is only
    part of the answer gains little alone. Then pairs are tried, and if none fits either the loop stops and says
    the element is unexplained, rather than add the least bad law. ``held_back`` says why."""
    for c in candidates:
        if not c.significant or c.gain >= rules.partial_min_gain or c.fit is None:
            continue
        samples = wb.reports[c.element].samples
        finding = unexplained(samples, c.fit, rules.unexplained_false_alarm) if samples is not None else None
        if finding is not None:
            c.significant = False
            c.held_back = (f"with it '{c.element}' is still not explained ({finding.noise_ratio:.1f}x the noise: "
                           f"{finding.trends.words()}) and it cuts the error less than the x"
                           f"{rules.partial_min_gain:g} a law must reach alone then -- an effect outside the "
                           f"library? (--add {c.element}:nonparametric)")


def _pairs(ranked: list[Candidate], element: str, pool: int) -> list[tuple[str, str]]:
    """The ``pool`` laws of the element with the largest positive kbar evidence, each paired with every other
    law of positive evidence: of two effects of one joint the one in the larger part of kbar (Im, say) has the
    larger evidence, and the other (in Re) may have far less -- its evidence is measured against a kbar still
    dominated by the first."""
    mine = sorted((c for c in ranked if c.element == element and len(c.laws) == 1 and c.evidence > 0),
                  key=lambda c: -c.evidence)
    pairs = dict.fromkeys(tuple(sorted((a.law, b.law))) for a in mine[:pool] for b in mine if b.law != a.law)
    return list(pairs)


def _best_pair(wb: Workbench, ranked: list[Candidate], rules: AutoRules,
               searched: frozenset[str] = frozenset(), taken_back: set[str] = frozenset()) -> Candidate | None:
    """The best significant pair of laws on an element whose kbar is not explained, or None. Elements in
    ``searched`` are left out: discovery already judged every set of up to three laws there; pairs in
    ``taken_back`` are not offered again."""
    best = None
    for el in wb.model.elements:
        report = wb.reports.get(el.name)
        if el.name in searched or report is None or not kbar_unexplained(report, rules.unexplained_false_alarm):
            continue
        pairs = _pairs(ranked, el.name, rules.pair_pool)
        scored = _judged(wb, wb.pair_candidates(el.name, pairs, rules.ranking) if pairs else [], rules,
                         taken_back=taken_back)
        found = [c for c in scored if c.significant]
        if found and (best is None or found[0].bic < best.bic):
            best = found[0]
    return best


def _reason(c: Candidate) -> str:
    mh = "" if c.multiharmonic_gain is None else f", {gain_phrase(c.multiharmonic_gain)} with harmonics"
    modes = f"; {c.by_modes}" if c.by_modes else ""
    return (f"top significant candidate ({gain_phrase(c.gain)} single-harmonic{mh}, kbar evidence "
            f"{c.evidence:.3g}{modes}): {c.explanation}")


#: How the reason of a law added beyond the kbar (:func:`_beyond_the_kbar`) begins
BEYOND_THE_KBAR = "nothing its kbar calls for is significant"


def _beyond_reason(c: Candidate, error: float, floor: float, rules: AutoRules) -> str:
    return (f"{BEYOND_THE_KBAR}, and the model stayed at {error:.3g}, "
            f"{error / floor:.3g} x what the test allows ({floor:.3g}); {c.name} cuts the FRF error "
            f"{gain_phrase(c.gain)}, beyond the x{rules.ranking.certain_gain:g} no law fitting lines its describing "
            f"function does not follow brings: the kbar cannot judge it there, and the FRFs and the levels its fits "
            f"did not see do: {c.explanation}")


def _stop_reason(ranked: list[Candidate], pairs_tried: bool, min_gain: float) -> str:
    if not ranked:
        return "no candidate could be scored (no element has enough well-conditioned lines)"
    top = ranked[0]
    why = top.model_form or top.held_back or (
        "its kbar evidence is not positive, or its element's laws already explain the kbar to within the noise"
        if not top.supported else "its FRF improvement is within the noise" if not top.above_noise else
        f"it cuts the error less than the x{min_gain:g} required")
    pairs = "; no pair of laws on an unexplained element is significant either" if pairs_tried else ""
    return (f"nothing significant is left: the best candidate, {top.name}, gives {top.error:.3g} "
            f"({gain_phrase(top.gain)}), not significant because {why}{pairs}")


def _discovery_reason(found: ElementDiscovery, still_empty: list[str]) -> str:
    """Why discovery's step was taken; where elements are still empty, the step's own error says little (the
    FRF gains judged it with them represented by their measured kbar)."""
    taken = [s for s in found.walk if s.taken]
    judged = "; ".join(s.text() for s in taken)
    reason = (f"the set of laws its kbar chooses ({found.sets_fitted} sets fitted), judged by the FRFs with the "
              f"other elements as measured: {judged}" if judged else
              f"the set of laws its kbar chooses ({found.sets_fitted} sets fitted)")
    if still_empty:
        reason += (f"; the error recorded here still has {', '.join(still_empty)} without laws, which dominates it "
                   "until added")
    return reason


def _modal_error(wb: Workbench) -> ModalError | None:
    """The model's natural frequency and damping error, None where the session measures neither (no response
    level, no phase-resonance run)."""
    return model_error(wb.model, wb.measurements) if measures_modes(wb.measurements) else None


def _refused_in_discovery(found: Discovery, laws: tuple[str, ...], c: Candidate) -> WalkStep | None:
    """The step of discovery's walk that refused candidate ``c`` beside its element's ``laws`` for what the
    element's kbar shows (:attr:`WalkStep.by_kbar`), or None. The kbar is the element's own, decoupled from the
    others, so the laws found since do not change that verdict; the loop's ranking asks less of a law beside
    friction or a clearance than the walk does, and adding what the walk refused undoes discovery's reading.
    A gap beside linear + Coulomb friction that the walk refused (the kbar shows it no more than the force that
    turns the friction's fundamental; only in its limit below every amplitude) would otherwise be added by the
    loop for what it fits in the FRFs: sticking friction's model-form error, which no law explains."""
    wanted = set(laws) | set(c.laws)
    return next((step for e in found.elements if e.element == c.element for step in e.walk
                 if step.by_kbar and set(step.laws) == wanted), None)


def _against_discovery(wb: Workbench, found: Discovery | None, c: Candidate) -> str:
    """Why discovery's reading of the candidate's element rules it out, "" where it does not (or discovery did
    not search that element). Discovery's sets hold one law of each kind (:func:`analysis.search.discovery.law_sets`):
    a second law of a kind the element holds is the first written twice, and beside friction it fits the
    sticking lines, whose misfit is the friction's model-form error, not a second effect. On data without
    harmonics, a set the walk refused for what the kbar shows is not added either (:func:`_refused_in_discovery`);
    with harmonics the ranking's kbar criterion is the walk's own."""
    if found is None or not any(e.element == c.element for e in found.elements):
        return ""
    laws = wb.law_names(c.element)
    held = {LAWS[n].kind for n in laws}
    twice = next((n for n in c.laws if LAWS[n].kind in held), None)
    if twice is not None:
        return (f"'{c.element}' holds a law of kind {LAWS[twice].kind} already, and discovery's sets hold one law "
                "of each kind: two of a kind at one joint are one effect written twice")
    step = _refused_in_discovery(found, laws, c) if wb.harmonics_blind else None
    if step is not None:
        return f"model discovery refused {'+'.join(step.laws)} at '{c.element}': {step.why}"
    return ""


def _hold_back_against_discovery(wb: Workbench, candidates: list[Candidate], found: Discovery | None) -> None:
    """Take significance away from a candidate discovery's reading of its element rules out
    (:func:`_against_discovery`)."""
    for c in candidates:
        why = _against_discovery(wb, found, c) if c.significant else ""
        if why:
            c.significant = False
            c.held_back = why


def _falls_short(c: Candidate, before: float, after: float, min_gain: float) -> bool:
    """Whether a candidate added gained less than ``min_gain`` with the model refitted (where its significance
    rested on its gain, not on the measured modes' word). The ranking judges a candidate at its kbar fit; on data
    without harmonics the model's own fit takes out the bias the harmonics put in the kbar, and what the
    candidate fitted of that bias is gone: a gain at its kbar fit can vanish once the model is refitted."""
    return not c.by_modes and before < min_gain * after


def _hold_back_taken_back(candidates: list[Candidate], taken_back: set[str]) -> None:
    """A take-back is final: the candidate is held back whatever would call for it again, significant or not
    (the measured modes' second witness would otherwise admit it once more, as it did the first time)."""
    for c in candidates:
        if c.name in taken_back:
            c.significant = False
            c.held_back = "added before and taken back (that step says why)"


def _judged(wb: Workbench, candidates: list[Candidate], rules: AutoRules,
            found: Discovery | None = None, taken_back: set[str] = frozenset()) -> list[Candidate]:
    """The loop's own holds on ranked candidates: a law discovery's reading of its element rules out, one
    added and taken back, a partial law held back, then the measured backbone and damping's veto and second
    witness (:mod:`analysis.missing.modal_judge`, which passes over what is held back) where the session measures
    them."""
    _hold_back_against_discovery(wb, candidates, found)
    _hold_back_taken_back(candidates, taken_back)
    _hold_back_partial(wb, candidates, rules)
    if rules.modes is not None and measures_modes(wb.measurements):
        judge_by_modes(wb.model, wb.measurements, candidates, rules.ranking.min_gain, rules.modes)
    return candidates


def _beyond_the_kbar(wb: Workbench, ranked: list[Candidate], rules: AutoRules, found: Discovery | None,
                     taken_back: set[str]) -> Candidate | None:
    """Where the loop would stop on data without harmonics with the model farther above what the test allows
    than a right model can be (``rules.readings_beyond_floor`` times :attr:`Workbench.error_floor`), the best
    candidate its element's kbar does not call for that cuts the FRF error by ``certain_gain``, the model-form
    check and the loop's own holds passed; None where there is none. The kbar's verdicts -- linear, the law's size
    within its interval of zero, no positive evidence -- are tests of one element's kbar at the false-alarm rate,
    and an element whose stiffness is small beside the structure's carries little of the FRFs' information: a
    law there can leave its kbar unmoved and still cut the FRF error many times (discovery sets a linear verdict
    aside at the same margin, :func:`analysis.search.walk._verdict_overruled`). The kbar cannot then judge the law;
    the FRFs judge it as every law the loop adds: the model refitted with it must keep ``min_gain``
    (:func:`_falls_short`) and predict the levels its fits did not see better where they judge it
    (:func:`analysis.loop.cross_check.predicts_no_better`)."""
    if not (rules.held_out and unfinished(wb, rules.readings_beyond_floor)):
        return None
    unsupported = [c for c in ranked if not c.significant and not c.model_form and c.above_noise
                   and c.gain >= rules.ranking.certain_gain]
    if not unsupported:
        return None
    for c in unsupported:
        c.significant, c.held_back = True, ""
    check_model_form(wb.predictor, unsupported, rules.ranking, wb.harmonics_or_default)
    return next((c for c in _judged(wb, unsupported, rules, found, taken_back) if c.significant), None)


def _checked_found(wb: Workbench, elements: list[ElementDiscovery], rules: AutoRules,
                   checked: Callable[[], HeldOut]) -> Iterator[tuple[AutoStep, HeldOut | None, bool]]:
    """The checks every set of laws discovery found meets once the whole model is fitted with it
    (:mod:`analysis.loop.discovered`): a law the model refitted without it does not miss, then a law whose model
    predicts the held-out levels no better, taken back. Yields each take-back step, the held-out error of the
    model after it where checked, and whether the held-out levels refused the law (it is then not offered again)."""
    for step in unneeded(wb, elements, rules.ranking.min_gain, rules.take_back_near_noise):
        yield step, None, False
    if rules.held_out:
        for step, alone in predicting_no_better(wb, elements, checked, rules.ranking.min_gain, rules.modes):
            yield step, alone, True


def _read_again(wb: Workbench, found: Discovery, rules: AutoRules,
                checked: Callable[[], HeldOut]) -> Iterator[tuple[AutoStep, HeldOut | None, bool]]:
    """Discovery's other readings weighed by prediction (:func:`analysis.loop.readings.other_readings`), and each
    element whose laws a reading replaced checked as discovery's own set was (:func:`_checked_found`): a reading
    is a set discovery fitted, and it may hold a law the data do not need beside the ones they do. Yields as
    :func:`_checked_found` does, the replacements first."""
    check = held_out_of_each if rules.held_out else (lambda _, starts: [NOT_CHECKED] * len(starts))
    replaced = []
    for step, held in other_readings(wb, found, rules.ranking.min_gain, rules.readings_beyond_floor, checked, check,
                                     rules.modes):
        yield step, held, False
        replaced += [e for e in found.elements if e.element == step.element]
    yield from _checked_found(wb, replaced, rules, checked)


def run_auto(wb: Workbench, rules: AutoRules = AutoRules(),
             progress: Callable[[AutoStep], None] | None = None,
             note: Callable[[str], None] | None = None,
             stop: Callable[[], bool] | None = None) -> AutoResult:
    """Run the loop on a started workbench (``wb.start()`` called). Afterwards ``wb.model`` is the final model
    and ``wb.history`` holds every step; ``progress`` is called with each step as it is taken, ``note`` with a
    line of text while discovery searches an element. ``stop`` is asked before every step and, within a step, at
    every evaluation of a fit and every line of a prediction (:mod:`analysis.common.interrupt`): once it answers
    True the loop ends there, the step under way is undone and the steps taken stay. Where the session measures the
    modes, their floors (``rules.modes``) are raised to how well the test repeats them from level to level
    (:class:`analysis.missing.modal_judge.ModalYardstick`, in the result)."""
    if not wb.history:
        raise ValueError("run_auto needs a started workbench (call wb.start() first)")
    steps: list[AutoStep] = []
    stopping = stop or (lambda: False)
    under_way = _UnderWay()
    yardstick = None
    if rules.modes is not None and measures_modes(wb.measurements):
        yardstick = ModalYardstick.of(wb.model, wb.measurements, rules.modes)
        rules = replace(rules, modes=yardstick.rules)
    with stoppable(stopping):
        try:
            result = _run(wb, rules, progress, note, stopping, steps, under_way)
        except Interrupted:
            wb.drop_unfinished()
            result = AutoResult(steps, STOPPED_BY_USER, [], under_way.found, under_way.what)
    result.modal_yardstick = yardstick
    return result


@dataclass
class _UnderWay:
    """What the loop is doing, for the words of a stop inside a step, and what discovery found."""
    what: str = DISCOVERY
    found: Discovery | None = None


def _run(wb: Workbench, rules: AutoRules, progress, note, stopping: Callable[[], bool], steps: list[AutoStep],
         under_way: _UnderWay) -> AutoResult:
    """The loop of :func:`run_auto`, telling ``under_way`` what it does."""

    modal = [_modal_error(wb)]          # the last step's natural frequency and damping error
    current: list[HeldOut | None] = [None]   # the model's held-out error, once checked

    def checked() -> HeldOut:
        """The current model's held-out error (checked now if no step has been)."""
        if current[0] is None:
            under_way.what = "the held-out check of the model the loop starts from"
            current[0] = held_out(wb) if rules.held_out else NOT_CHECKED
        return current[0]

    def take(step: AutoStep, known: HeldOut | None = None) -> None:
        if modal[-1] is not None:
            step.modal_before, step.modal_after = modal[-1], _modal_error(wb)
            modal.append(step.modal_after)
        try:
            if rules.held_out:
                under_way.what = "the held-out check of the step just taken"
                current[0] = known if known is not None else held_out(wb)
                step.held_out, step.held_out_folds = current[0].error, current[0].folds
                step.held_out_judges = current[0].judges if current[0].folds else None
                step.held_out_modal = current[0].modes
        finally:                        # a stop inside the check: the step is recorded and stays
            steps.append(step)
        if progress is not None:
            progress(step)

    found, searched = None, frozenset()
    taken_back: set[str] = set()       # laws added and taken back, by discovery's check or the loop's: not added again
    reread = False                     # discovery's other readings weighed (once, where the loop would stop)

    def take_checks(checks: Iterator[tuple[AutoStep, HeldOut | None, bool]]) -> bool:
        """Each step of :func:`_checked_found` or :func:`_read_again` taken, a law the held-out levels refused not
        offered again; whether any step was taken."""
        took = False
        for step, known, held_out_refused in checks:
            take(step, known=known)
            took = True
            if held_out_refused:
                taken_back.add(f"{step.element}:{step.laws[0]}")
        return took

    if rules.discovery is not None:
        under_way.what = DISCOVERY
        found = under_way.found = wb.discover(rules.discovery, note)
        searched = frozenset(e.element for e in found.elements)
        pending = [e for e in found.elements if e.laws]
        for k, element in enumerate(pending):
            if stopping():
                return AutoResult(steps, STOPPED_BY_USER, [], found)
            under_way.what = f"the fit of {element.element}:{'+'.join(element.laws)}, found by discovery"
            before = wb.history[-1].error
            after = wb.add_laws(element.element, element.laws, action="discover").error
            still_empty = [e.element for e in pending[k + 1:]]
            take(AutoStep("discover", element.element, element.laws, before, after,
                          _discovery_reason(element, still_empty)))
        under_way.what = "the check of discovery's laws"
        take_checks(_checked_found(wb, pending, rules, checked))
    if rules.linear_corrections:
        under_way.what = "the linear corrections"
        names = wb.linear_corrections()
        if names:
            before = wb.history[-1].error
            after = wb.apply_linear_corrections(names).error
            take(AutoStep("linear correction", ", ".join(names), ("linear",), before, after,
                          "linear verdict with a constant kbar offset: the reference is wrong there (the "
                          "corrections are coupled, so they are applied together)"))
    added = 0                          # laws (or pairs) added: a reading put in an element's place is not counted
    ranking: list[Candidate] | None = None   # the workbench's ranking of the model as it stands, where known
    while added < rules.max_steps:
        if stopping():
            return AutoResult(steps, STOPPED_BY_USER, [], found)
        under_way.what = "the ranking of the missing effects"
        raw, ranking = ranking or wb.candidates(rules=rules.ranking), None
        ranked = _judged(wb, [replace(c) for c in raw], rules, found, taken_back)
        top = next((c for c in ranked if c.significant), None)
        pairs_tried = top is None and rules.pairs
        if pairs_tried:
            top = _best_pair(wb, ranked, rules, searched, taken_back)
        beyond = False                 # the top candidate is one its kbar does not call for
        if top is None:
            if found is not None and not reread:
                reread = True
                under_way.what = "discovery's other readings"
                if take_checks(_read_again(wb, found, rules, checked)):
                    continue
            under_way.what = "the candidates the kbar does not call for"
            top = _beyond_the_kbar(wb, ranked, rules, found, taken_back)
            if top is None:
                return AutoResult(steps, _stop_reason(ranked, pairs_tried, rules.ranking.min_gain), ranked, found)
            beyond = True
        before, held_before = wb.history[-1].error, checked()
        under_way.what = f"the fit of {top.name}"
        after = wb.add_laws(top.element, top.laws).error
        added += 1
        take(AutoStep("add pair" if len(top.laws) > 1 else "add", top.element, top.laws, before, after,
                      _beyond_reason(top, before, wb.error_floor.total, rules) if beyond else _reason(top)))
        if not np.isfinite(after):
            return AutoResult(steps, f"the model with {top.name} has no prediction", [], found)
        why = ""
        if _falls_short(top, before, after, rules.ranking.min_gain):
            why = (f"the model refitted with it gains {gain_phrase(before / after)} ({before:.3g} -> {after:.3g}), "
                   f"not the x{rules.ranking.min_gain:g} it gained at its kbar fit")
        elif rules.held_out:
            why = predicts_no_better(held_before, checked(), rules.ranking.min_gain, rules.modes)
        if why:
            wb.back_to(len(wb.history) - 2, f"take back {top.name}")
            take(AutoStep("take back", top.element, top.laws, after, wb.history[-1].error, why), known=held_before)
            taken_back.add(top.name)
            # the model exactly as it was ranked: the same ranking, the loop's holds now holding this law back
            ranking = raw
    return AutoResult(steps, f"stopped after the {rules.max_steps} steps allowed (AutoRules.max_steps)", [], found)
