"""linear: spring and viscous damper, f = k x + c x'."""
import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def linear_force(x, v, p, s):
    return p[0] * x + p[1] * v


class Linear(Law):
    name = "linear"
    kind = "linear"
    summary = "linear spring and viscous damper"
    force_text = "k x + c x'"
    kbar_text = "k + j c w"
    explanation = ("kbar is a constant offset (Re {mean_re}, Im {mean_im}) that does not change with amplitude: the "
                   "element is linear but the reference stiffness or damping there is wrong -- a linear correction")
    params = (Param("k", "{F}/{L}", "stiffness"),
              Param("c", "{F}·s/{L}", "viscous damping coefficient"))
    linear = ("k", "c")
    example = {"k": 1.0e4, "c": 5.0}
    amplitude_dependent = False
    tangent_exact = True
    kernel = linear_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return np.stack([np.ones(X.shape, complex), 1j * w.astype(complex)])
