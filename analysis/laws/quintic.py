"""quintic: hardening (k5 > 0) or softening (k5 < 0) spring, f = k5 x^5.

Describing function: kbar = (5/8) k5 X^4 (real: the force is single-valued in x).
"""
import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def quintic_force(x, v, p, s):
    x2 = x * x
    return p[0] * x2 * x2 * x


class Quintic(Law):
    name = "quintic"
    kind = "stiffness"
    summary = "quintic spring"
    force_text = "k5 x^5"
    kbar_text = "(5/8) k5 X^4"
    explanation = "{re} steeply (log-slope {re_slope}) while Im stays flat: a spring whose force grows as x^5"
    params = (Param("k5", "{F}/{L}^5", "quintic stiffness"),)
    linear = ("k5",)
    example = {"k5": 1.0e8}
    example_amplitude = (1e-3, 1e-1)
    kernel = quintic_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.asarray(0.625 * X**4, complex)[None]
