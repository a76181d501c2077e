"""Whether a model's laws are physically admissible at the states it was measured in (docs/laws.md,
"Admissibility").

**Passive.** A joint dissipates energy over a cycle; it never gives any back. In the phasor convention of
docs/contracts.md §1 an element of complex stiffness kbar at relative amplitude |y| dissipates pi |y|^2 Im kbar per
cycle, and the structure pi x^H (w C) x. So the model, with each element at its measured amplitude, dissipates
energy at every motion at frequency w if and only if

    D = w C + sum_e Im kbar_e(X_e, w) v_e v_e^T        (n x n)

is positive semidefinite. The whole is judged, not each element: an element's kbar is what the joint adds to a
reference, and a reference fitted where the joint already slips holds part of the joint's damping, so an element
may be negative alone where the model is passive.

**Statically stiff.** In the same way

    S = K + sum_e Re kbar_e(X_e, w) v_e v_e^T

is the stiffness the structure has at that state; a smallest eigenvalue below zero means it would buckle, which
no joint of a structure standing on the shaker does (a free structure has zero eigenvalues: only a negative one is
flagged).

Both are checked at every measured state given (an identified line: each element's amplitude, the line's
frequency), to a relative tolerance ``TOLERANCE`` of the matrix's largest eigenvalue: the laws are evaluated
exactly, so anything beyond round-off is a property of the laws, not of the noise.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .structures import Structure

TOLERANCE = 1e-9
KbarFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]      # (X, w) -> kbar, same shape


@dataclass(frozen=True)
class Admissibility:
    """Per state checked: ``dissipation`` 0 where D is semidefinite, else negative by how far it is not (the
    smallest eigenvalue over the largest; for one element, the margin ``1 + a v^T B^+ v`` of the rank-one update,
    below), ``stiffness`` the same of S; ``amplitude`` (N, E) and ``w`` (N,) the states."""

    amplitude: np.ndarray
    w: np.ndarray
    dissipation: np.ndarray
    stiffness: np.ndarray

    @property
    def active(self) -> np.ndarray:
        """States where the model gives energy back."""
        return self.dissipation < -TOLERANCE

    @property
    def buckled(self) -> np.ndarray:
        """States where the static stiffness has a negative eigenvalue."""
        return self.stiffness < -TOLERANCE

    @property
    def passive(self) -> bool:
        return not self.active.any()

    @property
    def stiff(self) -> bool:
        return not self.buckled.any()

    @property
    def admissible(self) -> bool:
        return self.passive and self.stiff


def admissibility(structure: Structure, vectors: Sequence[np.ndarray], functions: Sequence[KbarFunction],
                  amplitude: np.ndarray, w: np.ndarray) -> Admissibility:
    """D and S (module docstring) at N states.

    Parameters
    ----------
    structure : Structure
        Its K and C (n x n).
    vectors : E arrays (n,)
        Each element's direction (:meth:`analysis.mechanics.elements.Element.vector`).
    functions : E callables
        Each element's describing function kbar(X, w) (N/m or N·m/rad).
    amplitude : ndarray (N, E)
        Each element's amplitude at each state (m or rad).
    w : ndarray (N,)
        Frequency of each state, rad/s.
    """
    amplitude = np.atleast_2d(np.asarray(amplitude, float))
    w = np.asarray(w, float)
    kbar = np.stack([np.asarray(f(amplitude[:, e], w), complex) for e, f in enumerate(functions)], axis=1) \
        if len(functions) else np.zeros((len(w), 0), complex)
    V = np.stack(vectors, axis=1) if len(vectors) else np.zeros((structure.n, 0))
    return Admissibility(amplitude, w, _shortfall(structure.C, w, V, kbar.imag),
                         _shortfall(structure.K, np.ones(len(w)), V, kbar.real))


def _shortfall(base: np.ndarray, scale: np.ndarray, V: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Per state n, 0 where ``scale[n] base + V diag(parts[n]) V^T`` is semidefinite, else how far it is not.
    ``base`` is semidefinite (checked when the structure is built) and ``scale`` positive, so only the states
    where some part is negative can fail. One element is a rank-one update ``s B + a v v^T``, semidefinite for
    a < 0 exactly when v lies in the range of B and ``1 + a v^T B^+ v / s >= 0`` (the matrix determinant lemma):
    one number per state, not an eigenproblem of the structure's size for each of the thousands a search makes.
    Several elements: the smallest eigenvalue over the largest."""
    out = np.zeros(len(parts))
    some = (parts < 0).any(axis=1)
    if not some.any():
        return out
    if V.shape[1] == 1:
        lam, U = np.linalg.eigh(base)
        proj = U.T @ V[:, 0]
        inside = lam > TOLERANCE * max(float(lam.max()), 0.0)
        if np.sum(proj[~inside] ** 2) > TOLERANCE * float(V[:, 0] @ V[:, 0]):
            out[some] = -1.0            # the element moves where the structure has no stiffness or damping
            return out
        q = float(np.sum(proj[inside] ** 2 / lam[inside]))
        margin = 1.0 + parts[some, 0] * q / scale[some]
        out[some] = np.minimum(margin, 0.0)
        return out
    A = scale[some, None, None] * base[None] + np.einsum("ie,ne,je->nij", V, parts[some], V)
    eig = np.linalg.eigvalsh(0.5 * (A + np.swapaxes(A, 1, 2)))
    size = np.abs(eig).max(axis=1)
    out[some] = np.minimum(np.divide(eig[:, 0], size, out=np.zeros(len(eig)), where=size > 0), 0.0)
    return out
