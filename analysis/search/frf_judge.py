"""The FRF judge of model discovery (step 4 of the overview in analysis/search/discovery.py; docs/discovery.md).

:class:`_Judge` scores a choice of law sets by the coupled FRFs, single-harmonic and with harmonics, and caches
each score by choice: a prediction costs milliseconds to seconds, and the walk asks the same choices many times.
It decides whether a step up from an element's current set earns its parameters -- the kbar's vetoes first
(analysis/search/kbar_evidence.py), then the FRF gain of ``min_gain`` per law added and above the noise -- and
runs the model-form check with harmonics. While one element is judged the other searched elements are
represented by their measured kbar (:func:`_standins`), so that no element's choice waits on another's.

Also here, the refinement against the FRFs, where the capped kbar of data without harmonics places a clearance
too roughly for its kbar fit to judge it: of one set beside the stand-ins, and of every element beside the
others' choices (:class:`_RefinedErrors`), by which a law beside a clearance is taken back where it gains less
than ``min_gain`` once every element is refined (:func:`_pruned_beside_clearance`; docs/discovery.md, "A
clearance judged at its refined parameters").
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from ..common.parallel import map_tasks
from ..common.statistics import chi_square_noise_bound
from ..fitting.fit import UNDETERMINED_Z
from ..laws import LAWS
from ..mechanics.nonparametric import fit_nonparametric
from ..missing.diagnosis import RankingRules, frf_criterion
from ..prediction.comparison import Comparison, HarmonicCriterion, Predictor, kbar_functions_with
from ..prediction.frf_refinement import FrfRefinement, refine_against_frfs, terms_function
from .candidates import _chi_square, _placed, _Search
from .kbar_evidence import (_beside_above_noise, _fits_better, _limit_only_laws, _not_seen_beside_friction,
                            _other_kinds, _unseen_laws, _unseen_why)
from .records import DiscoveryRules, LawSet, WalkStep


class _Judge:
    """Scores choices of law sets by the FRFs, single-harmonic and with harmonics (cached by choice).

    A choice maps element indices to law sets. In a single-harmonic score, the searched elements the choice
    leaves out are represented by their stand-ins (their measured kbar, :func:`_standins`) or, with
    ``standins=False``, by nothing; a score with harmonics needs every searched element's laws (a stand-in has
    no time-domain force)."""

    def __init__(self, predictor: Predictor, rules: DiscoveryRules, harmonics: HarmonicCriterion,
                 standins: dict[int, Callable], kbar_judges: bool = True):
        self.predictor = predictor
        self.rules = rules
        # whether a step must lower the kbar criterion too: not where lines depart from every describing function
        # (data without harmonics), whose capped criterion can prefer no law to a right one
        self.kbar_judges = kbar_judges
        self.criterion = replace(harmonics, limit=rules.ranking.model_form_thd)
        self.standins = standins
        self._single: dict[tuple, Comparison] = {}
        self._multi: dict[tuple, Comparison] = {}
        self._refined: dict[tuple, FrfRefinement] = {}
        # the laws each searched element holds while another is walked, for scores with harmonics (which need
        # laws, not stand-ins): its best set by the criterion until its own walk has chosen
        self.held: dict[int, LawSet] = {}

    @staticmethod
    def _key(choice: dict[int, LawSet], *extra) -> tuple:
        return tuple(sorted((i, s.laws) for i, s in choice.items())) + extra

    def single(self, choice: dict[int, LawSet], standins: bool = True) -> Comparison:
        return self.singles([choice], standins)[0]

    def singles(self, choices: list[dict[int, LawSet]], standins: bool = True) -> list[Comparison]:
        """:meth:`single` of each choice; those not yet scored are predicted at once, each apart from the others
        (:func:`analysis.common.parallel.map_tasks`)."""
        def score(choice: dict[int, LawSet]) -> Comparison:
            replace = {i: f for i, f in self.standins.items() if standins and i not in choice}
            replace.update({i: s.describing_function for i, s in choice.items()})
            return self.predictor.compare(kbar_functions_with(self.predictor.model.elements, replace))

        return _cached(self._single, [self._key(c, standins) for c in choices], choices, score)

    def multi(self, choice: dict[int, LawSet]) -> Comparison:
        return self.multis([choice])[0]

    def multis(self, choices: list[dict[int, LawSet]]) -> list[Comparison]:
        """:meth:`multi` of each choice, those not yet scored predicted at once as :meth:`singles`."""
        def score(choice: dict[int, LawSet]) -> Comparison:
            variant = self.predictor.with_laws({i: (s.fit.law_terms() if s.fit is not None else [])
                                                for i, s in choice.items()})
            return variant.compare(harmonics=self.criterion)

        return _cached(self._multi, [self._key(c) for c in choices], choices, score)

    def step_up(self, search: _Search, current: LawSet, larger: LawSet) -> WalkStep:
        """Whether ``larger`` earns its extra parameters on the element (the others by their stand-ins): the kbar
        criterion falls, the data tell the kinds of its laws, the kbar shows each of them as itself (or, on data
        without harmonics, the FRFs show the size the kbar leaves open: :meth:`_seen_in_frfs`), and the FRF
        error falls by ``min_gain`` per law added and above the noise, single-harmonic."""
        # a clearance on either side: both judged where refinement helps them, or the step weighs a refined set
        # against one at its kbar fit
        a = self.fitted_single(search, current, refine=_has_clearance(larger))
        b = self.single({search.index: larger})
        step = WalkStep(larger.laws, b.error, a.error, False)
        unseen = _unseen_laws(larger, current)
        step.why, step.not_itself = self._veto(search, current, larger, step, a, b, unseen)
        step.by_kbar = bool(step.why)
        if not step.why:
            if step.gain < _required(current, larger, self.rules.ranking):
                # refined only where the kbar lets the step through and the gain decides: a refinement costs seconds
                b = self.fitted_single(search, larger, refine=_has_clearance(current))
                step.error = b.error
            step.why, step.not_itself = self._frf_veto(current, larger, step, a, b, unseen)
            if step.why and np.isfinite(b.error) and self._gains_with_harmonics(search, current, larger, step):
                step.why, step.not_itself = "", False
        if not step.why and unseen:
            seen = self._seen_in_frfs(search, current, larger, unseen)
            if seen:
                step.seen_in_frfs = seen
            else:
                step.why, step.not_itself = _unseen_why(unseen), True
        step.taken = not step.why
        return step

    def _veto(self, search: _Search, current: LawSet, larger: LawSet, step: WalkStep, a: Comparison,
              b: Comparison, unseen: list[str]) -> tuple[str, bool]:
        """Why the step is not taken ("" where nothing stops it), and whether it gives way to the next set of its
        size (the kbar does not show a law of it as itself, or does not call for it beside the laws taken). A law
        whose size the kbar leaves open stops it here except on data without harmonics, where the FRFs are asked
        once nothing else stops it (:meth:`step_up`)."""
        ranking = self.rules.ranking
        limit_only = _limit_only_laws(larger, current, search, ranking.false_alarm, self.frfs_part_refined(search))
        if self.kbar_judges and larger.criterion >= current.criterion:
            return "its kbar does not call for it (the criterion, which charges for parameters, does not fall)", False
        if unseen and (self.kbar_judges or _placed(larger)):
            return _unseen_why(unseen), True
        if limit_only:
            return f"its kbar shows {limit_only[0][0]} only in its limit: {limit_only[0][1]}", True
        beside_friction = [] if self.kbar_judges else _not_seen_beside_friction(
            search, current, larger, ranking.false_alarm, self.frfs_part_refined(search))
        if beside_friction:
            step.instead = tuple(n for n in larger.laws if n != beside_friction[0])
            return (f"its kbar shows {beside_friction[0]} beside friction no more than the force that turns the "
                    "friction's fundamental on data without harmonics, which is no law"), True
        # a gain of certain_gain is not what a law fitting the lines no describing function follows brings; the
        # step is still checked with harmonics (holds_with_harmonics)
        if not self.kbar_judges and not unseen and step.gain < ranking.certain_gain and \
                not _beside_above_noise(search, current, larger, ranking.false_alarm):
            # no evidence against the sets of its size that replace a law taken: they are tried next
            return ("its kbar does not call for it: beside the laws taken its chi-square falls by less than the "
                    "noise explains"), True
        other_kinds = _other_kinds(self, search, larger) if self.kbar_judges else []
        if other_kinds:
            return (f"its kbar cannot tell which physics it is: {other_kinds[0].name} fits it as well with laws of "
                    "other kinds"), False
        return "", False

    def _frf_veto(self, current: LawSet, larger: LawSet, step: WalkStep, a: Comparison, b: Comparison,
                  unseen: list[str]) -> tuple[str, bool]:
        """Why the FRFs refuse a step the kbar lets through ("" where they take it): no prediction, too small a
        gain, or a fall of the FRF chi-square within the noise."""
        ranking = self.rules.ranking
        required = _required(current, larger, ranking)
        _, above = frf_criterion(a, b, max(larger.n_parameters - current.n_parameters, 1), ranking.false_alarm)
        if not np.isfinite(b.error):
            return "no prediction", unseen != []
        if step.gain < required:
            return f"less than the x{required:.3g} required", unseen != []
        if not above:
            return "within the noise", unseen != []
        return "", False

    def _gains_with_harmonics(self, search: _Search, current: LawSet, larger: LawSet, step: WalkStep) -> bool:
        """On data without harmonics, whether a step the single-harmonic FRFs refuse, and the kbar calls for by
        more than the noise explains (its chi-square falls by more than s^2 chi2_q for the parameters added), gains
        the margin with the lines that carry harmonics predicted multi-harmonically, every other searched element
        at the laws it holds (:attr:`held`). Friction whose force is near a square wave drives the structure at
        3w and 5w, and the fundamental it leaves differs from the single-harmonic one: a right law beside it,
        fitting the kbar far better than a linear law, can predict the FRFs worse than the linear law
        single-harmonically and many times better with harmonics. The step is then taken on that gain, and
        checked again as the element's last step with every element at its choice
        (:meth:`holds_with_harmonics`)."""
        ranking = self.rules.ranking
        if self.kbar_judges or not _fits_better(search, larger, current, ranking.false_alarm):
            return False
        if self._gains_with_harmonics_beside(self.held, search.index, current, larger, step,
                                             _required(current, larger, ranking)):
            return True
        step.why += ", with harmonics too"
        return False

    def _gains_with_harmonics_beside(self, others: dict[int, LawSet], i: int, before: LawSet, after: LawSet,
                                     step: WalkStep, required: float) -> bool:
        """Whether ``after`` in place of ``before`` on element ``i``, the others at ``others``, cuts the FRF error
        with harmonics by ``required`` and its chi-square by more than the noise explains (the gain goes into
        ``step.multiharmonic_gain``)."""
        ma, mb = self.multis([{**others, i: before}, {**others, i: after}])
        step.multiharmonic_gain = ma.error / mb.error if mb.error > 0 else float("inf")
        _, above = frf_criterion(ma, mb, max(after.n_parameters - before.n_parameters, 1),
                                 self.rules.ranking.false_alarm)
        return step.multiharmonic_gain >= required and above

    def frfs_part(self, search: _Search) -> Callable[[LawSet, LawSet], bool] | None:
        """On data without harmonics, whether the single-harmonic FRFs tell set ``b`` from set ``a`` of the element
        by ``certain_gain`` or more (``b`` the better): where the kbar's chi-square is capped, a law acting on the
        few lines near a resonance at the higher level hardly moves it, and the FRFs there show the law by far
        (a spring beside friction that saturates by a few percent at the largest amplitude only). None on data
        with harmonics, whose kbar is not capped."""
        if self.kbar_judges:
            return None
        i = search.index
        return lambda a, b: self.single({i: a}).error >= self.rules.ranking.certain_gain * self.single({i: b}).error

    def frfs_part_refined(self, search: _Search) -> Callable[[LawSet, LawSet], bool] | None:
        """:meth:`frfs_part`, or, below ``certain_gain``, a gain of ``min_gain`` at the kbar fits that holds by
        ``min_gain`` squared with both sets refined against the FRFs (:meth:`_refined_parts`): whether a law the
        kbar sees only in its linear limit is seen as itself (:func:`_limit_only_laws`). A refinement costs
        seconds, so only there."""
        part = self.frfs_part(search)
        if part is None:
            return None
        i = search.index
        ranking = self.rules.ranking

        def part_refined(a: LawSet, b: LawSet) -> bool:
            if part(a, b):
                return True
            gain = self.single({i: a}).error / self.single({i: b}).error
            return gain >= ranking.min_gain and self._refined_parts(search, a, b)
        return part_refined

    def _refined_parts(self, search: _Search, a: LawSet, b: LawSet) -> bool:
        """Whether set ``b``, refined against the FRFs, cuts the error of set ``a``, refined too, by ``min_gain``
        squared (the others by their stand-ins): the margin of the linear verdict set aside when refined
        (:func:`_overruled_refined`). At their kbar fits the capped kbar leaves both where the lines that stick
        put them; refined, a set that only fills part of the FRFs' misfit gains little, while a law the joint has
        keeps much of its gain."""
        before, after = self.refined_single(search, a).error, self.refined_single(search, b).error
        return before >= self.rules.ranking.min_gain ** 2 * after

    def _seen_in_frfs(self, search: _Search, current: LawSet, larger: LawSet, unseen: list[str]) -> str:
        """Where the kbar leaves the size of a law the step adds open, the FRFs of every line and sensor may
        determine it: both sets' parameters refined against them, the other elements by their stand-ins
        (:func:`analysis.prediction.frf_refinement.refine_against_frfs`). The sizes of those laws, in words, where every one
        is at least ``UNDETERMINED_Z`` standard errors from zero and the refined FRF chi-square falls by more than
        the noise explains for the parameters added (the test the kbar's chi-square fails there); "" otherwise.
        A small linear law beside a spring that only begins to saturate within the amplitudes measured is such a
        law: undetermined in the kbar, determined in the FRFs. The refined values, which carry the stand-ins' own
        error, decide the step only; the model keeps its kbar fit."""
        big = self.refined(search, larger)
        labels = [t.law.name for t in big.terms]
        if not all(big.size_seen(labels.index(n), UNDETERMINED_Z) for n in unseen):
            return ""
        small = self.refined(search, current)
        dof = max(larger.n_parameters - current.n_parameters, 1)
        scale = max(1.0, big.chi_square / max(big.n_residuals - larger.n_parameters, 1))
        if small.chi_square - big.chi_square <= chi_square_noise_bound(scale, dof, self.rules.ranking.false_alarm):
            return ""
        return "; ".join(f"{n} {big.size_text(labels.index(n))}" for n in unseen)

    def fitted_single(self, search: _Search, s: LawSet, refine: bool = False) -> Comparison:
        """The single-harmonic comparison of set ``s`` on its element (the others by their stand-ins); on data
        without harmonics, for a set with a clearance law (or any set, ``refine``), the better of those at its
        kbar fit and at its parameters refined against the FRFs. The capped kbar can place a gap a few percent
        off, and the FRFs of the lines where it closes are that sensitive to it: another law then gains by
        filling in that misfit (Anderson-Ferri friction of negative c or a negative quintic beside a gap). A step
        to or from a set with a clearance judges the other set so too: a set judged at its kbar fit against one
        refined is at a disadvantage, and can lose to a clearance it does not have."""
        own = self.single({search.index: s})
        if self.kbar_judges or not (refine or _has_clearance(s)):
            return own
        refined = self.refined_single(search, s)
        return refined if refined.error < own.error else own

    def refined_single(self, search: _Search, s: LawSet) -> Comparison:
        """The single-harmonic comparison of set ``s`` on its element at its refined parameters, the others by
        their stand-ins (cached with the single-harmonic scores: a step judges its current set this way again for
        every set it tries)."""
        key = self._key({search.index: s}, "refined")
        if key not in self._single:
            replace = {**self.standins, search.index: terms_function(self.refined(search, s).terms)}
            self._single[key] = self.predictor.compare(kbar_functions_with(self.predictor.model.elements, replace))
        return self._single[key]

    def stand_in(self, i: int, function: Callable) -> None:
        """Element ``i`` represented by ``function`` from now on: every score and refinement made beside its
        former stand-in is forgotten."""
        self.standins[i] = function
        self._single.clear()
        self._refined.clear()

    def refined(self, search: _Search, s: LawSet) -> FrfRefinement:
        """Set ``s``'s parameters on its element refined against the FRFs, the other searched elements by their
        stand-ins (cached by set)."""
        key = (search.index, s.laws)
        if key not in self._refined:
            others = {j: f for j, f in self.standins.items() if j != search.index}
            self._refined[key] = self.refined_beside(search.index, _terms_of(s), others, _seen_of(s))
        return self._refined[key]

    def refined_beside(self, i: int, terms: list, others: dict[int, Callable], free: list[list[str]]
                       ) -> FrfRefinement:
        """Law ``terms``' parameters ``free`` (per term: those their kbar fit sees, :meth:`LawFit.seen`) on element
        ``i`` refined against the FRFs from their values, the elements of ``others`` held at those describing
        functions (:func:`analysis.prediction.frf_refinement.refine_against_frfs`)."""
        return refine_against_frfs(self.predictor, i, terms, free, others)

    def holds_with_harmonics(self, choice: dict[int, LawSet], i: int, before: LawSet, step: WalkStep) -> bool:
        """The model-form check of a step taken on element ``i`` (the overview in discovery.py, step 4): with every
        searched element at its choice, the step must also gain ``min_gain``, above the noise, with the lines that
        carry harmonics predicted multi-harmonically. A gain beyond ``certain_gain`` is not the harmonics' effect where
        the lines far from harmonic are left out of the kbar (data with harmonics), nor for the element's first
        law; on data without harmonics those lines are in the kbar and a law beside another can gain x5 by
        fitting them (docs/discovery.md, "The model-form check")."""
        if step.gain >= self.rules.ranking.certain_gain and (self.kbar_judges or not before.laws):
            return True
        if self._gains_with_harmonics_beside(choice, i, before, choice[i], step, self.rules.ranking.min_gain):
            return True
        step.taken = False
        step.why = ("with the harmonics represented it gains too little: the single-harmonic gain fits what one "
                    "harmonic cannot represent")
        return False


def _cached(cache: dict[tuple, Comparison], keys: list[tuple], choices: list[dict[int, LawSet]],
            score: Callable[[dict[int, LawSet]], Comparison]) -> list[Comparison]:
    """The comparison of each choice from ``cache``, those missing scored first (each new key once)."""
    missing: dict[tuple, dict[int, LawSet]] = {}
    for key, choice in zip(keys, choices):
        if key not in cache:
            missing.setdefault(key, choice)       # the first of choices alike is scored, as one at a time
    missing = list(missing.items())
    for (key, _), comparison in zip(missing, map_tasks(lambda j: score(missing[j][1]), len(missing))):
        cache[key] = comparison
    return [cache[k] for k in keys]


def _required(current: LawSet, larger: LawSet, ranking: RankingRules) -> float:
    """The FRF gain a step must bring: the margin one law must for every law it adds (a step past a size not
    taken adds two)."""
    return ranking.min_gain ** max(len(larger.laws) - len(current.laws), 1)


def _has_clearance(s: LawSet) -> bool:
    return any(LAWS[n].kind == "clearance" for n in s.laws)


def _pruned_beside_clearance(judge: _Judge, index: dict[int, "_Search"],
                             judged: dict[int, LawSet]) -> dict[int, str]:
    """On data without harmonics, each element's law beside a clearance law taken back where, with every
    element's parameters refined against the FRFs, the set without it is within ``min_gain`` of the set with it,
    single-harmonic or with harmonics where that prediction can judge (:func:`_harmonics_judge`; ``judged`` is
    changed in place; returns element index -> why, in words).

    The walk judges a set at its kbar fit, the other elements by their stand-ins. Where a clearance closes within
    the amplitudes, the FRFs are so sensitive to its gap that a few percent of misplacement there, or the
    stand-ins' own misfit, is worth a law at the kbar fits, which brings little once every element is refined."""
    if judge.kbar_judges:
        return {}
    ranking = judge.rules.ranking
    why = {}
    for i in list(judged):
        chosen = judged[i]
        full = None                 # the set adopted last round was refined beside the same others: carried over
        while len(chosen.laws) >= 2 and _has_clearance(chosen):
            if full is None:
                full = _refined_errors(judge, i, chosen, judged)
            smaller = [s for s in index[i].sets if len(s.laws) == len(chosen.laws) - 1 and _has_clearance(s)
                       and set(s.laws) < set(chosen.laws)]
            verdicts = [(s, _refined_errors(judge, i, s, judged)) for s in smaller]
            # the harmonic prediction is asked only where the single-harmonic errors leave the margin
            lost = [(s, e) for s, e in verdicts if e.single <= ranking.min_gain * full.single or
                    (_harmonics_judge(full, ranking.min_gain) and e.multi <= ranking.min_gain * full.multi)]
            if not lost:
                break
            best, errors = min(lost, key=lambda pair: pair[1].single)
            dropped = next(n for n in chosen.laws if n not in best.laws)
            why[i] = (f"{dropped} taken back: with every element's parameters refined against the FRFs, "
                      f"{best.name} gives {errors.text()}, {chosen.name} {full.text()}: less than "
                      f"x{ranking.min_gain:g} in one of them")
            judged[i] = chosen = best
            full = errors
    return why


def _harmonics_judge(full: "_RefinedErrors", min_gain: float) -> bool:
    """Whether the harmonic prediction of a set refined single-harmonic can judge it: only where it follows the
    FRFs within ``min_gain`` of the single-harmonic one. A one-sided contact drives a mean that the
    single-harmonic refinement folds into its gap; with harmonics, that gap is no longer the set's own, and every
    set with it misses alike, by several times the single-harmonic error, so the harmonic prediction cannot tell
    them apart."""
    return full.multi <= min_gain * full.single


def _terms_of(s: LawSet) -> list:
    return s.fit.law_terms() if s.fit is not None else []


def _seen_of(s: LawSet) -> list[list[str]]:
    return s.fit.seen() if s.fit is not None else []


class _RefinedErrors:
    """A set's FRF errors with every element refined (:func:`_refined_errors`): single-harmonic, and with
    harmonics predicted when first asked (a harmonic prediction costs seconds)."""

    def __init__(self, single: float, predict_multi: Callable[[], float]):
        self.single = single
        self._predict_multi = predict_multi
        self._multi: float | None = None

    @property
    def multi(self) -> float:
        if self._multi is None:
            self._multi = self._predict_multi()
        return self._multi

    def text(self) -> str:
        """In words, with harmonics only where they were predicted."""
        return f"{self.single:.3g} single-harmonic" + (f", {self._multi:.3g} with harmonics"
                                                       if self._multi is not None else "")


def _refined_errors(judge: _Judge, i: int, s: LawSet, judged: dict[int, LawSet]) -> _RefinedErrors:
    """The FRF errors, single-harmonic and with harmonics, of set ``s`` on element ``i`` and the other elements
    at their choices (``judged``), all refined against the FRFs: ``s`` beside their kbar fits, then each of them
    beside it, then ``s`` again beside those. Each set judged has the others at their best beside it: their kbar
    fits' misfit is not ``s``'s laws to fill, nor is ``s``'s kbar fit's theirs."""
    fitted = {k: t.describing_function for k, t in judged.items() if k != i}
    first = judge.refined_beside(i, _terms_of(s), fitted, _seen_of(s)).terms
    held = {}
    for j, other in judged.items():
        if j != i:
            beside = {**{k: f for k, f in fitted.items() if k != j}, i: terms_function(first)}
            held[j] = judge.refined_beside(j, _terms_of(other), beside, _seen_of(other)).terms
    replace = {j: terms_function(ts) for j, ts in held.items()}
    # alone on the structure, the first refinement is already beside its best others
    terms = judge.refined_beside(i, first, replace, _seen_of(s)).terms if held else first
    replace[i] = terms_function(terms)
    single = judge.predictor.compare(kbar_functions_with(judge.predictor.model.elements, replace)).error
    return _RefinedErrors(single, lambda: judge.predictor.with_laws({**held, i: terms}).compare(
        harmonics=judge.criterion).error)


def _standins(searches: list["_Search"], robust: bool) -> dict[int, Callable]:
    """Each searched element's measured kbar as a describing function: while one element's laws are judged by the
    FRFs, the others are represented by what was measured of them, so no element's choice waits on another's
    (with another joint still empty or wrong, the FRF error is that joint's, and a right law elsewhere gains
    nothing). Of the non-parametric part fitted to its samples (:func:`analysis.mechanics.nonparametric.fit_nonparametric`)
    and its best set of laws by the criterion, the one that fits its samples better (the chi-square, capped as
    the sets' on data without harmonics): the part is additive in ln X and ln w and cannot follow a damping that
    grows as X w^2 (quadratic damping), which left an error floor of 0.14 under the other joint's laws."""
    out = {}
    for search in searches:
        s = search.samples
        part = fit_nonparametric(s.X, s.w, s.kbar, s.kbar_std).model
        best = search.best
        part_chi2 = _chi_square(part.describing_function(s.X, s.w) - s.kbar, s.kbar_std, robust)
        out[search.index] = best.describing_function if best.chi_square < part_chi2 else part.describing_function
    return out
