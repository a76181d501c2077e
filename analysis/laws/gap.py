"""gap: dead-zone spring, f = k (x - gap sgn x) for |x| > gap, else 0.

Describing function (u = gap / X):

    kbar = 0                                                   X <= gap
    kbar = k [1 - (2/pi) (asin u + u sqrt(1 - u^2))]           X > gap

The onset is smooth, ``~ (1 - u)^(3/2)``, not a step. The bracket equals twice the real
part of a unit Jenkins element at slip ratio ``(1 - u)/2`` (see _special.py), which is
how it is evaluated: without cancellation close to the onset.
"""
import numpy as np
from ..common.compiled import njit

from ._special import slip_real
from .base import Law, Param, broadcast

# the clearance is the law's shape parameter: the same object in both lists
_GAP = Param("gap", "{L}", "clearance on either side", lower=0.0)


@njit(cache=True)
def gap_force(x, v, p, s):
    k, gap = p[0], p[1]
    if x > gap:
        return k * (x - gap)
    if x < -gap:
        return k * (x + gap)
    return 0.0


class Gap(Law):
    name = "gap"
    kind = "clearance"
    summary = "dead-zone spring (clearance)"
    force_text = "k (x - gap sgn x) for |x| > gap, else 0"
    kbar_text = "X <= gap: 0; else k [1 - (2/pi)(asin u + u sqrt(1 - u^2))], u = gap/X"
    explanation = "{re} with Im flat, little below a threshold amplitude: a clearance that closes -- gap"
    params = (Param("k", "{F}/{L}", "contact stiffness beyond the clearance", lower=0.0), _GAP)
    linear = ("k",)
    shape = (_GAP,)
    example = {"k": 1.0e5, "gap": 1.0e-4}
    example_amplitude = (1e-5, 1e-2)
    kernel = gap_force

    def basis(self, X, w, gap):
        X, w = broadcast(X, w)
        return np.asarray(2.0 * slip_real((X - gap) / (2.0 * X)), complex)[None]
