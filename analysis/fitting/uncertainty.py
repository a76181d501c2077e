"""The uncertainty of a law fit: the covariance from the column-scaled weighted Jacobian, with its rank cut at
``rank_rtol`` (:func:`_covariance`); the parameter combinations the samples determine along the undetermined
directions, in their sparsest basis (:func:`_sparse_basis`); standard errors in the laws' own parameters
(:func:`_term_fits`), correlated pairs and parameters not determined by the data; and the information criteria
AIC and BIC (:func:`_information_criteria`). docs/fitting.md, "Identifiability".
"""
from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np

from ..common.statistics import charged_criterion
from .results import CORRELATION_LIMIT, UNDETERMINED_Z, Combination, Correlation, TermFit

if TYPE_CHECKING:
    from .projection import _Problem


# A parameter is reported non-identifiable when its squared component in the null
# space exceeds this (round-off and finite-difference noise stay far below it).
_NULL_WEIGHT = 1e-8
# Largest group of undetermined parameters whose determined combinations are searched for the sparsest basis
# (2^n small SVDs).
_SPARSE_LIMIT = 10
# Singular values (of orthonormal rows) below this count as zero there: the finite-difference Jacobian leaves
# the exact zeros at about 1e-8..1e-7.
_SPARSE_TOL = 1e-6


def _column_norms(A: np.ndarray) -> np.ndarray:
    """Each column's norm, 1 for a zero column (the scaling that makes the rank cut independent of units)."""
    norms = np.linalg.norm(A, axis=0)
    return np.where(norms > 0, norms, 1.0)


def _covariance(J: np.ndarray, rank_rtol: float):
    """Pseudo-inverse covariance (unscaled), rank, non-identifiable mask and groups.

    Columns are scaled to unit norm first so that the rank decision does not depend
    on the parameters' units. Each group is ``(indices, coefficient vectors)``: the
    coupled undetermined parameters and the combinations of them still determined
    (full-length coefficient vectors, largest magnitude 1).
    """
    P = J.shape[1]
    norms = _column_norms(J)
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)   # 2N > P: Vt is P x P
    keep = s > rank_rtol * s[0] if s[0] > 0 else np.zeros(P, bool)
    V = Vt.T
    cov = ((V[:, keep] / s[keep] ** 2) @ V[:, keep].T) / np.outer(norms, norms)
    null = V[:, ~keep]
    projector = null @ null.T        # independent of the basis chosen inside the null space
    involved = np.diag(projector) > _NULL_WEIGHT
    groups = []
    for group in _coupled_groups(projector, involved):
        # determined directions inside the group (in scaled parameters norm_j * theta_j)
        values, vectors = np.linalg.eigh(np.eye(len(group)) - projector[np.ix_(group, group)])
        combos = []
        for row in _sparse_basis(vectors[:, values > 0.5].T):
            coef = np.zeros(P)
            coef[group] = row * norms[group]
            combos.append(coef / coef[np.argmax(np.abs(coef))])
        groups.append((group, combos))
    return cov, int(np.count_nonzero(keep)), involved, groups


def _sparse_basis(rows: np.ndarray) -> np.ndarray:
    """The sparsest basis of the determined combinations (rows: a basis, in scaled parameters).

    Any basis of the determined subspace is right; the sparse one is what can be read: where the samples fix
    ``k + kt`` beside a combination of the iwan shapes, it says so instead of two mixtures of all four. For
    each set of parameters to leave out (most first), a combination without them exists when the basis
    restricted to them has a one-dimensional left null space; such combinations are taken, sparsest first,
    while they add a dimension. Of equally sparse ones, those that leave out the parameters listed last come
    first: the linear parameters (stiffnesses, sizes) are listed before the shapes, and a sum of stiffnesses the
    samples fix reads as itself, not as two mixtures each with a shape in it. Groups beyond ``_SPARSE_LIMIT``
    parameters keep the given basis."""
    m, g = rows.shape
    if g > _SPARSE_LIMIT or m == 0:
        return rows
    chosen: list[np.ndarray] = []
    for n_zero in range(g - 1, -1, -1):
        for zero in reversed(list(itertools.combinations(range(g), n_zero))):
            restricted = rows[:, list(zero)]
            _, sv, vt = np.linalg.svd(restricted.T, full_matrices=True) if n_zero else (None, np.zeros(0), np.eye(m))
            null = vt[np.count_nonzero(sv > _SPARSE_TOL):]
            if len(null) != 1:
                continue
            candidate = null[0] @ rows
            candidate[np.abs(candidate) < _SPARSE_TOL * np.abs(candidate).max()] = 0.0
            if np.linalg.matrix_rank(np.array(chosen + [candidate]), tol=_SPARSE_TOL) > len(chosen):
                chosen.append(candidate)
                if len(chosen) == m:
                    return np.array(chosen)
    return np.array(chosen) if len(chosen) == m else rows


def _coupled_groups(projector: np.ndarray, involved: np.ndarray) -> list[list[int]]:
    """Connected groups of involved parameters (coupled through the null-space projector)."""
    remaining = set(np.flatnonzero(involved).tolist())
    groups = []
    while remaining:
        group, frontier = [], [min(remaining)]
        remaining -= set(frontier)
        while frontier:
            i = frontier.pop()
            group.append(i)
            linked = {j for j in remaining if abs(projector[i, j]) > _NULL_WEIGHT}
            remaining -= linked
            frontier.extend(linked)
        groups.append(sorted(group))
    return groups


def _information_criteria(chi_square: float, rank: int, n_obs: int, sigma_given: bool) -> tuple[float, float]:
    """AIC and BIC (docs/fitting.md): -2 ln L up to a model-independent constant, plus the penalty."""
    if sigma_given:
        fit_term, k = chi_square, rank
    else:
        # Gaussian likelihood with the variance estimated as chi^2 / n: one more parameter
        # a perfect fit: its variance can round to zero below the smallest float (chi^2 itself subnormal)
        variance = chi_square / n_obs
        fit_term = n_obs * math.log(variance) if variance > 0 else -math.inf
        k = rank + 1
    return fit_term + 2 * k, charged_criterion(fit_term, k, n_obs)


def _term_fits(problem: _Problem, fit_values: np.ndarray, cov: np.ndarray,
               unidentified: np.ndarray) -> tuple[list[TermFit], list[str], np.ndarray]:
    """Contract parameters and their standard errors per law term (through ``Law.fit_jacobian``), with the
    names (``label.name``) and covariance of all contract parameters (undetermined rows and columns NaN)."""
    out, names, blocks_G, blocks_idx = [], [], [], []
    for blk in problem.blocks:
        law = blk.law
        idx = [*range(blk.linear.start, blk.linear.stop),
               *(problem.n_linear + j for j in range(blk.shape.start, blk.shape.stop))]
        fit_names = [*law.linear, *(p.name for p in law.shape)]
        values = dict(zip(fit_names, fit_values[idx].tolist()))
        lin = {name: values[name] for name in law.linear}
        shp = {p.name: values[p.name] for p in law.shape}
        params = {name: float(value) for name, value in law.from_fit(lin, shp).items()}
        G = law.fit_jacobian(lin, shp)
        free = ~unidentified[idx]
        block_cov = cov[np.ix_(idx, idx)][np.ix_(free, free)]
        var = np.einsum("ij,jk,ik->i", G[:, free], block_cov, G[:, free])
        # a contract parameter that depends on an undetermined fit parameter is undetermined
        scale = np.max(np.abs(G), axis=1, keepdims=True)
        depends_on_unidentified = np.any(np.abs(G[:, ~free]) > 1e-12 * scale, axis=1)
        stderr = np.where(depends_on_unidentified, np.inf, np.sqrt(np.maximum(var, 0.0)))
        out.append(TermFit(law, blk.label, params, dict(zip(law.param_names, stderr.tolist())), values,
                           tuple(n for n, bad in zip(law.param_names, depends_on_unidentified) if bad)))
        names += [f"{blk.label}.{n}" for n in law.param_names]
        blocks_G.append(np.where(depends_on_unidentified[:, None], np.nan, G))
        blocks_idx += idx
    G_all = np.zeros((len(names), len(blocks_idx)))
    row = col = 0
    for G in blocks_G:
        G_all[row:row + G.shape[0], col:col + G.shape[1]] = G
        row, col = row + G.shape[0], col + G.shape[1]
    sub = cov[np.ix_(blocks_idx, blocks_idx)]
    sub = np.where(np.isfinite(sub), sub, 0.0)              # undetermined rows of G are NaN already
    return out, names, G_all @ sub @ G_all.T


def _correlated_pairs(terms: list[TermFit], names: list[str], cov: np.ndarray) -> list[Correlation]:
    """Pairs of contract parameters whose estimates correlate beyond ``CORRELATION_LIMIT`` (a near-flat
    direction of the fit), each with the combination of the two the samples determine best.

    For standard errors s_i, s_j and correlation r that combination is ``p_i / s_i - sign(r) p_j / s_j``
    (the smaller eigenvalue's direction of the pair's correlation matrix), scaled so that its largest
    coefficient is 1: ``k + kt`` for a linear spring beside an iwan kt."""
    values = np.array([v for t in terms for v in t.params.values()])
    std = np.sqrt(np.abs(np.diag(cov)))
    usable = np.isfinite(std) & (std > 0)
    out = []
    for i, j in zip(*np.triu_indices(len(names), k=1)):
        if not (usable[i] and usable[j]):
            continue
        r = cov[i, j] / (std[i] * std[j])
        if not abs(r) > CORRELATION_LIMIT:
            continue
        a = np.array([1.0 / std[i], -math.copysign(1.0, r) / std[j]])
        a /= a[np.argmax(np.abs(a))]
        pair = [i, j]
        variance = a @ cov[np.ix_(pair, pair)] @ a
        combo = Combination({names[i]: float(a[0]), names[j]: float(a[1])}, float(a @ values[pair]),
                            float(np.sqrt(max(variance, 0.0))))
        out.append(Correlation((names[i], names[j]), float(r), combo))
    return out


def _mark_undetermined(terms: list[TermFit], correlated: list[Correlation]) -> None:
    """Mark the contract parameters the samples do not determine: no finite standard error, a 95 % interval
    that holds zero (``abs(value) < UNDETERMINED_Z * stderr``), or a member of a correlated pair."""
    in_group = {name for g in correlated for name in g.parameters}
    for t in terms:
        marked = set(t.undetermined)
        for name, value in t.params.items():
            err = t.stderr[name]
            if (not math.isfinite(err) or abs(value) < UNDETERMINED_Z * err
                    or f"{t.label}.{name}" in in_group):
                marked.add(name)
        t.undetermined = tuple(n for n in t.law.param_names if n in marked)
