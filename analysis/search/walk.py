"""The walk and the choice of model discovery (steps 3 and 4 of the overview in analysis/search/discovery.py;
docs/discovery.md), and :func:`discover`, which runs the whole method.

Each element's shortlists are walked from no law upward, one set of each size tried against the current choice:
the kbar orders the sets the FRFs cannot tell apart, and the FRFs overrule its first only where they still do
with harmonics or refined (:func:`_preferred`), because a single-harmonic FRF error carries the stand-ins' floor
and what one harmonic cannot represent. A linear verdict is set aside where one amplitude-dependent law beats
every set without one in the FRFs. Once every element has walked, each element's last step is checked with
harmonics, every other element at its choice, and a contact law refused there gives way first to its twin on
the other side, whose fundamental is alike. Of the sets alike the choice in the kbar the simplest is taken, and
the elements are reported in the order their laws best cut the error one at a time.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

from ..common.statistics import chi_square_noise_bound
from ..fitting.fit import UNDETERMINED_Z
from ..laws import LAWS, simplicity
from ..mechanics.surroundings import Surroundings
from ..missing.diagnosis import ElementSamples
from ..prediction.comparison import HarmonicCriterion, Predictor
from ..prediction.frf_refinement import terms_function
from .candidates import _Search, search_element
from .frf_judge import _has_clearance, _Judge, _pruned_beside_clearance, _standins
from .kbar_evidence import _alike, _explanations, _fits_better, _indistinguishable, _separation
from .records import Discovery, DiscoveryRules, ElementDiscovery, LawSet, Separation, WalkStep


def _walk_element(judge: _Judge, search: _Search) -> tuple[list[LawSet], list[WalkStep]]:
    """Element ``search.index``'s shortlists from no law upward, the others by their stand-ins (the overview in
    discovery.py, step 4): of each size the sets the FRFs cannot tell from the best of them (:func:`_preferred`,
    of its shortlist and the sets that keep the laws already taken) are tried against the current choice in the
    walk's order until one is taken. A set refused gives way to the next: the order is a preference among sets
    the FRFs do not part (the laws taken kept, a clearance judged refined), not a verdict on the others, and each
    of them still has to pass every test of a step on its own. A set not seen as itself also no longer sets the
    FRF error the others are held to; a set refused otherwise leaves the others held to the error they were.
    Returns the sets taken, from no law on, and every step tried."""
    taken = [search.by_size[0][0]]
    steps = []
    for size in sorted(search.by_size):
        if size == 0:
            continue
        pool = search.by_size[size] + _extension(search, taken[-1], size)
        alike: list[LawSet] | None = None      # once a set was refused but seen as itself: the sets kept beside it
        while pool:
            ranked = _preferred(judge, search, pool, taken[-1])
            if alike is not None:
                ranked = [s for s in ranked if s in alike]
                if not ranked:
                    break
            candidate = ranked[0]
            step = judge.step_up(search, taken[-1], candidate)
            steps.append(step)
            if step.taken:
                taken.append(candidate)
                break
            if _took_instead(judge, search, step, taken, steps):
                break
            if not step.not_itself and alike is None:
                alike = ranked
            pool.remove(candidate)
    return taken, steps


def _took_instead(judge: _Judge, search: _Search, step: WalkStep, taken: list[LawSet], steps: list[WalkStep]) -> bool:
    """Where a step was refused for a law its kbar does not show beside friction, the set without that law is
    tried in its place (appended to ``taken`` and ``steps``): the other laws of the step may be right, and the
    walk, which tries one set of each size, would not come back to the smaller one."""
    instead = next((s for s in search.sets if set(s.laws) == set(step.instead)), None) if step.instead else None
    if instead is None or set(instead.laws) == set(taken[-1].laws):
        return False
    tried = judge.step_up(search, taken[-1], instead)
    steps.append(tried)
    if tried.taken:
        taken.append(instead)
    return tried.taken


def _offer_frf_best_single(judge: _Judge, search: _Search) -> None:
    """The single law the FRFs like best joins the shortlist of one law, where the kbar criterion left it out. A
    law that acts on a few lines only -- a clearance that closes at the resonance of the higher level, a quintic
    spring -- changes few kbar samples, and where lines may depart from every describing function (data without
    harmonics) their chi-square is capped: the criterion hardly sees it, though the FRFs near that resonance show
    it by far. One prediction per law of the library; the walk still asks the kbar to show the law and the FRFs
    to gain the margin."""
    singles = [s for s in search.sets if len(s.laws) == 1]
    if not singles or 1 not in search.by_size:
        return
    best = _best_single(judge, search.index, singles)
    if best not in search.by_size[1]:
        search.by_size[1].append(best)


def _best_single(judge: _Judge, i: int, sets: list[LawSet]) -> LawSet:
    """The first of ``sets`` with the lowest single-harmonic FRF error on element ``i`` (the others by their
    stand-ins), all of them scored at once."""
    errors = [c.error for c in judge.singles([{i: s} for s in sets])]
    return sets[errors.index(min(errors))]


def _verdict_overruled(judge: _Judge, search: _Search, rules: DiscoveryRules,
                       around: Surroundings | None) -> _Search | None:
    """On data without harmonics, an element whose linearity verdict is linear searched again with every law of
    the library, where a single law whose kbar depends on the amplitude beats every set without such a law in the
    FRFs by ``certain_gain`` (:meth:`_Judge.frfs_part`); None where none does. The verdict is a test of the kbar
    at the false-alarm rate, and an element whose kbar is small beside the structure's carries little of it: a
    law there can lower the kbar's chi-square too little for the verdict and still cut the FRF error many times,
    and a loop bound by the verdict would leave the joint empty. The single laws are fitted first;
    the sets of two and three only where the verdict is set aside."""
    part = judge.frfs_part(search)
    if part is None:
        return None
    i = search.index
    singles = search_element(i, search.samples, False, replace(rules, max_laws=1), robust=True, around=around)
    amplitude = [s for s in singles.sets if len(s.laws) == 1 and LAWS[s.laws[0]].amplitude_dependent]
    if not amplitude:
        return None
    best, linear = _best_single(judge, i, amplitude), _best_single(judge, i, search.sets)
    if part(linear, best):
        gain = judge.single({i: linear}).error / judge.single({i: best}).error
        why = f"{best.name} beats every set without amplitude dependence in the FRFs x{gain:.3g}"
    else:
        why = _overruled_refined(judge, search, linear, best)
        if not why:
            return None
    full = search_element(i, search.samples, False, rules, robust=True, around=around)
    full.overruled = (f"its linearity verdict (linear, from its kbar at the false-alarm rate) is set aside: {why}, "
                      "so the laws that move with amplitude were searched too")
    # the other elements' steps are judged beside what the FRFs showed of it, not beside its linear kbar
    judge.stand_in(i, terms_function(judge.refined(search, best).terms))
    return full


def _overruled_refined(judge: _Judge, search: _Search, linear: LawSet, best: LawSet) -> str:
    """Where the best single law with amplitude dependence gains ``min_gain`` at its kbar fit but less than
    ``certain_gain``: both it and the best set without amplitude dependence refined against the FRFs (the others
    by their stand-ins), the law's size seen and the refined error cut by ``min_gain`` squared; "" otherwise.
    A law that hardly moves its element's kbar can gain as much refined as at its kbar fit; left out, another
    element judged beside a linear stand-in takes a law to fill its misfit."""
    ranking = judge.rules.ranking
    i = search.index
    if judge.single({i: linear}).error < ranking.min_gain * judge.single({i: best}).error:
        return ""
    refined = judge.refined(search, best)
    if not refined.size_seen(0, UNDETERMINED_Z):
        return ""
    before, after = judge.refined_single(search, linear).error, judge.refined_single(search, best).error
    if before < ranking.min_gain ** 2 * after:
        return ""
    return (f"{best.name} refined against the FRFs ({refined.size_text(0)}) cuts the error of the best set "
            f"without amplitude dependence, refined too, x{before / after:.3g} ({before:.3g} -> {after:.3g})")


def _offer_frf_best_alike(judge: _Judge, search: _Search) -> None:
    """On data without harmonics, for every size of more than one law: the sets that fit the kbar as well as a set
    of the shortlist within the noise join it where they beat the shortlist's best FRF error by
    ``certain_gain`` (:meth:`_Judge.frfs_part`); the walk tries them by the criterion, as the others, and a set
    not seen as itself gives way (Coulomb friction as an Iwan element of no slip displacement, which fits the
    FRFs as well as Coulomb friction itself). The kbar's chi-square is capped there, and the sets it ranks first
    can all leave out what only a few lines near a resonance show, ranking below them a set whose FRF error is
    many times lower."""
    part = judge.frfs_part(search)
    if part is None:
        return
    for size, shortlist in search.by_size.items():
        if size < 2 or not shortlist:
            continue
        alike = [s for s in search.sets if len(s.laws) == size and s not in shortlist
                 and any(_alike(search, s, t, judge.rules.ranking.false_alarm) for t in shortlist)]
        listed = _best_single(judge, search.index, shortlist)
        shortlist.extend([s for s in alike if part(listed, s)])


def _preferred(judge: _Judge, search: _Search, sets: list[LawSet], taken: LawSet) -> list[LawSet]:
    """Of sets of one size, those whose single-harmonic FRF error is within ``min_gain`` of the best of them,
    by the kbar criterion: the kbar chooses, and the FRFs overrule it only by the margin a law must bring (the
    stand-ins of the other elements leave an error floor of their own, within which the FRFs cannot choose). The
    walk tries the first and, where it is refused, the next (:func:`_walk_element`); where the kbar does not show
    a law of it as itself, the sets left are held to the best FRF error among them (a clearance whose gap runs
    below every amplitude is a linear spring, which comes next once it gives way; a saturating spring whose size
    the kbar does not determine can fit the fundamental of friction's harmonics better than the linear law beside
    friction, which comes next only once it has given way). The set the kbar ranks first stays first where the FRFs
    overrule it only at its kbar fit (:func:`_overruled_at_kbar_fit_only`). ``taken``: the element's current
    choice (:func:`_walk_order`)."""
    i = search.index
    errors = [c.error for c in judge.singles([{i: s} for s in sets])]
    best = min(errors)
    ordered = sorted(zip(sets, errors), key=lambda pair: _walk_order(judge, taken, pair[0]))
    kept = [s for s, e in ordered if e <= judge.rules.ranking.min_gain * best]
    first = ordered[0][0]
    if first not in kept and (_overruled_at_kbar_fit_only(judge, search, first, kept)
                              or _overruled_single_harmonically_only(judge, search, first, kept)):
        kept.insert(0, first)
    return kept


def _overruled_single_harmonically_only(judge: _Judge, search: _Search, first: LawSet, rivals: list[LawSet]) -> bool:
    """On data without harmonics, whether the set the kbar ranks first, which the single-harmonic FRFs overrule,
    predicts them within ``min_gain`` of the best of the ``walk_width`` rivals they prefer once the lines that
    carry harmonics are predicted multi-harmonically, every other searched element at the laws it holds
    (:attr:`_Judge.held`); asked only where the kbar prefers it to each of those rivals by more than the noise
    explains (a score with harmonics costs seconds). A spring that saturates within the amplitudes measured has
    a force near a square wave, whose harmonics change the fundamental: the single-harmonic FRFs can prefer a
    rival that the FRFs with harmonics refuse, and a law taken beside that rival then stands in for the
    difference."""
    if judge.kbar_judges:
        return False
    i = search.index
    closest = _closest(judge, search, rivals)
    if not all(_fits_better(search, first, s, judge.rules.ranking.false_alarm) for s in closest):
        return False
    *theirs, mine = judge.multis([{**judge.held, i: s} for s in closest] + [{**judge.held, i: first}])
    return mine.error <= judge.rules.ranking.min_gain * min(c.error for c in theirs)


def _closest(judge: _Judge, search: _Search, rivals: list[LawSet]) -> list[LawSet]:
    """The ``walk_width`` rivals with the lowest single-harmonic FRF errors."""
    errors = [c.error for c in judge.singles([{search.index: s} for s in rivals])]
    return [s for s, _ in sorted(zip(rivals, errors), key=lambda pair: pair[1])][:judge.rules.walk_width]


def _overruled_at_kbar_fit_only(judge: _Judge, search: _Search, first: LawSet, rivals: list[LawSet]) -> bool:
    """On data without harmonics, whether the set the kbar ranks first, which the FRFs overrule at its kbar fit,
    and which holds a clearance law, fits them as well as the ``walk_width`` rivals they prefer once every set's
    parameters are refined against them (its FRF chi-square within the noise of the best rival's,
    :meth:`_Judge.refined`). The capped kbar can place a clearance's gap a few percent off, and the FRFs of the
    lines where it closes are that sensitive to it (a refinement costs seconds, a minute for three laws with
    friction: only there is it asked): a gap a few percent off at its kbar fit can lose to a rival in the FRFs,
    and beat it many times over in FRF chi-square once refined."""
    if judge.kbar_judges or not _has_clearance(first):
        return False
    own = judge.refined(search, first)
    closest = _closest(judge, search, rivals)
    best, best_set = min(((judge.refined(search, s), s) for s in closest), key=lambda pair: pair[0].chi_square)
    scale = max(1.0, best.chi_square / max(best.n_residuals - best_set.n_parameters, 1))
    return own.chi_square <= best.chi_square + chi_square_noise_bound(scale, 1, judge.rules.ranking.false_alarm)


def _walk_order(judge: _Judge, taken: LawSet, s: LawSet) -> tuple[bool, float]:
    """The order in which the walk tries sets the FRFs cannot tell apart: by the kbar criterion, except on data
    without harmonics beside laws taken, where the sets that keep those laws come first. There the kbar beyond
    the main effect is what friction's sticking puts in the fundamental, and a law that replaces the one taken
    can fit it better: beside Coulomb friction a gap whose gap lies at the smallest amplitudes it slips at
    (1/X in Re, as friction is 1/X in Im) can fit the kbar far better than the linear spring the joint has,
    while the FRFs, with harmonics too, hardly tell the two apart."""
    keeps = bool(taken.laws) and not judge.kbar_judges and set(taken.laws) <= set(s.laws)
    return not keeps, s.criterion


def _extension(search: _Search, current: LawSet, size: int) -> list[LawSet]:
    """The sets of ``size`` laws that keep every law of ``current`` (those not on the shortlist already): the walk
    also tries adding to what it took, not only the shortlist's other sets. One law more beside laws taken: every
    such set fitted, for the FRFs to choose from -- once the element's main effect is taken, what its kbar ranks
    the sets by is what that law leaves, and where a friction contact sticks that is the lines departing from
    every describing function, which laws fitting the sticking follow better than the law the joint has beside
    the one taken; the kbar still vetoes a step whose criterion does not fall or whose law it does not show. Two
    laws more beside laws taken: every such set too, for the same reason (docs/discovery.md, section 4). From no
    law: the best by the criterion (the first law's ranking is that of the whole kbar, the main effect's)."""
    keep = set(current.laws)
    extending = [s for s in search.sets if len(s.laws) == size and keep <= set(s.laws)]
    if not current.laws:
        extending = extending[:1]
    return [s for s in extending if s not in search.by_size[size]]


#: The contact laws the fundamental alone hardly tells apart: a contact that closes on one side and one that closes
#: on both differ first in their harmonics (a mean and even ones against odd ones)
CONTACT_TWINS = {"gap": "unilateral", "unilateral": "gap"}


def _contact_twin(search: _Search, s: LawSet) -> LawSet | None:
    """Set ``s`` with its contact law on the other side (:data:`CONTACT_TWINS`), as fitted to the element's kbar;
    None where ``s`` holds no such law, or holds both, or the twin was not fitted."""
    contacts = [n for n in s.laws if n in CONTACT_TWINS]
    if len(contacts) != 1:
        return None
    twin = {CONTACT_TWINS[contacts[0]] if n == contacts[0] else n for n in s.laws}
    return next((t for t in search.sets if set(t.laws) == twin and not t.tied), None)


def _check_with_harmonics(judge: _Judge, index: dict[int, _Search], taken: dict[int, list[LawSet]],
                          walks: dict[int, list[WalkStep]]) -> None:
    """Each element's last step, checked with the harmonics represented and every other element at its choice;
    a step that fails is taken back and the one before it checked in turn. A set with a contact law that fails
    gives way first to its twin with the contact on the other side (:func:`_contact_twin`), stepped up to and
    checked the same way: on data without harmonics the kbar can read a gap as a one-sided contact, and the
    harmonics that part the two are what refused the set; taken back without its twin tried, the set's other
    laws, which may be right, are lost with it."""
    for i, sets in taken.items():
        while len(sets) > 1:
            step = next(s for s in reversed(walks[i]) if s.taken and s.laws == sets[-1].laws)
            if judge.holds_with_harmonics(_choices(taken), i, sets[-2], step):
                break
            failed = sets.pop()
            if _twin_holds(judge, index[i], taken, walks[i], failed):
                break


def _twin_holds(judge: _Judge, search: _Search, taken: dict[int, list[LawSet]], walk: list[WalkStep],
                failed: LawSet) -> bool:
    """Whether the contact twin of a set refused with harmonics (:func:`_contact_twin`) is stepped up to from the
    set before it and holds with harmonics; it is then taken (appended to ``taken`` and ``walk``). Data with
    harmonics show which side a contact closes on in the kbar already."""
    twin = None if judge.kbar_judges else _contact_twin(search, failed)
    sets = taken[search.index]
    if twin is None or any(set(s.laws) == set(twin.laws) for s in sets):
        return False
    step = judge.step_up(search, sets[-1], twin)
    walk.append(step)
    if not step.taken:
        return False
    sets.append(twin)
    if judge.holds_with_harmonics(_choices(taken), search.index, sets[-2], step):
        return True
    sets.pop()
    return False


def _choices(taken: dict[int, list[LawSet]]) -> dict[int, LawSet]:
    """Every element at the last set it took."""
    return {j: sets[-1] for j, sets in taken.items()}


def _simplest(judge: "_Judge", search: _Search, chosen: LawSet, judged: dict[int, LawSet]) -> LawSet:
    """Of the sets alike ``chosen`` in the kbar (itself included) whose single-harmonic FRF error is within
    ``min_gain`` of its own, the simplest (:func:`analysis.laws.simplicity`: fewest parameters, then fewest laws
    whose kbar depends on the amplitude, then fewest shape parameters); ``chosen`` where none is simpler. On data
    without harmonics a simpler set must also hold with the harmonics represented, every element at its choice
    (``judged``): a one-sided contact follows a symmetric gap's fundamental single-harmonic, but not the mean it
    drives: the two tie single-harmonic, the contact being no larger, while with harmonics it misses by far."""
    rules = judge.rules.ranking
    i = search.index
    own = simplicity(chosen.laws)
    alike = sorted((s for s in search.sets if s is not chosen and simplicity(s.laws) < own
                    and _alike(search, s, chosen, rules.false_alarm)),
                   key=lambda s: (simplicity(s.laws), s.criterion))
    limit = rules.min_gain * judge.single({i: chosen}).error
    return next((s for s in alike if judge.single({i: s}).error <= limit and _holds_as_simpler(judge, s, i, judged)),
                chosen)


def _holds_as_simpler(judge: "_Judge", s: LawSet, i: int, judged: dict[int, LawSet]) -> bool:
    """Whether ``s`` in element ``i``'s place leaves the FRF error with harmonics within ``min_gain`` of its
    choice's, the others at theirs; always on data with harmonics, where the kbar carries what the harmonics do."""
    if judge.kbar_judges:
        return True
    limit = judge.rules.ranking.min_gain * judge.multi(judged).error
    return judge.multi({**judged, i: s}).error <= limit


def discover(predictor: Predictor, samples: dict[str, ElementSamples], linear: frozenset[str],
             rules: DiscoveryRules = DiscoveryRules(), harmonics: HarmonicCriterion = HarmonicCriterion(),
             progress: Callable[[str], None] | None = None, robust: bool = False) -> Discovery:
    """The laws of every element of ``predictor.model`` that has none and has kbar samples (the overview in
    discovery.py).

    ``samples``: element name -> its identified kbar samples; ``linear``: the elements whose verdict is linear;
    ``robust``: the data carry no harmonics, so the kbar fits leave out the lines that do not follow them
    (:func:`_fit_set`). The other elements keep their laws. ``progress`` is called with a line of text as each
    element is searched.
    """
    searches: list[_Search] = []
    for i, el in enumerate(predictor.model.elements):
        s = samples.get(el.name)
        if el.laws or el.nonparametric is not None or s is None or len(s.X) < 3:
            continue
        searches.append(search_element(i, s, el.name in linear, rules, robust, el.surroundings))
        if progress is not None:
            best = searches[-1].sets[0]
            progress(f"discovery: {el.name}: {len(searches[-1].sets) - 1} sets of laws fitted to its kbar; "
                     f"best {best.name}")
    if not searches:
        return Discovery([])
    judge = _Judge(predictor, rules, harmonics, _standins(searches, robust), kbar_judges=not robust)
    elements = predictor.model.elements
    searches = [(_verdict_overruled(judge, search, rules, elements[search.index].surroundings)
                 if elements[search.index].name in linear else None) or search for search in searches]
    taken, walks = {}, {}
    judge.held = {search.index: search.best for search in searches}
    for search in searches:
        _offer_frf_best_single(judge, search)
        _offer_frf_best_alike(judge, search)
        taken[search.index], walks[search.index] = _walk_element(judge, search)
        judge.held[search.index] = taken[search.index][-1]
    index = {s.index: s for s in searches}
    _check_with_harmonics(judge, index, taken, walks)
    judged = {i: sets[-1] for i, sets in taken.items()}
    pruned = _pruned_beside_clearance(judge, index, judged)
    choice = {i: _simplest(judge, index[i], s, judged) for i, s in judged.items()}
    names = {i: el.name for i, el in enumerate(predictor.model.elements)}
    found = []
    for search in searches:
        chosen = choice[search.index]
        equivalents = [Separation(s.laws, _separation(search, chosen, s))
                       for s in _indistinguishable(judge, search, chosen)]
        found.append(ElementDiscovery(names[search.index], chosen, search.scale, len(search.sets) - 1,
                                      ([search.overruled] if search.overruled else [])
                                      + ([pruned[search.index]] if search.index in pruned else [])
                                      + _explanations(names[search.index], search, chosen), equivalents,
                                      walks.get(search.index, []),
                                      judged[search.index].laws if judged[search.index] is not chosen else None,
                                      _readings(search, walks.get(search.index, []))))
    by_index = {s.index: f for s, f in zip(searches, found)}
    return Discovery([by_index[i] for i in _order(judge, choice)])


def _readings(search: _Search, walk: list[WalkStep]) -> tuple[tuple[str, ...], ...]:
    """The sets the element's walk chose among, with one law or more (:attr:`ElementDiscovery.readings`): by size,
    each size's shortlist and then every other set of that size the walk tried -- beside the laws taken the walk
    tries every set that keeps them, and a set it refused for what the kbar cannot tell apart is as much a reading
    of the kbar as one the criterion ranked."""
    tried = [step.laws for step in walk]
    out: dict[frozenset, tuple[str, ...]] = {}
    for size in sorted((set(search.by_size) | {len(t) for t in tried}) - {0}):
        for laws in [*(s.laws for s in search.by_size.get(size, [])), *(t for t in tried if len(t) == size)]:
            out.setdefault(frozenset(laws), laws)
    return tuple(out.values())


def _order(judge: _Judge, choice: dict[int, LawSet]) -> list[int]:
    """The elements in the order their laws are best added one at a time: each time the one whose laws cut the
    (single-harmonic) error most with those already added and the rest still empty, so that the history falls
    step by step (a joint's laws added while another joint is still empty may show little alone)."""
    added: dict[int, LawSet] = {}
    order = []
    while len(order) < len(choice):
        rest = [i for i in choice if i not in added]
        errors = [c.error for c in judge.singles([{**added, i: choice[i]} for i in rest], standins=False)]
        best = rest[errors.index(min(errors))]
        added[best] = choice[best]
        order.append(best)
    return order
