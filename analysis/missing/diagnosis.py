"""Which physical effect is missing: candidate laws ranked by what they do to the FRF error, explained by
the signature of the complex stiffness (docs/method.md §3).

For every element and every law of the library not yet on it (laws not ``visible_in_kbar`` -- bilinear, whose
formula's kbar is a constant the linear law already reproduces and which only discovery offers, placed -- are never
proposed), the element's laws plus the candidate are
fitted to the element's kbar samples, the FRFs of every stepped-sine run are predicted by harmonic balance,
and the error is computed.

Two numbers judge a candidate:
- *kbar evidence* ``E = chi2_kbar(current) - chi2_kbar(with candidate) - k ln N``: how much of the element's
  measured kbar the law explains, with a BIC penalty of ln N per added parameter. A candidate is *supported*
  when ``E > 0`` and either it falls short of the best evidence among the candidates of that element by no
  more than the noise explains (the chi-square quantile) or ``tie`` (0.1 %) of that best evidence -- a tie, as
  between coulomb and jenkins with a tiny slip displacement -- or it explains at least half as much and its FRF
  error is within ``frf_tie`` of the best FRF error of that element's candidates with positive evidence (a
  look-alike law may fit the kbar's model-form residue marginally better and still predict the FRFs worse;
  a law the kbar hardly indicates may compensate another missing effect in the FRFs and is not supported).
  This keeps a law that merely compensates another missing effect in the FRFs (a quintic standing in for
  missing damping near resonance) from ranking above the law the kbar signature points to.
- *FRF criterion* ``BIC = chi2_FRF + k ln N_FRF`` (or ``N ln(error^2) + k ln N`` without noise estimates).
A candidate whose parameters the fit cannot separate from those of the laws already on the element (a
linear spring beside an Iwan element that stays in micro-slip) is not proposed: it could only slide along a
flat direction of the fit. Where the element's verdict is linear, only laws whose kbar does not depend on the
amplitude (``linear``, ``velocity_stiffness``) are supported: the verdict found nothing else to explain.
Supported candidates come first. Elements are ordered by the FRF criterion of their best supported candidate.
Within an element the candidates whose FRF errors lie within ``frf_tie`` (5 %) of the best are tied and come
first, the simplest law first (:func:`analysis.laws.simplicity`), then the larger kbar evidence
(coulomb before jenkins and iwan, which reduce to it; ``linear`` before a softening law that is linear over the
amplitudes seen); the others follow by the FRF criterion. A candidate is *significant* only if it is supported,
cuts the FRF error by at least ``min_gain`` (x1.3) *and* by more than the noise explains (chi-square drop above
its 1e-3 quantile). The ``linear`` law is the linear correction: a constant
offset in kbar means the reference stiffness or damping at that element is wrong (the paper's k_w). The gain
threshold guards against laws that only fit what the single-harmonic model itself cannot represent: on the
simulated beam such laws gained up to x1.26 once the true effects were in, while every true effect that was
missing alone gained x1.5 or more.

The thresholds are the fields of :class:`RankingRules`; each decision is one function (``_supported``,
``_significant``, ``_rank_key``), so a retune changes one function.

The explanation of a candidate is built from the signature measured in the data -- log-slopes of Im kbar
against X and w, the change of Re kbar over the amplitude range in standard deviations -- the element name, and
the physics of the law (its ``explanation`` template, filled with :class:`SignatureWords`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import scipy.stats

from ..common.errors import InputError
from ..common.parallel import map_tasks
from ..common.statistics import (capped_chi_square, charged_criterion, chi_square_shares, falls_above_noise,
                                 noise_scale)
from ..common.wording import change_words, parameter_words
from ..fitting.fit import LawFit, TermFit, fit_laws
from ..fitting.friction_fundamental import chi_square_with_friction_turn, holds_friction
from ..laws import LAWS, simplicity
from ..laws.base import SignatureWords
from ..mechanics.elements import LawTerm
from ..mechanics.surroundings import Surroundings
from ..prediction.comparison import (Comparison, HarmonicCriterion, Predictor, chi_square_falls, gain_phrase,
                         kbar_functions_with)


@dataclass
class ElementSamples:
    """Identified kbar samples of one element over all runs (well-conditioned lines only).

    X in m (rad), w in rad/s, kbar and kbar_std in N/m (N·m/rad); ``level`` is the run's force, N.
    """

    name: str
    X: np.ndarray
    w: np.ndarray
    kbar: np.ndarray
    kbar_std: np.ndarray | None
    level: np.ndarray
    rotational: bool = False

    @property
    def units(self) -> tuple[str, str]:
        return ("N·m/rad", "rad") if self.rotational else ("N/m", "m")

    @classmethod
    def joined(cls, parts: list["ElementSamples"]) -> "ElementSamples":
        """The samples of several runs of one element as one set (``kbar_std`` None unless every part has it)."""
        stds = [p.kbar_std for p in parts]
        return cls(parts[0].name, np.concatenate([p.X for p in parts]), np.concatenate([p.w for p in parts]),
                   np.concatenate([p.kbar for p in parts]),
                   None if any(s is None for s in stds) else np.concatenate(stds),
                   np.concatenate([p.level for p in parts]), parts[0].rotational)


@dataclass
class Signature:
    """What the kbar samples (minus the current model) look like, in numbers."""

    im_slope_X: float | None        # d ln Im / d ln X
    im_slope_w: float | None        # d ln Im / d ln w
    re_slope_X: float | None        # p of Re = a + b X^p (None where Re does not change beyond 3 sigma)
    re_change_sigma: float          # (Re at large X - Re at small X) / its std
    im_change_sigma: float
    mean_re: float
    mean_im: float
    re_small: float                 # mean Re over the smallest-amplitude quarter
    re_large: float
    im_small: float
    im_large: float
    X_range: tuple[float, float]
    w_varies: bool


@dataclass
class Candidate:
    """A law proposed for an element, with the error after adding it and refitting."""

    element: str
    law: str
    error: float
    error_before: float
    bic: float
    above_noise: bool               # the FRF chi-square drops by more than the noise explains
    explanation: str
    evidence: float = 0.0
    supported: bool = False         # decided by _supported, once all candidates of the element are scored
    significant: bool = False       # decided by _significant, then by check_model_form
    fit: LawFit | None = field(default=None, repr=False)
    comparison: Comparison | None = field(default=None, repr=False)
    laws: tuple[str, ...] = ()      # every law the candidate adds (a pair: two); () means (law,)
    multiharmonic_gain: float | None = None   # the gain with the harmonics represented (check_model_form)
    model_form: str = ""            # why the model-form check took significance away ("" if it did not)
    held_back: str = ""             # why the automatic loop did not take it (analysis.loop.auto; "" if it did)
    by_modes: str = ""              # why the measured backbone and damping made it significant (analysis.missing.modal_judge)

    def __post_init__(self):
        self.laws = tuple(self.laws) or (self.law,)

    @property
    def name(self) -> str:
        """``element:law`` or ``element:law1+law2``."""
        return f"{self.element}:{'+'.join(self.laws)}"

    @property
    def gain(self) -> float:
        """error_before / error (> 1 means better)."""
        return self.error_before / self.error if self.error > 0 else float("inf")

    def to_json(self) -> dict:
        n = len(self.laws)
        return {"element": self.element, "law": self.law, "laws": list(self.laws), "error": self.error,
                "gain": self.gain, "significant": self.significant, "kbar_evidence": self.evidence,
                "supported": self.supported, "multiharmonic_gain": self.multiharmonic_gain,
                "model_form": self.model_form, "held_back": self.held_back, "by_modes": self.by_modes,
                "explanation": self.explanation,
                "params": {} if self.fit is None else
                {k: v for t in self.fit.terms[-n:] for k, v in t.params.items()}}


# exponents tried by _power: every power law of the library's stiffness laws lies on this grid
_POWERS = np.round(np.arange(-2.0, 6.0001, 0.05), 2)
_POWERS = _POWERS[np.abs(_POWERS) > 0.01]


def _power(lx: np.ndarray, values: np.ndarray, std: np.ndarray) -> float:
    """The exponent p of ``values = a + b X^p`` best fitting by weighted least squares (``lx = ln X``): the
    log-slope of a change, free of the offset it starts from (the slope of ``ln |v - v(smallest X)|`` read a
    cubic's X^2 as +0.65 where the smallest amplitudes sit on the noise)."""
    u = lx - lx.max()                                    # X / X_max: the powers stay within range
    wt = 1.0 / np.maximum(std, 1e-300)
    y = values * wt
    best, best_p = np.inf, float("nan")
    for p in _POWERS:
        A = np.stack([wt, np.exp(p * u) * wt], axis=1)
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        r = A @ coef - y
        cost = float(r @ r)
        if cost < best:
            best, best_p = cost, float(p)
    return best_p


def signature(samples: ElementSamples, model_kbar: np.ndarray | None = None) -> Signature:
    """The signature of ``samples.kbar - model_kbar`` (docs/method.md §3 table)."""
    res = samples.kbar - (0.0 if model_kbar is None else model_kbar)
    X, w = samples.X, samples.w
    lx, lw = np.log(X), np.log(w)
    std = samples.kbar_std if samples.kbar_std is not None else np.full(len(X), np.std(res) + 1e-300)
    order = np.argsort(X)
    q = max(1, len(X) // 4)
    small, large = order[:q], order[-q:]

    weight = 2.0 / np.maximum(std, 1e-300) ** 2          # per part: Re and Im each carry std / sqrt(2)

    def change(values):
        # inverse-variance means of the smallest- and largest-amplitude quarters, and the std of their difference
        wa, wb = weight[small], weight[large]
        a, b = np.sum(wa * values[small]) / wa.sum(), np.sum(wb * values[large]) / wb.sum()
        return a, b, (b - a) / (np.sqrt(1 / wa.sum() + 1 / wb.sum()) + 1e-300)

    re_small, re_large, re_sig = change(res.real)
    im_small, im_large, im_sig = change(res.imag)
    w_varies = np.ptp(lw) > 0.05
    im = res.imag
    usable = im > 2 * std / np.sqrt(2)
    im_slope_X = im_slope_w = None
    if usable.sum() >= 4 and np.ptp(lx[usable]) > 0.1:
        cols = [np.ones(usable.sum()), lx[usable]] + ([lw[usable]] if w_varies else [])
        coef, *_ = np.linalg.lstsq(np.stack(cols, axis=1), np.log(im[usable]), rcond=None)
        im_slope_X = float(coef[1])
        im_slope_w = float(coef[2]) if w_varies else None
    re_slope_X = _power(lx, res.real, std / np.sqrt(2)) if abs(re_sig) >= 3 and np.ptp(lx) > 0.1 else None
    return Signature(im_slope_X, im_slope_w, re_slope_X, float(re_sig), float(im_sig), float(res.real.mean()),
                     float(res.imag.mean()), float(re_small), float(re_large), float(im_small), float(im_large),
                     (float(X.min()), float(X.max())), bool(w_varies))


def _slope(value: float | None) -> str:
    return "n/a" if value is None else f"{value:+.2f}"


def explain(element: str, law: str, sig: Signature, term: TermFit | None, units: tuple[str, str]) -> str:
    """One sentence: what the data show for ``element`` and why ``law`` is the physics behind it (``term``: the
    law's fitted values, stated where given)."""
    X0, X1 = sig.X_range
    params = ""
    reading = None if term is None else LAWS[law].reading(term.params, X0, X1)
    if reading is not None:             # its other parameters are no findings (docs/laws.md, "Limits")
        params = (f"as {reading.limit}: {term.reading_words(reading, units[1] == 'rad')} "
                  f"({', '.join(reading.undetermined)} not determined apart)")
    elif term is not None:
        params = ", ".join(parameter_words(k, v, undetermined=k in term.undetermined, digits=4)
                           for k, v in term.params.items())
    head = f"'{element}' over X = {X0:.3g}..{X1:.3g} {units[1]}: "
    return head + LAWS[law].explain(signature_words(sig, units[0])) + (f"; fitted {params}" if params else "")


def signature_words(sig: Signature, stiffness_unit: str) -> SignatureWords:
    """The signature in the words a law's explanation is written with."""
    k_u = stiffness_unit
    re_flat = abs(sig.re_change_sigma) < 3
    im_flat = abs(sig.im_change_sigma) < 3
    re_text = ("Re kbar stays flat" if re_flat else
               "Re kbar {} {}".format(*change_words(sig.re_small, sig.re_large, k_u))
               + f" ({abs(sig.re_change_sigma):.0f} sigma)")
    im_text = ("Im kbar stays flat" if im_flat else
               "Im kbar {} {}".format(*change_words(sig.im_small, sig.im_large, k_u))
               + f" (log-slope {_slope(sig.im_slope_X)} in X"
               + (f", {_slope(sig.im_slope_w)} in w)" if sig.im_slope_w is not None else ")"))
    return SignatureWords(re=re_text, im=im_text, re_slope=_slope(sig.re_slope_X),
                          mean_re=f"{sig.mean_re:+.3g} {k_u}", mean_im=f"{sig.mean_im:+.3g} {k_u}",
                          spring="hardening" if sig.re_large > sig.re_small else "softening")


def _kbar_chi_square(samples: ElementSamples, fit: LawFit | None) -> float:
    """chi-square of the element's kbar against its current laws, in the convention of fit_laws."""
    if fit is not None:
        if fit.excluded is not None:    # outliers left out of that fit: every sample counts here, as for a candidate
            return float(np.sum(np.abs(fit.normalized_residuals) ** 2))
        return fit.chi_square
    return float(np.sum(chi_square_shares(samples.kbar, samples.kbar_std)))


def explained_within_noise(samples: ElementSamples, fit: LawFit | None, false_alarm: float) -> bool:
    """Whether the element's laws (none: zero) already explain its kbar samples to within their noise: the
    chi-square of the samples against them at or below its ``1 - false_alarm`` quantile. Then the kbar holds
    no evidence of anything missing at that element, and a law added there could only improve the FRFs by
    standing in for something else (the refit of a flat direction of the present laws, another element's
    effect, what one harmonic cannot represent). False without standard deviations (nothing to judge by)."""
    if samples.kbar_std is None:
        return False
    dof = 2 * len(samples.X) - (fit.n_parameters if fit is not None else 0)
    return bool(dof > 0 and _kbar_chi_square(samples, fit) <= scipy.stats.chi2.ppf(1 - false_alarm, dof))


def tied_parameters(fit: LawFit, terms: set[int], max_correlation: float) -> set[str]:
    """The fit parameters of the law terms at indices ``terms`` that the fit cannot tell apart from a parameter
    of its other terms -- e.g. the stiffness of a linear spring beside an Iwan element that never leaves
    micro-slip, which trades off against the Iwan's: either the fit finds a direction exactly flat across both
    (a degeneracy), or the two are correlated beyond ``max_correlation`` (such a pair correlates to within a
    thousandth of -1)."""
    mine = tuple(fit.terms[j].label + "." for j in terms)
    tied = set()
    for d in fit.degeneracies:
        inside = [p for p in d.parameters if p.startswith(mine)]
        if inside and len(inside) < len(d.parameters):
            tied.update(inside)
    names = fit.fit_parameter_names
    is_mine = np.array([n.startswith(mine) for n in names])
    if is_mine.all() or not is_mine.any():
        return tied
    cov = fit.covariance
    sd = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    block = np.nan_to_num(np.abs(corr[np.ix_(is_mine, ~is_mine)]), nan=0.0) > max_correlation
    return tied | {n for n, row in zip(np.array(names)[is_mine], block) if row.any()}


def inseparable(fit: LawFit, terms: set[int], max_correlation: float) -> bool:
    """Whether any parameter of the law terms at indices ``terms`` is tied to one of the other terms
    (:func:`tied_parameters`)."""
    return bool(tied_parameters(fit, terms, max_correlation))


def _duplicates_present_laws(fit: LawFit, n_new: int, max_correlation: float) -> bool:
    """Whether the new (last ``n_new``) terms are not separately identifiable from the terms already there
    (:func:`inseparable`): such a candidate would only move along a flat direction of the fit."""
    n = len(fit.terms)
    return inseparable(fit, set(range(n - n_new, n)), max_correlation)


@dataclass(frozen=True)
class RankingRules:
    """The thresholds of the ranking (module docstring)."""

    min_gain: float = 1.3       # error_before / error needed, with a chi-square drop above the noise, to be significant
    tie: float = 1e-3           # fraction of the element's best kbar evidence within which a candidate is supported
    false_alarm: float = 1e-3   # of the chi-square tests (kbar evidence slack, FRF drop above the noise)
    frf_tie: float = 0.05       # candidates of one element whose FRF errors lie this close to the best are tied
    max_correlation: float = 0.995   # a new parameter this correlated with a present one: a flat direction
    model_form_thd: float = 1e-3     # lines whose displacement THD exceeds this are predicted with harmonics
                                     # when a significant candidate is checked (check_model_form)
    certain_gain: float = 5.0        # a single-harmonic gain this large is not the harmonics' effect (laws that
                                     # only fit what one harmonic cannot represent gained x1.26-x2.5 in every
                                     # case measured): on data without harmonics the capped kbar does not veto
                                     # it; model discovery checks no such step with harmonics on data with
                                     # them, nor an element's first law


@dataclass
class _Scene:
    """What every candidate is scored against: the model's predictor, its current kbar functions (element index ->
    kbar(X, w)) and the comparison of the current model."""

    predictor: Predictor
    current_fns: dict[int, Callable]
    base: Comparison


@dataclass
class _Element:
    """One element as the ranking sees it: its samples, its current laws and how well they explain its kbar."""

    index: int
    name: str
    samples: ElementSamples
    terms: list[LawTerm]
    signature: Signature
    chi2_now: float


@dataclass
class _Leader:
    """The best supported candidate of an element: its FRF criterion (orders the elements) and FRF error."""

    bic: float
    error: float


def frf_criterion(base: Comparison, comp: Comparison, k_added: int, false_alarm: float) -> tuple[float, bool]:
    """(BIC of the FRFs, whether the FRF chi-square drops by more than the noise explains:
    :func:`analysis.prediction.comparison.chi_square_falls`)."""
    n_obs = base.n_observations
    if base.chi_square is not None and comp.chi_square is not None:
        bic = charged_criterion(comp.chi_square, k_added, n_obs)
    else:
        bic = charged_criterion(n_obs * np.log(comp.error ** 2), k_added, n_obs)
    return float(bic), chi_square_falls(base, comp, k_added, false_alarm)


def _score(scene: _Scene, el: _Element, laws: tuple[str, ...], rules: RankingRules) -> Candidate | None:
    """The element's laws plus ``laws`` (one, or a pair) fitted to its kbar, every run predicted; None where they
    cannot be a candidate (too few samples for their parameters, no direction of their own, no prediction)."""
    s = el.samples
    try:
        fit = fit_laws(el.terms + [LawTerm(LAWS[law], {}) for law in laws], s.X, s.w, s.kbar, s.kbar_std,
                       surroundings=scene.predictor.model.elements[el.index].surroundings)
    except InputError:
        return None                           # too few samples for this many parameters
    if _duplicates_present_laws(fit, len(laws), rules.max_correlation):
        return None                           # adds nothing the element's laws cannot already express
    k_added = sum(len(LAWS[law].params) for law in laws)
    evidence = el.chi2_now - charged_criterion(fit.chi_square, k_added, 2 * len(s.X))
    fns = kbar_functions_with(scene.predictor.model.elements, {**scene.current_fns, el.index: fit.describing_function})
    comp = scene.predictor.compare(fns)
    if not np.isfinite(comp.error):
        return None
    bic, above_noise = frf_criterion(scene.base, comp, k_added, rules.false_alarm)
    text = "; ".join(explain(el.name, law, el.signature, fit.terms[-1] if law == laws[-1] else None, s.units)
                     for law in laws)
    return Candidate(el.name, laws[0], comp.error, scene.base.error, bic, above_noise, text, float(evidence),
                     fit=fit, comparison=comp, laws=laws)


def _supported(c: Candidate, best_evidence: float, best_frf: float, linear_verdict: bool,
               rules: RankingRules, explained: bool = False) -> bool:
    """Near the element's best kbar evidence, or as good as the best in the FRFs -- what the ranking is about --
    with positive evidence; where the verdict is linear, only laws without amplitude dependence; nothing where
    the element's laws already explain its kbar to within the noise (:func:`explained_within_noise`)."""
    if explained:
        return False
    if linear_verdict and LAWS[c.law].amplitude_dependent:
        return False                          # the verdict found no amplitude dependence to explain
    slack = max(scipy.stats.chi2.ppf(1 - rules.false_alarm, len(LAWS[c.law].params)), rules.tie * best_evidence)
    return bool(c.evidence > 0 and (best_evidence - c.evidence <= slack or
                                    (c.error <= (1 + rules.frf_tie) * best_frf and c.evidence >= 0.5 * best_evidence)))


def _unseen(c: Candidate) -> bool:
    """Whether the kbar leaves the size of a law the candidate adds open (:attr:`analysis.fitting.fit.TermFit.size_unseen`):
    it then fits nothing of the element's kbar, and an FRF gain with it is another effect's -- beside a clearance
    whose formula misses the lines where it closes (RK4 data), a quintic, Coulomb friction, a Jenkins element, a
    linear law, a one-sided contact and quadratic damping were added one after another, each of undetermined
    size, the error not falling after the first (model discovery asks the same, docs/discovery.md §4)."""
    return c.fit is not None and any(t.size_unseen for t in c.fit.terms[-len(c.laws):])


def _fits_only_departing_lines(el: _Element, c: Candidate, current: LawFit | None,
                               surroundings: Surroundings | None, rules: RankingRules) -> bool:
    """On data without harmonics, whether a candidate beside the element's laws (``current``; none: its first law,
    which the linearity verdict asked) is held back: it gains less than ``certain_gain`` in the FRFs and the
    capped kbar does not call for it (:func:`_beside_above_noise`). A larger gain is no fit of the lines that
    follow no describing function: a clearance closing at a few lines near the higher level's resonance changes
    few kbar samples, each of whose shares is capped, so the capped kbar need not call for it even where it gains
    many times in the FRFs; :func:`check_model_form` still judges it with harmonics."""
    return (current is not None and c.gain < rules.certain_gain
            and not _beside_above_noise(el, c, current, surroundings, rules.false_alarm))


def _beside_above_noise(el: _Element, c: Candidate, current: LawFit, surroundings: Surroundings | None,
                        false_alarm: float) -> bool:
    """On data without harmonics: whether the element's laws with the candidate, fitted leaving out the lines
    that do not follow them, fit its kbar better than its laws alone by more than the noise explains -- the capped
    chi-square (:func:`analysis.fitting.fit.capped_chi_square`) falling by more than s^2 chi2_q(parameters added), s^2 the
    larger fit's reduced capped chi-square, at least 1. Model discovery asks a law beside laws taken the same
    (:func:`analysis.search.discovery._beside_above_noise`); the loop asks it too, or it adds what discovery refused:
    beside a one-sided contact, whose kbar on data without harmonics departs from its describing function at the
    lines where it closes, cubic damping can fit those lines and cut the single-harmonic FRF error while the
    capped chi-square falls by less than the noise explains. Beside friction each side
    is taken at its best, as fitted or with the force that turns the friction's fundamental on such data
    (:mod:`analysis.fitting.friction_fundamental`)."""
    s = el.samples
    terms = el.terms + [LawTerm(LAWS[c.law], {})]
    try:
        larger = fit_laws(terms, s.X, s.w, s.kbar, s.kbar_std,
                          exclude_outliers=True, surroundings=surroundings)
    except InputError:
        return False
    before = capped_chi_square(np.abs(current.normalized_residuals) ** 2)
    after = capped_chi_square(np.abs(larger.normalized_residuals) ** 2)
    if s.kbar_std is not None and holds_friction([t.law for t in el.terms]):
        # beside friction, what the force that turns its fundamental fits is no law (analysis.fitting.friction_fundamental):
        # each side at its best, with or without it
        before = min(before, chi_square_with_friction_turn(el.terms, s.X, s.w, s.kbar, s.kbar_std, surroundings))
        after = min(after, chi_square_with_friction_turn(terms, s.X, s.w, s.kbar, s.kbar_std, surroundings))
    scale = noise_scale(after, 2 * len(s.X), larger.n_parameters)
    return falls_above_noise(before, after, larger.n_parameters - current.n_parameters, scale, false_alarm)


def _significant(c: Candidate, rules: RankingRules) -> bool:
    """Supported, above the noise in the FRFs, and cutting the error by at least ``min_gain``."""
    return bool(c.above_noise and c.supported and c.gain >= rules.min_gain)


def _rank_key(c: Candidate, leader: _Leader | None, frf_tie: float) -> tuple[float, ...]:
    """Sort key, all numbers: supported candidates first, their elements by the FRF criterion of the element's
    best; within an element the candidates tied in FRF error first, simplest law first
    (:func:`analysis.laws.simplicity`), then the larger kbar evidence; the others by the FRF criterion. Unsupported
    candidates follow by the FRF criterion."""
    if not c.supported:
        return (1, c.bic, 0, 0, 0, 0, 0)
    if c.error <= (1 + frf_tie) * leader.error:
        return (0, leader.bic, 0, *simplicity([c.law]), -c.evidence)
    return (0, leader.bic, 1, c.bic, 1, 0, -c.evidence)


def _scene(predictor: Predictor, fits: dict[str, LawFit | None], base: Comparison) -> _Scene:
    return _Scene(predictor, {i: (fits[el.name].describing_function if fits.get(el.name) else el.describing_function)
                              for i, el in enumerate(predictor.model.elements)}, base)


def _element(predictor: Predictor, i: int, samples: dict[str, ElementSamples],
             fits: dict[str, LawFit | None]) -> _Element | None:
    """Element ``i`` as the ranking sees it; None without enough samples to fit anything to."""
    el = predictor.model.elements[i]
    s = samples.get(el.name)
    if s is None or len(s.X) < 3:
        return None
    current = fits.get(el.name)
    terms = [LawTerm(t.law, dict(current.terms[j].params) if current else dict(t.values))
             for j, t in enumerate(el.laws)]
    sig = signature(s, current.describing_function(s.X, s.w) if current else None)
    return _Element(i, el.name, s, terms, sig, _kbar_chi_square(s, current))


def rank_candidates(predictor: Predictor, samples: dict[str, ElementSamples], fits: dict[str, LawFit | None],
                    base: Comparison, laws=None, linear_elements: frozenset = frozenset(),
                    rules: RankingRules = RankingRules(), robust: bool = False) -> list[Candidate]:
    """Rank every (element, law) candidate, best first (module docstring).

    Parameters
    ----------
    predictor : Predictor for the model (structure + elements) and the measurements.
    samples : element name -> its identified kbar samples.
    fits : element name -> the current fit of its laws (None: no laws yet).
    base : the current model's comparison.
    laws : law names to try (default: the whole library); laws not ``visible_in_kbar`` are never tried.
    linear_elements : elements whose verdict is linear: only laws whose kbar does not depend on the amplitude
        are supported there.
    rules : the thresholds of support, significance and ties.
    robust : the data carry no harmonics (the fits leave out the lines that do not follow them): a significant
        law beside laws present must also lower the kbar's capped chi-square above the noise
        (:func:`_beside_above_noise`), unless it gains ``certain_gain`` in the FRFs
        (:func:`_fits_only_departing_lines`).
    """
    elements = predictor.model.elements
    names = [n for n in (laws or LAWS) if LAWS[n].visible_in_kbar]
    scene = _scene(predictor, fits, base)
    out: list[Candidate] = []
    for i, el in enumerate(elements):
        element = _element(predictor, i, samples, fits)
        if element is None:
            continue
        present = {t.law.name for t in el.laws}
        tried = [law for law in names if law not in present]
        # each law's fit and prediction needs nothing of the others'
        mine = [c for c in map_tasks(lambda k: _score(scene, element, (tried[k],), rules), len(tried))
                if c is not None]
        best_evidence = max((c.evidence for c in mine), default=0.0)
        best_frf = min((c.error for c in mine if c.evidence > 0), default=np.inf)
        explained = explained_within_noise(element.samples, fits.get(el.name), rules.false_alarm)
        for c in mine:
            c.supported = _supported(c, best_evidence, best_frf, el.name in linear_elements, rules, explained)
            if c.supported and _unseen(c):
                c.supported = False
                c.held_back = (f"its kbar does not show {c.law}: every size parameter of it is within its 95 % "
                               "interval of zero")
            c.significant = _significant(c, rules)
            if c.significant and robust and _fits_only_departing_lines(element, c, fits.get(el.name),
                                                                         el.surroundings, rules):
                c.supported = c.significant = False
                c.held_back = ("beside the laws present its kbar's capped chi-square falls by less than the noise "
                               "explains: it fits only lines that follow no describing function")
        out += mine
    leaders: dict[str, _Leader] = {}
    for c in out:
        if c.supported:
            best = leaders.setdefault(c.element, _Leader(np.inf, np.inf))
            best.bic, best.error = min(best.bic, c.bic), min(best.error, c.error)
    out.sort(key=lambda c: _rank_key(c, leaders.get(c.element), rules.frf_tie))
    return out


def rank_pairs(predictor: Predictor, samples: dict[str, ElementSamples], fits: dict[str, LawFit | None],
               base: Comparison, element: str, pairs: list[tuple[str, str]], linear_verdict: bool = False,
               rules: RankingRules = RankingRules()) -> list[Candidate]:
    """Pairs of laws added together to one element, best FRF criterion first. Where two effects of one element
    are missing at once, each alone may explain little of its kbar and cut the FRF error little; together they
    can. A pair is supported when its kbar evidence is positive (and, on a linear verdict, neither law depends
    on the amplitude), significant by the same test as a single law (:func:`_significant`)."""
    i = next(j for j, el in enumerate(predictor.model.elements) if el.name == element)
    view = _element(predictor, i, samples, fits)
    if view is None:
        return []
    scene = _scene(predictor, fits, base)
    out = [c for c in (_score(scene, view, pair, rules) for pair in pairs) if c is not None]
    for c in out:
        c.supported = bool(c.evidence > 0 and not (linear_verdict and any(LAWS[n].amplitude_dependent
                                                                          for n in c.laws)) and not _unseen(c))
        c.significant = _significant(c, rules)
    out.sort(key=lambda c: (not c.supported, c.bic))
    return out


def check_model_form(predictor: Predictor, candidates: list[Candidate], rules: RankingRules = RankingRules(),
                     harmonics: HarmonicCriterion = HarmonicCriterion()) -> None:
    """Take significance away from a candidate that only fits what the single-harmonic balance cannot represent.

    Candidates are scored single-harmonically. Where the motion carries harmonics that are not negligible (a
    displacement THD above ``rules.model_form_thd`` at a line, measured or implied by the single-harmonic
    solution), a right model still misses the measurement there by the harmonics' effect on the fundamental,
    and a law the physics does not contain can fit that remainder. So every significant candidate is judged
    once more with those lines predicted by multi-harmonic balance, for the current model and for the model
    with the candidate: it stays significant only if the error still falls by ``min_gain`` and the FRF
    chi-square by more than the noise explains (``multiharmonic_gain``; ``model_form`` says why not)."""
    significant = [c for c in candidates if c.significant]
    if not significant:
        return
    criterion = replace(harmonics, limit=rules.model_form_thd)
    base = predictor.compare(harmonics=criterion)
    index = {el.name: i for i, el in enumerate(predictor.model.elements)}
    for c in significant:
        variant = predictor.with_laws({index[c.element]: c.fit.law_terms()})
        comp = variant.compare(harmonics=criterion)
        c.multiharmonic_gain = base.error / comp.error if comp.error > 0 else float("inf")
        _, above_noise = frf_criterion(base, comp, sum(len(LAWS[n].params) for n in c.laws), rules.false_alarm)
        if not (above_noise and c.multiharmonic_gain >= rules.min_gain):
            c.significant = False
            c.model_form = (f"with the harmonics represented at the lines where they are not negligible the error "
                            f"goes {base.error:.3g} -> {comp.error:.3g} ({gain_phrase(c.multiharmonic_gain)}"
                            f"{'' if above_noise else ', within the noise'}): the single-harmonic gain fits "
                            f"what one harmonic cannot represent")
