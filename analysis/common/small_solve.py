"""A small dense linear solve inside compiled loops: Gaussian elimination with partial pivoting.

The rig simulator's element-force Newton and a placed contact's harmonic balance (analysis/mechanics/surroundings.py)
each solve thousands of systems of a few to a few tens of unknowns per call. Compiled in their loops it costs less
than one call into LAPACK and allocates nothing (no runtime needed: the simulator's loop runs without it). Two
compiled forms of the one function: :func:`solve_small_inline`, inlined where the caller is disk-cached (the
simulator's loop, compiled once per clone), and :func:`solve_small`, a call, where the caller is compiled once
per set of laws (a balance with its laws' kernels fixed): inlining there costs seconds of compile per set.

Both forms are compiled from the one function with the same options but ``inline``, and numba keys a disk-cached
function by its source, not its options: keep the two forms' other options identical. An edit here recompiles the
simulator's loop, which inlines it: the disk cache is keyed on every source of analysis/ and drivers/
(:mod:`analysis.common.compiled`).
"""
import math

from .compiled import njit

SOLVED, SINGULAR, NOT_FINITE = 0, 1, 2


def _solve_small(J, b, out, n):
    """Solve J out = b (n x n, partial pivoting); J and b are overwritten. Returns SOLVED, SINGULAR (a pivot exactly
    zero, as LAPACK's gesv reports it) or NOT_FINITE (a pivot inf or NaN: the system holds a non-finite entry),
    so that a caller can tell a singular system from one made of bad numbers."""
    for c in range(n):
        p = c
        best = abs(J[c, c])
        for i in range(c + 1, n):
            if abs(J[i, c]) > best:
                best = abs(J[i, c])
                p = i
        if best == 0.0:
            return SINGULAR
        if not math.isfinite(best):
            return NOT_FINITE
        if p != c:
            for j in range(n):
                J[c, j], J[p, j] = J[p, j], J[c, j]
            b[c], b[p] = b[p], b[c]
        for i in range(c + 1, n):
            f = J[i, c] / J[c, c]
            for j in range(c, n):
                J[i, j] -= f * J[c, j]
            b[i] -= f * b[c]
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, n):
            acc -= J[i, j] * out[j]
        out[i] = acc / J[i, i]
    return SOLVED


solve_small = njit(cache=True, _nrt=False)(_solve_small)
solve_small_inline = njit(cache=True, _nrt=False, inline="always")(_solve_small)
