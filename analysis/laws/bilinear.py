"""bilinear: spring of different stiffness in tension and compression.

    f = k_pos x (x > 0),   f = k_neg x (x <= 0)

Describing function of the spring alone: kbar = (k_pos + k_neg) / 2 at every amplitude and frequency, so its formula
cannot part k_pos from k_neg. But the force has a mean and even harmonics as large as the difference, and in a
structure they move the element (a static offset, a response at 2w), which returns into the fundamental by an
amount that depends on the structure's receptance at 0 and 2w: the element's kbar moves with frequency, never with
amplitude (a linear structure with a bilinear spring is homogeneous of degree one). Placed in its structure
(``placed``, analysis/mechanics/surroundings.py) the law is fitted by that kbar, which determines both stiffnesses;
it is then the zero-clearance limit of a one-sided contact beside a linear spring,
``k_neg x + (k_pos - k_neg) max(x, 0)``.

Which side is the stiffer one the fundamental cannot tell: the motion mirrored (x -> -x) has the same kbar with the
two stiffnesses swapped; only the phase of the even harmonics could. A fit therefore gives the stiffer side as
``k_pos``. Fit parametrisation: ``k_pos`` linear (scaling the whole force), the ratio ``k_neg / k_pos`` between 0
and 1 (shape), so that kbar = k_pos (1 + ratio) / 2 alone and k_pos g(X, w; ratio) placed: a fit finds springs whose
two sides push the same way; one with sides of opposite sign (a model file may hold one) is beyond it.
"""
import numpy as np
from ..common.compiled import njit

from .base import Law, Param, broadcast

# Where a placement starts the ratio: one side carrying most of the stiffness the formula found. At an even split
# the placed kbar, even in the asymmetry, is flat in the ratio, and a refit starting there would stay there.
_PLACED_START_RATIO = 0.1


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
    explanation = ("kbar does not change with amplitude but its real part moves with frequency: a stiffness that "
                   "differs in tension and compression, whose mean and even harmonics move the structure and return "
                   "into the fundamental (which side is the stiffer the fundamental cannot tell: it is given as k_pos)")
    visible_in_kbar = False
    amplitude_dependent = False
    placed = True
    params = (Param("k_pos", "{F}/{L}", "stiffness for x > 0"),
              Param("k_neg", "{F}/{L}", "stiffness for x <= 0"))
    linear = ("k_pos",)
    shape = (Param("ratio", "1", "k_neg / k_pos, the softer side's stiffness over the stiffer's", lower=0.0,
                   upper=1.0),)
    example = {"k_pos": 2.0e4, "k_neg": 1.0e4}
    kernel = bilinear_force

    def to_fit(self, values):
        """The stiffer side as ``k_pos``: where k_neg is the stiffer, the mirror image, of the same kbar placed or
        not (module docstring)."""
        stiff, soft = sorted((values["k_pos"], values["k_neg"]), key=abs, reverse=True)
        return {"k_pos": stiff}, {"ratio": soft / stiff if stiff != 0.0 else 0.0}

    def from_fit(self, linear, shape):
        return {"k_pos": linear["k_pos"], "k_neg": linear["k_pos"] * shape["ratio"]}

    def placed_start(self, values):
        """One side carrying most of the stiffness the formula's fit found (``_PLACED_START_RATIO``), their mean
        kept."""
        mean = (values["k_pos"] + values["k_neg"]) / 2.0
        k_pos = 2.0 * mean / (1.0 + _PLACED_START_RATIO)
        return {"k_pos": k_pos, "k_neg": _PLACED_START_RATIO * k_pos}

    def basis(self, X, w, ratio):
        X, w = broadcast(X, w)
        return np.full(X.shape, (1.0 + ratio) / 2.0 + 0j)[None]
