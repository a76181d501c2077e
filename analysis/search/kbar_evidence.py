"""What an element's kbar shows of a set of laws, judged in the kbar's own noise (steps 3 and 4 of the overview in
analysis/search/discovery.py; docs/discovery.md).

A set fits better than another only by more than the noise explains for the parameters it adds, and two sets of
as many laws whose chi-squares differ by less are alike. A law a step adds must be seen in the kbar: its size
outside its 95 % interval of zero, seen as itself rather than only as a limit of its amplitude scale below or
beyond every amplitude measured, and, beside friction on data without harmonics, fitting more than the force
that turns the friction's fundamental, which is no law. A set the kbar cannot part from the choice, and the FRFs
cannot either, is named as indistinguishable with the test that would separate them; each chosen law is explained
from the part of the kbar it explains. The kbar is each element's own evidence, free of the other elements'
laws, which is why it vetoes before the FRFs judge.

Where a test needs the FRFs to break a tie (the capped kbar of data without harmonics), the judge is handed in
as an argument or a ``frfs_part`` callable and never imported: the judge (analysis/search/frf_judge.py) builds
on these tests.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np
import scipy.stats

from ..common.statistics import chi_square_noise_bound, chi_square_shares, falls_above_noise, part_weight
from ..fitting.fit import UNDETERMINED_Z, LawFit, TermFit, unit_exponents
from ..fitting.friction_fundamental import chi_square_with_friction_turn, holds_friction
from ..laws import LAWS, simplicity
from ..missing.diagnosis import ElementSamples, explain, signature, tied_parameters
from .candidates import _Search
from .records import LawSet

if TYPE_CHECKING:
    from .frf_judge import _Judge


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
    than the noise explains (the overview in discovery.py, step 3)."""
    return (len(a.laws) == len(b.laws) and abs(a.chi_square - b.chi_square)
            <= _noise_bound(search, abs(a.n_parameters - b.n_parameters), false_alarm))


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
    clearance that vanishes a spring, a saturating spring that saturates beyond every amplitude a linear one) or no
    law at all (a saturating spring saturated below every amplitude is a force of constant size in phase with the
    displacement, sgn x: on data without harmonics it fitted the sticking lines of a friction contact, and beside
    them a velocity stiffness, x2.4 in the FRFs). Beyond the largest amplitude the law is its linear limit where its
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
    verdict found its main effect, and the capped chi-square can hardly fall for a right one, nor a step that adds
    several laws at once or replaces laws: that is another reading of the element, held to the FRF margin of
    every law it adds, whose capped chi-square can fall by less than the noise explains for its parameters while
    the FRFs gain by far (docs/discovery.md, section 4)."""
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
    """The sets alike ``s``, as simple or simpler (:func:`analysis.laws.simplicity`), whose laws are of other kinds
    and whose single-harmonic FRF error is within ``min_gain`` of its own: where there are any, the data do not
    tell what physics the set adds (a law fitting what no describing function of the library represents -- the
    mean shift of a one-sided contact -- can be written with laws of several kinds alike). A less simple set of
    other kinds that fits as well says nothing against ``s``; it is named beside it (:func:`_indistinguishable`):
    with parameters to spare, a gap spring and a Jenkins element can follow a cubic and Coulomb friction, and an
    arctan spring, whose kbar moves with amplitude, the linear spring beside an Iwan element. Nor does a set the
    FRFs tell apart by more than a law's margin: where the samples of high amplitude are those near resonance, a
    law of frequency can fit the kbar as well as one of amplitude and leave the FRFs far worse."""
    rules = judge.rules.ranking
    limit = rules.min_gain * judge.single({search.index: s}).error
    own = simplicity(s.laws)
    return [t for t in search.sets if t is not s and simplicity(t.laws) <= own
            and _alike(search, t, s, rules.false_alarm) and _kinds(t) != _kinds(s)
            and judge.single({search.index: t}).error <= limit]


def _one_law_more_alike(search: _Search, s: LawSet, chosen: LawSet, false_alarm: float,
                        max_correlation: float) -> bool:
    """Whether ``s`` has one law more than ``chosen``, of every kind ``chosen`` has (the same mechanisms with one
    more beside them; a richer set of other kinds that fits as well says nothing, :func:`_other_kinds`), no law
    of it of no size (:func:`_of_no_size`: a law of no size is no other reading), none seen only in a limit of
    its amplitude scale (:func:`_limit_only_laws`: that is another law, named as itself), and fits the kbar
    neither better nor worse by more than the noise explains for the parameters it adds. Its laws then read the
    kbar otherwise, and as well: a saturating spring alone, or a linear spring with a softening cubic beside it
    (a spring that only begins to saturate at the largest amplitude reads either way)."""
    # the cheap tests first: the limit test scans the element's sets; every law of ``s`` is asked, the choice's too
    # (refitted beside another law, it can run to a limit)
    return (s.fit is not None and len(s.laws) == len(chosen.laws) + 1 and set(_kinds(chosen)) <= set(_kinds(s))
            and abs(chosen.chi_square - s.chi_square) <= _noise_bound(search, s.n_parameters - chosen.n_parameters,
                                                                      false_alarm)
            and not any(_of_no_size(s.fit, j, max_correlation) for j in range(len(s.fit.terms)))
            and not _limit_only_laws(s, LawSet((), None, 0.0, 0), search, false_alarm))


def _of_no_size(fit: LawFit, j: int, max_correlation: float) -> bool:
    """Whether law ``j`` of ``fit`` has no size the kbar sees: its size is unseen (:attr:`TermFit.size_unseen`)
    and no size parameter of it is tied to another law's (:func:`analysis.missing.diagnosis.tied_parameters`).
    A size that trades with another law's is one the kbar cannot share out between the two, not one it finds to be
    zero: the set is then another reading of the same force (a spring's stiffness beside a saturating spring that
    barely saturates over the amplitudes measured, which holds the whole of it alike)."""
    term = fit.terms[j]
    if not term.size_unseen:
        return False
    tied = tied_parameters(fit, {j}, max_correlation)
    return not any(f"{term.label}.{name}" in tied for name in term.law.linear)


def _indistinguishable(judge: "_Judge", search: _Search, chosen: LawSet) -> list[LawSet]:
    """The sets whose single-harmonic FRF error is within ``min_gain`` of ``chosen``'s that fit its kbar as well:
    alike it, with at least as many parameters, or with one law more (:func:`_one_law_more_alike`; of those only
    the best by the criterion of each set of kinds: the reading is the kinds, and a saturating spring follows a
    softening cubic as well as the cubic does). A set with one law more whose law is tied to another's
    (:attr:`LawSet.tied`) is such a reading too, and the plainest: the kbar cannot part its laws (a linear spring
    beside an arctan spring that saturates little over the amplitudes measured reads as a tanh spring alone, the
    arctan's alpha correlated with the linear k beyond ``max_correlation``). These are the ones the user is told
    of. A set the kbar cannot tell apart but the FRFs can, either way, is not indistinguishable on these data --
    save a set whose fit holds the choice (:func:`_holds_the_choice`): the FRFs then part the two only where that
    set fits them better."""
    rules = judge.rules.ranking
    own = judge.single({search.index: chosen}).error
    tie = judge.rules.max_correlation
    out, readings = [], set()
    for s in sorted(search.sets + search.tied, key=lambda s: s.criterion):
        if s is chosen:
            continue
        alike = (not s.tied and s.n_parameters >= chosen.n_parameters
                 and _alike(search, s, chosen, rules.false_alarm))
        reading = tuple(_kinds(s))
        more = not alike and reading not in readings and _one_law_more_alike(search, s, chosen, rules.false_alarm, tie)
        if not (alike or more):
            continue
        error = judge.single({search.index: s}).error
        if own / rules.min_gain <= error and (error <= rules.min_gain * own or _holds_the_choice(s, chosen, tie)):
            out.append(s)
            if more:
                readings.add(reading)
    return out


def _holds_the_choice(s: LawSet, chosen: LawSet, max_correlation: float) -> bool:
    """Whether the fit of ``s``, the choice's laws and one more whose size is unseen but trades with another's
    (not :func:`_of_no_size`), holds the choice itself: along the valley of that trade the kbar fits alike, and the
    valley reaches the choice where the law added has no size. Where the fit stopped in the valley depends on its
    start and search, not on the data (analysis/fitting/limits.py), so the FRFs of that point cannot find the set
    worse than the choice; only better."""
    if s.fit is None or not set(chosen.laws) < set(s.laws):
        return False
    return any(t.size_unseen and not _of_no_size(s.fit, j, max_correlation)
               for j, t in enumerate(s.fit.terms) if t.law.name not in chosen.laws)


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
