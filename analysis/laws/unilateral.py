"""unilateral: one-sided contact spring, f = k (x - gap) for x > gap, else 0.

``gap > 0`` is a clearance, ``gap < 0`` a preload (the contact is closed at rest).
Describing function (u = gap / X):

    kbar = 0                                                   u >= 1
    kbar = (k/2) [1 - (2/pi) (asin u + u sqrt(1 - u^2))]       -1 < u < 1
    kbar = k                                                   u <= -1  (never opens)

The force also has a mean value and even harmonics as large as its fundamental; in a structure they move the
element (a new mean position, a response at 2w, 3w ...), which changes how far the contact opens: the formula
above is the contact alone (``x = X sin wt``), and a model places the law in its structure (``placed``,
analysis/mechanics/surroundings.py). The
bracket is evaluated as twice the unit Jenkins real part at slip ratio ``(1 - u)/2``
(_special.py), free of cancellation at the onset.
"""
import numpy as np
from ..common.compiled import njit

from ._special import slip_real
from .base import Law, Param, broadcast

# the clearance is the law's shape parameter: the same object in both lists
_GAP = Param("gap", "{L}", "clearance (> 0) or preload displacement (< 0)")


@njit(cache=True)
def unilateral_force(x, v, p, s):
    k, gap = p[0], p[1]
    if x > gap:
        return k * (x - gap)
    return 0.0


class Unilateral(Law):
    name = "unilateral"
    kind = "clearance"
    summary = "one-sided contact spring (clearance or preload)"
    force_text = "k (x - gap) for x > gap, else 0"
    kbar_text = "u >= 1: 0; u <= -1: k; else (k/2)[1 - (2/pi)(asin u + u sqrt(1 - u^2))], u = gap/X"
    explanation = "{re} with Im flat: contact on one side only -- unilateral spring"
    params = (Param("k", "{F}/{L}", "contact stiffness", lower=0.0), _GAP)
    linear = ("k",)
    shape = (_GAP,)
    example = {"k": 1.0e5, "gap": 1.0e-4}
    example_amplitude = (1e-5, 1e-2)
    kernel = unilateral_force
    placed = True

    def basis(self, X, w, gap):
        X, w = broadcast(X, w)
        return np.asarray(slip_real((X - gap) / (2.0 * X)), complex)[None]
