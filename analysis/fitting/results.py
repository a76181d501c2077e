"""What a law fit returns: each law's fitted parameters with their standard errors (:class:`TermFit`), the
parameter combinations the samples determine where the parameters themselves are not (:class:`Degeneracy`,
:class:`Combination`), pairs of estimates that correlate beyond :data:`CORRELATION_LIMIT` (:class:`Correlation`), and
the whole fit (:class:`LawFit`: residuals, chi-square, information criteria, covariance). docs/fitting.md.
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np

from ..common.statistics import OUTLIER_SHARE_LIMIT, capped_chi_square
from ..laws import Law
from ..laws.base import LimitReading, broadcast
from ..mechanics.elements import LawTerm
from ..mechanics.surroundings import Surroundings, placed_kbar


#: Two parameters whose estimates correlate beyond this (in magnitude) lie along a near-flat direction of the
#: fit: the samples determine a combination of them, not each one (docs/fitting.md, "Identifiability").
CORRELATION_LIMIT = 0.99
#: A parameter closer to zero than this many standard errors is "not determined by the data": its 95 %
#: interval holds zero, so the samples tell neither its size nor its sign.
UNDETERMINED_Z = 1.959964


@dataclass
class TermFit:
    """The fitted values of one law term.

    Attributes
    ----------
    law : Law
        The law.
    label : str
        Name used in notes: the law's name, or ``name[i]`` (``i`` its position in
        the list of laws) when the same law appears twice.
    params : dict[str, float]
        Contract parameters (docs/contracts.md §2), in the law's units.
    stderr : dict[str, float]
        Standard errors of ``params``, same units; ``inf`` where the data do not
        determine the parameter (see :attr:`LawFit.degeneracies`).
    fit_params : dict[str, float]
        The same values in the law's fit parametrisation (linear, then shape).
    undetermined : tuple[str, ...]
        Contract parameters the samples do not determine: an infinite standard error, a 95 %
        interval that holds zero (``UNDETERMINED_Z``), or a member of a correlated pair
        (:attr:`LawFit.correlated`). Their values are not findings; print them as undetermined.
    surroundings : Surroundings or None
        Where a contact law was fitted placed in its structure (``fit_laws(surroundings=...)``): the
        structure around the element with the element's amplitude-independent laws; its kbar is placed there.
    limit : TermFit or None
        Where the law was taken in a limit the data cannot tell it from (:mod:`analysis.fitting.limits`): the fit
        of the limit's own form, whose parameters are the combination the data determine; ``params`` are then the
        law placed in that limit, and the parameters the limit leaves open have no finite ``stderr``.
    """

    law: Law
    label: str
    params: dict[str, float]
    stderr: dict[str, float]
    fit_params: dict[str, float]
    undetermined: tuple[str, ...] = ()
    surroundings: Surroundings | None = None
    limit: "TermFit | None" = None

    @property
    def findings(self) -> "TermFit":
        """The fit whose parameters and errors are what the data determine: the limit's own form where the law
        was taken in a limit (:attr:`limit`), else this one."""
        return self.limit or self

    def reading_words(self, reading: LimitReading, rotational: bool = False) -> str:
        """The values of ``reading`` (this law read in a limit) as the user reads them: with the errors of
        :attr:`findings`, and what that fit leaves open worded as not determined (a stiffness of 1e26 that a
        linear spring beside it shares is no finding)."""
        found = self.findings
        return reading.values_text(rotational, found.stderr, found.undetermined)

    @property
    def size_unseen(self) -> bool:
        """Whether the samples leave the law's size open: every linear parameter (its force scale) has a 95 %
        interval that holds zero, or no finite error. Such a law fits nothing of the samples."""
        return all(not np.isfinite(self.stderr[n]) or abs(self.params[n]) < UNDETERMINED_Z * self.stderr[n]
                   for n in self.law.linear)

    def law_term(self) -> LawTerm:
        """The fitted term as a :class:`LawTerm` (e.g. to write a fitted model file)."""
        return LawTerm(self.law, dict(self.params))

    def describing_function(self, X, w) -> np.ndarray:
        """kbar of this term, complex, broadcast over X (m or rad) and w (rad/s)."""
        if self.surroundings is not None:
            return placed_kbar([(self.law, self.params)], X, w, self.surroundings)
        if not hasattr(self, "_term"):            # one validated LawTerm, reused by the solvers
            self._term = self.law_term()
        return self._term.describing_function(X, w)


@dataclass(frozen=True)
class Combination:
    """A linear combination of fit parameters that the samples do determine.

    Attributes
    ----------
    coefficients : dict[str, float]
        ``label.name`` -> coefficient; the largest coefficient magnitude is 1.
    value : float
        The combination evaluated at the fitted parameters.
    stderr : float
        Its standard error.
    """

    coefficients: dict[str, float]
    value: float
    stderr: float

    def __str__(self) -> str:
        parts = []
        for name, a in self.coefficients.items():
            sign = "-" if a < 0 else "+"
            magnitude = "" if f"{abs(a):.4g}" == "1" else f"{abs(a):.4g}*"
            parts.append(f"{sign} {magnitude}{name}")
        text = " ".join(parts)
        text = text[2:] if text.startswith("+ ") else text
        return f"{text} = {self.value:.6g} ± {self.stderr:.2g}"


@dataclass(frozen=True)
class Degeneracy:
    """A group of fit parameters that the samples do not determine separately.

    Attributes
    ----------
    parameters : tuple[str, ...]
        ``label.name`` of every fit parameter in the group; each has an infinite
        standard error.
    determined : tuple[Combination, ...]
        The combinations of them the samples still determine (e.g. ``k_pos + k_neg``
        for bilinear); empty when the samples say nothing about any of them.
    """

    parameters: tuple[str, ...]
    determined: tuple[Combination, ...]

    def __str__(self) -> str:
        names = ", ".join(self.parameters)
        if not self.determined:
            if len(self.parameters) == 1:
                return f"not identifiable from these samples: {names}"
            return f"not identifiable from these samples: {names} (no combination of them is determined)"
        return (f"not separately identifiable: {names}; the samples determine only "
                + "; ".join(str(c) for c in self.determined))

    def to_json(self) -> dict:
        return {"parameters": list(self.parameters),
                "determined": [{"combination": dict(c.coefficients), "value": c.value, "stderr": c.stderr}
                               for c in self.determined], "text": str(self)}


@dataclass(frozen=True)
class Correlation:
    """Two contract parameters the samples determine only together: their estimates correlate beyond
    ``CORRELATION_LIMIT`` (a near-flat direction of the fit, e.g. a linear spring beside an iwan ``kt`` on
    samples without macro-slip).

    Attributes
    ----------
    parameters : tuple[str, str]
        ``label.name`` of the two contract parameters.
    correlation : float
        The correlation of their estimates (-1..1).
    determined : Combination
        The combination of them the samples determine best, with its value and standard error.
    """

    parameters: tuple[str, ...]
    correlation: float
    determined: Combination

    def __str__(self) -> str:
        return (f"not determined separately (correlation {self.correlation:+.4f}): {' and '.join(self.parameters)}; "
                f"the samples determine {self.determined}")

    def to_json(self) -> dict:
        c = self.determined
        return {"parameters": list(self.parameters), "correlation": self.correlation,
                "combination": dict(c.coefficients), "value": c.value, "stderr": c.stderr, "text": str(self)}


@dataclass
class LawFit:
    """Result of :func:`fit_laws`.

    Attributes
    ----------
    terms : list[TermFit]
        One entry per law term, in the order given.
    residuals : ndarray, complex, shape (N,)
        ``kbar_model - kbar`` per sample, in the units of kbar (N/m or N·m/rad).
    normalized_residuals : ndarray, complex, shape (N,)
        Residual parts divided by their standard deviations,
        ``Re r / sigma_re + j Im r / sigma_im`` (equal to ``residuals`` when no
        sigma was given).
    chi_square : float
        Sum of squares of the normalized residual parts.
    dof : int
        Degrees of freedom, ``2 N - effective_parameters``.
    n_samples : int
        Number of complex samples N (2 N real observations).
    n_parameters : int
        Number of fit parameters (all laws, linear and shape).
    effective_parameters : int
        Numerical rank of the weighted Jacobian at the optimum: the number of
        parameter combinations the samples determine.
    aic, bic : float
        Akaike and Bayesian information criteria (docs/fitting.md); smaller is
        better, comparable between fits of the same samples with the same sigma.
    sigma_given : bool
        Whether sample standard deviations were given; if not, the standard errors
        are scaled by the reduced chi-square.
    fit_parameter_names : list[str]
        ``label.name`` of the fit parameters, the order of ``covariance``.
    covariance : ndarray, shape (n_parameters, n_parameters)
        Covariance of the fit parameters (pseudo-inverse on the determined
        subspace); a non-identifiable parameter has ``inf`` variance and ``nan``
        covariances.
    degeneracies : list[Degeneracy]
        Non-identifiable parameter groups.
    notes : list[str]
        Human-readable remarks: degeneracies, correlated groups, parameters that ended on a
        bound, a shape search that ran out of evaluations, samples left out as outliers.
    correlated : list[Correlation]
        Pairs of contract parameters the samples determine only together.
    excluded : ndarray of bool, shape (N,), or None
        With ``exclude_outliers``: the samples left out of the fit (their residuals are still
        reported); None otherwise.
    """

    terms: list[TermFit]
    residuals: np.ndarray
    normalized_residuals: np.ndarray
    chi_square: float
    dof: int
    n_samples: int
    n_parameters: int
    effective_parameters: int
    aic: float
    bic: float
    sigma_given: bool
    fit_parameter_names: list[str]
    covariance: np.ndarray
    degeneracies: list[Degeneracy] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    correlated: list[Correlation] = field(default_factory=list)
    excluded: np.ndarray | None = None

    @property
    def outlier_share(self) -> float:
        """The share of the samples left out as outliers (0 for a fit that leaves none out)."""
        return float(np.mean(self.excluded)) if self.excluded is not None and len(self.excluded) else 0.0

    @property
    def describes_the_data(self) -> bool:
        """At most OUTLIER_SHARE_LIMIT of the samples left out (:data:`analysis.common.statistics.OUTLIER_SHARE_LIMIT`):
        beyond it the laws follow a part of the data, and the fit is no description of the element."""
        return self.outlier_share <= OUTLIER_SHARE_LIMIT

    @property
    def judged_chi_square(self) -> float:
        """The chi-square fits of the same samples are compared by: capped at the outlier limit per sample
        (:func:`analysis.common.statistics.capped_chi_square`) where the fit left samples out, so that a fit gains
        nothing by leaving out more; the plain chi-square otherwise."""
        if self.excluded is None:
            return self.chi_square
        return capped_chi_square(np.abs(self.normalized_residuals) ** 2)

    @property
    def reduced_chi_square(self) -> float:
        """chi_square / dof (about 1 when the model is right and sigma is true)."""
        return self.chi_square / self.dof

    @property
    def identifiable(self) -> bool:
        """True when every fit parameter is determined by the samples."""
        return not self.degeneracies

    def law_terms(self) -> list[LawTerm]:
        """The fitted terms as :class:`LawTerm` objects."""
        return [t.law_term() for t in self.terms]

    def seen(self) -> list[list[str]]:
        """Per term, the contract parameters the samples see: a finite standard error (not a degeneracy's
        member, not left open by a limit the law was taken in). What a refinement of the same laws against the
        FRFs may move: the single-harmonic FRFs see a law only through its describing function at the amplitudes
        the lines reached, as the samples do, so a direction the samples do not see is one the FRFs do not see
        either, and a search free to move it drifts along it (a damper measured from an origin, which the
        origin's damper cancels, to 1e14; an Iwan joint in micro-slip out of its limit) to values whose
        time-domain force is rounding."""
        return [[n for n in t.law.param_names if t.stderr.get(n) != math.inf] for t in self.terms]

    def describing_function(self, X, w) -> np.ndarray:
        """kbar of the fitted sum of laws, complex, broadcast over X and w (rad/s)."""
        X, w = broadcast(np.asarray(X, float), np.asarray(w, float))
        return sum((t.describing_function(X, w) for t in self.terms), np.zeros(X.shape, complex))
