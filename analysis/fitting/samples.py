"""The inputs of a law fit, validated: the law terms with their starting values, and the samples ``X`` (m or rad,
shape (N,)), ``w`` (rad/s, (N,)), ``kbar`` (N/m, complex, (N,)) with their per-part weights ``1 / std`` of the real
and imaginary parts (:class:`_Samples`); the search settings (:class:`_Options`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..common.errors import InputError
from ..common.recent import Recent
from ..common.statistics import part_weight
from ..laws import Law, get_law
from ..laws.base import Origin
from ..mechanics.elements import LawTerm


def _resolve_terms(laws, start, relative: bool = False, origin: Origin | None = None
                   ) -> list[tuple[Law, dict[str, float]]]:
    """(law, starting values) per term from names, Law objects or LawTerms; ``relative``: each law measured from
    its small-amplitude state, or from ``origin`` where the reference was made at one
    (:meth:`analysis.laws.base.Law.relative`), the element's reference holding that state."""
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
        terms.append((law.relative(origin) if relative else law, law.check_params(values, field=where)))
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


#: Law bases kept by one fit's samples (:class:`_Bases`): a local search's point and its finite-difference steps
#: for a few laws, over the passes that restart where the last one ended
_KEPT_BASES = 64


class _Bases:
    """The laws' unweighted bases (complex, shape (p, N)) at one fit's amplitudes ``X`` and frequencies ``w``,
    kept by law and shape values for every pass of that fit. A reweighted pass, an outlier pass or a refit starts
    at the values the last pass ended on and asks again for the bases there and at its first finite-difference
    steps; a basis is a harmonic balance per sample for a placed contact. Between passes only the weights and the
    samples left out change, never X and w, so a basis is evaluated at every sample once and each pass takes its
    rows."""

    def __init__(self, X: np.ndarray, w: np.ndarray):
        self.X, self.w = X, w
        self._kept: Recent[tuple[Law, np.ndarray]] = Recent(_KEPT_BASES)

    def at(self, law: Law, shape: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
        """``law``'s basis at shape values ``shape`` (natural units, in ``law.shape``'s order), on ``rows`` of the
        samples (None: all). Kept by the law object itself (held, so its identity is not reused)."""
        key = (id(law), shape.tobytes())
        kept = self._kept.get(key)
        if kept is None or kept[0] is not law:
            values = dict(zip((p.name for p in law.shape), shape))
            basis = np.asarray(law.basis(self.X, self.w, **values), complex).reshape(-1, self.X.size)
            kept = self._kept.keep(key, (law, basis))
        return kept[1] if rows is None else kept[1][:, rows]


@dataclass(frozen=True)
class _Samples:
    """Validated samples with their per-part weights (1 / std); ``sigma_given`` False: unit weights. ``bases``:
    the laws' bases at the samples this set was taken from, ``rows`` which of those samples it holds (None:
    all), shared by every subset and reweighting of them."""

    X: np.ndarray
    w: np.ndarray
    kbar: np.ndarray
    w_re: np.ndarray
    w_im: np.ndarray
    sigma_given: bool
    bases: _Bases | None = field(default=None, compare=False)
    rows: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self):
        if self.bases is None:
            object.__setattr__(self, "bases", _Bases(self.X, self.w))

    def subset(self, keep: np.ndarray, weight: np.ndarray | None = None) -> "_Samples":
        """The kept samples, their stds divided by ``sqrt(weight)`` (iteratively reweighted fits)."""
        root = 1.0 if weight is None else np.sqrt(weight[keep])
        rows = np.flatnonzero(keep) if self.rows is None else self.rows[keep]
        return _Samples(self.X[keep], self.w[keep], self.kbar[keep], self.w_re[keep] * root,
                        self.w_im[keep] * root, self.sigma_given, self.bases,
                        None if rows.size == self.bases.X.size else rows)

    def reweighted(self, w_re: np.ndarray, w_im: np.ndarray, sigma_given: bool) -> "_Samples":
        """The same samples with other weights."""
        return _Samples(self.X, self.w, self.kbar, w_re, w_im, sigma_given, self.bases, self.rows)

    def distance(self, model: np.ndarray) -> np.ndarray:
        """sqrt of each sample's chi-square contribution (Re and Im together) against a model kbar."""
        r = model - self.kbar
        return np.hypot(r.real * self.w_re, r.imag * self.w_im)
