"""cubic_damping: cubic viscous damper, f = c3 x'^3.

Describing function: kbar = j (3/4) c3 w^3 X^2.
"""
import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def cubic_damping_force(x, v, p, s):
    return p[0] * v * v * v


class CubicDamping(Law):
    name = "cubic_damping"
    kind = "damping"
    summary = "cubic viscous damper"
    force_text = "c3 x'^3"
    kbar_text = "j (3/4) c3 w^3 X^2"
    explanation = ("{im} while Re stays flat: damping that grows as the square of the velocity amplitude -- cubic "
                   "damping")
    params = (Param("c3", "{F}·s^3/{L}^3", "cubic damping coefficient"),)
    linear = ("c3",)
    example = {"c3": 10.0}
    kernel = cubic_damping_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.asarray(0.75j * w**3 * X**2, complex)[None]
