"""A step towards the fixed point ``x = G(x)`` of a map that is costly to evaluate and may overshoot.

The plain iteration ``x <- G(x)`` converges only where the map's slope lies within (-1, 1) at the fixed point; where
it is negative (each correction overshoots) it oscillates about the fixed point, slowly or for ever. Anderson's
mixing of depth one is a secant step on the residual ``f = G(x) - x``: with the last two iterates it solves the
map's linear part along the last step, so a map linear in that direction is solved in one step whatever its slope,
and near the fixed point of a smooth map it converges superlinearly. It knows nothing of what ``x`` is.
"""
from __future__ import annotations

import numpy as np


def secant_step(x: np.ndarray, f: np.ndarray, previous: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """The next iterate from ``x`` and its residual ``f = G(x) - x`` (vectors of one shape, real or complex),
    ``previous`` the ``(x, f)`` of the step before (None: the plain step ``x + f``).

    With ``dx = x - x_prev`` and ``df = f - f_prev``, the real ``gamma`` that minimises ``|f - gamma df|`` gives
    ``x + f - gamma (dx + df)``; where ``df`` is zero (nothing learnt of the slope) the plain step."""
    if previous is None:
        return x + f
    dx, df = x - previous[0], f - previous[1]
    norm = float(np.vdot(df, df).real)
    if not norm > 0.0:
        return x + f
    gamma = float(np.vdot(df, f).real) / norm
    return x + f - gamma * (dx + df)
