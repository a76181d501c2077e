"""Model discovery: the laws of every element that has none, found from an empty law set (docs/discovery.md).

A user knows the structure and where the joints are, not a single law. The closed-form identification gives
every element its own kbar samples with their noise, so the elements' laws can be chosen where the elements are
decoupled, at the cost of a kbar fit each, and the coupled FRFs only judge the few best choices:

1. **Sets of laws, fitted to the element's kbar.** Every set of one to ``max_laws`` laws of the library, at most
   one of each kind (:data:`analysis.laws.base.KINDS`: one joint has one stiffness mechanism, one damping, one
   friction...), is fitted to the element's kbar samples (pairs all; triples extend the ``triple_pool`` best pairs).
   A set is also refitted from a larger set's fit that holds every other law at no size and fits better, which
   is a fit of the smaller set its own search missed (:func:`_reach_larger_fits`).
   A set in which one law adds no direction of its own (every parameter of it tied to another law's, by an exact
   degeneracy or a correlation beyond ``max_correlation``) is not a set of separate effects and is never chosen,
   only named as a reading the data cannot part (step 3). Where
   the element's verdict is linear, only laws without amplitude dependence enter, among them a bilinear spring
   placed in the element's structure (the one law whose placement alone shows it). Data without harmonics: the
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
   the noise explains; a set turned down gives way to the next of those the FRFs kept beside it
   (:func:`_preferred`, :func:`_walk_element`). On data without harmonics the single-harmonic FRFs decide against
   the kbar only where the FRFs with harmonics agree: a step the kbar calls for beyond the noise is judged with
   harmonics where they refuse it (:meth:`_Judge._gains_with_harmonics`), and the set the kbar ranks first beyond
   the noise stays first where they overrule it (:func:`_overruled_single_harmonically_only`).
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

This is the front end: the names other code uses are here, and the method lives beside it, one stage of
its path a module:

- ``records.py``: the rules and what discovery returns (:class:`DiscoveryRules`, :class:`LawSet`,
  :class:`WalkStep`, :class:`Separation`, :class:`ElementDiscovery`, :class:`Discovery`);
- ``candidates.py``: steps 1 and 2, the sets of laws enumerated and fitted to each element's kbar, charged for
  their parameters and shortlisted, and :func:`amplitude_dependence`;
- ``kbar_evidence.py``: what the kbar shows -- better, alike, seen, seen as itself, seen beside friction,
  indistinguishable, the test that separates, the explanations;
- ``frf_judge.py``: the FRF judge (:class:`_Judge`), the stand-ins, and every element refined against the FRFs;
- ``walk.py``: step 4's walk and the choice -- the sets preferred, the verdict set aside, the model-form check and
  contact twins, the simplest of those alike -- and :func:`discover`.
"""
from __future__ import annotations

from .candidates import (AmplitudeDependence, _adds_nothing, _fit_set, _reach_larger_fits, _Search, _shortlists,
                         _warm_start, amplitude_dependence, law_sets, search_element)
from .frf_judge import _Judge, _pruned_beside_clearance, _RefinedErrors
from .kbar_evidence import (_alike, _beside_above_noise, _indistinguishable, _kinds, _limit_only_laws, _noise_bound,
                            _not_seen_beside_friction, _one_law_more_alike, _other_kinds, _seen_as_its_tail,
                            _separation, _unseen_laws)
from .records import Discovery, DiscoveryRules, ElementDiscovery, LawSet, Separation, WalkStep
from .walk import (CONTACT_TWINS, _check_with_harmonics, _contact_twin, _extension, _offer_frf_best_alike,
                   _offer_frf_best_single, _preferred, _simplest, _verdict_overruled, _walk_element, discover)

# the names other code imports from here; then the steps the tests call one at a time, named here for them. A
# monkeypatch must go to the module that calls the name (a function here is looked up in its own module's globals)
__all__ = ["AmplitudeDependence", "CONTACT_TWINS", "Discovery", "DiscoveryRules", "ElementDiscovery", "LawSet",
           "Separation", "WalkStep", "amplitude_dependence", "discover", "law_sets", "search_element",
           "_adds_nothing", "_alike", "_beside_above_noise", "_check_with_harmonics", "_contact_twin", "_extension",
           "_fit_set", "_indistinguishable", "_Judge", "_kinds", "_limit_only_laws", "_noise_bound",
           "_not_seen_beside_friction", "_offer_frf_best_alike", "_offer_frf_best_single", "_one_law_more_alike",
           "_other_kinds", "_preferred", "_pruned_beside_clearance", "_reach_larger_fits", "_RefinedErrors", "_Search",
           "_seen_as_its_tail", "_separation", "_shortlists", "_simplest", "_unseen_laws", "_verdict_overruled",
           "_walk_element", "_warm_start"]
