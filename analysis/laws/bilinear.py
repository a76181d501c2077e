"""bilinear: spring of different stiffness in tension and compression.

    f = k_pos x (x > 0),   f = k_neg x (x <= 0)

Describing function: kbar = (k_pos + k_neg) / 2 at every amplitude and frequency. Only
the sum is observable in kbar; the difference shows only in the mean force and the
even harmonics, so a fit of kbar alone cannot separate k_pos from k_neg (the fitter
reports the pair as non-identifiable). Both basis functions are 1/2.
"""
import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def bilinear_force(x, v, p, s):
    if x > 0.0:
        return p[0] * x
    return p[1] * x


class Bilinear(Law):
    name = "bilinear"
    kind = "linear"
    summary = "bilinear spring (different tension and compression stiffness)"
    force_text = "k_pos x (x > 0), k_neg x (x <= 0)"
    kbar_text = "(k_pos + k_neg)/2"
    explanation = "kbar is constant: a bilinear stiffness shows only in the mean and even harmonics"
    visible_in_kbar = False
    params = (Param("k_pos", "{F}/{L}", "stiffness for x > 0"),
              Param("k_neg", "{F}/{L}", "stiffness for x <= 0"))
    linear = ("k_pos", "k_neg")
    example = {"k_pos": 2.0e4, "k_neg": 1.0e4}
    kernel = bilinear_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        half = np.full(X.shape, 0.5 + 0j)
        return np.stack([half, half])
