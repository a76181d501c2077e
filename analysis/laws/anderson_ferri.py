"""anderson_ferri: generalised friction of Anderson and Ferri (paper eq. 33).

    f = ((pi/4) a + (pi/2) b |x| + c |x'|) sgn(x')

a constant (Coulomb) part, a part growing with the displacement magnitude, and a
part growing with speed (``c |x'| sgn(x') = c x'``: viscous). Describing function
(pure sliding): kbar = j (a / X + b + c w). At zero velocity the contact can hold up
to ``stick_limit(x, p) = (pi/4) a + (pi/2) b |x|`` (clipped at zero: a negative
friction force cannot hold anything). The paper's fitted a and b are negative for
some load cases (Table 3), so the signs are free; only non-negative values describe
a passive friction contact.
"""
import math

import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def anderson_ferri_force(x, v, p, s):
    magnitude = 0.25 * math.pi * p[0] + 0.5 * math.pi * p[1] * abs(x) + p[2] * abs(v)
    if v > 0.0:
        return magnitude
    if v < 0.0:
        return -magnitude
    return 0.0


@njit(cache=True)
def anderson_ferri_stick_limit(x, p):
    return max(0.25 * math.pi * p[0] + 0.5 * math.pi * p[1] * abs(x), 0.0)


class AndersonFerri(Law):
    name = "anderson_ferri"
    kind = "friction"
    summary = "Anderson-Ferri generalised friction (paper eq. 33)"
    force_text = "((pi/4) a + (pi/2) b |x| + c |x'|) sgn(x'); stick limit max(0, (pi/4) a + (pi/2) b |x|)"
    kbar_text = "j (a/X + b + c w)"
    explanation = "{im}: friction whose normal load follows the motion (Anderson-Ferri)"
    params = (Param("a", "{F}", "Coulomb part (describing-function units)"),
              Param("b", "{F}/{L}", "displacement-dependent part"),
              Param("c", "{F}·s/{L}", "viscous part"))
    linear = ("a", "b", "c")
    example = {"a": 1.0, "b": 500.0, "c": 2.0}
    example_amplitude = (1e-5, 1e-2)
    kernel = anderson_ferri_force
    stick_limit = anderson_ferri_stick_limit

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.stack([1j / X, np.full(X.shape, 1j), 1j * w])
