"""The inputs of a law fit, validated: the law terms with their starting values, and the samples ``X`` (m or rad,
shape (N,)), ``w`` (rad/s, (N,)), ``kbar`` (N/m, complex, (N,)) with their per-part weights ``1 / std`` of the real
and imaginary parts (:class:`_Samples`); the search settings (:class:`_Options`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..common.errors import InputError
from ..common.statistics import part_weight
from ..laws import Law, get_law
from ..mechanics.elements import LawTerm


def _resolve_terms(laws, start, relative: bool = False) -> list[tuple[Law, dict[str, float]]]:
    """(law, starting values) per term from names, Law objects or LawTerms; ``relative``: each law measured from
    its small-amplitude state (:meth:`analysis.laws.base.Law.relative`), the element's reference holding it."""
    if isinstance(laws, (str, Law, LawTerm)):
        laws = [laws]
    try:
        laws = list(laws)
    except TypeError:
        raise InputError(f"must be a list of law names, Law or LawTerm objects, got {type(laws).__name__}",
                         None, "laws") from None
    if not laws:
        raise InputError("no law to fit: give at least one", None, "laws")
    if start is not None:
        start = list(start)
        if len(start) != len(laws):
            raise InputError(f"has {len(start)} entries for {len(laws)} laws", None, "start")
    terms = []
    for i, entry in enumerate(laws):
        where = f"laws[{i}]"
        if isinstance(entry, LawTerm):
            law, values = entry.law, dict(entry.values)
        elif isinstance(entry, Law):
            law, values = entry, {}
        elif isinstance(entry, str):
            law, values = get_law(entry, None, where), {}
        else:
            raise InputError(f"must be a law name, Law or LawTerm, got {type(entry).__name__}", None, where)
        if start is not None and start[i] is not None:
            if not isinstance(start[i], Mapping):
                raise InputError(f"must be a table of parameter values, got {type(start[i]).__name__}",
                                 None, f"start[{i}]")
            values.update(start[i])
        terms.append((law.relative() if relative else law, law.check_params(values, field=where)))
    return terms


def _real_array(value, name: str, n: int | None = None) -> np.ndarray:
    """``value`` as a float array; with ``n``, a scalar or shape (n,) broadcast to (n,)."""
    try:
        a = np.asarray(value, float)
    except (TypeError, ValueError):
        raise InputError("must be an array of real numbers", None, name) from None
    if n is None:
        return a
    if a.ndim > 1 or (a.ndim == 1 and a.size != n):
        raise InputError(f"shape {a.shape} does not match kbar's {(n,)}", None, name)
    return np.broadcast_to(a, (n,)).copy()


def _samples(X, w, kbar, sigma):
    """Validated samples X, w, kbar and per-part weights 1/std (real, imaginary), each shape (N,)."""
    try:
        kbar = np.asarray(kbar, complex)
    except (TypeError, ValueError):
        raise InputError("must be an array of complex numbers", None, "kbar") from None
    if kbar.ndim != 1 or kbar.size == 0:
        raise InputError(f"must be a non-empty 1-D array, got shape {kbar.shape}", None, "kbar")
    n = kbar.size
    X, w = _real_array(X, "X", n), _real_array(w, "w", n)
    for name, a in (("X", X), ("w", w), ("kbar", kbar)):
        bad = np.count_nonzero(~np.isfinite(a))
        if bad:
            raise InputError(f"{bad} of {n} values are not finite (NaN or inf)", None, name)
    if np.any(X <= 0):
        raise InputError("amplitudes must be > 0", None, "X")
    if sigma is None:
        return X, w, kbar, np.ones(n), np.ones(n)
    s = _real_array(sigma, "sigma")
    if s.ndim == 0:
        s = np.full(n, float(s))
    if s.shape == (n,):
        w_re = w_im = part_weight(s)          # std of the complex sample: each part carries half the variance
    elif s.shape == (n, 2):
        w_re, w_im = 1.0 / s[:, 0], 1.0 / s[:, 1]
    else:
        raise InputError(f"must be a scalar, shape (N,) or (N, 2) with N = {n}, got {s.shape}", None, "sigma")
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise InputError("standard deviations must be finite and > 0", None, "sigma")
    return X, w, kbar, w_re, w_im


@dataclass(frozen=True)
class _Options:
    """The search settings of :func:`fit_laws`."""

    grid_points: int
    grid_budget: int
    n_starts: int
    tolerance: float
    max_evaluations: int
    rank_rtol: float


@dataclass(frozen=True)
class _Samples:
    """Validated samples with their per-part weights (1 / std); ``sigma_given`` False: unit weights."""

    X: np.ndarray
    w: np.ndarray
    kbar: np.ndarray
    w_re: np.ndarray
    w_im: np.ndarray
    sigma_given: bool

    def subset(self, keep: np.ndarray, weight: np.ndarray | None = None) -> "_Samples":
        """The kept samples, their stds divided by ``sqrt(weight)`` (iteratively reweighted fits)."""
        root = 1.0 if weight is None else np.sqrt(weight[keep])
        return _Samples(self.X[keep], self.w[keep], self.kbar[keep], self.w_re[keep] * root,
                        self.w_im[keep] * root, self.sigma_given)

    def distance(self, model: np.ndarray) -> np.ndarray:
        """sqrt of each sample's chi-square contribution (Re and Im together) against a model kbar."""
        r = model - self.kbar
        return np.hypot(r.real * self.w_re, r.imag * self.w_im)
