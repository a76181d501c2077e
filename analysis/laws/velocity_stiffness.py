"""velocity_stiffness: stiffness growing with frequency, f = (pi/2) gamma |x'| sgn(x).

The second term of the paper's eq. 32. Its fundamental is in phase with ``x``:
kbar = gamma w (real, independent of the amplitude). The paper's fitted values of
gamma are negative (Table 3), so the sign is free.
"""
import math

import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def velocity_stiffness_force(x, v, p, s):
    if x > 0.0:
        return 0.5 * math.pi * p[0] * abs(v)
    if x < 0.0:
        return -0.5 * math.pi * p[0] * abs(v)
    return 0.0


class VelocityStiffness(Law):
    name = "velocity_stiffness"
    kind = "rate stiffness"
    summary = "frequency-proportional stiffness (paper eq. 32)"
    force_text = "(pi/2) gamma |x'| sgn(x)"
    kbar_text = "gamma w (real)"
    explanation = "Re kbar changes with frequency, not amplitude ({re}): velocity-dependent stiffness"
    params = (Param("gamma", "{F}·s/{L}", "stiffness per unit angular frequency"),)
    linear = ("gamma",)
    example = {"gamma": 10.0}
    amplitude_dependent = False
    kernel = velocity_stiffness_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.asarray(w, complex)[None]
