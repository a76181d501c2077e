"""jenkins: spring kt in series with a Coulomb slider of slip force fs (hysteretic).

State ``s[0]``: slider position z. The force is ``kt (x - z)``; whenever it would exceed
``fs`` in magnitude the slider moves so that it equals ``+-fs``. The update is exact along
any monotone path between two calls (the velocity argument is not used: the law is rate
independent).

Describing function (slip displacement Xs = fs / kt, s = Xs / X):

    X <= Xs:  kbar = kt                                              (stuck)
    X >  Xs:  cos(psi) = 1 - 2 s,
              Re = (kt / pi) (psi - sin(2 psi) / 2),  Im = (4 fs / (pi X)) (1 - s)

Fit parametrisation: ``kt`` linear, the slip displacement ``xs = fs / kt`` (shape), so
that kbar = kt * g(X; xs).
"""
import numpy as np
from ..common.compiled import njit

from ._special import slip_imag, slip_real
from .base import Law, LimitReading, Param, broadcast


@njit(cache=True)
def jenkins_force(x, v, p, s):
    kt, fs = p[0], p[1]
    f = kt * (x - s[0])
    if f > fs:
        s[0] = x - fs / kt
        return fs
    if f < -fs:
        s[0] = x + fs / kt
        return -fs
    return f


def jenkins_unit(X, xs) -> np.ndarray:
    """kbar / kt of a Jenkins element of slip displacement ``xs`` at amplitude ``X`` (complex)."""
    with np.errstate(over="ignore"):  # xs / X = inf (e.g. a vanishing kt) is simply stuck
        ratio = xs / np.asarray(X, float)
    return slip_real(ratio) + 1j * slip_imag(ratio)


class Jenkins(Law):
    name = "jenkins"
    kind = "friction"
    summary = "Jenkins element (spring in series with a Coulomb slider)"
    force_text = "kt (x - z), slider z moves so that |f| <= fs"
    kbar_text = "X <= Xs: kt; X > Xs: kt ReJ(Xs/X) + j (4 fs/(pi X))(1 - Xs/X), Xs = fs/kt"
    explanation = ("{re} and {im}: the contact sticks at small amplitude and slips beyond a threshold -- macro-slip "
                   "friction (Jenkins)")
    params = (Param("kt", "{F}/{L}", "stiffness while stuck", lower=0.0, lower_open=True),
              Param("fs", "{F}", "slip force", lower=0.0))
    linear = ("kt",)
    shape = (Param("xs", "{L}", "slip displacement fs / kt", lower=0.0),)
    n_state = 1
    hysteretic = True
    example = {"kt": 1.0e5, "fs": 10.0}
    example_amplitude = (1e-6, 1e-2)
    kernel = jenkins_force

    def to_fit(self, values):
        return {"kt": values["kt"]}, {"xs": values["fs"] / values["kt"]}

    def from_fit(self, linear, shape):
        return {"kt": linear["kt"], "fs": linear["kt"] * shape["xs"]}

    def small_amplitude_basis(self, xs):
        return np.ones(1)       # stuck: the slider's stiffness kt

    def basis(self, X, w, xs):
        X, w = broadcast(X, w)
        return jenkins_unit(X, xs)[None]

    def reading(self, values, X_min, X_max):
        """Coulomb friction where the slider slips from a tenth of the smallest amplitude on (``X_min >= 10 xs``):
        kbar is then within a few per cent of 4 j fs / (pi X), and the stiffness while stuck is not determined
        (a stiffness beyond the structure's reads the same)."""
        kt, fs = float(values["kt"]), float(values["fs"])
        if X_min >= 10.0 * fs / kt:
            return LimitReading(
                "Coulomb friction", {"fs": fs}, {"fs": "{F}"},
                f"the slider slips from a tenth of the smallest amplitude on (slip displacement {fs / kt:.3g} "
                f"against {X_min:.3g}): kbar is a dry friction's, 4 j fs / (pi X)", ("kt",))
        return None
