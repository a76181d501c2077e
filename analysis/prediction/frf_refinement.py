"""One element's law parameters refined against the measured FRFs, with their standard errors
(docs/discovery.md, "Seen in the FRFs").

The laws are fitted to the element's kbar samples, which are decoupled from the other elements and cost
milliseconds. The kbar is not all the data hold: lines where the closed-form identification is ill-conditioned
are left out of it, and where a law's effect shows on a few lines its size can stay open in the kbar while the
FRFs of every line and sensor determine it. Here the parameters of one element's set of laws, started from their
kbar fit, are refined by least squares on the single-harmonic FRF residuals of every stepped-sine run, each in
units of its noise (``receptance_std``, Re and Im each carrying it over sqrt 2; relative to the measured modulus where there is none), with the other
elements held at given describing functions. The standard errors come from the Jacobian at the optimum, scaled
by the reduced chi-square where that exceeds 1. It costs one prediction of every run per evaluation: seconds,
not milliseconds, so it is asked only where the kbar leaves a law's size open and the FRFs gain with it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import least_squares

from ..common.errors import InputError
from ..common.statistics import part_weight
from ..mechanics.elements import LawTerm
from .comparison import Predictor, compare_predictions, kbar_functions_with


DIFF_STEP = 1e-4       # relative step of the Jacobian's differences, in the scaled parameters


@dataclass(frozen=True)
class FrfRefinement:
    """The refined terms and, per term, each refined parameter's standard error."""

    terms: list[LawTerm]
    stderr: list[dict[str, float]]
    chi_square: float                 # of the FRF residuals, each in units of its noise
    n_residuals: int
    evaluations: int

    def size_seen(self, j: int, z: float) -> bool:
        """Whether term ``j``'s size is determined: some force-scale parameter of it at least ``z`` standard errors
        from zero."""
        t = self.terms[j]
        return any(n in self.stderr[j] and np.isfinite(self.stderr[j][n]) and abs(t.values[n]) >= z * self.stderr[j][n]
                   for n in t.law.linear)

    def size_text(self, j: int) -> str:
        t = self.terms[j]
        return ", ".join(f"{n} = {t.values[n]:.4g} +- {self.stderr[j][n]:.2g}" for n in t.law.linear
                         if n in self.stderr[j])


def terms_function(terms: list[LawTerm]) -> Callable:
    """The describing function of a list of law terms together."""
    def kbar(X, w):
        return sum((t.describing_function(X, w) for t in terms), np.zeros(np.shape(X), complex))
    return kbar


def refine_against_frfs(predictor: Predictor, index: int, terms: list[LawTerm], free: list[list[str]],
                        others: dict[int, Callable], max_evaluations: int = 60) -> FrfRefinement:
    """Refine the ``free`` parameters (per term) of element ``index``'s ``terms`` against the FRFs; ``others``:
    element index -> describing function of the elements held."""
    keys = [(j, n) for j, names in enumerate(free) for n in names]
    x0 = np.array([terms[j].values[n] for j, n in keys], float)
    scale = np.where(np.abs(x0) > 0, np.abs(x0), 1.0)
    lower, upper = _bounds(terms, keys, scale)
    start = np.clip(x0 / scale, lower, upper)
    runs = predictor.runs
    # Re and Im each carry std / sqrt(2); relative to the measured modulus where no std was measured
    weights = {run.name: part_weight(run.receptance_std if run.receptance_std is not None else np.abs(run.receptance))
               for run in runs}

    def trial(x) -> list[LawTerm]:
        out = [LawTerm(t.law, dict(t.values)) for t in terms]
        for (j, n), v in zip(keys, x * scale):
            out[j].values[n] = float(v)
        return out

    def predicted(x, near=None) -> tuple[dict | None, np.ndarray]:
        """The predictions at scaled parameters ``x`` (None where the law refuses them) and their residuals."""
        kbar = terms_function(trial(x))
        try:
            predictions = predictor.predict(kbar_functions_with(predictor.model.elements, {**others, index: kbar}),
                                            near)
        except InputError:                    # values the law refuses (beyond what its bounds say): far off
            return None, np.full(n_residuals, 1e3)
        comp = compare_predictions(runs, predictions)
        parts = []
        for run in runs:
            d = weights[run.name] * (comp.compared[run.name] - run.receptance)
            parts += [d.real.ravel(), d.imag.ravel()]
        r = np.concatenate(parts)
        # a line the prediction fails at counts as far off, not as nothing
        return predictions, np.where(np.isfinite(r), r, 1e3)

    last = None                               # the latest evaluation: (x, predictions, residuals)

    def residuals(x) -> np.ndarray:
        nonlocal last
        predictions, r = predicted(x)
        last = (np.array(x), predictions, r)
        return r

    def jacobian(x) -> np.ndarray:
        """Forward differences of :func:`residuals` (backward at an upper bound), each step's prediction started
        from the one at ``x`` (:meth:`Predictor.predict`'s ``near``): a few Newton steps per line instead of a
        sweep."""
        if last is None or not np.array_equal(last[0], x):
            residuals(x)
        _, base, r0 = last
        J = np.empty((r0.size, x.size))
        for k in range(x.size):
            h = DIFF_STEP * (1.0 if x[k] >= 0 else -1.0) * max(1.0, abs(x[k]))
            if not lower[k] <= x[k] + h <= upper[k]:
                h = -h
            xh = np.array(x, float)
            xh[k] += h
            J[:, k] = (predicted(xh, base)[1] - r0) / (xh[k] - x[k])
        return J

    n_residuals = 2 * sum(np.size(run.receptance) for run in runs)
    if not keys:
        r = residuals(start)
        return FrfRefinement(trial(start), [{} for _ in terms], float(r @ r), r.size, 1)
    # a chi-square of hundreds is decided to within one unit: 1e-3 of it
    sol = least_squares(residuals, start, jac=jacobian, bounds=(lower, upper), ftol=1e-3, xtol=1e-4,
                        max_nfev=max_evaluations)
    n, p = sol.jac.shape
    chi2 = float(2 * sol.cost)
    s2 = max(1.0, chi2 / max(n - p, 1))
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2
    se = np.sqrt(np.abs(np.diag(cov))) * scale
    stderr: list[dict[str, float]] = [{} for _ in terms]
    for (j, name), e in zip(keys, se):
        stderr[j][name] = float(e)
    return FrfRefinement(trial(sol.x), stderr, chi2, n, int(sol.nfev))


def _bounds(terms: list[LawTerm], keys: list[tuple[int, str]], scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each free parameter's contract range in the scaled units the search runs in; an open lower bound a hair
    inside."""
    lower, upper = np.empty(len(keys)), np.empty(len(keys))
    for k, (j, name) in enumerate(keys):
        param = next(p for p in terms[j].law.params if p.name == name)
        lower[k] = param.lower / scale[k] + (1e-9 if param.lower_open else 0.0)
        upper[k] = param.upper / scale[k]
    return lower, upper
