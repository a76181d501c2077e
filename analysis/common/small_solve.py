"""A small dense linear solve inside compiled loops: Gaussian elimination with partial pivoting.

The rig simulator's element-force Newton and a placed contact's harmonic balance (analysis/mechanics/surroundings.py)
each solve thousands of systems of a few to a few tens of unknowns per call. Compiled in their loops it costs less
than one call into LAPACK and allocates nothing (no runtime needed: the simulator's loop runs without it). Two
compiled forms of the one function: :func:`solve_small_inline`, inlined where the caller is disk-cached (the
simulator's loop, compiled once per clone), and :func:`solve_small`, a call, where the caller is compiled in
every process (a balance with its laws' kernels fixed): inlining there costs seconds of compile per process.
"""
import math

from numba import njit


def _solve_small(J, b, out, n):
    """Solve J out = b (n x n, partial pivoting); J and b are overwritten. False if singular (a pivot exactly zero,
    as LAPACK's gesv reports it) or not finite."""
    for c in range(n):
        p = c
        best = abs(J[c, c])
        for i in range(c + 1, n):
            if abs(J[i, c]) > best:
                best = abs(J[i, c])
                p = i
        if best == 0.0 or not math.isfinite(best):
            return False
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
    return True


solve_small = njit(cache=True, _nrt=False)(_solve_small)
solve_small_inline = njit(cache=True, _nrt=False, inline="always")(_solve_small)
