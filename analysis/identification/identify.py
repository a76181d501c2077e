"""Equivalent complex stiffness of unknown elements from measured FRFs, in closed form.

The structure with its unknown elements has the dynamic stiffness ``Z + Delta`` with
``Delta = sum_i kbar_i e_i e_i^T`` (paper eq. 5-7), where ``e_i`` is +1 at the
element's DOF ``a`` and -1 at ``b`` for an element between two DOFs. From
``(Z + Delta) Hbar = I`` and ``H = Z^-1`` follows ``Hbar = H - H Delta Hbar``; for one
excited column ``q`` and the measured rows ``P`` this is *linear* in
``u_i = kbar_i e_i^T hbar_q`` (docs/method.md §1)::

    H_{P,A} u = h_{P,q} - hbar_{P,q}            (least squares when |P| > r)
    hbar_{e,q} = E^T h_q - E^T H E u            (element response, measured or not)
    kbar_i = u_i / hbar_{e_i,q}

with ``H_{P,A} = H_{P,:} E`` and ``E = [e_1 ... e_r]``. It is exact to round-off on
noise-free data and has the same minimiser as the paper's recursive
Sherman-Morrison equations (eqs. 14-21) solved numerically: the map ``kbar -> u`` is
one-to-one wherever ``hbar_e != 0`` and the model FRF is ``h_{P,q} - H_{P,A} u``, so
the output error is the same function in either parametrisation. All frequency
lines are solved at once.

Noise model: the measured receptance of row ``p`` at line ``l`` carries circular
complex noise with ``E|n|^2 = std[l, p]^2`` (real and imaginary parts each
``std / sqrt(2)``), independent between rows and lines. It is propagated to first
order; ``kbar_std`` is ``sqrt(E|delta kbar|^2)`` in the same sense.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.ndimage import median_filter

from ..common.errors import InputError
from ..mechanics.elements import Element
from ..mechanics.structures import Structure

DEFAULT_COND_LIMIT = 1.0e3
DEFAULT_ANTIRESONANCE_RATIO = 1.0e-2
DEFAULT_ANTIRESONANCE_WINDOW = 10


@dataclass
class ComplexStiffnessIdentification:
    """Result of :func:`identify_complex_stiffness` for L lines and r elements.

    Attributes
    ----------
    kbar : ndarray, shape (L, r), complex
        Equivalent complex stiffness of each element, N/m (N·m/rad on rotations).
    element_receptance : ndarray, shape (L, r), complex
        ``hbar_e = e^T hbar_q``: the element displacement per unit excitation force,
        m/N, whether or not the element DOFs were measured.
    amplitude : ndarray, shape (L, r), or None
        Element displacement amplitude ``X = |hbar_e| |F|``, m; None when no force
        amplitude was given.
    cond : ndarray, shape (L,)
        2-norm condition number of the (noise-weighted) matrix ``H_{P,A}`` with its
        columns scaled to unit norm, so element units do not enter. ``inf`` when
        the elements cannot be separated at that line.
    sensitivity : ndarray, shape (L, r)
        Relative condition number of each kbar: the rms error of kbar_i when every
        measured FRF value carries a relative error of 1 (first order), divided by
        ``max(|kbar_i|, 1 / |e_i^T H e_i|)``, the larger of kbar and the reference's
        dynamic stiffness at the element. The second term keeps a vanishing kbar (a
        right reference model) from counting as ill-conditioned. It grows
        where the elements barely change the measured FRF, at anti-resonances of the
        element response and where ``cond`` is large.
    antiresonance : ndarray, shape (L, r), bool
        The element response ``|hbar_e|`` is below ``antiresonance_ratio`` times
        ``|e^T h_q| + |e^T H E u|`` (the two terms it is the difference of), or
        below that fraction of its median over the neighbouring lines, or zero:
        ``kbar = u / hbar_e`` divides by a small, poorly known number there.
    ill_conditioned : ndarray, shape (L,), bool
        ``cond`` or any ``sensitivity`` above ``cond_limit``, an anti-resonance of
        any element, or a non-finite result. Weight down or drop these lines.
    residual : ndarray, shape (L,)
        ``||H_{P,A} u - (h_{P,q} - hbar_{P,q})||_2``, m/N; zero (to round-off) when
        ``|P| == r``.
    residual_dof : int
        Real degrees of freedom of the residual, ``2 (|P| - r)``.
    residual_chi2 : ndarray, shape (L,), or None
        ``2 sum_p |residual_p / std_p|^2``: chi-square with ``residual_dof`` degrees
        of freedom when the reference model is right and the noise is as stated.
    kbar_cov : ndarray, shape (L, r, r), complex, or None
        First-order covariance ``E[delta kbar delta kbar^H]``, (N/m)^2.
    kbar_std : ndarray, shape (L, r), or None
        ``sqrt(diag(kbar_cov))``, N/m; Re and Im each have ``kbar_std / sqrt(2)``.
    element_names : list of str
        One label per element, in the order of the columns.
    frf_per_kbar : ndarray, shape (L, P, r), complex
        ``d hbar_{p,q} / d kbar_i``, m/N per N/m: the first-order change of each measured FRF per unit change
        of each element's kbar, ``-(hbar E)_{p,i} hbar_e_i`` with ``hbar E = H_{P,A} (I + diag(kbar) E^T H E)^-1``
        the structure with its elements answering a unit force pair at element i (Woodbury). What a scatter of
        kbar between runs does to the FRFs (:func:`analysis.identification.between_runs.frf_error_floor`); NaN
        where kbar is.
    """

    kbar: np.ndarray
    element_receptance: np.ndarray
    amplitude: np.ndarray | None
    cond: np.ndarray
    sensitivity: np.ndarray
    antiresonance: np.ndarray
    ill_conditioned: np.ndarray
    residual: np.ndarray
    residual_dof: int
    residual_chi2: np.ndarray | None
    kbar_cov: np.ndarray | None
    kbar_std: np.ndarray | None
    element_names: list[str]
    frf_per_kbar: np.ndarray | None = None


def identify_complex_stiffness(reference, measured, rows: Sequence, column, elements: Sequence, *,
                               w=None, dofs: Sequence[str] | None = None, force=None, noise_std=None,
                               cond_limit: float = DEFAULT_COND_LIMIT,
                               antiresonance_ratio: float = DEFAULT_ANTIRESONANCE_RATIO,
                               antiresonance_window: int = DEFAULT_ANTIRESONANCE_WINDOW,
                               ) -> ComplexStiffnessIdentification:
    """Identify ``kbar`` of r unknown elements at every frequency line, without root solving.

    Parameters
    ----------
    reference : Structure or array_like, shape (L, n, n), complex
        The reference linear structure (then ``w`` is required) or its receptance
        matrix H(w) at the L lines, m/N.
    measured : array_like, shape (L, P), complex
        Measured receptance ``hbar_{p,q}`` of the structure with its elements, for the
        P measured rows and the one excited column, m/N. Shape (L,) is accepted
        when P == 1. Lines in frequency order (anti-resonances are judged against
        neighbouring lines).
    rows : sequence of int or str, length P
        The measured DOFs (indices, or names when the DOF names are known).
    column : int or str
        The excited DOF q.
    elements : sequence, length r
        Each an :class:`~analysis.mechanics.elements.Element`, a DOF (grounded element), or a
        tuple ``(a,)`` / ``(a, b)`` of DOFs (element between a and b).
    w : array_like, shape (L,), optional
        Angular frequencies, rad/s; required when ``reference`` is a Structure.
    dofs : sequence of str, optional
        DOF names in matrix order, to resolve names when ``reference`` is an array.
    force : float or array_like, shape (L,), optional
        Excitation force amplitude |F|, N (complex phasors accepted: the modulus is
        used); gives ``amplitude``.
    noise_std : float or array_like, shape (P,) or (L, P), optional
        Standard deviation of the measured receptance, ``sqrt(E|n|^2)``, m/N, > 0.
        Rows are then weighted by ``1 / std`` in the least squares (best linear
        unbiased estimate when P > r) and the covariance of kbar is returned.
    cond_limit : float
        Lines with ``cond`` or ``sensitivity`` above this are flagged: both are
        factors by which relative errors in the FRFs grow in the result.
    antiresonance_ratio : float
        An element response below this fraction of the terms it is computed from,
        or of its neighbourhood median, is flagged as an anti-resonance.
    antiresonance_window : int
        Half-width, in lines, of that neighbourhood.

    Returns
    -------
    ComplexStiffnessIdentification

    Raises
    ------
    InputError
        Shapes that do not fit, unknown or repeated DOFs, fewer measured rows than
        elements, elements that cannot be told apart, non-finite data.
    """
    H, names = _reference_receptance(reference, w, dofs)
    n_lines, n = H.shape[0], H.shape[1]
    index = _dof_resolver(n, names)
    row_idx = _rows(rows, index)
    q = index(column, "column")
    E, element_names = _element_matrix(elements, n, index)
    r = E.shape[1]
    hbar = _measured(measured, n_lines, len(row_idx), r)
    std = None if noise_std is None else _noise(noise_std, n_lines, len(row_idx))
    force_amplitude = None if force is None else _force(force, n_lines)
    if not (cond_limit > 1.0 and antiresonance_ratio >= 0.0 and int(antiresonance_window) >= 1):
        raise InputError("needs cond_limit > 1, antiresonance_ratio >= 0 and antiresonance_window >= 1",
                         field="cond_limit")

    G = H[:, row_idx, :] @ E                      # H_{P,A}, (L, P, r)
    d = H[:, row_idx, q] - hbar                   # h_{P,q} - hbar_{P,q}, (L, P)
    weight = np.ones(d.shape) if std is None else 1.0 / std
    G_weighted = G * weight[:, :, None]

    # Unit-norm columns: the least-squares solution is invariant to column scaling,
    # and the condition number then measures separability, not element units.
    col_norm = np.linalg.norm(G_weighted, axis=1)                     # (L, r)
    col_norm = np.where(col_norm > 0.0, col_norm, 1.0)
    U, s, Vh = np.linalg.svd(G_weighted / col_norm[:, None, :], full_matrices=False)
    rank_tol = s[:, :1] * max(G.shape[1], r) * np.finfo(float).eps
    s_inv = np.divide(1.0, s, out=np.zeros_like(s), where=s > rank_tol)
    cond = np.divide(s[:, 0], s[:, -1], out=np.full(n_lines, np.inf), where=s[:, -1] > rank_tol[:, 0])
    # Pseudo-inverse of the weighted H_{P,A}, (L, r, P): u = pinv (weight d).
    pinv = (np.conj(np.swapaxes(Vh, 1, 2)) * s_inv[:, None, :]) @ np.conj(np.swapaxes(U, 1, 2))
    pinv = pinv / col_norm[:, :, None]
    u = (pinv @ (weight * d)[:, :, None])[:, :, 0]

    fit_error = (G @ u[:, :, None])[:, :, 0] - d
    residual = np.linalg.norm(fit_error, axis=1)
    B = E.T @ H @ E                                                   # E^T H E, (L, r, r)
    reference_part = H[:, :, q] @ E
    element_part = (B @ u[:, :, None])[:, :, 0]
    hbar_e = reference_part - element_part
    with np.errstate(divide="ignore", invalid="ignore"):
        kbar = u / hbar_e

    # First-order map from the measured FRF to kbar: delta u = -pinv (weight n),
    # delta hbar_e = -B delta u, delta kbar = (delta u - kbar delta hbar_e) / hbar_e.
    with np.errstate(divide="ignore", invalid="ignore"):
        to_kbar = (np.eye(r)[None] + kbar[:, :, None] * B) / hbar_e[:, :, None]
        data_to_kbar = to_kbar @ (pinv * weight[:, None, :])          # (L, r, P), N/m per m/N
        # 1 / |e^T H e|: the reference's dynamic stiffness seen by the element.
        kbar_scale = np.maximum(np.abs(kbar), 1.0 / np.abs(np.diagonal(B, axis1=1, axis2=2)))
        sensitivity = np.linalg.norm(data_to_kbar * np.abs(hbar)[:, None, :], axis=2) / kbar_scale

    # Anti-resonance of the element response: either the subtraction hbar_e = h - B u
    # cancels (the elements themselves create the zero; relative errors grow by the
    # ratio), or the response dips far below its neighbouring lines (a zero of the reference).
    magnitude = np.abs(hbar_e)
    neighbourhood = median_filter(magnitude, size=(2 * int(antiresonance_window) + 1, 1), mode="nearest")
    cancellation = magnitude <= antiresonance_ratio * (np.abs(reference_part) + np.abs(element_part))
    antiresonance = cancellation | (magnitude <= antiresonance_ratio * neighbourhood) | (magnitude == 0.0)
    ill = ((cond > cond_limit) | antiresonance.any(axis=1) | ~(sensitivity <= cond_limit).all(axis=1)
           | ~np.isfinite(kbar).all(axis=1))

    # hbar E = H_{P,A} (I + K B)^-1, K = diag(kbar): the elements' own answer to a force pair at each of them
    coupling = np.eye(r)[None] + kbar[:, :, None] * B
    answer = np.full(G.shape, np.nan, complex)
    finite = np.isfinite(coupling).all(axis=(1, 2))
    try:
        answer[finite] = np.swapaxes(np.linalg.solve(np.swapaxes(coupling[finite], 1, 2),
                                                     np.swapaxes(G[finite], 1, 2)), 1, 2)
    except np.linalg.LinAlgError:       # (I + K B) is the damped structure with its elements: singular at no line
        for line in np.flatnonzero(finite):
            try:
                answer[line] = np.linalg.solve(coupling[line].T, G[line].T).T
            except np.linalg.LinAlgError:
                pass
    frf_per_kbar = -answer * hbar_e[:, None, :]

    kbar_cov = kbar_std = residual_chi2 = None
    if std is not None:
        residual_chi2 = 2.0 * np.sum(np.abs(weight * fit_error) ** 2, axis=1)
        kbar_cov = (data_to_kbar * std[:, None, :] ** 2) @ np.conj(np.swapaxes(data_to_kbar, 1, 2))
        kbar_std = np.sqrt(np.abs(np.diagonal(kbar_cov, axis1=1, axis2=2)))

    return ComplexStiffnessIdentification(
        kbar=kbar, element_receptance=hbar_e,
        amplitude=None if force_amplitude is None else magnitude * force_amplitude[:, None],
        cond=cond, sensitivity=sensitivity, antiresonance=antiresonance, ill_conditioned=ill, residual=residual,
        residual_dof=2 * (len(row_idx) - r), residual_chi2=residual_chi2,
        kbar_cov=kbar_cov, kbar_std=kbar_std, element_names=element_names, frf_per_kbar=frf_per_kbar)


# --- input checking ----------------------------------------------------------------

def _reference_receptance(reference, w, dofs) -> tuple[np.ndarray, list[str] | None]:
    if isinstance(reference, Structure):
        if w is None:
            raise InputError("a Structure as reference needs the angular frequencies w (rad/s)", field="w")
        w = np.atleast_1d(np.asarray(w, float))
        if w.ndim != 1 or not np.isfinite(w).all():
            raise InputError(f"must be a 1-D array of finite angular frequencies, got shape {w.shape}",
                             field="w")
        return reference.frf(w), list(reference.dofs)
    H = np.asarray(reference)
    if H.ndim != 3 or H.shape[1] != H.shape[2] or H.shape[0] < 1 or H.shape[1] < 1:
        raise InputError(f"reference receptance must have shape (lines, n, n), got {H.shape}",
                         field="reference")
    if not np.isfinite(H).all():
        raise InputError("reference receptance contains non-finite values (a line exactly at an undamped "
                         "resonance?)", field="reference")
    if dofs is not None and len(dofs) != H.shape[1]:
        raise InputError(f"{len(dofs)} DOF names given for a {H.shape[1]}-DOF receptance", field="dofs")
    return H.astype(complex, copy=False), None if dofs is None else list(dofs)


def _dof_resolver(n: int, names: list[str] | None):
    lookup = {} if names is None else {name: i for i, name in enumerate(names)}

    def index(dof, field: str) -> int:
        if isinstance(dof, (int, np.integer)) and not isinstance(dof, bool):
            if not 0 <= dof < n:
                raise InputError(f"DOF index {dof} is outside 0..{n - 1}", field=field)
            return int(dof)
        if isinstance(dof, str):
            if names is None:
                raise InputError(f"DOF name {dof!r} needs the DOF names: pass a Structure or dofs=[...]",
                                 field=field)
            if dof not in lookup:
                raise InputError(f"DOF {dof!r} is not in the structure", field=field)
            return lookup[dof]
        raise InputError(f"a DOF is an index or a name, got {dof!r}", field=field)

    return index


def _rows(rows, index) -> list[int]:
    if isinstance(rows, (str, int, np.integer)):
        rows = [rows]
    idx = [index(p, f"rows[{k}]") for k, p in enumerate(rows)]
    if not idx:
        raise InputError("at least one measured row is needed", field="rows")
    if len(set(idx)) != len(idx):
        raise InputError("a DOF is listed twice among the measured rows", field="rows")
    return idx


def _element_matrix(elements, n: int, index) -> tuple[np.ndarray, list[str]]:
    """E (n, r) with column i = e_i, and element labels."""
    if isinstance(elements, (str, int, np.integer, Element)):
        elements = [elements]
    if len(elements) == 0:
        raise InputError("at least one element is needed", field="elements")
    columns, labels, seen = [], [], {}
    for i, spec in enumerate(elements):
        field = f"elements[{i}]"
        if isinstance(spec, Element):
            dofs, label = spec.dofs, spec.name
        elif isinstance(spec, (str, int, np.integer)):
            dofs, label = (spec,), None
        elif isinstance(spec, (tuple, list)):
            dofs, label = tuple(spec), None
        else:
            raise InputError(f"an element is an Element, a DOF or a tuple (a,) / (a, b), got {spec!r}",
                             field=field)
        if len(dofs) not in (1, 2):
            raise InputError(f"an element acts on one DOF (grounded) or two (between), got {len(dofs)}",
                             field=field)
        idx = tuple(index(d, field) for d in dofs)
        if len(idx) == 2 and idx[0] == idx[1]:
            raise InputError("an element between a DOF and itself does nothing", field=field)
        key = (min(idx), max(idx)) if len(idx) == 2 else idx
        if key in seen:
            raise InputError(f"acts on the same DOFs as elements[{seen[key]}]: their kbar cannot be separated",
                             field=field)
        seen[key] = i
        e = np.zeros(n)
        e[idx[0]] = 1.0
        if len(idx) == 2:
            e[idx[1]] = -1.0
        columns.append(e)
        labels.append(label or (f"dof {dofs[0]}" if len(dofs) == 1 else f"between {dofs[0]} and {dofs[1]}"))
    E = np.stack(columns, axis=1)
    if np.linalg.matrix_rank(E) < E.shape[1]:
        raise InputError("the element DOF vectors are linearly dependent (e.g. grounded at a, grounded at b "
                         "and between a and b): their kbar cannot be separated", field="elements")
    return E, labels


def _measured(measured, n_lines: int, n_rows: int, r: int) -> np.ndarray:
    hbar = np.asarray(measured)
    if hbar.ndim == 1 and n_rows == 1:
        hbar = hbar[:, None]
    if hbar.ndim != 2 or hbar.shape != (n_lines, n_rows):
        raise InputError(f"measured receptance must have shape (lines, rows) = ({n_lines}, {n_rows}), "
                         f"got {hbar.shape}", field="measured")
    if n_rows < r:
        raise InputError(f"{r} elements need at least {r} measured FRF rows; got {n_rows}", field="measured")
    bad = ~np.isfinite(hbar).all(axis=1)
    if bad.any():
        raise InputError(f"measured receptance is not finite at {bad.sum()} lines (first at line "
                         f"{np.flatnonzero(bad)[0]})", field="measured")
    return hbar.astype(complex, copy=False)


def _noise(noise_std, n_lines: int, n_rows: int) -> np.ndarray:
    std = np.asarray(noise_std, float)
    try:
        std = np.broadcast_to(std, (n_lines, n_rows))
    except ValueError:
        raise InputError(f"noise std must be a scalar or have shape ({n_rows},) or ({n_lines}, {n_rows}), "
                         f"got {std.shape}", field="noise_std") from None
    if not (np.isfinite(std).all() and (std > 0.0).all()):
        raise InputError("noise std must be finite and > 0 (leave it out for noise-free data)",
                         field="noise_std")
    return std


def _force(force, n_lines: int) -> np.ndarray:
    amplitude = np.abs(np.asarray(force))
    try:
        amplitude = np.broadcast_to(amplitude, (n_lines,)).astype(float)
    except ValueError:
        raise InputError(f"force must be a scalar or have shape ({n_lines},), got {amplitude.shape}",
                         field="force") from None
    if not (np.isfinite(amplitude).all() and (amplitude > 0.0).all()):
        raise InputError("force amplitude must be finite and > 0", field="force")
    return amplitude
