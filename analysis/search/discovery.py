"""Model discovery: the laws of every element that has none, found from an empty law set (docs/discovery.md).

A user knows the structure and where the joints are, not a single law. The closed-form identification gives
every element its own kbar samples with their noise, so the elements' laws can be chosen where the elements are
decoupled, at the cost of a kbar fit each, and the coupled FRFs only judge the few best choices:

1. **Sets of laws, fitted to the element's kbar.** Every set of one to ``max_laws`` laws of the library, at most
   one of each kind (:data:`analysis.laws.base.KINDS`: one joint has one stiffness mechanism, one damping, one
   friction...), is fitted to the element's kbar samples (pairs all; triples extend the ``triple_pool`` best pairs).
   A set in which one law adds no direction of its own (every parameter of it tied to another law's, by an exact
   degeneracy or a correlation beyond ``max_correlation``) is not a set of separate effects and is never chosen,
   only named as a reading the data cannot part (step 3). Where
   the element's verdict is linear, only laws without amplitude dependence enter. Data without harmonics: the
   fits leave out the lines that do not follow them, and sets are judged by :func:`capped_chi_square`.
2. **A criterion that charges for parameters.** ``chi2 / s^2 + p ln(2N)`` (BIC in the kbar noise), with ``s^2``
   the reduced chi-square of the best-fitting set where it exceeds 1: no law of the library fits a kbar the
   single-harmonic describing function cannot represent (friction that sticks for part of the cycle), and that
   remainder is noise to every set alike, not evidence for a richer one.
3. **Equivalent sets are named.** Sets of as many laws that fit the kbar neither better nor worse than each other
   by more than the noise explains (``|chi2_a - chi2_b| <= s^2 q``, ``q`` the chi-square quantile at
   ``false_alarm``) are alike (:func:`_alike`). Of those alike the FRFs' choice, the simplest is taken
   (:func:`_simplest`); the others are listed as *indistinguishable on these data* with the test that would
   separate them (where their describing functions part: a lower or higher level, another band), and so are
   sets of one law more that read the kbar otherwise and as well, a set with a tied law among them
   (:func:`_one_law_more_alike`).
4. **The FRFs judge the size.** Each element's shortlists (:func:`_shortlists`), with every set one or two laws
   larger than its current choice (:func:`_extension`), are walked from no law upward, every other searched element
   represented meanwhile by its own measured kbar (a stand-in, :func:`_standins`), so that no element's choice
   waits on another's: of each size the set the kbar criterion prefers among those whose single-harmonic FRF
   error is within ``min_gain`` of the best is tried, and taken only if the kbar criterion prefers it to the
   current choice too (on data without harmonics: beside laws taken, its chi-square falls by more than the noise
   explains, :func:`_beside_above_noise`; beside friction, by more than the force that turns the friction's
   fundamental fits, :func:`_not_seen_beside_friction`, the set without a law that fails it tried in its place,
   :func:`_took_instead`) and no set alike it in the kbar, with no more parameters and an FRF
   error within ``min_gain``, has laws of other kinds (neither on data without harmonics, where the capped criterion can
   prefer no law to a right one), every law of it is seen in the kbar (:func:`_unseen_laws`) and seen as itself,
   not only in a limit of its amplitude scale, below or beyond every amplitude (:func:`_limit_only_laws`), and it
   cuts the error of the current choice by ``min_gain`` for every law it adds and the FRF chi-square by more than
   the noise explains; a set not seen as itself, or not called for beside the laws taken, gives way to the next
   (:func:`_preferred`). On data without harmonics the single-harmonic FRFs decide against the kbar only where
   the FRFs with harmonics agree: a step the kbar calls for beyond the noise is judged with harmonics where they
   refuse it (:meth:`_Judge._gains_with_harmonics`), and the set the kbar ranks first beyond the noise stays
   first where they overrule it (:func:`_overruled_single_harmonically_only`).
   Then -- the model-form check, with every element at its choice -- each element's last step must do the same
   with the lines that carry harmonics predicted multi-harmonically (unless its gain is beyond ``certain_gain``
   and the data carry harmonics or the step is the element's first law), or it is taken back. A law that fits
   only what one harmonic cannot represent, or a wrong law standing in for part of a kbar, gains too little
   there. On data without harmonics a set with a clearance law is also judged at its parameters refined against
   the FRFs, and a law beside a clearance is taken back where, every element refined, it gains less than
   ``min_gain`` (:func:`_overruled_at_kbar_fit_only`, :meth:`_Judge.fitted_single`,
   :func:`_pruned_beside_clearance`; docs/discovery.md, "A clearance judged at its refined parameters").

The chosen laws' explanations are written from the *partial* kbar each law explains (the samples less the other
laws of the set), so the log-slopes printed beside a law are the ones it fits; a law whose own signature departs
from them says so.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import scipy.stats

from ..common.errors import InputError
from ..common.statistics import (capped_chi_square, charged_criterion, chi_square_noise_bound, chi_square_shares,
                                 falls_above_noise, noise_scale, part_weight)
from ..fitting.fit import UNDETERMINED_Z, LawFit, TermFit, fit_laws, unit_exponents
from ..fitting.friction_fundamental import chi_square_with_friction_turn, holds_friction
from ..laws import LAWS
from ..mechanics.admissibility import admissibility
from ..mechanics.nonparametric import fit_nonparametric
from ..mechanics.surroundings import Surroundings
from ..missing.diagnosis import ElementSamples, RankingRules, explain, frf_criterion, signature, tied_parameters
from ..prediction.comparison import Comparison, HarmonicCriterion, Predictor, gain_phrase, kbar_functions_with
from ..prediction.frf_refinement import FrfRefinement, refine_against_frfs, terms_function


@dataclass(frozen=True)
class DiscoveryRules:
    """The settings of model discovery (module docstring)."""

    max_laws: int = 3                 # laws in one set at most
    triple_pool: int = 8              # best pairs extended to sets of three
    walk_width: int = 3               # sets of each size the FRFs judge (:func:`_shortlists`)
    max_correlation: float = 0.995    # parameters of two laws of a set this correlated: not separate effects
    screening_grid: int = 4           # shape-parameter grid points per parameter while sets are screened
    screening_starts: int = 1         # local searches per screening fit
    screening_evaluations: int = 30   # residual evaluations per local search while screening
    placed_pool: int = 8              # best sets with a contact law refitted placed (with their smaller sets)
    ranking: RankingRules = RankingRules()   # min_gain, certain_gain, false_alarm, model_form_thd


@dataclass
class LawSet:
    """One set of laws fitted to one element's kbar."""

    laws: tuple[str, ...]
    fit: LawFit | None                # None for the empty set
    chi_square: float
    n_parameters: int
    criterion: float = np.inf         # chi2 / s^2 + p ln(2N), set once s^2 is known
    tied: bool = False                # a law of it adds no direction of its own (:func:`_adds_nothing`)

    @property
    def name(self) -> str:
        return "+".join(self.laws) if self.laws else "no law"

    def describing_function(self, X, w) -> np.ndarray:
        X, w = np.broadcast_arrays(np.asarray(X, float), np.asarray(w, float))
        return self.fit.describing_function(X, w) if self.fit is not None else np.zeros(X.shape, complex)


@dataclass
class Separation:
    """Where an indistinguishable set's describing function parts from the chosen one's."""

    laws: tuple[str, ...]
    test: str                          # the test that would separate them, in words

    def to_json(self) -> dict:
        return {"laws": list(self.laws), "test": self.test}


@dataclass
class WalkStep:
    """One comparison of the walk: a set tried against the element's current choice, with the FRF errors."""

    laws: tuple[str, ...]
    error: float                       # single-harmonic FRF error with it
    error_before: float                # ... with the current choice
    taken: bool
    multiharmonic_gain: float | None = None
    why: str = ""
    not_itself: bool = False           # not taken because the kbar does not show a law of it as itself, or does
    #                                    not call for it beside the laws taken: the next set of its size is tried
    seen_in_frfs: str = ""             # the sizes the FRFs determine where the kbar leaves them open
    instead: tuple[str, ...] = ()      # the set without a law the kbar does not show beside friction, to try next
    by_kbar: bool = False              # refused for what the element's own kbar shows (:meth:`_Judge._veto`), which
    #                                    the laws the other elements take do not change

    @property
    def gain(self) -> float:
        return self.error_before / self.error if self.error > 0 else float("inf")

    def text(self) -> str:
        name = "+".join(self.laws) if self.laws else "no law"
        mh = "" if self.multiharmonic_gain is None else f", {gain_phrase(self.multiharmonic_gain)} with harmonics"
        verdict = "taken" if self.taken else f"not taken{': ' + self.why if self.why else ''}"
        if self.taken and self.seen_in_frfs:
            verdict += f" (its kbar leaves the size open; the FRFs refined give {self.seen_in_frfs})"
        return f"{name}: {self.error:.3g} ({gain_phrase(self.gain)} single-harmonic{mh}), {verdict}"

    def to_json(self) -> dict:
        return {"laws": list(self.laws), "error": self.error, "error_before": self.error_before, "gain": self.gain,
                "taken": self.taken, "multiharmonic_gain": self.multiharmonic_gain, "why": self.why,
                "seen_in_frfs": self.seen_in_frfs, "by_kbar": self.by_kbar}


@dataclass
class ElementDiscovery:
    """What discovery found for one element."""

    element: str
    chosen: LawSet
    scale: float                       # s^2: the best set's reduced chi-square, at least 1
    sets_fitted: int
    explanations: list[str]
    equivalents: list[Separation] = field(default_factory=list)
    walk: list[WalkStep] = field(default_factory=list)
    simplified_from: tuple[str, ...] | None = None   # the set the FRFs took, where a simpler alike one replaced it

    @property
    def laws(self) -> tuple[str, ...]:
        return self.chosen.laws

    def text(self) -> str:
        out = [f"{self.element}: {self.chosen.name} ({self.chosen.n_parameters} parameter(s); {self.sets_fitted} "
               f"sets of up to three laws fitted to its kbar)"]
        out += [f"  {e}" for e in self.explanations]
        if self.equivalents:
            out.append("  indistinguishable on these data (they fit its kbar as well, and the FRFs within the margin "
                       "a law must bring; the fewest parameters are taken): "
                       + "; ".join(f"{'+'.join(s.laws)} ({s.test})" for s in self.equivalents))
        if self.walk:
            out.append("  judged by the FRFs: " + "; ".join(s.text() for s in self.walk))
        if self.simplified_from:
            out.append(f"  taken as {self.chosen.name} rather than {'+'.join(self.simplified_from)}: it fits the "
                       "kbar as well with fewer parameters or fewer laws whose kbar depends on the amplitude")
        return "\n".join(out)

    def to_json(self) -> dict:
        return {"element": self.element, "laws": list(self.chosen.laws), "n_parameters": self.chosen.n_parameters,
                "kbar_chi_square": self.chosen.chi_square, "kbar_scale": self.scale,
                "sets_fitted": self.sets_fitted, "explanations": self.explanations,
                "indistinguishable": [s.to_json() for s in self.equivalents],
                "walk": [s.to_json() for s in self.walk],
                "simplified_from": None if self.simplified_from is None else list(self.simplified_from)}


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


def _candidate_laws(linear_verdict: bool) -> list[str]:
    """The laws discovery may use on an element: those kbar can reveal; only laws without amplitude dependence
    where the element's verdict is linear (the verdict found nothing else to explain)."""
    return [n for n, law in LAWS.items()
            if law.visible_in_kbar and not (linear_verdict and law.amplitude_dependent)]


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
    for laws in dict.fromkeys(chosen):
        s = _fit_set(samples, laws, rules, robust, around)
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
    chi2 = capped_chi_square(np.abs(fit.normalized_residuals) ** 2) if robust else fit.chi_square
    return LawSet(laws, fit, chi2, fit.n_parameters, tied=tied)


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
        values = dict(best.fit.terms[best.laws.index(name)].params)
        try:
            LAWS[name].check_params(values)
        except InputError:                # a value at a bound the fit may reach but a start may not take
            values = None
        start.append(values)
    return start if any(v is not None for v in start) else None


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
    """s^2: the reduced chi-square of the best-fitting set, at least 1 (module docstring, step 2)."""
    best = min(sets, key=lambda s: s.chi_square)
    return noise_scale(best.chi_square, n_obs, best.n_parameters)


def search_element(index: int, samples: ElementSamples, linear_verdict: bool,
                   rules: DiscoveryRules = DiscoveryRules(), robust: bool = False,
                   around: Surroundings | None = None) -> _Search:
    """The kbar stage of one element (module docstring, steps 1 and 2; ``robust``: :func:`_fit_set`; ``around``:
    the structure around the element, where the best sets with a contact law are refitted placed,
    :func:`_place_contacts`)."""
    names = _candidate_laws(linear_verdict)
    sets = [_empty_set(samples, robust)]
    by_laws: dict[tuple[str, ...], LawSet] = {}
    tied: list[LawSet] = []

    def keep(s: LawSet | None) -> None:
        if _separate(s):
            by_laws[s.laws] = s
        elif s is not None:
            tied.append(s)

    for size in range(1, min(rules.max_laws, 2) + 1):
        for laws in law_sets(names, size):
            keep(_fit_set(samples, laws, rules, robust, start=_warm_start(laws, by_laws)))
    if rules.max_laws >= 3:
        pairs = sorted((s for s in by_laws.values() if len(s.laws) == 2), key=lambda s: s.chi_square)
        tried = set()
        for pair in pairs[:rules.triple_pool]:
            for extra in names:
                laws = tuple(sorted(pair.laws + (extra,), key=names.index))
                if len(set(laws)) < 3 or laws in tried or len({LAWS[n].kind for n in laws}) < 3:
                    continue
                tried.add(laws)
                keep(_fit_set(samples, laws, rules, robust, start=_warm_start(laws, by_laws)))
    if around is not None:
        _place_contacts(by_laws, samples, rules, robust, around)
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


def _noise_bound(search: _Search, dof: int, false_alarm: float) -> float:
    """The kbar chi-square difference the noise explains at the false-alarm rate for ``dof`` parameters (at least
    one): s^2 chi2_q."""
    return chi_square_noise_bound(search.scale, dof, false_alarm)


def _fits_better(search: _Search, better: LawSet, worse: LawSet, false_alarm: float) -> bool:
    """Whether ``better`` fits the element's kbar better than ``worse`` by more than the noise explains for the
    parameters it adds."""
    return falls_above_noise(worse.chi_square, better.chi_square, better.n_parameters - worse.n_parameters,
                             search.scale, false_alarm)


def _alike(search: _Search, a: LawSet, b: LawSet, false_alarm: float) -> bool:
    """Whether two sets of as many laws fit the element's kbar neither better nor worse than each other by more
    than the noise explains (module docstring, step 3)."""
    return (len(a.laws) == len(b.laws) and abs(a.chi_square - b.chi_square)
            <= _noise_bound(search, abs(a.n_parameters - b.n_parameters), false_alarm))


def _simplest(judge: "_Judge", search: _Search, chosen: LawSet, judged: dict[int, LawSet]) -> LawSet:
    """Of the sets alike ``chosen`` in the kbar (itself included) whose single-harmonic FRF error is within
    ``min_gain`` of its own, the one with the fewest parameters, then the fewest laws whose kbar depends on the
    amplitude (a linear spring before a preloaded one-sided contact that never opens, which is the same spring);
    ``chosen`` where none is simpler by these. On data without harmonics a simpler set must also hold with the
    harmonics represented, every element at its choice (``judged``): a one-sided contact follows a symmetric gap's
    fundamental single-harmonic, but not the mean it drives: the two tie single-harmonic, the contact being no
    larger, while with harmonics it misses by far."""
    rules = judge.rules.ranking
    i = search.index

    def simpler(s: LawSet) -> tuple[int, int]:
        return s.n_parameters, sum(LAWS[n].amplitude_dependent for n in s.laws)

    alike = sorted((s for s in search.sets if s is not chosen and simpler(s) < simpler(chosen)
                    and _alike(search, s, chosen, rules.false_alarm)), key=lambda s: (simpler(s), s.criterion))
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


def _unseen_laws(s: LawSet, current: LawSet) -> list[str]:
    """The laws ``s`` adds to ``current`` whose size the kbar does not determine: every one of its linear
    parameters (the law's ``linear``, its force scale) has a 95 % interval that holds zero, or no finite error.
    Such a law fits nothing of the element's kbar; an FRF gain with it is another element's or the harmonics'
    (a velocity stiffness whose gamma's interval held zero gained x1.36 beside a gap at the other joint). A law
    whose stiffness trades with another's but whose damping is its own is seen (the beam's tangential linear
    law beside the Iwan: k and kt have no finite error alone, c = -5.0e-4 +- 0.95e-4)."""
    if s.fit is None:
        return []
    return [t.law.name for t in s.fit.terms if t.law.name not in current.laws and t.size_unseen]


def _unseen_why(unseen: list[str]) -> str:
    return f"its kbar does not show {unseen[0]}: every size parameter of it is within its 95 % interval of zero"


def _linear_within_noise(term: TermFit, samples: ElementSamples, false_alarm: float) -> bool:
    """Whether a law's kbar over the samples is its value at a vanishing amplitude -- a constant spring -- to within
    the noise: what it adds to a linear law is then not seen."""
    if samples.kbar_std is None:
        return False
    own = term.law.describing_function(samples.X, samples.w, **term.params)
    limit = term.law.describing_function(1e-6 * samples.X.min(), samples.w, **term.params)
    return _within_noise(own - limit, samples, term, false_alarm)


def _within_noise(misfit: np.ndarray, samples: ElementSamples, term: TermFit, false_alarm: float) -> bool:
    """Whether a law's kbar departs from a simpler form by ``misfit`` within the noise: a chi-square below the
    false-alarm quantile for the law's shape parameters."""
    z = float(np.sum(chi_square_shares(misfit, samples.kbar_std)))
    return bool(np.isfinite(z) and z < scipy.stats.chi2.ppf(1 - false_alarm, max(len(term.law.shape), 1)))


def _seen_as_its_tail(term: TermFit, samples: ElementSamples, false_alarm: float) -> bool:
    """Whether a law's kbar over the samples is, within the noise, a spring and a force of constant size in phase
    with the displacement (Re kbar = a + b / X, Im kbar constant): what a clearance or a saturating spring whose
    amplitude scale lies below every amplitude measured shows of itself (a gap g far below X: kbar = k (1 -
    4 g / (pi X)) to order (g / X)^3). Such a law is seen only as its limit, a spring, and the constant force
    beside it is no law of the library: on data without harmonics it fits the few smallest lines of a friction
    contact, whose kbar departs from every describing function, and such a law can then take a linear spring's
    place beside the friction."""
    if samples.kbar_std is None:
        return False
    own = term.law.describing_function(samples.X, samples.w, **term.params)
    weight = part_weight(samples.kbar_std)
    tail = np.column_stack([np.ones_like(samples.X), 1.0 / samples.X]) * weight[:, None]
    re_coef = np.linalg.lstsq(tail, own.real * weight, rcond=None)[0]
    im_mean = np.sum(own.imag * weight ** 2) / np.sum(weight ** 2)
    return _within_noise(own - (re_coef[0] + re_coef[1] / samples.X) - 1j * im_mean, samples, term, false_alarm)


def _fits_as_its_linear_limit(search: "_Search", s: LawSet, name: str, false_alarm: float,
                              frfs_part: Callable[[LawSet, LawSet], bool] | None = None) -> bool:
    """Whether ``s`` with a linear law in the place of law ``name`` (or without it, where ``s`` has a linear law
    already) fits the kbar as well within the noise: what ``name`` adds to a linear spring is then not seen,
    though its kbar over the samples may bend by more than the noise where another law's misfit pulls it (the
    sticking lines of friction beside a softer joint, which a saturating spring can fit with its kbar well off
    its linear limit at the smallest amplitudes, while linear + Coulomb fits the kbar as well).
    ``frfs_part(limit, s)``: whether the FRFs tell the two apart beyond doubt, where the kbar's
    chi-square is capped (:meth:`_Judge.frfs_part`); the law is then seen."""
    laws = (set(s.laws) - {name}) | {"linear"}
    limit = next((t for t in search.sets if set(t.laws) == laws), None)
    if limit is None:
        return False
    as_well = limit.chi_square - s.chi_square <= _noise_bound(search, s.n_parameters - limit.n_parameters,
                                                               false_alarm)
    return as_well and (frfs_part is None or not frfs_part(limit, s))


def _limit_only_laws(s: LawSet, current: LawSet, search: "_Search", false_alarm: float,
                     frfs_part: Callable[[LawSet, LawSet], bool] | None = None) -> list[tuple[str, str]]:
    """The laws ``s`` adds to ``current`` that the kbar shows only in a limit of their amplitude scale: a shape
    parameter that is a length (or its inverse) puts the law's scale below the smallest amplitude measured, and
    its 95 % interval holds zero or it has no finite error -- the samples would fit as well with it smaller still
    -- or above the largest (the test there is below). Such a law is not seen as itself but as its limit, which is
    either another law of the library (a Jenkins element whose slip displacement vanishes is Coulomb friction, a
    clearance that vanishes a spring, a saturating spring that saturates beyond every amplitude a linear one) or no law at all (a
    saturating spring saturated below every amplitude is a force of constant size in phase with the displacement,
    sgn x: on data without harmonics it fitted the sticking lines of a friction contact, and beside them a
    velocity stiffness, x2.4 in the FRFs). Beyond the largest amplitude the law is its linear limit where its
    kbar over the samples is that limit within the noise (:func:`_linear_within_noise`; a tanh spring standing
    for a softer joint beside Coulomb friction, its scale 1/beta far above every amplitude measured), whether
    or not the noise determines the scale at 2 sigma, or where the set with a linear law in its place fits the
    kbar as well (:func:`_fits_as_its_linear_limit`); an undetermined scale alone says
    nothing there (an Iwan element in micro-slip has its slip displacement beyond every amplitude, tied to its
    other shape parameters, and its kbar is far from linear: "beam jenkins" of the matrix). Returns (law, the
    limit in words)."""
    if s.fit is None:
        return []
    samples = search.samples
    x_min, x_max = float(samples.X.min()), float(samples.X.max())
    names = s.fit.fit_parameter_names
    errors = np.sqrt(np.abs(np.diag(s.fit.covariance)))
    out = []
    for term in s.fit.terms:
        if term.law.name in current.laws:
            continue
        for p in term.law.shape:
            length = unit_exponents(p.unit)[1]
            key = f"{term.label}.{p.name}"
            if abs(length) != 1 or key not in names:
                continue
            value, err = term.fit_params[p.name], errors[names.index(key)]
            if value == 0:
                continue
            undetermined = not (np.isfinite(err) and abs(value) >= UNDETERMINED_Z * err)
            scale = abs(value) ** length
            if scale < x_min and undetermined:
                out.append((term.law.name, "its amplitude scale lies below the smallest amplitude measured and is "
                                           "not determined"))
                break
            if scale < x_min and _seen_as_its_tail(term, samples, false_alarm):
                out.append((term.law.name, "its amplitude scale lies below the smallest amplitude measured, where "
                                           "its kbar is a spring's and a force of constant size in phase with the "
                                           "displacement within the noise"))
                break
            if scale <= x_max:
                continue
            above = "its amplitude scale lies above the largest amplitude measured, "
            if _linear_within_noise(term, samples, false_alarm):
                out.append((term.law.name, above + "where its kbar is a linear spring's within the noise"))
                break
            if _fits_as_its_linear_limit(search, s, term.law.name, false_alarm, frfs_part):
                out.append((term.law.name, above + "and a linear spring in its place fits the kbar as well within "
                                                   "the noise"))
                break
    return out


def _beside_above_noise(search: _Search, current: LawSet, larger: LawSet, false_alarm: float) -> bool:
    """On data without harmonics, where the kbar criterion does not judge a step: whether ``larger`` fits the kbar
    better than the laws taken (``current``, not none) by more than the noise explains at the false-alarm rate,
    its capped chi-square falling by more than s^2 chi2_q(dof of the parameters added). A law beside others can
    fit part of the lines that depart from every describing function, and gain in the FRFs by that, where friction
    sticks, with harmonics too (they represent no sticking either), while its capped chi-square falls by less
    than the noise explains. The element's first law is not asked: the linearity
    verdict found its main effect, and the capped chi-square can hardly fall for a right one (the RK4 paper data:
    a cubic alone), nor a step that adds several laws at once or replaces laws: that is another reading of the
    element, held to the FRF margin of every law it adds (on the measured Brake-Reuss beam, cubic + cubic damping
    + gap after cubic damping alone: x2.06 in the FRFs, 0.499 -> 0.242, and a capped chi-square that fell by less
    than the noise explains for three parameters)."""
    if not current.laws or not (set(current.laws) < set(larger.laws) and len(larger.laws) == len(current.laws) + 1):
        return True
    return _fits_better(search, larger, current, false_alarm)


def _not_seen_beside_friction(search: _Search, current: LawSet, larger: LawSet, false_alarm: float,
                              frfs_part: Callable[[LawSet, LawSet], bool] | None = None) -> list[str]:
    """On data without harmonics: the laws ``larger`` adds beside a friction law of it that fit the kbar no better
    than the force that turns the friction's fundamental there (:mod:`analysis.fitting.friction_fundamental`): each set
    taken at its best, as it is or fitted with that force, ``larger`` beats itself without the law by less than
    the noise explains for the law's parameters. That force is no law; a law that fits no more than it is not seen
    beside the friction (a velocity stiffness, a saturated tanh spring, or a gap or a clearance below every
    amplitude can each fit that force). A clearance is seen where the FRFs part ``larger`` from
    the set without it (``frfs_part``, :func:`_clearance_seen_in_frfs`)."""
    samples = search.samples
    if samples.kbar_std is None or not holds_friction([LAWS[n] for n in larger.laws]):
        return []

    def turned(laws: tuple[str, ...]) -> float:
        return chi_square_with_friction_turn(laws, samples.X, samples.w, samples.kbar, samples.kbar_std)

    out = []
    with_it = min(larger.chi_square, turned(larger.laws))
    for name in larger.laws:
        if name in current.laws or LAWS[name].kind == "friction":
            continue
        rest = tuple(n for n in larger.laws if n != name)
        fitted = next((t for t in search.sets if set(t.laws) == set(rest)), None)
        without = min(turned(rest), np.inf if fitted is None else fitted.chi_square)
        if without - with_it <= _noise_bound(search, len(LAWS[name].params), false_alarm) and \
                not _clearance_seen_in_frfs(name, fitted, larger, frfs_part):
            out.append(name)
    return out


def _clearance_seen_in_frfs(name: str, without: LawSet | None, larger: LawSet,
                            frfs_part: Callable[[LawSet, LawSet], bool] | None) -> bool:
    """Whether clearance law ``name`` of ``larger`` is seen in the FRFs beside friction, which its kbar cannot
    show: the gap closes on the few lines near the higher level's resonance, the capped kbar there hardly moves,
    and what it moves the force that turns the friction's fundamental can fit as well. The FRFs of those lines
    show it by far: ``frfs_part`` (:meth:`_Judge.frfs_part_refined`) parts ``larger`` from the set ``without`` it.
    Refused for its kbar alone, a gap beside friction can leave the joint with no law at all, the friction alone
    being refused in turn with harmonics."""
    return (LAWS[name].kind == "clearance" and without is not None and frfs_part is not None
            and frfs_part(without, larger))


def _kinds(s: LawSet) -> list[str]:
    return sorted(LAWS[n].kind for n in s.laws)


def _other_kinds(judge: "_Judge", search: _Search, s: LawSet) -> list[LawSet]:
    """The sets alike ``s``, with no more parameters, whose laws are of other kinds and whose single-harmonic FRF
    error is within ``min_gain`` of its own: where there are any, the data do not tell what physics the set adds
    (a law fitting what no describing function of the library represents -- the mean shift of a one-sided
    contact -- can be written with laws of several kinds alike). A richer set of other kinds that fits as well
    says nothing against ``s``: with parameters to spare, a gap spring and a Jenkins element can follow a cubic
    and Coulomb friction. Nor does a set the FRFs tell apart by more than a law's margin (on the 3-DOF chain,
    Coulomb friction with a velocity stiffness fitted the kbar as well as with the cubic the rig has, where
    samples of high amplitude are samples near resonance, and left x4.8 the FRF error)."""
    rules = judge.rules.ranking
    limit = rules.min_gain * judge.single({search.index: s}).error
    return [t for t in search.sets if t is not s and t.n_parameters <= s.n_parameters
            and _alike(search, t, s, rules.false_alarm) and _kinds(t) != _kinds(s)
            and judge.single({search.index: t}).error <= limit]


def _one_law_more_alike(search: _Search, s: LawSet, chosen: LawSet, false_alarm: float) -> bool:
    """Whether ``s`` has one law more than ``chosen``, of every kind ``chosen`` has (the same mechanisms with one
    more beside them; a richer set of other kinds that fits as well says nothing, :func:`_other_kinds`), every
    law of it seen in the kbar (none whose size is within its 95 % interval of zero, :attr:`TermFit.size_unseen`:
    a law of no size is no other reading; none seen only in a limit of its amplitude scale,
    :func:`_limit_only_laws`: that is another law, named as itself), and fits the kbar neither better nor worse
    by more than the noise explains for the parameters it adds. Its laws then read the kbar otherwise, and as
    well: a saturating spring alone, or a linear spring with a softening cubic beside it (a spring that only
    begins to saturate at the largest amplitude reads either way)."""
    # the cheap tests first: the limit test scans the element's sets; every law of ``s`` is asked, the choice's too
    # (refitted beside another law, it can run to a limit)
    return (s.fit is not None and len(s.laws) == len(chosen.laws) + 1 and set(_kinds(chosen)) <= set(_kinds(s))
            and abs(chosen.chi_square - s.chi_square) <= _noise_bound(search, s.n_parameters - chosen.n_parameters,
                                                                      false_alarm)
            and not any(t.size_unseen for t in s.fit.terms)
            and not _limit_only_laws(s, LawSet((), None, 0.0, 0), search, false_alarm))


def _indistinguishable(judge: "_Judge", search: _Search, chosen: LawSet) -> list[LawSet]:
    """The sets whose single-harmonic FRF error is within ``min_gain`` of ``chosen``'s that fit its kbar as well:
    alike it, with at least as many parameters, or with one law more (:func:`_one_law_more_alike`; of those only
    the best by the criterion of each set of kinds: the reading is the kinds, and a saturating spring follows a
    softening cubic as well as the cubic does). A set with one law more whose law is tied to another's
    (:attr:`LawSet.tied`) is such a reading too, and the plainest: the kbar cannot part its laws (a linear spring
    beside an arctan spring that saturates little over the amplitudes measured reads as a tanh spring alone, the
    arctan's alpha correlated with the linear k beyond ``max_correlation``). These are the ones the user is told
    of. A set the kbar cannot tell apart but the FRFs can, either way, is not indistinguishable on these data."""
    rules = judge.rules.ranking
    own = judge.single({search.index: chosen}).error
    out, readings = [], set()
    for s in sorted(search.sets + search.tied, key=lambda s: s.criterion):
        if s is chosen:
            continue
        alike = (not s.tied and s.n_parameters >= chosen.n_parameters
                 and _alike(search, s, chosen, rules.false_alarm))
        reading = tuple(_kinds(s))
        more = not alike and reading not in readings and _one_law_more_alike(search, s, chosen, rules.false_alarm)
        if (alike or more) and own / rules.min_gain <= judge.single({search.index: s}).error <= rules.min_gain * own:
            out.append(s)
            if more:
                readings.add(reading)
    return out


def _separation(search: _Search, chosen: LawSet, other: LawSet) -> str:
    """The test that would tell ``other`` from ``chosen``: the nearest amplitude outside the measured range (at
    the measured frequencies), or the nearest frequency outside the band (at the measured amplitudes), where
    their describing functions part by three times the kbar noise."""
    s = search.samples
    noise = 3.0 * np.sqrt(search.scale) * (float(np.median(s.kbar_std)) if s.kbar_std is not None else
                                           float(np.std(s.kbar - chosen.describing_function(s.X, s.w))))
    x_lo, x_hi = float(s.X.min()), float(s.X.max())
    w_lo, w_hi = float(s.w.min()), float(s.w.max())
    unit = s.units[1]
    w_mid = float(np.median(s.w))
    X_mid = float(np.median(s.X))

    def parts(X, w) -> np.ndarray:
        return np.abs(chosen.describing_function(X, w) - other.describing_function(X, w)) > noise

    factors = np.geomspace(1.05, 100.0, 40)
    for f in factors:                                      # nearest first, lower and higher side by side
        if parts(x_lo / f, w_mid):
            return f"a lower level would: they part at X = {x_lo / f:.2g} {unit}"
        if parts(x_hi * f, w_mid):
            return f"a higher level would: they part at X = {x_hi * f:.2g} {unit}"
    for f in factors:
        if parts(X_mid, w_lo / f):
            return f"a lower band would: they part at {w_lo / f / (2 * np.pi):.3g} Hz"
        if parts(X_mid, w_hi * f):
            return f"a higher band would: they part at {w_hi * f / (2 * np.pi):.3g} Hz"
    return "no test within 100 x of the measured amplitudes and band separates them"


def _explanations(name: str, search: _Search, chosen: LawSet) -> list[str]:
    """One sentence per law of the chosen set, from the part of the kbar that law explains (the samples less the
    set's other laws); where the law's own signature departs from that part's, the sentence says so."""
    if chosen.fit is None:
        return []
    s = search.samples
    whole = chosen.fit.describing_function(s.X, s.w)
    out = []
    for term in chosen.fit.terms:
        own = term.describing_function(s.X, s.w)
        sig = signature(s, whole - own)
        text = explain(name, term.law.name, sig, term, s.units)
        own_sig = signature(ElementSamples(s.name, s.X, s.w, own, s.kbar_std, s.level, s.rotational))
        departs = _departing_slope(sig, own_sig)
        if departs:
            text += f" (the law's own kbar has {departs}: another effect overlaps this part here)"
        elif LAWS[term.law.name].amplitude_dependent and _flat(sig):
            text += (" (between the quarters of smallest and largest amplitude the change is within 3 sigma: "
                     "the law rests on its fit to every line together, which lowers the chi-square beyond the "
                     "noise)")
        out.append(text)
    return out


def _flat(sig) -> bool:
    """No change with amplitude in either part that the signature's quarter means resolve."""
    return abs(sig.re_change_sigma) < 3 and abs(sig.im_change_sigma) < 3


def _departing_slope(measured, own, tolerance: float = 0.5) -> str:
    """The log-slope of the law's own kbar that differs from the measured part's by more than ``tolerance``,
    in words ("" where they agree or cannot be compared)."""
    for label, a, b in (("Im log-slope in X", measured.im_slope_X, own.im_slope_X),
                        ("Im log-slope in w", measured.im_slope_w, own.im_slope_w),
                        ("Re log-slope in X", measured.re_slope_X, own.re_slope_X)):
        if a is not None and b is not None and abs(a - b) > tolerance:
            return f"{label} {b:+.2f} where the data show {a:+.2f}"
    return ""


class _Judge:
    """Scores choices of law sets by the FRFs, single-harmonic and with harmonics (cached by choice).

    A choice maps element indices to law sets. In a single-harmonic score, the searched elements the choice
    leaves out are represented by their stand-ins (their measured kbar, :func:`_standins`) or, with
    ``standins=False``, by nothing; a score with harmonics needs every searched element's laws (a stand-in has
    no time-domain force)."""

    def __init__(self, predictor: Predictor, rules: DiscoveryRules, n_harmonics: int, n_time: int,
                 standins: dict[int, Callable], kbar_judges: bool = True):
        self.predictor = predictor
        self.rules = rules
        # whether a step must lower the kbar criterion too: not where lines depart from every describing function
        # (data without harmonics), whose capped criterion can prefer no law to a right one
        self.kbar_judges = kbar_judges
        self.criterion = HarmonicCriterion(rules.ranking.model_form_thd, n_harmonics, n_time)
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
        key = self._key(choice, standins)
        if key not in self._single:
            replace = {i: f for i, f in self.standins.items() if standins and i not in choice}
            replace.update({i: s.describing_function for i, s in choice.items()})
            self._single[key] = self.predictor.compare(kbar_functions_with(self.predictor.model.elements, replace))
        return self._single[key]

    def multi(self, choice: dict[int, LawSet]) -> Comparison:
        key = self._key(choice)
        if key not in self._multi:
            variant = self.predictor.with_laws({i: (s.fit.law_terms() if s.fit is not None else [])
                                                for i, s in choice.items()})
            self._multi[key] = variant.compare(harmonics=self.criterion)
        return self._multi[key]

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
        if unseen and (self.kbar_judges or any(t.surroundings is not None for t in larger.fit.terms)):
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
        ma, mb = self.multi({**others, i: before}), self.multi({**others, i: after})
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
            self._refined[key] = self.refined_beside(search.index, _terms_of(s), others)
        return self._refined[key]

    def refined_beside(self, i: int, terms: list, others: dict[int, Callable]) -> FrfRefinement:
        """Law ``terms``' parameters on element ``i`` refined against the FRFs from their values, the elements of
        ``others`` held at those describing functions (:func:`analysis.prediction.frf_refinement.refine_against_frfs`)."""
        return refine_against_frfs(self.predictor, i, terms, [list(t.law.param_names) for t in terms], others)

    def holds_with_harmonics(self, choice: dict[int, LawSet], i: int, before: LawSet, step: WalkStep) -> bool:
        """The model-form check of a step taken on element ``i`` (module docstring, step 4): with every searched
        element at its choice, the step must also gain ``min_gain``, above the noise, with the lines that carry
        harmonics predicted multi-harmonically. A gain beyond ``certain_gain`` is not the harmonics' effect where
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
    first = judge.refined_beside(i, _terms_of(s), fitted).terms
    held = {}
    for j, other in judged.items():
        if j != i:
            beside = {**{k: f for k, f in fitted.items() if k != j}, i: terms_function(first)}
            held[j] = judge.refined_beside(j, _terms_of(other), beside).terms
    replace = {j: terms_function(ts) for j, ts in held.items()}
    # alone on the structure, the first refinement is already beside its best others
    terms = judge.refined_beside(i, first, replace).terms if held else first
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


def _walk_element(judge: _Judge, search: _Search) -> tuple[list[LawSet], list[WalkStep]]:
    """Element ``search.index``'s shortlists from no law upward, the others by their stand-ins (module docstring,
    step 4): of each size one set (:func:`_preferred`, of its shortlist and the best that keeps the laws already
    taken) is tried against the current choice.
    Returns the sets taken, from no law on, and every step tried."""
    i = search.index
    taken = [search.by_size[0][0]]
    steps = []
    for size in sorted(search.by_size):
        if size == 0:
            continue
        pool = search.by_size[size] + _extension(search, taken[-1], size)
        while pool:
            candidate = _preferred(judge, search, pool, taken[-1])[0]
            step = judge.step_up(search, taken[-1], candidate)
            steps.append(step)
            if step.taken:
                taken.append(candidate)
            elif _took_instead(judge, search, step, taken, steps):
                break
            if not step.not_itself:
                break
            # a set not seen as itself gives way, and no longer sets the FRF error the others are held to
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
    best = min(singles, key=lambda s: judge.single({search.index: s}).error)
    if best not in search.by_size[1]:
        search.by_size[1].append(best)


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
    best = min(amplitude, key=lambda s: judge.single({i: s}).error)
    linear = min(search.sets, key=lambda s: judge.single({i: s}).error)
    if part(linear, best):
        gain = judge.single({i: linear}).error / judge.single({i: best}).error
        why = f"{best.name} beats every set without amplitude dependence in the FRFs x{gain:.3g}"
    else:
        why = _overruled_refined(judge, search, linear, best)
        if not why:
            return None
    full = search_element(i, search.samples, False, rules, robust=True, around=around)
    full.overruled = (f"its linearity verdict (linear, from its kbar at the false-alarm rate) is set aside: {why}, "
                      "so every law of the library was searched")
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
        listed = min(shortlist, key=lambda s: judge.single({search.index: s}).error)
        shortlist.extend([s for s in alike if part(listed, s)])


def _preferred(judge: _Judge, search: _Search, sets: list[LawSet], taken: LawSet) -> list[LawSet]:
    """Of sets of one size, those whose single-harmonic FRF error is within ``min_gain`` of the best of them,
    by the kbar criterion: the kbar chooses, and the FRFs overrule it only by the margin a law must bring (the
    stand-ins of the other elements leave an error floor of their own, within which the FRFs cannot choose). The
    walk tries the first; only where the kbar does not show a law of it as itself does it give way, and the sets
    left are held to the best FRF error among them (a clearance whose gap runs below every amplitude is a linear
    spring, which comes next once it gives way; a saturating spring whose size the kbar does not determine can
    fit the fundamental of friction's harmonics better than the linear law beside friction, which comes next
    only once it has given way). The set the kbar ranks first stays first where the FRFs
    overrule it only at its kbar fit (:func:`_overruled_at_kbar_fit_only`). ``taken``: the element's current
    choice (:func:`_walk_order`)."""
    i = search.index
    errors = [judge.single({i: s}).error for s in sets]
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
    best = min(judge.multi({**judge.held, i: s}).error for s in closest)
    return judge.multi({**judge.held, i: first}).error <= judge.rules.ranking.min_gain * best


def _closest(judge: _Judge, search: _Search, rivals: list[LawSet]) -> list[LawSet]:
    """The ``walk_width`` rivals with the lowest single-harmonic FRF errors."""
    return sorted(rivals, key=lambda s: judge.single({search.index: s}).error)[:judge.rules.walk_width]


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
    every describing function (on the 3-DOF chain a saturating spring and a linear law fitting the sticking came
    first, the cubic beside Coulomb friction far behind although the FRFs gain x5.8 with it); the kbar still
    vetoes a step whose criterion does not fall or whose law it does not show. Two laws more beside laws taken:
    every such set too (on the measured Brake-Reuss beam the best by the criterion beside cubic damping was an
    arctan spring with a preloaded one-sided contact, x1.53 in the FRFs, and the cubic with a gap, x2.06, was
    not tried). From no law: the best by the criterion (the first law's ranking is that of the whole kbar, the
    main effect's)."""
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


@dataclass
class Discovery:
    """The laws found for every element that had none, in the order they are best added."""

    elements: list[ElementDiscovery]

    def text(self) -> str:
        if not self.elements:
            return "model discovery: no element without laws"
        return "\n".join(["model discovery (laws chosen per element from its kbar, judged by the FRFs):"] +
                         ["  " + line for e in self.elements for line in e.text().splitlines()])

    def to_json(self) -> dict:
        return {"elements": [e.to_json() for e in self.elements]}


def discover(predictor: Predictor, samples: dict[str, ElementSamples], linear: frozenset[str],
             rules: DiscoveryRules = DiscoveryRules(), n_harmonics: int = 7, n_time: int = 512,
             progress: Callable[[str], None] | None = None, robust: bool = False) -> Discovery:
    """The laws of every element of ``predictor.model`` that has none and has kbar samples (module docstring).

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
    judge = _Judge(predictor, rules, n_harmonics, n_time, _standins(searches, robust), kbar_judges=not robust)
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
                                      judged[search.index].laws if judged[search.index] is not chosen else None))
    by_index = {s.index: f for s, f in zip(searches, found)}
    return Discovery([by_index[i] for i in _order(judge, choice)])


def _order(judge: _Judge, choice: dict[int, LawSet]) -> list[int]:
    """The elements in the order their laws are best added one at a time: each time the one whose laws cut the
    (single-harmonic) error most with those already added and the rest still empty, so that the history falls
    step by step (a joint's laws added while another joint is still empty may show little alone)."""
    added: dict[int, LawSet] = {}
    order = []
    while len(order) < len(choice):
        rest = [i for i in choice if i not in added]
        best = min(rest, key=lambda i: judge.single({**added, i: choice[i]}, standins=False).error)
        added[best] = choice[best]
        order.append(best)
    return order
