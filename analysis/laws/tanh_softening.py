"""tanh_softening: saturating spring, f = alpha tanh(beta x) (paper eq. 32, first term).

Initial stiffness ``alpha beta``; the force saturates at ``alpha``. Describing function
(z = beta X):

    kbar = alpha beta G(z),   G(z) = (4 / (pi z)) int_0^{pi/2} tanh(z sin t) sin t dt,

with G(z) = 1 - z^2/4 + O(z^4) at small z and 4 / (pi z) at large z. The exact series

    kbar = (4 alpha / (beta X^2)) sum_{n>=1} [1 - a_n / sqrt(a_n^2 + X^2)],  a_n = (n - 1/2) pi / beta

(from the partial fractions of tanh) converges like 1/n and needs ~z terms, so G is
evaluated by Gauss-Legendre quadrature in the phase t instead. The integrand is
analytic except for poles of tanh at ``t = i asinh((n - 1/2) pi / z)``, which approach
t = 0 as z grows. The interval is split geometrically toward t = 0 (panels
[pi/2^(k+1), pi/2^k], down to a first panel shorter than half the distance to the
nearest pole) so every panel is at least twice its own half-length away from the
poles; 20 nodes per panel then give G to about 1e-15 relative for any z (the tests
check 1e-6 against quadrature of the force and against the series summed with an
Euler-Maclaurin tail, over eight decades of z).

Beyond z = 200 the quadrature's panels grow as log2 z (a fit can run beta to 1e26), and
the large-z expansion is exact to round-off instead: with 1 - tanh u = 2 / (e^(2u) + 1)
concentrated in t < 1/z and 1 / sqrt(1 - s^2) = 1 + s^2/2 + ..., s = sin t,

    G(z) = (4 / (pi z)) [1 - c_0 / z^2 - c_1 / (2 z^4) - O(z^-6)],
    c_m = int_0^inf (1 - tanh u) u^(2m+1) du = 2^(-2m-1) (2m+1)! eta(2m+2),

c_0 = pi^2/24, c_1 = 7 pi^4/960 (eta: Dirichlet's eta function); the next term, 1.39 z^-6,
is below 2e-14 there.

The paper's eq. 34, attributed to this law, is dimensionally wrong as printed and, once
corrected, is the describing function of the arctan law (see arctan_softening.py): it
overestimates the tanh describing function by 26 % at ``beta X = 4``.
"""
import math

import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast, saturated_spring

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(20)
# the large-z expansion (module docstring): its coefficients and where it takes over from the quadrature
_C0, _C1 = math.pi ** 2 / 24.0, 7.0 * math.pi ** 4 / 960.0
_LARGE_Z = 200.0

# beta is the law's shape parameter: the same object in both lists
_BETA = Param("beta", "1/{L}", "inverse of the softening displacement", lower=0.0, lower_open=True)


@njit(cache=True)
def tanh_softening_force(x, v, p, s):
    return p[0] * math.tanh(p[1] * x)


def _phase_rule(z_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, pi/2], graded toward 0 for z <= z_max."""
    pole_distance = math.asinh(0.5 * math.pi / z_max) if z_max > 0 else math.inf
    # halve [0, pi/2] until the first panel is shorter than half the pole distance
    n_halvings = math.ceil(math.log2(math.pi / pole_distance)) if pole_distance < math.pi else 0
    edges = np.concatenate(([0.0], 0.5 * math.pi * 2.0 ** -np.arange(n_halvings, -1, -1.0)))
    lo, hi = edges[:-1, None], edges[1:, None]
    nodes = 0.5 * (hi - lo) * _NODES + 0.5 * (hi + lo)
    weights = 0.5 * (hi - lo) * _WEIGHTS
    return nodes.ravel(), weights.ravel()


def tanh_fundamental(z) -> np.ndarray:
    """G(z): describing function of ``tanh(x)`` at amplitude z, over its slope at 0.

    Parameters
    ----------
    z : array_like
        Dimensionless amplitude ``beta X`` (>= 0), any shape.

    Returns
    -------
    ndarray
        ``(4 / (pi z)) int_0^{pi/2} tanh(z sin t) sin t dt``, same shape as ``z`` (1 at z = 0).
    """
    z = np.asarray(z, float)
    flat = z.ravel()
    large = flat > _LARGE_Z
    if large.all():                         # saturated everywhere (a fit can run beta to 1e26): no masks
        return _large_z(flat).reshape(z.shape)
    out = np.empty(flat.shape)
    out[large] = _large_z(flat[large])
    small = ~large
    if small.any():
        zs = flat[small]
        nodes, weights = _phase_rule(float(zs.max()))
        sin_t = np.sin(nodes)
        zc = zs[:, None]
        safe = np.where(zc > 0, zc, 1.0)
        # tanh(z sin t) / z, with its limit sin t at z = 0
        ratio = np.where(zc > 0, np.tanh(zc * sin_t) / safe, sin_t)
        out[small] = (4.0 / math.pi) * (ratio * sin_t) @ weights
    return out.reshape(z.shape)


def _large_z(z: np.ndarray) -> np.ndarray:
    """G(z) by the large-z expansion (module docstring), z > _LARGE_Z; powers of 1/z: no overflow however large z."""
    r = 1.0 / z
    return (4.0 / math.pi) * r * (1.0 - _C0 * r * r - 0.5 * _C1 * (r * r) ** 2)


# G(z) - 1 = sum_{n>=2} g_n z^(2n-2) for |z| < pi/2: g_n = 2 a_n (2n-1)!!/(2n)!!, a_n the coefficient of u^(2n-1) in
# tanh u. Five terms leave 0.0015 z^12, below 1e-12 of the sum (about z^2/4) for z < 0.1, where subtracting 1 from
# the quadrature would lose 1e-16 / (z^2 / 4) instead.
_DEPARTURE = (-1.0 / 4.0, 1.0 / 12.0, -17.0 / 576.0, 31.0 / 2880.0, -691.0 / 172800.0)
_SERIES_Z = 0.1


def tanh_departure(z) -> np.ndarray:
    """G(z) - 1 (:func:`tanh_fundamental`) without the cancellation of the subtraction at small z: its Taylor
    series below z = 0.1, the quadrature less 1 above. Same shape as ``z`` (>= 0)."""
    z = np.asarray(z, float)
    flat = z.ravel()
    large = flat >= _SERIES_Z
    if large.all():
        return (tanh_fundamental(flat) - 1.0).reshape(z.shape)
    out = np.empty(flat.shape)
    out[large] = tanh_fundamental(flat[large]) - 1.0
    z2 = flat[~large] ** 2
    series = np.zeros_like(z2)
    for c in reversed(_DEPARTURE):          # Horner in z^2
        series = series * z2 + c
    out[~large] = series * z2
    return out.reshape(z.shape)


class TanhSoftening(Law):
    name = "tanh_softening"
    kind = "stiffness"
    summary = "tanh saturating spring (paper eq. 32)"
    force_text = "alpha tanh(beta x)"
    kbar_text = "alpha beta G(beta X), G below"
    explanation = "{re} and Im stays flat: a spring that saturates -- tanh softening"
    params = (Param("alpha", "{F}", "saturation force", lower=0.0), _BETA)
    linear = ("alpha",)
    shape = (_BETA,)
    example = {"alpha": 10.0, "beta": 1.0e3}
    example_amplitude = (1e-4, 1e-1)
    kernel = tanh_softening_force

    def reading(self, values, X_min, X_max):
        """The saturated spring where beta X_min >= 10 (:func:`analysis.laws.base.saturated_spring`): kbar is then
        within 0.4 % of 4 alpha / (pi X) at every amplitude measured."""
        return saturated_spring(float(values["alpha"]), float(values["beta"]), X_min, "alpha")

    def small_amplitude_basis(self, beta):
        return np.array([beta])     # alpha tanh(beta x) ~ alpha beta x

    def basis(self, X, w, beta):
        X, w = broadcast(X, w)
        return np.asarray(beta * tanh_fundamental(beta * X), complex)[None]

    def basis_from_small_amplitude(self, X, w, beta):
        X, w = broadcast(X, w)
        return np.asarray(beta * tanh_departure(beta * X), complex)[None]
