"""The candidate sets of an element, fitted to its kbar (steps 1 and 2 of the overview in
analysis/search/discovery.py; docs/discovery.md).

Every set of one to ``max_laws`` laws of the library, at most one of each kind, is fitted to the element's kbar
samples with the screening settings: pairs all, triples only by extending the ``triple_pool`` best pairs, each
set started from its smaller sets' fits, the best sets with a contact law refitted placed in the element's
structure, and each set refitted from a larger set's fit that holds the other laws at no size. A set with a law
tied to another's is kept apart (named, never chosen) and a set with which the structure would not be admissible
is refused; every other set is charged for its parameters,
``chi2 / s^2 + p ln(2N)`` with s^2 the best set's reduced chi-square where it exceeds 1, and each size's shortlist
is drawn for the FRFs to judge. The kbar is the element's own, decoupled from the structure, so a fit costs
milliseconds and every set can be tried; nothing here predicts an FRF.

Also here, since it fits sets the same way: :func:`amplitude_dependence`, one amplitude-dependent law beside a
linear one tested against the noise, which can tell a linear verdict wrong.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import scipy.stats

from ..common.errors import InputError
from ..common.parallel import map_tasks
from ..common.statistics import capped_chi_square, charged_criterion, chi_square_shares, noise_scale
from ..fitting.fit import LawFit, fit_laws
from ..laws import LAWS
from ..mechanics.admissibility import admissibility
from ..mechanics.surroundings import Surroundings
from ..missing.diagnosis import ElementSamples, tied_parameters
from .records import DiscoveryRules, LawSet


@dataclass
class _Search:
    """The kbar stage of one element: every set fitted, the scale and each size's representative."""

    index: int
    samples: ElementSamples
    sets: list[LawSet]
    scale: float
    by_size: dict[int, list[LawSet]]   # the shortlist of each number of laws (:func:`_shortlists`)
    overruled: str = ""                # why the linearity verdict was set aside (:func:`_verdict_overruled`)
    tied: list[LawSet] = field(default_factory=list)   # sets with a law tied to another's: named, never chosen
    refused: list[LawSet] = field(default_factory=list)  # sets no discovery may take (:func:`_refusal`)

    @property
    def best(self) -> LawSet:
        """The set the kbar criterion prefers."""
        return min(self.sets, key=lambda s: s.criterion)


def law_sets(names: list[str], size: int) -> list[tuple[str, ...]]:
    """Every set of ``size`` laws out of ``names`` with at most one law of each kind."""
    return [combo for combo in itertools.combinations(names, size)
            if len({LAWS[n].kind for n in combo}) == size]


def _candidate_laws(linear_verdict: bool, placed: bool) -> list[str]:
    """The laws discovery may use on an element: those kbar can reveal; only laws without amplitude dependence
    where the element's verdict is linear (the verdict found nothing else to explain). A law whose formula's kbar
    is a linear spring's and which only its placement in the structure shows (bilinear: the zero-clearance limit
    of a one-sided contact beside a linear spring) enters where the element can be placed (``placed``) and its
    verdict is linear: where the kbar moves with amplitude, the contact law, whose clearance is searched, holds
    that limit already."""
    return [n for n, law in LAWS.items()
            if (law.visible_in_kbar or (law.placed and placed and linear_verdict))
            and not (linear_verdict and law.amplitude_dependent)]


def _place_contacts(by_laws: dict[tuple[str, ...], LawSet], samples: ElementSamples, rules: DiscoveryRules,
                    robust: bool, around: Surroundings) -> None:
    """The best ``placed_pool`` sets with a contact law (by the criterion of their fit with its formula alone), and
    every smaller set within them that keeps the contact law, refitted with it placed in the element's structure
    (docs/fitting.md, "Contact laws in their structure"); the rest keep the formula. A placed fit costs 0.1-1 s
    against milliseconds. The formula's misfit is what laws of other kinds beside it fill in, so by the formula's
    fit the larger sets lead; their smaller sets are placed too, so that a law only there to fill that misfit
    meets the set without it on equal terms."""
    n_obs = 2 * len(samples.X)
    scale = _scale(list(by_laws.values()), n_obs)
    contact = sorted((laws for laws in by_laws if any(LAWS[n].placed for n in laws)),
                     key=lambda laws: charged_criterion(by_laws[laws].chi_square, by_laws[laws].n_parameters, n_obs,
                                                        scale))
    chosen = []
    for laws in contact[:rules.placed_pool]:
        kept = [n for n in laws if LAWS[n].placed]
        chosen += [sub for size in range(1, len(laws) + 1) for sub in itertools.combinations(laws, size)
                   if set(kept) <= set(sub) and sub in by_laws]
    chosen = list(dict.fromkeys(chosen))
    # each placed refit needs nothing of the others
    refits = map_tasks(lambda k: _fit_set(samples, chosen[k], rules, robust, around, _own_start(by_laws[chosen[k]])),
                       len(chosen))
    for laws, s in zip(chosen, refits):
        if _separate(s):
            by_laws[laws] = s


def _fit_set(samples: ElementSamples, laws: tuple[str, ...], rules: DiscoveryRules, robust: bool,
             around: Surroundings | None = None, start: list[dict | None] | None = None) -> LawSet | None:
    """The set fitted with the screening settings; None where it cannot be fitted. A set one of whose laws adds no
    direction of its own (:func:`_adds_nothing`) is marked ``tied``: it is no set of separate effects, only
    another way of writing a smaller one, and is never chosen (:attr:`_Search.tied`). ``robust``: the fit leaves
    out the samples that do not follow it (data without harmonics, where no line could be left out as far from
    harmonic), and the set is judged by :func:`capped_chi_square`. ``start``: starting values per law, refined
    besides the grid's best point (:func:`_warm_start`)."""
    try:
        fit = fit_laws(list(laws), samples.X, samples.w, samples.kbar, samples.kbar_std, start,
                       grid_points=rules.screening_grid, n_starts=rules.screening_starts,
                       max_evaluations=rules.screening_evaluations, exclude_outliers=robust,
                       surroundings=around)
    except InputError:
        return None                                   # too few samples for this many parameters
    tied = len(laws) > 1 and any(_adds_nothing(fit, j, rules.max_correlation) for j in range(len(laws)))
    return LawSet(laws, fit, fit.judged_chi_square, fit.n_parameters, tied=tied)


def _reach_larger_fits(by_laws: dict[tuple[str, ...], LawSet], samples: ElementSamples, rules: DiscoveryRules,
                       robust: bool, around: Surroundings | None) -> None:
    """Each set refitted from a larger set's fit where that fit holds its other laws at no size and fits better:
    that fit *is* a fit of the smaller set, which its own search missed (``by_laws`` is changed in place). A set
    is searched from the grid and from its smaller sets' fits; a local search that stops in another valley leaves
    the set worse than the same laws with a law of no size beside them, and which valley it stops in can turn on
    round-off (docs/discovery.md, "How stable an answer is"). The refit starts at those values too, fitted as the
    larger set was (its contact placed in the structure or by its formula), and is kept where it fits better. A
    placed fit is not refitted as a formula's: the placement is the more faithful of the two
    (:func:`_place_contacts`)."""
    for laws in sorted(by_laws, key=len):
        own = by_laws[laws]
        reached = [s for s in by_laws.values() if set(laws) < set(s.laws) and s.chi_square < own.chi_square
                   and (_placed(s) or not _placed(own)) and _others_of_no_size(s, laws)]
        if not reached:
            continue
        best = min(reached, key=lambda s: s.chi_square)
        refit = _fit_set(samples, laws, rules, robust, around if _placed(best) else None, _start_from(best, laws))
        if _separate(refit) and refit.chi_square < own.chi_square:
            by_laws[laws] = refit


def _placed(s: LawSet) -> bool:
    """Whether ``s`` was fitted with a contact placed in its structure (:func:`_place_contacts`)."""
    return s.fit is not None and any(t.surroundings is not None for t in s.fit.terms)


def _others_of_no_size(s: LawSet, laws: tuple[str, ...]) -> bool:
    """Whether every law of ``s`` outside ``laws`` has each of its size parameters (its ``linear``, the force
    scale) at exactly zero: it adds nothing to the kbar."""
    return s.fit is not None and all(t.params.get(n, 1.0) == 0.0 for name, t in zip(s.laws, s.fit.terms)
                                     if name not in laws for n in t.law.linear)


def _separate(s: LawSet | None) -> bool:
    """Whether ``s`` was fitted and is a set of separate effects (not ``tied``)."""
    return s is not None and not s.tied


def _warm_start(laws: tuple[str, ...], by_laws: dict[tuple[str, ...], LawSet]) -> list[dict | None] | None:
    """Starting values for a set from the fits of its smaller sets: each law with shape parameters at its values
    in the largest smaller set that holds it (of those, the best fitting); None where no law of the set has a
    shape parameter or none was fitted. The grid's best point alone can lead the local search to a minimum where
    one law takes what the other explains: a cubic beside a gap, refined from the grid, kept the cubic alone
    and the gap at no stiffness, while the gap's own fit started both right."""
    start: list[dict | None] = []
    within = [s for sub, s in by_laws.items() if set(sub) < set(laws) and s.fit is not None]
    for name in laws:
        smaller = [s for s in within if name in s.laws]
        if not LAWS[name].shape or not smaller:
            start.append(None)
            continue
        best = max(smaller, key=lambda s: (len(s.laws), -s.chi_square))
        start.append(_start_values(best, name))
    return start if any(v is not None for v in start) else None


def _own_start(s: LawSet) -> list[dict | None] | None:
    """Starting values for a placed refit of ``s``: where its fit with the laws' formulas stands (started from its
    smaller sets, :func:`_warm_start`), each law with shape parameters at its values there; None where none has
    any. A placed fit begins with a fit of the formulas of its own (docs/fitting.md, "Contact laws in their
    structure"), from its grid's best point and from these values, the better kept: from the grid alone a contact
    beside a law that holds most of the kbar can run to no stiffness, where its gap moves nothing and the search
    stops, and the set is read as the other law alone although the fit of its formulas had found the contact."""
    return _start_from(s, s.laws)


def _start_from(s: LawSet, laws: tuple[str, ...]) -> list[dict | None] | None:
    """Starting values for ``laws`` (all of them laws of ``s``) from the fit of ``s``: each law with shape
    parameters at its values there; None where ``s`` has no fit or none of ``laws`` has a shape parameter."""
    if s.fit is None:
        return None
    start = [_start_values(s, name) if LAWS[name].shape else None for name in laws]
    return start if any(v is not None for v in start) else None


def _start_values(s: LawSet, name: str) -> dict | None:
    """Law ``name``'s values in the fit of ``s`` as a start; None where one is at a bound the fit may reach but
    a start may not take."""
    values = dict(s.fit.terms[s.laws.index(name)].params)
    try:
        LAWS[name].check_params(values)
    except InputError:
        return None
    return values


def _adds_nothing(fit: LawFit, j: int, max_correlation: float) -> bool:
    """Whether every parameter of law ``j`` of the set is tied to another law's
    (:func:`analysis.missing.diagnosis.tied_parameters`): the law is then no separate effect, only another way of
    writing the others. A law with some parameters tied and others free stays: a linear law beside an Iwan
    element in micro-slip trades its stiffness with the Iwan's, but its damping is its own (a reference whose
    damping is wrong at the joint)."""
    tied = tied_parameters(fit, {j}, max_correlation)
    prefix = fit.terms[j].label + "."
    return all(name in tied for name in fit.fit_parameter_names if name.startswith(prefix))


def _chi_square(misfit: np.ndarray, std: np.ndarray | None, robust: bool) -> float:
    """The samples' chi-square, capped as the sets' on data without harmonics (``robust``)."""
    z = chi_square_shares(misfit, std)
    return capped_chi_square(z) if robust else float(np.sum(z))


def _empty_set(samples: ElementSamples, robust: bool) -> LawSet:
    return LawSet((), None, _chi_square(samples.kbar, samples.kbar_std, robust), 0)


def _scale(sets: list[LawSet], n_obs: int) -> float:
    """s^2: the reduced chi-square of the best-fitting set, at least 1 (the overview in discovery.py, step 2)."""
    best = min(sets, key=lambda s: s.chi_square)
    return noise_scale(best.chi_square, n_obs, best.n_parameters)


def search_element(index: int, samples: ElementSamples, linear_verdict: bool,
                   rules: DiscoveryRules = DiscoveryRules(), robust: bool = False,
                   around: Surroundings | None = None) -> _Search:
    """The kbar stage of one element (the overview in discovery.py, steps 1 and 2; ``robust``: :func:`_fit_set`;
    ``around``: the structure around the element, where the best sets with a contact law are refitted placed,
    :func:`_place_contacts`)."""
    names = _candidate_laws(linear_verdict, around is not None)
    sets = [_empty_set(samples, robust)]
    by_laws: dict[tuple[str, ...], LawSet] = {}
    tied: list[LawSet] = []

    def keep(s: LawSet | None) -> None:
        if _separate(s):
            by_laws[s.laws] = s
        elif s is not None:
            tied.append(s)

    def fit_all(many: list[tuple[str, ...]]) -> None:
        """Sets of one size, each started from the smaller sets already fitted: they need nothing of each other."""
        for s in map_tasks(lambda k: _fit_set(samples, many[k], rules, robust, start=_warm_start(many[k], by_laws)),
                           len(many)):
            keep(s)

    for size in range(1, min(rules.max_laws, 2) + 1):
        fit_all(list(law_sets(names, size)))
    if rules.max_laws >= 3:
        pairs = sorted((s for s in by_laws.values() if len(s.laws) == 2), key=lambda s: s.chi_square)
        triples = (tuple(sorted(pair.laws + (extra,), key=names.index))
                   for pair in pairs[:rules.triple_pool] for extra in names)
        fit_all([laws for laws in dict.fromkeys(triples)
                 if len(set(laws)) == 3 and len({LAWS[n].kind for n in laws}) == 3])
    if around is not None:
        _place_contacts(by_laws, samples, rules, robust, around)
    _reach_larger_fits(by_laws, samples, rules, robust, around)
    refused = [s for s in by_laws.values() if _refusal(s, samples, around)]
    sets += [s for s in by_laws.values() if not any(s is r for r in refused)]
    n_obs = 2 * len(samples.X)
    scale = _scale(sets, n_obs)
    for s in sets + tied:
        s.criterion = charged_criterion(s.chi_square, s.n_parameters, n_obs, scale)
    sets.sort(key=lambda s: s.criterion)
    tied.sort(key=lambda s: s.criterion)
    return _Search(index, samples, sets, scale, _shortlists(sets, rules.walk_width), tied=tied, refused=refused)


def _refusal(s: LawSet, samples: ElementSamples, around: Surroundings | None) -> str:
    """Why a fitted set is no discovery however it scores ('' where nothing): the structure with the element at
    its fitted laws is not admissible at the samples' states -- it would give energy back, or lose its static
    stiffness (analysis/mechanics/admissibility.py). The element is judged in the reference alone, the other
    elements absent: their laws are not known yet, and a joint's own laws must not rest on another's damping.

    A set whose fit leaves out many lines as outliers is not refused here: on data without harmonics the lines
    where a friction sticks or a contact closes follow no describing function, and a right set leaves them out
    (docs/fitting.md, "Outliers"); the report says when a fit leaves out more than a tenth."""
    if s.fit is None or around is None:
        return ""
    check = admissibility(around.structure, [around.vector], [s.describing_function], samples.X[:, None], samples.w)
    if not check.passive:
        return "the element would give energy back to the structure (not passive)"
    if not check.stiff:
        return "the structure's static stiffness would turn negative"
    return ""


@dataclass(frozen=True)
class AmplitudeDependence:
    """A law whose kbar depends on the amplitude, fitting an element's kbar beside a linear law better than the
    linear law alone by more than the noise explains (:func:`amplitude_dependence`)."""

    law: str
    chi_square_drop: float            # in units of the noise, s^2 taken out
    threshold: float                  # its quantile, the false alarm shared among the laws tried
    laws_tried: int

    def text(self) -> str:
        return (f"{self.law} beside a linear law lowers the kbar's chi-square by {self.chi_square_drop:.3g} against "
                f"{self.threshold:.3g} that noise would reach once in a thousand among the {self.laws_tried} "
                "amplitude-dependent laws tried: the kbar depends on the amplitude where that law says")


def amplitude_dependence(samples: ElementSamples, rules: DiscoveryRules = DiscoveryRules(),
                         robust: bool = False) -> AmplitudeDependence | None:
    """The amplitude-dependent law of the library that departs most from a linear law on the element's kbar, where
    it departs by more than the noise explains; None where none does. The linearity verdict tests against every
    departure at once, its degrees of freedom spread over every line; one law's signature on the few lines of
    highest amplitude can stay below it, and the verdict then calls linear an element whose law, fitted alone
    beside a linear one, lowers the chi-square well beyond the noise. The law's size
    must be seen (:attr:`analysis.fitting.fit.TermFit.size_unseen`); the drop is taken in units of the best fit's
    reduced chi-square where that exceeds 1."""
    base = _fit_set(samples, ("linear",), rules, robust)
    if base is None:
        return None
    names = [n for n, law in LAWS.items() if law.visible_in_kbar and law.amplitude_dependent]
    fitted = [s for s in (_fit_set(samples, ("linear", n), rules, robust) for n in names)
              if _separate(s) and not s.fit.terms[1].size_unseen]
    if not fitted:
        return None
    scale = _scale(fitted + [base], 2 * len(samples.X))
    found = []
    for s in fitted:
        drop = (base.chi_square - s.chi_square) / scale
        threshold = float(scipy.stats.chi2.isf(rules.ranking.false_alarm / len(names),
                                               s.n_parameters - base.n_parameters))
        if drop > threshold:
            found.append(AmplitudeDependence(s.laws[1], drop, threshold, len(names)))
    return max(found, key=lambda d: d.chi_square_drop - d.threshold, default=None)


def _determined(s: LawSet) -> bool:
    return s.fit is not None and not any(t.undetermined for t in s.fit.terms)


def _shortlists(sets: list[LawSet], width: int) -> dict[int, list[LawSet]]:
    """Per number of laws, the sets the FRFs judge (``sets`` sorted by the criterion): the ``width`` best that
    fit the kbar differently (of sets with the same chi-square, as Coulomb and a stiff Jenkins element, only the
    first), and the best whose parameters the kbar all determines. Where lines depart from every describing
    function (friction whose harmonics the data do not carry) the kbar criterion can prefer a law with a
    parameter run to its limit -- a saturating spring turned into a sign function -- over the true one by a
    little, and the FRFs tell them apart by far."""
    out: dict[int, list[LawSet]] = {}
    for s in sets:
        mine = out.setdefault(len(s.laws), [])
        fits_alike = any(abs(s.chi_square - t.chi_square) <= 1e-6 * max(t.chi_square, 1e-300) for t in mine)
        if len(mine) < width and not fits_alike:
            mine.append(s)
    for size, mine in out.items():
        if not any(_determined(s) for s in mine):
            best = next((s for s in sets if len(s.laws) == size and _determined(s)), None)
            if best is not None:
                mine.append(best)
    return out
