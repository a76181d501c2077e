"""coulomb: dry friction of constant slip force, f = fs sgn(x').

``kernel`` is the sliding force; at zero velocity the contact can hold any force up to
``stick_limit(x, p) = fs``, which a time integrator uses to model true stick.

Describing function (pure sliding): kbar = j 4 fs / (pi X). It is exact whenever the
contact slides through every half cycle. Under small motions a real contact sticks for
part of each cycle, and this describing function then overstates the dissipation.
"""
import math

import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def coulomb_force(x, v, p, s):
    if v > 0.0:
        return p[0]
    if v < 0.0:
        return -p[0]
    return 0.0


@njit(cache=True)
def coulomb_stick_limit(x, p):
    return p[0]


class Coulomb(Law):
    name = "coulomb"
    kind = "friction"
    summary = "Coulomb dry friction"
    force_text = "fs sgn(x'); stick limit fs"
    kbar_text = "j 4 fs / (pi X) (pure sliding)"
    explanation = "{im} while Re stays flat: energy lost per cycle does not grow with amplitude -- dry friction"
    params = (Param("fs", "{F}", "slip force", lower=0.0),)
    linear = ("fs",)
    example = {"fs": 1.0}
    example_amplitude = (1e-5, 1e-2)
    kernel = coulomb_force
    stick_limit = coulomb_stick_limit

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.asarray(4j / (math.pi * X), complex)[None]
