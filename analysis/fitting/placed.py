"""A contact law fitted by its kbar placed in the structure around the element
(:mod:`analysis.mechanics.surroundings`), the mean and harmonics it drives included: the law's basis is its placed kbar
at a reference value of its scaling parameter (:class:`_PlacedLaw`), and the fit is repeated, the reference moved by
secant steps, until the fitted value is the reference (:func:`_settle`).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from ..common.errors import InputError
from ..laws import Law
from ..laws.base import KbarFunction
from ..mechanics.surroundings import Surroundings, linear_part, placed_kbar
from .projection import _fit_once
from .results import LawFit
from .robust import _quick
from .samples import _Options, _Samples


# A contact law placed in its surroundings: refits with the placement of the previous fit's values, at most
# this many, until its scaling parameter moves by less than _PLACED_TOLERANCE (relative)
_PLACED_REFITS = 8
_PLACED_TOLERANCE = 1e-3
# ... and where outliers are left out, one refit from the placement settled on every sample
_ROBUST_PLACED_REFITS = 1


class _PlacedLaw:
    """A contact law whose basis is its kbar placed in ``around`` with its scaling parameter held at
    ``reference`` (and divided by it): the fit's linear parameter then rescales a fixed placement, and
    :func:`_fit_placed` refits until the two agree. Everything else is the law's own."""

    def __init__(self, law: Law, reference: float, around: Surroundings):
        self.law, self.reference, self.around = law, reference, around

    def __getattr__(self, name):
        if name.startswith("__"):           # asked before the attributes are set (a copy in the making)
            raise AttributeError(name)
        return getattr(self.law, name)

    def basis(self, X, w, **shape):
        values = self.law.from_fit({self.law.linear[0]: self.reference}, shape)
        return placed_kbar([(self.law, values)], X, w, self.around)[None] / self.reference

    def kbar_function(self, **params):
        """kbar of this basis at the given values (what a fit in progress judges its samples by)."""
        linear, shape = self.law.to_fit(self.law.check_params(params, complete=True))
        return KbarFunction(self, (linear[self.law.linear[0]],), shape)

    def describing_function(self, X, w, **params):
        return self.kbar_function(**params)(X, w)


def _scaling(law: Law, values: Mapping[str, float]) -> float:
    """The parameter scaling a placed law's force (its one linear parameter)."""
    return values[law.linear[0]]


def _fit_placed(terms, data: _Samples, opts: _Options, surroundings: Surroundings, fitter) -> LawFit:
    """The fit of ``terms`` with their contact laws placed in ``surroundings`` (:mod:`analysis.mechanics.surroundings`).

    The placed kbar depends on the law's scaling parameter (the contact's stiffness against the structure's),
    which the fit solves for linearly: from the fit of the describing function alone, the laws are placed at a
    reference value and refitted until the fitted value is the reference (:func:`_settle`), first on every sample
    and then, where outliers are left out, by ``fitter`` from there (a placement far off would leave out the very
    samples that show the contact)."""
    laws = [law for law, _ in terms]
    placed = [law.name for law in laws if law.placed]
    if len(placed) > 1:
        # each law's basis is placed alone, where a model places them together (one mean, one set of harmonics)
        raise InputError(f"laws {' and '.join(placed)} are both placed in the structure: one such law per element")
    fit = _settle(laws, _started(laws, _fit_once(terms, data, opts)), data, _quick(opts), surroundings, _fit_once,
                  _PLACED_REFITS)
    if fitter is not _fit_once:
        fit = _settle(laws, fit, data, _quick(opts), surroundings, fitter, _ROBUST_PLACED_REFITS)
    around = _around(fit, surroundings)
    for t, law in zip(fit.terms, laws):
        placed = isinstance(t.law, _PlacedLaw)
        t.law = law
        t.surroundings = around if placed else None
    return fit


def _started(laws: list[Law], formula: LawFit) -> LawFit:
    """The formula's fit with each placed law at the values its placement starts from
    (:meth:`~analysis.laws.base.Law.placed_start`): where the formula leaves a shape of the law open (a bilinear
    spring's ratio of its two stiffnesses), the refits, which refine from where they start, would stay where
    that fit left it."""
    return replace(formula, terms=[replace(t, params=law.placed_start(t.params)) if law.placed else t
                                   for t, law in zip(formula.terms, laws)])


def _around(fit: LawFit, surroundings: Surroundings) -> Surroundings:
    """The surroundings with the fit's amplitude-independent laws in parallel."""
    return surroundings.with_parallel(linear_part([(t.law, t.params) for t in fit.terms]))


def _settle(laws: list[Law], fit: LawFit, data: _Samples, opts: _Options, surroundings: Surroundings, fitter,
            refits: int) -> LawFit:
    """Refits of ``fit``'s terms (laws ``laws``) with the contact laws placed at reference values until each fitted
    scaling parameter equals its reference (``_PLACED_TOLERANCE``), the references moved by secant steps on
    ``fitted - reference`` (a plain substitution converges slowly where the contact is as stiff as the
    structure); each refit refines from the last values. A contact whose
    scaling parameter is 0 has no force to place: the terms are then refitted by ``fitter`` as they are."""
    placed = [law.placed for law in laws]
    reference = np.array([_scaling(law, t.params) for t, law, m in zip(fit.terms, laws, placed) if m])
    previous = None
    for i in range(refits):
        if np.any(reference == 0.0):
            return fit if i else fitter([(law, dict(t.params)) for t, law in zip(fit.terms, laws)], data, opts)
        around = _around(fit, surroundings)
        refs = iter(reference)
        fit = fitter([(_PlacedLaw(law, next(refs), around) if m else law, dict(t.params))
                      for t, law, m in zip(fit.terms, laws, placed)], data, opts)
        fitted = np.array([_scaling(law, t.params) for t, law, m in zip(fit.terms, laws, placed) if m])
        gap = fitted - reference
        if np.all(np.abs(gap) <= _PLACED_TOLERANCE * np.abs(reference)):
            break
        following = fitted
        if previous is not None:
            with np.errstate(divide="ignore", invalid="ignore"):     # an unmoved reference: no slope, no secant
                slope = (gap - previous[1]) / (reference - previous[0])
            secant = reference - gap / np.where(slope < 0.0, slope, -1.0)
            # a secant step where the fitted value falls as the reference rises (the placement's own effect),
            # never across zero
            following = np.where((slope < 0.0) & (secant * reference > 0.0), secant, fitted)
        previous = (reference, gap)
        reference = following
    return fit
