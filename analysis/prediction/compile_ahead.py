"""The law library's compiled code made ahead, for an analysis to load from the disk cache.

A fresh checkout -- or one whose analysis/ or drivers/ changed, since :mod:`analysis.common.compiled` keys its
disk cache on their sources -- compiles each law's march and each placed contact's balance the first time an
analysis asks for it, in the middle of the analysis. A command that measures before it analyses
(``contactid demo``) runs :func:`compile_library` meanwhile in a process of its own (:mod:`app.compile_ahead`),
on the core the measurement leaves idle; where the cache holds it all already, it only loads it.

What is made: every placed law's balance alone in a one-DOF structure (its fits placed in the structure), every
law's march over a sampled history and over periodic motions (its force in the time domain), and the prediction
with harmonics that places a force's jumps (a friction law's, on a one-DOF structure). The balances of several
laws placed together, which a model's prediction builds, are left to it: there are as many as there are
combinations.
"""
from __future__ import annotations

import numpy as np

from ..laws import LAWS
from ..mechanics.elements import Element, LawTerm
from ..mechanics.structures import Structure
from ..mechanics.surroundings import placed_kbar, surroundings_of
from .multiharmonic import predict_multiharmonic

_SAMPLES = 64    # samples of a period marched: any number compiles the same code


def compile_library() -> None:
    """Compile (or load from the disk cache) the library's placed balances, marches and the placing of jumps
    (module docstring); the placed balances first, the longest to compile."""
    structure = Structure(["x"], np.eye(1), np.eye(1) * 1e4, np.eye(1))
    around = surroundings_of(structure, np.ones(1))
    X, w = np.array([1e-4, 1e-3]), np.array([90.0, 100.0])
    for law in LAWS.values():
        if law.placed:
            placed_kbar([(law, law.example)], X, w, around)
    phase = np.linspace(0.0, 2 * np.pi, _SAMPLES, endpoint=False)
    x, v = np.sin(phase), np.cos(phase)
    for law in LAWS.values():
        p = law.parameter_vector(**law.example)
        law.march(x, v, p)
        law.march_periodic(x[None], v[None], p)
    friction = Element("joint", ("x",), [LawTerm(LAWS["coulomb"], LAWS["coulomb"].example)])
    predict_multiharmonic(structure, [friction], "x", np.array([15.0, 16.0]), 1.0, n_harmonics=3, n_time=64)

