"""Fitting element laws to equivalent complex-stiffness samples of one element.

Given samples ``kbar_k`` of one element's equivalent complex stiffness at amplitudes
``X_k`` and angular frequencies ``w_k`` (k = 1..N), :func:`fit_laws` finds the
parameters of any sum of laws (docs/contracts.md §2) that best explains them:

    kbar_model(X, w) = sum_j lin_j * B_j(X, w; shape)

where ``B`` stacks the basis functions of every law (:meth:`Law.basis`), ``lin``
are the parameters that enter linearly and ``shape`` the others. The fit is a
weighted least-squares fit of the real and imaginary parts, solved by variable
projection: for given shape parameters the linear ones follow from one exact
linear solve, so the nonlinear search runs over the shape parameters only (none
for most laws). docs/fitting.md states the definitions.

This is the front end; the method lives beside it, one concern a module: the inputs (:mod:`.samples`), variable
projection (:mod:`.projection`), the uncertainty (:mod:`.uncertainty`), fits that leave out outliers
(:mod:`.robust`), contact laws placed in their surroundings (:mod:`.placed`) and what a fit returns
(:mod:`.results`).
"""
from __future__ import annotations

from ..mechanics.surroundings import Surroundings
from .placed import _fit_placed
from .projection import RANK_RTOL, _fit_once, unit_exponents
from .results import CORRELATION_LIMIT, UNDETERMINED_Z, Combination, Correlation, Degeneracy, LawFit, TermFit
from .robust import HUBER_LIMIT, _fit_robust
from .samples import _Options, _resolve_terms, _Samples, _samples

__all__ = ["CORRELATION_LIMIT", "Combination", "Correlation", "Degeneracy", "HUBER_LIMIT", "LawFit", "RANK_RTOL",
           "TermFit", "UNDETERMINED_Z", "fit_laws", "unit_exponents"]


def fit_laws(laws, X, w, kbar, sigma=None, start=None, *, grid_points: int = 7, grid_budget: int = 128,
             n_starts: int = 3, tolerance: float = 1e-12, max_evaluations: int = 60,
             rank_rtol: float = RANK_RTOL, exclude_outliers: bool = False,
             surroundings: Surroundings | None = None) -> LawFit:
    """Fit a sum of laws on one element to complex-stiffness samples.

    Parameters
    ----------
    laws : sequence of str, Law or LawTerm
        The law terms of the element. A LawTerm's (possibly partial) values are
        starting values for the shape parameters; linear parameters need none.
    X : array_like, shape (N,) or scalar
        Element amplitude per sample, m (or rad), > 0.
    w : array_like, shape (N,) or scalar
        Angular frequency per sample, rad/s.
    kbar : array_like, complex, shape (N,)
        Equivalent complex stiffness samples, N/m (or N·m/rad).
    sigma : array_like, optional
        Standard deviation per sample: scalar or shape (N,) for the complex sample
        (``sqrt(E|e|^2)``, shared equally by real and imaginary parts), or shape
        (N, 2) for the real and imaginary parts separately; same units as kbar.
        Without it every part is weighted alike and standard errors are scaled by
        the reduced chi-square.
    start : sequence of mapping, optional
        One entry per law (or None): starting values by contract parameter name,
        overriding those of a LawTerm.
    grid_points : int
        Starting values per shape parameter on the scan grid.
    grid_budget : int
        Upper bound on the number of grid points (with several shape parameters
        the points per parameter shrink, down to 2).
    n_starts : int
        Number of best grid points refined by the bounded local search; the
        user's starting values are refined in addition. 0 with starting values
        for every shape parameter skips the grid scan (a quick refit); 0 without
        them refines the best grid point only.
    tolerance : float
        ftol, xtol and gtol of :func:`scipy.optimize.least_squares`.
    max_evaluations : int
        Residual evaluations per local search (finite-difference Jacobians not
        counted). A well-posed search needs about 5-25; running out means a flat
        cost (shape parameters the samples hardly determine) and is noted.
    rank_rtol : float
        Relative singular-value cut of the column-scaled weighted Jacobian below
        which a parameter combination counts as not determined.
    exclude_outliers : bool
        Leave out the samples that do not follow the fitted laws (chi-square of the
        sample above :func:`outlier_limit`, from an iteratively reweighted start), and
        scale the standard errors by the reduced chi-square where it exceeds 1
        (docs/fitting.md, "Outliers"). :attr:`LawFit.excluded` says which.
    surroundings : Surroundings, optional
        The structure around the element (:mod:`analysis.mechanics.surroundings`): a contact law (``placed``) is
        fitted by its kbar placed there, the mean and harmonics it drives in the structure included
        (:func:`_fit_placed`); without it, or without such a law, by its describing function alone.

    Returns
    -------
    LawFit

    Raises
    ------
    InputError
        Unknown law, malformed starting values, arrays of the wrong shape, non-finite
        samples, amplitudes <= 0, sigma <= 0, or no more real observations (2N)
        than fit parameters.
    """
    terms = _resolve_terms(laws, start, surroundings is not None and surroundings.in_reference,
                           surroundings.origin if surroundings is not None else None)
    X, w, kbar, w_re, w_im = _samples(X, w, kbar, sigma)
    opts = _Options(grid_points, grid_budget, n_starts, tolerance, max_evaluations, rank_rtol)
    data = _Samples(X, w, kbar, w_re, w_im, sigma is not None)
    fitter = _fit_robust if exclude_outliers else _fit_once
    if surroundings is None or not any(law.placed for law, _ in terms):
        return fitter(terms, data, opts)
    return _fit_placed(terms, data, opts, surroundings, fitter)
