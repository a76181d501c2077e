"""arctan_softening: saturating spring, f = alpha arctan(beta x).

Initial stiffness ``alpha beta``; the force saturates at ``(pi/2) alpha``. Exact
describing function (z = beta X):

    kbar = 2 alpha (sqrt(1 + z^2) - 1) / (beta X^2) = 2 alpha beta / (1 + sqrt(1 + z^2)),

evaluated in the second form (no cancellation at small z). Small X: alpha beta (1 - z^2/4);
large X: 2 alpha / X.

The paper's eq. 34 prints the stiffness term as ``2 alpha (sqrt((beta X)^2 + 1) - 1) / (beta X)``
and attributes it to the tanh law of eq. 32. As printed it has the units of a force,
not of a stiffness. With ``beta X^2`` in the denominator it is exactly the describing
function of this arctan law, not of tanh; the tanh law (tanh_softening.py) differs from
it by 26 % at ``beta X = 4``.
"""
import math

import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast, saturated_spring

# beta is the law's shape parameter: the same object in both lists
_BETA = Param("beta", "1/{L}", "inverse of the softening displacement", lower=0.0, lower_open=True)


@njit(cache=True)
def arctan_softening_force(x, v, p, s):
    return p[0] * math.atan(p[1] * x)


class ArctanSoftening(Law):
    name = "arctan_softening"
    kind = "stiffness"
    summary = "arctan saturating spring"
    force_text = "alpha arctan(beta x)"
    kbar_text = "2 alpha beta / (1 + sqrt(1 + beta^2 X^2))"
    explanation = "{re} and Im stays flat: a spring that saturates -- arctan softening"
    params = (Param("alpha", "{F}", "force scale (the force saturates at (pi/2) alpha)", lower=0.0), _BETA)
    linear = ("alpha",)
    shape = (_BETA,)
    example = {"alpha": 10.0, "beta": 1.0e3}
    example_amplitude = (1e-4, 1e-1)
    kernel = arctan_softening_force

    def reading(self, values, X_min, X_max):
        """The saturated spring where beta X_min >= 10 (:func:`analysis.laws.base.saturated_spring`): kbar is then
        within 10 % of 4 (pi/2) alpha / (pi X) at every amplitude measured."""
        return saturated_spring(float(values["alpha"]), float(values["beta"]), X_min, "(pi/2) alpha")

    def small_amplitude_basis(self, beta):
        return np.array([beta])     # the tangent at x = 0: alpha beta

    def basis(self, X, w, beta):
        X, w = broadcast(X, w)
        z = beta * X
        return np.asarray(2.0 * beta / (1.0 + np.sqrt(1.0 + z * z)), complex)[None]

    def basis_from_small_amplitude(self, X, w, beta):
        # 2 beta / (1 + s) - beta = -beta z^2 / (1 + s)^2, s = sqrt(1 + z^2): no cancellation at small z
        X, w = broadcast(X, w)
        z = beta * X
        return np.asarray(-beta * z * z / (1.0 + np.sqrt(1.0 + z * z)) ** 2, complex)[None]
