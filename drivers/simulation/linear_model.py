"""The rig's linear part: assembly, checks at rest and Craig-Bampton reduction.

Built once per rig by :func:`drivers.simulation.rig.load_rig`, so a rig file that is unstable at rest, adds
energy or cannot be resolved by the internal time step is refused before any integration.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from analysis.mechanics.elements import Element
from analysis.common.errors import InputError
from analysis.mechanics.structures import Structure, definiteness

if TYPE_CHECKING:
    from .rig import Rig

# The internal rate must be at least this many times the highest mode the simulator
# keeps: the mode is then sampled without aliasing (below 80 % of the internal
# Nyquist frequency), with margin for elements that stiffen it.
RESOLUTION_FACTOR = 2.5
# Displacement and velocity steps for the elements' small-amplitude stiffness and damping
_TANGENT_DX = 1e-9
_TANGENT_DV = 1e-9
# Below this fraction of the diagonal at its DOFs an element's negative tangent is round-off, not a cause
NEGLIGIBLE_TANGENT = 1e-9


# --- linear model -----------------------------------------------------------------
@dataclass
class LinearModel:
    """The rig's linear part in the coordinates the simulator integrates.

    Attributes
    ----------
    coordinates : list of str
        Names of the generalised coordinates q: physical DOF names (kept DOFs) and
        ``mode1``, ``mode2``, ... (normal-mode coordinates of a reduced beam).
    T : ndarray, shape (n_dofs, n_q)
        Physical displacements ``x = T q`` (every DOF of the structure).
    M, C, K : ndarray, shape (n_q, n_q)
        Reduced mass, damping and stiffness, including the shaker's armature and
        suspension and the elements' small-amplitude stiffness ``k0`` and damping ``c0``.
    element_vectors : ndarray, shape (r, n_q)
        Element displacement ``x_e = element_vectors[e] @ q``.
    excitation_vector : ndarray, shape (n_q,)
    sensor_rows : ndarray, shape (n_sensors, n_q)
    k0, c0 : ndarray, shape (r,)
        Small-amplitude stiffness (N/m or N·m/rad) and damping of each element's
        smooth laws, moved into the linear part (the simulator integrates the rest).
    natural_frequencies : ndarray
        Undamped natural frequencies of (M, K), Hz.
    kept_modes : int
        Normal modes in a reduced model (0 when not reduced).
    """

    coordinates: list[str]
    T: np.ndarray
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    element_vectors: np.ndarray
    excitation_vector: np.ndarray
    sensor_rows: np.ndarray
    k0: np.ndarray
    c0: np.ndarray
    natural_frequencies: np.ndarray
    kept_modes: int

    @property
    def n(self) -> int:
        return len(self.coordinates)

    @property
    def highest_mode_hz(self) -> float:
        return float(self.natural_frequencies[-1])

    def structure(self) -> Structure:
        """The reduced linear model as a Structure over its coordinates (for FRFs)."""
        return Structure(list(self.coordinates), self.M, self.K, self.C, set(), "reduced rig model")

    def physical_frf(self, w, excitation_row: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Receptance of physical rows ``rows @ x`` to a force on ``excitation_row @ x``.

        Parameters
        ----------
        w : array_like, rad/s
        excitation_row : (n_dofs,)
        rows : (m, n_dofs)

        Returns
        -------
        ndarray, shape (len(w), m), complex
        """
        load = (self.T.T @ excitation_row)[:, None]
        q = self.structure().response(w, load)[:, :, 0]
        return q @ (rows @ self.T).T


def element_tangent(element: Element) -> tuple[float, float]:
    """Small-amplitude stiffness and damping of an element's smooth laws.

    Central differences of each law's own kernel about rest (fresh state); dry
    friction is left out (it has no stiffness at rest and its damping is set-valued).
    Any value is exact for the simulator (only the residual is integrated implicitly);
    a good one makes the implicit solve easy and lets the linear check see the rig
    the elements make at rest.
    """
    k0 = c0 = 0.0
    for term in element.laws:
        law = term.law
        if law.stick_limit is not None:
            continue
        p = law.parameter_vector(**term.values)

        def force(x, v):
            return float(law.kernel(x, v, p, law.initial_state(p)))

        k0 += (force(_TANGENT_DX, 0.0) - force(-_TANGENT_DX, 0.0)) / (2 * _TANGENT_DX)
        c0 += (force(0.0, _TANGENT_DV) - force(0.0, -_TANGENT_DV)) / (2 * _TANGENT_DV)
    return k0, c0


@dataclass
class AtRest:
    """A structure with its elements' small-amplitude stiffness added (what a low-level test sees of it)."""
    structure: Structure
    added: list[tuple[Element, float]]      # the elements whose laws have values, with their stiffness k0
    without_values: list[Element]           # the elements whose laws lack values (or that have none): left out


def structure_at_rest(structure: Structure, elements: list[Element]) -> AtRest:
    """``structure`` with each element's small-amplitude stiffness (:func:`element_tangent`) added, for the
    elements whose laws all have values."""
    K = structure.K.copy()
    added, without = [], []
    for el in elements:
        if not el.laws or not all(term.complete for term in el.laws):
            without.append(el)
            continue
        k0, _ = element_tangent(el)
        E = el.vector(structure)
        if abs(k0) <= NEGLIGIBLE_TANGENT * np.abs(np.diag(structure.K))[E != 0].max(initial=0.0):
            k0 = 0.0                        # round-off of the central difference (a cubic law at rest)
        K += k0 * np.outer(E, E)
        added.append((el, k0))
    return AtRest(structure.with_matrices(K=K), added, without)


def build_linear_model(rig: Rig) -> LinearModel:
    """Assemble, check and (for beams) reduce the rig's linear part.

    Raises
    ------
    InputError
        If the rig is unstable or adds energy at rest, or the internal time step
        cannot resolve the highest mode kept.
    """
    s = rig.structure
    M, C, K = s.M.copy(), s.C.copy(), s.K.copy()
    exc = s.index(rig.excitation_dof)
    if rig.shaker is not None:
        M[exc, exc] += rig.shaker.armature_mass
        K[exc, exc] += rig.shaker.suspension_stiffness
        C[exc, exc] += rig.shaker.suspension_damping
    r = len(rig.elements)
    tangents = np.array([element_tangent(el) for el in rig.elements], float).reshape(r, 2)
    k0, c0 = tangents[:, 0].copy(), tangents[:, 1].copy()
    E = np.array([el.vector(s) for el in rig.elements], float).reshape(r, s.n)
    K += E.T @ (k0[:, None] * E)
    C += E.T @ (c0[:, None] * E)
    _check_definite(rig, K, E, k0, "stiffness")
    _check_definite(rig, C, E, c0, "damping")

    if rig.simulation.reduction == "craig-bampton":
        cutoff = rig.simulation.mode_cutoff or rig.daq.passband * rig.daq.sample_rate
        boundary = sorted({exc, *(i for el in rig.elements for i in el.indices(s) if i is not None)})
        T, coordinates, kept = _craig_bampton(s, M, K, boundary, cutoff)
    else:
        T, coordinates, kept = np.eye(s.n), list(s.dofs), 0
    Mr, Cr, Kr = (T.T @ A @ T for A in (M, C, K))
    Mr, Cr, Kr = (0.5 * (A + A.T) for A in (Mr, Cr, Kr))
    lam = scipy.linalg.eigh(Kr, Mr, eigvals_only=True)
    freqs = np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi)
    model = LinearModel(coordinates, T, Mr, Cr, Kr, E @ T, T[exc].copy(),
                        T[[s.index(d) for d in rig.sensor_dofs]], k0, c0, freqs, kept)
    _check_resolution(rig, model)
    return model


def _check_definite(rig: Rig, A: np.ndarray, E: np.ndarray, tangent: np.ndarray, key: str) -> None:
    """InputError when the rig's stiffness is not positive definite (or its damping is negative), naming
    every element whose small-amplitude value is negative beyond round-off (else the structure).

    A tangent counts as negative when it exceeds ``NEGLIGIBLE_TANGENT`` of the largest diagonal entry at the
    element's own DOFs: the central difference of a cubic law at rest gives ``k3 dx^2`` (about 1e-16), which
    is no cause of anything."""
    stiffness = key == "stiffness"
    ok, _ = definiteness(A, semidefinite=not stiffness)
    if ok:
        return
    diagonal = np.abs(np.diag(A))
    culprits = [i for i, value in enumerate(tangent)
                if value < -NEGLIGIBLE_TANGENT * diagonal[E[i] != 0].max(initial=0.0)]
    problem = ("is unstable at rest: its stiffness, with the elements' small-amplitude stiffness, is not "
               "positive definite" if stiffness else
               "would add energy: its damping, with the elements' small-amplitude damping, is negative")
    if not culprits:
        raise InputError(f"the rig {problem}", rig.source, f"[structure].{key}")
    symbol = "k0" if stiffness else "c0"
    names = ", ".join(f"{rig.elements[i].name!r} ({symbol} = {tangent[i]:.4g})" for i in culprits)
    raise InputError(f"the rig {problem}: negative small-amplitude {key} of element{'s' * (len(culprits) > 1)} "
                     f"{names}", rig.source, f"[[element]][{culprits[0]}].laws")


def _craig_bampton(s: Structure, M, K, boundary: list[int], cutoff_hz: float):
    """Reduction basis: boundary DOFs physical, interior = static shapes + normal-mode residuals.

    The interior follows the boundary through the static (constraint) modes
    ``psi = -K_ii^-1 K_ib``; the lowest normal modes of the whole linear rig below
    ``cutoff_hz`` are added through their interior residuals ``phi_i - psi phi_b``, so
    the basis holds those modes exactly and the boundary DOFs stay physical.
    """
    n = s.n
    interior = [i for i in range(n) if i not in set(boundary)]
    T = np.zeros((n, len(boundary)))
    T[boundary, range(len(boundary))] = 1.0
    if not interior:
        return T, [s.dofs[i] for i in boundary], 0
    psi = -np.linalg.solve(K[np.ix_(interior, interior)], K[np.ix_(interior, boundary)])
    T[interior] = psi
    lam, phi = scipy.linalg.eigh(K, M)
    kept = int(np.sum(np.sqrt(np.clip(lam, 0, None)) / (2 * np.pi) < cutoff_hz))
    residual = phi[interior, :kept] - psi @ phi[boundary, :kept]
    Mii = M[np.ix_(interior, interior)]
    columns = []
    for k in range(kept):
        norm = math.sqrt(max(float(residual[:, k] @ Mii @ residual[:, k]), 0.0))
        if norm > 1e-12 * math.sqrt(float(phi[:, k] @ M @ phi[:, k])):
            column = np.zeros(n)
            column[interior] = residual[:, k] / norm
            columns.append(column)
    if columns:
        T = np.column_stack([T, *columns])
    names = [s.dofs[i] for i in boundary] + [f"mode{k + 1}" for k in range(len(columns))]
    return T, names, len(columns)


def _check_resolution(rig: Rig, model: LinearModel) -> None:
    f_max = model.highest_mode_hz
    needed = RESOLUTION_FACTOR * f_max
    daq = rig.daq
    internal = daq.sample_rate * daq.oversample
    if internal >= needed:
        return
    reduced = rig.simulation.reduction == "craig-bampton"
    which = f"mode {len(model.natural_frequencies)} of the {'reduced ' if reduced else ''}model (the highest kept)"
    hint = (f"raise sample_rate to {needed / daq.oversample:.6g} Hz or oversample to "
            f"{math.ceil(needed / daq.sample_rate)}")
    if reduced:
        hint += ", or lower [simulation].mode_cutoff"
    raise InputError(f"the internal rate {daq.oversample} x {daq.sample_rate:g} Hz = {internal:.6g} Hz cannot "
                     f"resolve {which} at {f_max:.6g} Hz: it needs at least {needed:.6g} Hz "
                     f"({RESOLUTION_FACTOR} x the mode); {hint}", rig.source, "[daq].sample_rate")
