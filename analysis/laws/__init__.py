"""The element laws of docs/contracts.md §2, one module per law, and their registry."""
from __future__ import annotations

import numpy as np

from ..common.errors import InputError
from .anderson_ferri import AndersonFerri
from .arctan_softening import ArctanSoftening
from .base import LIBRARY, Law, Param
from .bilinear import Bilinear
from .coulomb import Coulomb
from .cubic import Cubic
from .cubic_damping import CubicDamping
from .gap import Gap
from .iwan import Iwan
from .jenkins import Jenkins
from .linear import Linear
from .quadratic_damping import QuadraticDamping
from .quintic import Quintic
from .tanh_softening import TanhSoftening
from .unilateral import Unilateral
from .velocity_stiffness import VelocityStiffness

# in the order of docs/contracts.md §2
LAWS: dict[str, Law] = LIBRARY
LAWS.update({law.name: law for law in (
    Linear(), Cubic(), Quintic(), QuadraticDamping(), CubicDamping(), Coulomb(),
    TanhSoftening(), ArctanSoftening(), VelocityStiffness(), AndersonFerri(),
    Jenkins(), Iwan(), Gap(), Unilateral(), Bilinear(),
)})


def simplicity(names) -> tuple[int, int, int]:
    """How simple the set of laws ``names`` is, the key by which a choice among sets (or laws) the data cannot
    tell apart takes the simplest: its parameters; then its laws whose kbar depends on the amplitude (a linear
    spring before a preloaded one-sided contact that never opens, which is the same spring); then its shape
    parameters, those its describing function depends on nonlinearly (a linear spring and dashpot before a
    bilinear spring, which holds a linear spring at equal stiffnesses and bends away from it by its ratio). A set
    earns each added degree of freedom only by fitting what the simpler one cannot."""
    laws = [LAWS[n] for n in names]
    return (sum(len(law.params) for law in laws), sum(law.amplitude_dependent for law in laws),
            sum(len(law.shape) for law in laws))


def get_law(name: str, source: str | None = None, field: str | None = None) -> Law:
    """The law called ``name``; InputError naming the field if there is none."""
    try:
        return LAWS[name]
    except (KeyError, TypeError):
        raise InputError(f"unknown law {name!r} (known laws: {', '.join(LAWS)})", source, field) from None


def describing_function(name: str, X, w, **params: float) -> np.ndarray:
    """Equivalent complex stiffness of law ``name``: complex array broadcast over X and w.

    Parameters
    ----------
    name : str
        Law name (docs/contracts.md §2).
    X : array_like
        Amplitude of the element displacement, m (or rad), > 0.
    w : array_like
        Angular frequency, rad/s.
    **params : float
        The law's parameters by their contract names.
    """
    return get_law(name).describing_function(X, w, **params)


__all__ = ["LAWS", "Law", "Param", "get_law", "describing_function"]
