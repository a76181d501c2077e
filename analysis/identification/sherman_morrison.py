"""The paper's identification route: recursive Sherman-Morrison updates and a root solve per line.

Adding one element ``kbar e e^T`` to a dynamic stiffness whose inverse is ``H`` gives
(Sherman-Morrison, paper eqs. 10-11)::

    Hbar = H - kbar (H e)(e^T H) / (1 + kbar e^T H e)

Applying this once per element, each time to the receptance already updated by the
previous ones, expresses ``hbar_pq(kbar_1, ..., kbar_r)`` (eqs. 14-21; for a grounded
element ``e`` is a unit vector and the update is eq. 11 entry by entry). Only the
DOFs the measurement and the elements touch are needed, so the updates run on that
principal block of H.

:func:`solve_per_line` then solves ``hbar_pq(kbar) = measured`` for the 2r real
unknowns at each line with :func:`scipy.optimize.root`, as the paper does. It is the
slow, independent cross-check of :mod:`analysis.identification.identify`, which needs no root solve.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.optimize

from ..common.errors import InputError

RESIDUAL_TOLERANCE = 1.0e-8


@dataclass
class RootSolveResult:
    """kbar per line from the root solve.

    Attributes
    ----------
    kbar : ndarray, shape (L, r), complex
        The solver's final point at each line, N/m (meaningful where ``converged``).
    converged : ndarray, shape (L,), bool
        The solver reported success and, for as many rows as elements, the scaled
        residual is below ``RESIDUAL_TOLERANCE``.
    evaluations : ndarray, shape (L,), int
        Residual evaluations used at each line.
    """

    kbar: np.ndarray
    converged: np.ndarray
    evaluations: np.ndarray


def receptance_with_elements(H, element_vectors, kbar) -> np.ndarray:
    """Receptance after adding the elements one at a time by rank-one updates.

    Parameters
    ----------
    H : array_like, shape (..., m, m), complex
        Receptance of the reference structure (or a principal block of it that
        contains every DOF the elements act on), m/N.
    element_vectors : array_like, shape (r, m)
        Row i is ``e_i``: +1 at the element's DOF a, -1 at b (between elements).
    kbar : array_like, shape (..., r), complex
        Equivalent complex stiffness of each element, N/m.

    Returns
    -------
    ndarray, shape (..., m, m), complex
        ``(H^-1 + sum_i kbar_i e_i e_i^T)^-1`` without forming an inverse.
    """
    updated = np.asarray(H, complex)
    vectors = np.asarray(element_vectors, float)
    kbar = np.asarray(kbar, complex)
    for i, e in enumerate(vectors):
        h_col = updated @ e                       # H e
        h_row = e @ updated                       # e^T H
        h_ee = h_col @ e                          # e^T H e
        gain = kbar[..., i] / (1.0 + kbar[..., i] * h_ee)
        updated = updated - gain[..., None, None] * h_col[..., :, None] * h_row[..., None, :]
    return updated


def solve_per_line(H, measured, rows: Sequence[int], column: int, elements: Sequence[tuple[int, ...]],
                   guess=None, xtol: float = 1.0e-12) -> RootSolveResult:
    """Solve the recursive Sherman-Morrison equations for kbar, one line at a time.

    Parameters
    ----------
    H : array_like, shape (L, n, n), complex
        Reference receptance, m/N.
    measured : array_like, shape (L, P), complex
        Measured receptance of rows ``rows`` in column ``column``, m/N.
    rows : sequence of int, length P >= r
        Measured DOF indices.
    column : int
        Excited DOF index.
    elements : sequence of tuple of int, length r
        ``(a,)`` for a grounded element, ``(a, b)`` for one between a and b.
    guess : array_like, shape (L, r) or (r,), complex, optional
        Starting point; default zero (the reference structure), as in the paper.
    xtol : float
        Relative step tolerance of the solver.

    Returns
    -------
    RootSolveResult

    Notes
    -----
    The unknowns are ``[Re kbar, Im kbar]`` and the equations ``[Re, Im]`` of
    ``(hbar_model - measured) / max|measured|``. With as many rows as elements
    the system is square and Powell's hybrid method (MINPACK hybrd, as
    ``fsolve``) is used; with more rows, Levenberg-Marquardt least squares.
    """
    H = np.asarray(H, complex)
    measured = np.asarray(measured, complex)
    rows = [int(p) for p in rows]
    elements = [tuple(int(d) for d in el) for el in elements]
    r = len(elements)
    if H.ndim != 3 or H.shape[1] != H.shape[2]:
        raise InputError(f"reference receptance must have shape (lines, n, n), got {H.shape}", field="H")
    n_lines, n = H.shape[0], H.shape[1]
    if measured.shape != (n_lines, len(rows)):
        raise InputError(f"measured receptance must have shape ({n_lines}, {len(rows)}), got {measured.shape}",
                         field="measured")
    if len(rows) < r:
        raise InputError(f"{r} elements need at least {r} measured FRF rows; got {len(rows)}", field="measured")
    involved = sorted({*rows, column, *(d for el in elements for d in el)})
    if involved[0] < 0 or involved[-1] >= n or any(len(el) not in (1, 2) for el in elements):
        raise InputError(f"rows, column and element DOFs must be indices in 0..{n - 1}; elements (a,) or (a, b)",
                         field="elements")
    local = {dof: k for k, dof in enumerate(involved)}
    vectors = np.zeros((r, len(involved)))
    for i, el in enumerate(elements):
        vectors[i, local[el[0]]] = 1.0
        if len(el) == 2:
            vectors[i, local[el[1]]] = -1.0
    row_local = [local[p] for p in rows]
    q_local = local[column]
    block = H[:, involved][:, :, involved]
    start = np.zeros((n_lines, r), complex) if guess is None else np.broadcast_to(
        np.asarray(guess, complex), (n_lines, r))
    square = len(rows) == r
    method, options = ("hybr", {"xtol": xtol}) if square else ("lm", {"xtol": xtol, "ftol": xtol})

    kbar = np.zeros((n_lines, r), complex)
    converged = np.zeros(n_lines, bool)
    evaluations = np.zeros(n_lines, int)
    for line in range(n_lines):
        target = measured[line]
        scale = np.abs(target).max()
        scale = scale if scale > 0.0 else 1.0

        def equations(x, h=block[line], target=target, scale=scale):
            model = receptance_with_elements(h, vectors, x[:r] + 1j * x[r:])[row_local, q_local]
            mismatch = (model - target) / scale
            return np.concatenate([mismatch.real, mismatch.imag])

        x0 = np.concatenate([start[line].real, start[line].imag])
        with np.errstate(all="ignore"):
            sol = scipy.optimize.root(equations, x0, method=method, options=options)
        evaluations[line] = sol.nfev
        kbar[line] = sol.x[:r] + 1j * sol.x[r:]
        final = np.asarray(sol.fun)
        converged[line] = bool(sol.success) and np.isfinite(final).all() and (
            not square or np.abs(final).max() <= RESIDUAL_TOLERANCE)
    return RootSolveResult(kbar, converged, evaluations)
