"""cubic: hardening (k3 > 0) or softening (k3 < 0) spring, f = k3 x^3."""
import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast


@njit(cache=True)
def cubic_force(x, v, p, s):
    return p[0] * x * x * x


class Cubic(Law):
    name = "cubic"
    kind = "stiffness"
    summary = "cubic spring"
    force_text = "k3 x^3"
    kbar_text = "(3/4) k3 X^2"
    explanation = "{re} while Im stays flat: a {spring} spring whose force grows as x^3"
    params = (Param("k3", "{F}/{L}^3", "cubic stiffness"),)
    linear = ("k3",)
    example = {"k3": 1.0e6}
    kernel = cubic_force

    def basis(self, X, w):
        X, w = broadcast(X, w)
        return (0.75 * X**2)[None].astype(complex)
