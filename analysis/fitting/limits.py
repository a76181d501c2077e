"""A law read in a limit the data cannot tell it from: the limit fitted as its own law of the combination it
determines, and taken where the law fits no better (docs/fitting.md, "Limits the data cannot tell apart").

Near a limit a law keeps a flat direction: an Iwan joint that never slips through at the amplitudes measured has
its kbar set by the stuck stiffness, the density's exponent and the dissipation's size alone, and its slip force
and spike slide along a valley of equal fit. Where its own fit stops in that valley depends on the start and the
search, not on the data; so would the reading of its parameters. Each law names such limits
(:meth:`analysis.laws.base.Law.limit_forms`) as laws of the combination the data determine there. The element's
set is refitted with the law replaced by the form; where the law's own fit does not fall below the form's by more
than the noise explains for the parameters the law adds (:func:`analysis.common.statistics.falls_above_noise`),
the data cannot tell the law from its limit, and the form's fit is kept: its parameters are the combination with
its errors, and the law's values placed in the limit (:meth:`analysis.laws.base.LimitForm.law_values`) are the
model's.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping

import numpy as np

from ..common.errors import InputError
from ..common.statistics import falls_above_noise, noise_scale
from ..laws.base import Law, LimitForm
from ..mechanics.elements import LawTerm
from ..mechanics.surroundings import Surroundings
from .fit import fit_laws
from .results import LawFit, TermFit


def settle_in_limits(fit: LawFit, laws: list[LawTerm], X, w, kbar, sigma, *, false_alarm: float,
                     exclude_outliers: bool = False, surroundings: Surroundings | None = None) -> LawFit:
    """``fit`` of the terms ``laws`` to the samples (X, w, kbar, sigma: as :func:`analysis.fitting.fit.fit_laws`
    takes them, with the same ``exclude_outliers`` and ``surroundings``), each law in turn refitted as each of its
    limit forms over the samples' amplitudes, the others from their fitted values, and the form taken where the
    law's fit does not fall below it by more than the noise explains at ``false_alarm``: ``s^2 chi2_q(p)`` on the
    chi-square of the fits compared (:attr:`LawFit.judged_chi_square`), ``p`` the parameters the law adds, ``s^2``
    the law's fit's reduced chi-square where above 1. A form whose fit leaves out more lines than a fit may
    (:attr:`LawFit.describes_the_data`) does not stand for a law's fit that does not: it describes part of the
    data, and a capped chi-square can prefer that part to all of it. Returns the fit with every law taken in its
    limit there (:func:`_in_limit`); its terms' ``params`` are the model's values either way."""
    X_max = float(np.max(X))
    n_obs = 2 * len(np.atleast_1d(X))
    for j, term in enumerate(laws):
        for form in term.law.limit_forms(X_max):
            trial = [LawTerm(t.law, f.params) for t, f in zip(laws, fit.terms)]
            own = fit.terms[j].params
            trial[j] = LawTerm(form, {p.name: own[p.name] for p in form.shape if p.name in own})
            try:
                limit = fit_laws(trial, X, w, kbar, sigma, exclude_outliers=exclude_outliers,
                                 surroundings=surroundings)
            except InputError:
                continue
            placed = _placed(limit, j, term.law)
            if placed is None or (fit.describes_the_data and not limit.describes_the_data):
                continue
            scale = noise_scale(fit.judged_chi_square, n_obs, fit.n_parameters)
            if falls_above_noise(limit.judged_chi_square, fit.judged_chi_square,
                                 fit.n_parameters - limit.n_parameters, scale, false_alarm):
                continue
            fit = placed
            break
    return fit


def fit_in_limits(laws: list[LawTerm], forms: Mapping[int, LimitForm], X, w, kbar, sigma, *,
                  exclude_outliers: bool = False, surroundings: Surroundings | None = None) -> LawFit | None:
    """The terms ``laws`` fitted to the samples (as :func:`analysis.fitting.fit.fit_laws` takes them) with term
    ``j`` as its limit form ``forms[j]`` for every ``j`` given, each placed back in its law as
    :func:`settle_in_limits` places a form it takes; the others as themselves. None where a form's fit places
    back in no values of its law (the caller fits the law itself then)."""
    trial = [LawTerm(forms[j], {p.name: t.values[p.name] for p in forms[j].shape if p.name in t.values})
             if j in forms else t for j, t in enumerate(laws)]
    fit = fit_laws(trial, X, w, kbar, sigma, exclude_outliers=exclude_outliers, surroundings=surroundings)
    for j in forms:
        fit = _placed(fit, j, laws[j].law)
        if fit is None:
            return None
    return fit


def _placed(fit: LawFit, j: int, law: Law) -> LawFit | None:
    """``fit``, whose term ``j`` is a limit form of ``law``, with that term placed back in ``law``
    (:meth:`analysis.laws.base.LimitForm.law_values`, :func:`_in_limit`): where the form's stiffness is determined
    only in a sum with another law's linear parameter (:func:`_shared_stiffness`), that parameter takes the
    difference, and the sum the data determine is kept. None where no values of ``law`` sit in the limit."""
    shared = _shared_stiffness(fit, j)
    form_fit = fit.terms[j]
    placed_back = form_fit.law.law_values(form_fit.params, stiffness_seen=shared is None)
    if placed_back is None:
        return None
    terms = list(fit.terms)
    terms[j] = _in_limit(law, form_fit, placed_back)
    if shared is not None:
        i, name = shared
        moved = dict(terms[i].params)
        moved[name] -= placed_back[form_fit.law.stiffness] - form_fit.params[form_fit.law.stiffness]
        terms[i] = replace(terms[i], params=moved)
    return replace(fit, terms=terms)


def _shared_stiffness(fit: LawFit, j: int) -> tuple[int, str] | None:
    """(term, parameter) of the linear parameter of another law that ``fit`` determines only in a sum with term
    ``j``'s :attr:`LimitForm.stiffness` (one degeneracy of the two, its one determined combination their sum: a
    linear spring beside a friction law's stuck stiffness); None where there is none."""
    form = fit.terms[j]
    if form.law.stiffness is None:
        return None
    own = f"{form.label}.{form.law.stiffness}"
    for d in fit.degeneracies:
        if own not in d.parameters or len(d.parameters) != 2 or len(d.determined) != 1:
            continue
        other = next(p for p in d.parameters if p != own)
        coefficients = d.determined[0].coefficients
        if not math.isclose(coefficients.get(own, 0.0), coefficients.get(other, 0.0), rel_tol=1e-6):
            continue
        label, name = other.rsplit(".", 1)
        for i, t in enumerate(fit.terms):
            if i != j and t.label == label and name in t.law.linear and name in t.params:
                return i, name
    return None


def _in_limit(law: Law, form: TermFit, placed: dict[str, float]) -> TermFit:
    """``law`` placed in its limit (contract values ``placed``), carrying ``form``, the fit of the limit's own
    form (its label and surroundings, the form named as its law): a parameter of both keeps the form's error; one
    the form does not have is left open."""
    names = law.param_names
    stderr = {n: form.stderr.get(n, math.inf) for n in names}
    undetermined = tuple(n for n in names if n not in form.params or n in form.undetermined)
    return TermFit(law, form.label, placed, stderr, {}, undetermined, form.surroundings, limit=form)
