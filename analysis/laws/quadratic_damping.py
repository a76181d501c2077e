"""quadratic_damping: velocity-squared damper, f = c2 |x'| x'.

Describing function: kbar = j (8 / (3 pi)) c2 w^2 X.
"""
import math

import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def quadratic_damping_force(x, v, p, s):
    return p[0] * abs(v) * v


class QuadraticDamping(Law):
    name = "quadratic_damping"
    kind = "damping"
    summary = "quadratic (velocity-squared) damper"
    force_text = "c2 |x'| x'"
    kbar_text = "j (8/(3 pi)) c2 w^2 X"
    explanation = ("{im} while Re stays flat: damping that grows with velocity amplitude -- quadratic (drag-like) "
                   "damping")
    params = (Param("c2", "{F}·s^2/{L}^2", "quadratic damping coefficient"),)
    linear = ("c2",)
    example = {"c2": 10.0}
    kernel = quadratic_damping_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.asarray(1j * (8.0 / (3.0 * math.pi)) * w**2 * X, complex)[None]
