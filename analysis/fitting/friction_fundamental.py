"""What the fundamental of a friction force carries on data without harmonics, and what a law beside friction
must therefore beat there.

A friction force reverses where the velocity does. The motion's harmonics move those instants, so the force's
fundamental turns against the displacement's by a near-constant angle: the element's kbar is its friction law's
plus a force of constant size in phase with the displacement, Re kbar = 4 F0 / (pi X). Measured harmonics would
show where the motion went; receptances alone (imported FRFs) cannot, and no law of the library is that force.
At the smallest amplitudes the turn can be a few percent of the friction's 4 fs / (pi X), enough that a law the
joint does not have (a saturated tanh spring, a clearance below every amplitude, a velocity stiffness or an arctan
spring) fits it beside the friction and cuts the FRF error severalfold.

So on such data, beside a friction law, a law must lower the kbar's capped chi-square below what the element's
laws with that force reach (:func:`chi_square_with_friction_turn`), not only below the laws alone.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from ..common.compiled import njit

from ..common.errors import InputError
from ..common.statistics import capped_chi_square
from ..laws import Law, Param
from ..laws.base import broadcast
from ..mechanics.elements import LawTerm
from ..mechanics.surroundings import Surroundings
from .fit import fit_laws


@njit(cache=True)
def _in_phase_force(x, v, p, s):
    return p[0] * np.sign(x)


class ConstantInPhaseForce(Law):
    """A force of constant size in phase with the displacement, F0 sgn(x): what turns a friction's fundamental.
    Not a law of the library (not in ``LAWS``): only the reference a law beside friction must beat."""

    name = "constant_in_phase_force"
    kind = "stiffness"
    summary = "a force of constant size in phase with the displacement (a friction's turned fundamental)"
    force_text = "F0 sgn(x)"
    kbar_text = "4 F0 / (pi X) (real)"
    explanation = "{re}: the friction's fundamental turned by the motion's harmonics"
    params = (Param("F0", "{F}", "force"),)
    linear = ("F0",)
    example = {"F0": 0.01}
    kernel = _in_phase_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.asarray(4.0 / (math.pi * X), complex)[None]


FRICTION_TURN = ConstantInPhaseForce()


def holds_friction(laws: Sequence[Law]) -> bool:
    return any(law.kind == "friction" for law in laws)


def chi_square_with_friction_turn(terms: Sequence[str | Law | LawTerm], X: np.ndarray, w: np.ndarray,
                                  kbar: np.ndarray, kbar_std: np.ndarray,
                                  surroundings: Surroundings | None = None) -> float:
    """The capped chi-square of the element's laws (``terms``) fitted with the force that turns a friction's
    fundamental, leaving out the samples that do not follow them, as the fits on data without harmonics do; inf
    where they cannot be fitted. ``surroundings``: where the element's contact laws are placed in its structure."""
    try:
        fit = fit_laws(list(terms) + [FRICTION_TURN], X, w, kbar, kbar_std, exclude_outliers=True,
                       surroundings=surroundings)
    except InputError:
        return np.inf
    return capped_chi_square(np.abs(fit.normalized_residuals) ** 2)
