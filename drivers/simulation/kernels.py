"""Numba kernels of the rig simulator: the whole integration loop of a block.

The linear part (structure, shaker, the elements' small-amplitude stiffness and
damping) is advanced exactly by precomputed matrix exponentials; the element laws
enter as the *residual* force ``g = f_law(x, x', state) - k0 x - c0 x'`` with a
first-order hold over each step, solved implicitly at the step end (modified Newton
on the r element forces, with a finite-difference Jacobian kept while it converges
well). Dry-friction terms (laws with a ``stick_limit``) are handled as a set-valued
force: an element either sticks (its velocity is held at zero by a constraint force
no larger than the stick limit) or slides with the friction law's force in the
direction of the slip.

Law forces are never written here: every force comes from the law's own numba
kernel, called through a C callback (:func:`law_callbacks`) whose address the loop
receives in an integer array. One compiled, disk-cached integration loop therefore
serves every combination of laws, and a new rig costs only loading the callbacks of its
laws from the disk cache.
"""
from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import carray, typeof, types
from numba.core import cgutils
from numba.extending import intrinsic

from analysis.common.compiled import cfunc_fixed, njit
from analysis.common.small_solve import SOLVED, solve_small_inline

# element modes of the friction solver
FREE = 0     # no dry-friction term: smooth law forces only
STICK = 1    # dry friction holds the element: relative velocity zero
SLIP = 2     # dry friction slides in direction sigma

# velocity handed to a dry-friction law while it slides but the Newton iterate says
# otherwise: it selects the slip branch of the law's sgn(v) without changing the force
_SLIP_PROBE = 1e-300
_MAX_NEWTON = 40
_MAX_BACKTRACK = 30
_RTOL = 1e-10
# a Newton step that reduces the residual less than this factor refreshes the Jacobian
_SLOW_CONTRACTION = 0.25
# the bracketed fallback of a single element (:func:`_bracketed`): search reach and bisection steps
_BRACKET_DOUBLINGS = 13
_MAX_BISECTION = 200

_FORCE_SIGNATURE = types.float64(types.float64, types.float64, types.CPointer(types.float64), types.intp,
                                 types.CPointer(types.float64), types.CPointer(types.float64), types.intp)
_LIMIT_SIGNATURE = types.float64(types.float64, types.CPointer(types.float64), types.intp)
_COMMIT_SIGNATURE = types.void(types.CPointer(types.float64), types.CPointer(types.float64), types.intp)

_CALLBACKS: dict[str, tuple] = {}


# --- the records the integration loop takes ------------------------------------------
class StepMatrices(NamedTuple):
    """The linear part discretised over one internal step (nz states, r elements, nch channels).

    The state may be in modal coordinates, where Phi is block diagonal: only its diagonal blocks
    ``edges[b]:edges[b + 1]`` are used (one block [0, nz] for a dense Phi).
    """

    Phi: np.ndarray   # (nz, nz) state transition over one step
    edges: np.ndarray  # (n_blocks + 1,) int64 first state of each diagonal block of Phi, then nz
    Qu: np.ndarray    # (nz, 3) drive input at the step start, middle and end (quadratic hold)
    Pg0: np.ndarray   # (nz, r) residual element forces at the step start (first-order hold)
    Pg1: np.ndarray   # (nz, r) ... and at the step end
    Cy: np.ndarray    # (2 r, nz) element displacements then velocities from the state
    D: np.ndarray     # (2 r, r) Cy @ Pg1: how the step-end element motion depends on the step-end forces
    Co: np.ndarray    # (nch, nz) channel outputs (force, accelerations) from the state, column-major (the loop
    #                   sums the channels side by side, a column at a time),
    Dou: np.ndarray   # (nch,) ... from the drive
    Dog: np.ndarray   # (nch, r) ... and from the residual element forces


class LawTable(NamedTuple):
    """The law terms of all elements, one row per term, and the elements' linear part."""

    force_address: np.ndarray   # (n_terms,) int64 address of each term's force callback (:func:`law_callbacks`)
    limit_address: np.ndarray   # (n_terms,) int64 address of its stick-limit callback, 0 = none
    commit_address: np.ndarray  # (n_terms,) int64 address of its commit callback
    count: int                  # n_terms
    element: np.ndarray         # (n_terms,) int64 element of each term
    friction: np.ndarray        # (n_terms,) bool: the term is dry friction
    P: np.ndarray               # (n_terms, max params) parameters, row k padded
    n_params: np.ndarray        # (n_terms,) int64 parameters used in each row of P
    n_state: np.ndarray         # (n_terms,) int64 state entries used in each row of the law states
    k0: np.ndarray              # (r,) small-amplitude stiffness moved into the linear part
    c0: np.ndarray              # (r,) small-amplitude damping moved into the linear part
    has_friction: np.ndarray    # (r,) bool: the element has a dry-friction term


class SolverState(NamedTuple):
    """What the integration carries from one step (and block) to the next; updated in place."""

    z: np.ndarray            # (nz,) state
    g: np.ndarray            # (r,) residual element forces now
    g_prev: np.ndarray       # (3, r) ... one, two and three steps earlier
    S: np.ndarray            # (n_terms, max states) committed law states, rows as LawTable.P
    mode: np.ndarray         # (r,) int64 friction mode per element (FREE, STICK, SLIP)
    sigma: np.ndarray        # (r,) slip direction per element
    jac: np.ndarray          # (r, r) the Newton Jacobian kept across steps
    jac_valid: np.ndarray    # (1,) int64: whether jac is usable


class Recording(NamedTuple):
    """Where a block's results go."""

    out: np.ndarray      # (n_steps, nch) channel values at every internal step (before the anti-alias filter)
    z_daq: np.ndarray    # (n_steps // oversample, nz) state at the DAQ instants
    f_daq: np.ndarray    # (n_steps // oversample, r) element law forces at the DAQ instants


class Scratch(NamedTuple):
    """Work space of :func:`integrate_block` (the loop allocates nothing: it runs without reference
    counting, which would otherwise dominate its cost)."""

    zf: np.ndarray        # (nz,) free state at the step end
    y_free: np.ndarray    # (2 r,) element motion of the free state
    x: np.ndarray         # (r,) element displacements at the step end
    v: np.ndarray         # (r,) element velocities at the step end
    F: np.ndarray         # (r,) law forces at the step end
    g_new: np.ndarray     # (r,) step-end residual forces being solved for
    work: np.ndarray      # (11, r) rows of Newton work vectors
    J: np.ndarray         # (r, r) factorised copy of the Jacobian
    S_trial: np.ndarray   # law states of the iterate (what the laws wrote: :func:`law_callbacks`)
    S_probe: np.ndarray   # law states of the Jacobian's probes and the bracketed fallback's evaluations


def law_callbacks(law) -> tuple:
    """C callbacks ``(force, stick_limit, commit)`` of a law.

    ``force(x, v, p_ptr, n_p, s_ptr, out_ptr, n_s) -> f`` evaluates the law from the state at ``s_ptr`` and
    writes the state after to ``out_ptr`` (``law.update``, handed the pointers themselves: called with arrays
    it took 20 ns more per evaluation, more than the iwan's arithmetic; for a law without one, the state is
    copied and ``law.kernel`` updates the copy); ``commit(out_ptr, s_ptr, n_s)`` makes the state at ``s_ptr``
    what an evaluation wrote (``law.commit``, else the whole state is copied); ``stick_limit(x, p_ptr, n_p)`` is None
    for laws without a stick limit. Built once per law and process and kept alive here (the integration
    loop holds only their addresses). Disk-cached per law (analysis.common.compiled.cfunc_fixed): compiled,
    a callback took 0.2-1 s in every process.
    """
    if law.name not in _CALLBACKS:
        limit = None if law.stick_limit is None else _limit_callback(law.stick_limit)
        if law.update is None:
            force, commit = _copying_force_callback(law.kernel), _copy_commit_callback()
        else:
            force, commit = _force_callback(law.update), _commit_callback(law.commit)
        _CALLBACKS[law.name] = (force, limit, commit)
    return _CALLBACKS[law.name]


def _force_callback(update):
    @cfunc_fixed(_FORCE_SIGNATURE)
    def force(x, v, p, n_p, s, out, n_s):
        return update(x, v, p, s, out)
    return force


def _copying_force_callback(kernel):
    @cfunc_fixed(_FORCE_SIGNATURE)
    def force(x, v, p, n_p, s, out, n_s):
        state = carray(out, (n_s,))
        source = carray(s, (n_s,))
        for i in range(n_s):
            state[i] = source[i]
        return kernel(x, v, carray(p, (n_p,)), state)
    return force


def _commit_callback(commit):
    @cfunc_fixed(_COMMIT_SIGNATURE)
    def callback(out, s, n_s):
        commit(out, s)
    return callback


@functools.cache
def _copy_commit_callback():
    """The commit of every law without its own: the whole state (one callback for all of them)."""
    @cfunc_fixed(_COMMIT_SIGNATURE)
    def callback(out, s, n_s):
        for i in range(n_s):
            s[i] = out[i]
    return callback


def _limit_callback(stick_limit):
    @cfunc_fixed(_LIMIT_SIGNATURE)
    def limit(x, p, n_p):
        return stick_limit(x, carray(p, (n_p,)))
    return limit


@intrinsic
def _call_force(typingctx, address, x, v, p_address, n_p, s_address, out_address, n_s):
    """Call the force callback at ``address`` with the parameter row, the state row read and the row written."""
    sig = types.float64(types.intp, types.float64, types.float64, types.intp, types.intp, types.intp,
                        types.intp, types.intp)

    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        pointer = double.as_pointer()
        index = context.get_value_type(types.intp)
        function = builder.inttoptr(args[0], ir.FunctionType(double, [double, double, pointer, index, pointer,
                                                                      pointer, index]).as_pointer())
        return builder.call(function, [args[1], args[2], builder.inttoptr(args[3], pointer), args[4],
                                       builder.inttoptr(args[5], pointer), builder.inttoptr(args[6], pointer),
                                       args[7]])

    return sig, codegen


@intrinsic
def _call_commit(typingctx, address, out_address, s_address, n_s):
    """Call the commit callback at ``address``: the state row at ``s_address`` becomes what was written."""
    sig = types.void(types.intp, types.intp, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        pointer = ir.DoubleType().as_pointer()
        index = context.get_value_type(types.intp)
        function = builder.inttoptr(args[0], ir.FunctionType(ir.VoidType(), [pointer, pointer, index]).as_pointer())
        builder.call(function, [builder.inttoptr(args[1], pointer), builder.inttoptr(args[2], pointer), args[3]])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _call_limit(typingctx, address, x, p_address, n_p):
    """Call the stick-limit callback at ``address``."""
    sig = types.float64(types.intp, types.float64, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        pointer = double.as_pointer()
        index = context.get_value_type(types.intp)
        function = builder.inttoptr(args[0], ir.FunctionType(double, [double, pointer, index]).as_pointer())
        return builder.call(function, [args[1], builder.inttoptr(args[2], pointer), args[3]])

    return sig, codegen


@intrinsic
def _copy_doubles(typingctx, destination, source, count):
    """Copy ``count`` float64 from the address ``source`` to ``destination`` (one memcpy: a loop in its place,
    inlined with :func:`_element_forces` wherever the solver evaluates the laws, slowed the beam's loop by 2 %
    even where it never ran)."""
    sig = types.void(types.intp, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        pointer = ir.DoubleType().as_pointer()
        cgutils.raw_memcpy(builder, builder.inttoptr(args[0], pointer), builder.inttoptr(args[1], pointer),
                           args[2], 8, align=8)
        return context.get_dummy_value()

    return sig, codegen


# --- law evaluation --------------------------------------------------------------
# The law evaluations below (and the Jacobian, which makes two of them) are compiled as calls of their own, not
# inlined into the loop: the Newton iteration evaluates the laws at four places, and each inlined copy was typed
# and lowered again -- a third of the loop's first compile (12.3 -> 8.0 s on a fresh clone). Their work is the
# laws' C callbacks, which the call does not slow (the simulator benchmark the same within its scatter, the
# samples the same to the bit; docs/performance.md, "First compile of the integration loop").
@njit(cache=True, _nrt=False)
def _element_forces(laws, S, S_trial, x, v, mode, sigma, out):
    """Sum of the law forces per element at (x, v), from the committed law states ``S``.

    What the laws write of their updated states lands in ``S_trial`` (``S`` is untouched; :func:`_commit`).
    Dry-friction terms of a stuck element are left out (their force is the constraint force; their state is
    copied as it is); the other terms of a stuck element see zero velocity.
    """
    out[:] = 0.0
    P = laws.P
    p_base = P.ctypes.data
    trial_base = S_trial.ctypes.data
    s_base = S.ctypes.data
    for k in range(laws.count):
        e = laws.element[k]
        ns = laws.n_state[k]
        ve = v[e]
        if mode[e] == STICK:
            if laws.friction[k]:
                _copy_doubles(trial_base + k * S_trial.strides[0], s_base + k * S.strides[0], ns)
                continue
            ve = 0.0
        elif mode[e] == SLIP and laws.friction[k] and sigma[e] * ve <= 0.0:
            ve = sigma[e] * _SLIP_PROBE
        out[e] += _call_force(laws.force_address[k], x[e], ve, p_base + k * P.strides[0], laws.n_params[k],
                              s_base + k * S.strides[0], trial_base + k * S_trial.strides[0], ns)


@njit(cache=True, _nrt=False)
def _commit(laws, S, S_trial):
    """The committed law states become those of the last evaluation into ``S_trial``."""
    s_base = S.ctypes.data
    trial_base = S_trial.ctypes.data
    for k in range(laws.count):
        _call_commit(laws.commit_address[k], trial_base + k * S_trial.strides[0], s_base + k * S.strides[0],
                     laws.n_state[k])


@njit(cache=True, _nrt=False)
def _stick_limits(laws, x, out):
    """Largest friction force each element can hold at zero velocity (sum over its friction terms)."""
    out[:] = 0.0
    P = laws.P
    p_base = P.ctypes.data
    for k in range(laws.count):
        if laws.friction[k]:
            e = laws.element[k]
            out[e] += _call_limit(laws.limit_address[k], x[e], p_base + k * P.strides[0], laws.n_params[k])


@njit(cache=True, _nrt=False, inline="always")
def _element_motion(y_free, D, g, r, x, v):
    """Element displacement and velocity at the step end for residual forces g."""
    for e in range(r):
        xe = y_free[e]
        ve = y_free[r + e]
        for j in range(r):
            xe += D[e, j] * g[j]
            ve += D[r + e, j] * g[j]
        x[e] = xe
        v[e] = ve


@njit(cache=True, _nrt=False)
def _residual(g, x, v, F, k0, c0, mode, y_free, D, r, res):
    """Residuals of the step-end equations; returns the largest |res| / tolerance.

    Force rows (sliding or smooth elements) are judged against the largest force
    term of all elements, the constraint forces of stuck elements included, velocity
    rows (stuck elements) against the largest velocity term: an element whose forces
    are tiny is then not held to a tolerance below round-off of the coupled solve (a
    free element next to a stuck one moves by the difference of the free motion and
    the constraint force's effect, which cancel to round-off).

    A call of its own, not inlined into the Newton iteration: inlined, it took 1.8 s of a fresh checkout's first
    compile of the loop, for no speed a benchmark could tell apart.
    """
    force_scale = 0.0
    velocity_scale = 0.0
    for e in range(r):
        if mode[e] == STICK:
            res[e] = v[e]
            scale = abs(y_free[r + e])
            for j in range(r):
                scale += abs(D[r + e, j] * g[j])
            velocity_scale = max(velocity_scale, scale)
            force_scale = max(force_scale, abs(g[e]))
        else:
            smooth = F[e] - k0[e] * x[e] - c0[e] * v[e]
            res[e] = g[e] - smooth
            force_scale = max(force_scale, abs(g[e]) + abs(F[e]) + abs(k0[e] * x[e]) + abs(c0[e] * v[e]))
    worst = 0.0
    for e in range(r):
        scale = velocity_scale if mode[e] == STICK else force_scale
        ratio = abs(res[e]) / (_RTOL * scale + 1e-300)
        if not math.isfinite(ratio):
            return math.inf
        worst = max(worst, ratio)
    return worst


@njit(cache=True, _nrt=False)
def _jacobian(laws, S, S_probe, D, r, mode, sigma, x, v, F, work, jac):
    """Jacobian of the step-end residuals in g, by forward differences of the law forces."""
    x_probe, v_probe, F_probe, dfdx, dfdv = work[3], work[4], work[5], work[8], work[9]
    k0, c0 = laws.k0, laws.c0
    for e in range(r):
        x_probe[e] = x[e] + (1e-7 * abs(x[e]) + 1e-13)
        v_probe[e] = v[e]
    _element_forces(laws, S, S_probe, x_probe, v_probe, mode, sigma, F_probe)
    for e in range(r):
        dfdx[e] = (F_probe[e] - F[e]) / (x_probe[e] - x[e]) - k0[e]
        x_probe[e] = x[e]
        v_probe[e] = v[e] + (1e-7 * abs(v[e]) + 1e-12)
    _element_forces(laws, S, S_probe, x_probe, v_probe, mode, sigma, F_probe)
    for e in range(r):
        dfdv[e] = (F_probe[e] - F[e]) / (v_probe[e] - v[e]) - c0[e]
    for e in range(r):
        for j in range(r):
            if mode[e] == STICK:
                jac[e, j] = D[r + e, j]
            else:
                jac[e, j] = (1.0 if e == j else 0.0) - dfdx[e] * D[e, j] - dfdv[e] * D[r + e, j]


@njit(cache=True, _nrt=False, inline="always")
def _broyden(jac, lam, step, res, res_new, r):
    """Broyden's rank-one update of the kept Jacobian along the accepted step ``lam step``.

    The element forces' tangent changes along the path (a hardening spring stiffens over the cycle); the
    update follows it at no cost in law evaluations, so the kept Jacobian stays good and one Newton
    iteration usually suffices. Rows that are linear in g (stuck elements) are left exact.
    """
    norm = 0.0
    for j in range(r):
        norm += (lam * step[j]) ** 2
    if norm == 0.0:
        return
    for e in range(r):
        predicted = 0.0
        for j in range(r):
            predicted += jac[e, j] * lam * step[j]
        c = (res_new[e] - res[e] - predicted) / norm
        for j in range(r):
            jac[e, j] += c * lam * step[j]


@njit(cache=True, _nrt=False, inline="always")
def _newton(laws, S, S_trial, S_probe, y_free, D, r, mode, sigma, g, x, v, F, work, jac, jac_valid, J):
    """Solve the step-end equations for the residual forces g with the element modes fixed.

    Modified Newton: the Jacobian in ``jac`` is reused across iterations and steps
    while ``jac_valid[0]`` is set, and refreshed when a step fails or converges slowly.
    On return x, v, F and S_trial belong to the accepted g. Returns the number of
    iterations, or -1 if the iteration did not converge.
    """
    res, res_trial, g_trial, x_probe, v_probe, F_probe, step, rhs = (work[0], work[1], work[2], work[3],
                                                                    work[4], work[5], work[6], work[7])
    k0, c0 = laws.k0, laws.c0
    _element_motion(y_free, D, g, r, x, v)
    _element_forces(laws, S, S_trial, x, v, mode, sigma, F)
    worst = _residual(g, x, v, F, k0, c0, mode, y_free, D, r, res)
    for it in range(_MAX_NEWTON):
        if worst <= 1.0:
            return it
        fresh = jac_valid[0] == 0
        if fresh:
            _jacobian(laws, S, S_probe, D, r, mode, sigma, x, v, F, work, jac)
            jac_valid[0] = 1
        for e in range(r):
            for j in range(r):
                J[e, j] = jac[e, j]
            rhs[e] = -res[e]
        if solve_small_inline(J, rhs, step, r) != SOLVED:
            if fresh:
                return -1
            jac_valid[0] = 0
            continue
        lam = 1.0
        accepted = False
        trial = worst
        for _ in range(_MAX_BACKTRACK):
            for e in range(r):
                g_trial[e] = g[e] + lam * step[e]
            _element_motion(y_free, D, g_trial, r, x_probe, v_probe)
            # the trial's law states go straight to S_trial: only an accepted iterate's are committed (a
            # rejected trial is followed by another trial, or the iteration fails)
            _element_forces(laws, S, S_trial, x_probe, v_probe, mode, sigma, F_probe)
            trial = _residual(g_trial, x_probe, v_probe, F_probe, k0, c0, mode, y_free, D, r, res_trial)
            if trial < worst or trial <= 1.0:
                accepted = True
                break
            if not fresh:
                break  # an old Jacobian: refresh it before shortening the step
            lam *= 0.5
        if not accepted:
            if fresh:
                return -1
            jac_valid[0] = 0
            continue
        if trial > _SLOW_CONTRACTION * worst and trial > 1.0:
            jac_valid[0] = 0
        _broyden(jac, lam, step, res, res_trial, r)
        worst = trial
        for e in range(r):
            g[e] = g_trial[e]
            x[e] = x_probe[e]
            v[e] = v_probe[e]
            F[e] = F_probe[e]
            res[e] = res_trial[e]
    return -1 if worst > 1.0 else _MAX_NEWTON


# The bracketed fallback (this function and the next two) runs at few steps. Compiled as calls of their own
# instead of inlined into the loop, they take 16 s off the loop's first compile (36.6 -> 20.7 s on a fresh
# clone), and the loop runs no slower (docs/performance.md, "First compile of the integration loop").
@njit(cache=True, _nrt=False)
def _signed_residual(laws, S, S_probe, y_free, D, mode, sigma, gv, work):
    """Residual of a single free element at residual force ``gv`` (signed), and its size in tolerances.

    The motion, law forces and states of the evaluation are left in ``work[3:6]`` and ``S_probe``."""
    res, g_trial, x_probe, v_probe, F_probe = work[1], work[2], work[3], work[4], work[5]
    g_trial[0] = gv
    _element_motion(y_free, D, g_trial, 1, x_probe, v_probe)
    _element_forces(laws, S, S_probe, x_probe, v_probe, mode, sigma, F_probe)
    worst = _residual(g_trial, x_probe, v_probe, F_probe, laws.k0, laws.c0, mode, y_free, D, 1, res)
    return res[0], worst


@njit(cache=True, _nrt=False)
def _bracketed(laws, S, S_trial, S_probe, y_free, D, mode, sigma, g, x, v, F, work):
    """Fallback of a single free element whose Newton iteration failed: bisection on the residual's sign change.

    A law force that jumps with the displacement (velocity_stiffness's sgn(x) at x = 0, while the element
    moves) leaves the step-end equation without a root whenever the step's free motion ends within
    ``|D_x| * jump`` of the discontinuity: the residual steps over zero there. The sign change is then the
    jump itself, and the step ends on the discontinuity with the law force between its one-sided limits, as
    a stuck friction element's constraint force lies within its stick limit (the set-valued solution of the
    step). The motion crosses the discontinuity, it is not held there: the next step leaves it. Returns
    False if no sign change lies within 2^12 residuals of the last iterate (no solution near: divergence).
    On success g, x, v, F and S_trial belong to the accepted side of the bracket.
    """
    r0, worst = _signed_residual(laws, S, S_probe, y_free, D, mode, sigma, g[0], work)
    if not math.isfinite(r0):
        return False
    lo = hi = g[0]
    r_lo = r_hi = r0
    reach = abs(r0)
    found = False
    for _ in range(_BRACKET_DOUBLINGS):
        # the residual rises with g where the law force is smooth: the root lies on the side against its sign
        probe = g[0] - reach if r0 > 0.0 else g[0] + reach
        rp, _w = _signed_residual(laws, S, S_probe, y_free, D, mode, sigma, probe, work)
        if not math.isfinite(rp):
            return False
        if (rp > 0.0) != (r0 > 0.0):
            lo, hi, r_lo, r_hi = (probe, g[0], rp, r0) if probe < g[0] else (g[0], probe, r0, rp)
            found = True
            break
        reach *= 2.0
    if not found:
        return False
    for _ in range(_MAX_BISECTION):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        rm, worst = _signed_residual(laws, S, S_probe, y_free, D, mode, sigma, mid, work)
        if worst <= 1.0:
            lo = hi = mid
            r_lo = r_hi = rm
            break
        if (rm > 0.0) == (r_lo > 0.0):
            lo, r_lo = mid, rm
        else:
            hi, r_hi = mid, rm
    g[0] = lo if abs(r_lo) <= abs(r_hi) else hi
    _element_motion(y_free, D, g, 1, x, v)
    _element_forces(laws, S, S_trial, x, v, mode, sigma, F)
    return True


@njit(cache=True, _nrt=False)
def _bracket_fallback(laws, S, S_trial, S_probe, y_free, D, r, mode, sigma, g, x, v, F, work, jac_valid):
    """After a failed Newton iteration: :func:`_bracketed` where it applies (one element, not stuck)."""
    if r != 1 or mode[0] == STICK:
        return False
    jac_valid[0] = 0  # the kept Jacobian failed here (and a jump's side is no guide to the next step)
    return _bracketed(laws, S, S_trial, S_probe, y_free, D, mode, sigma, g, x, v, F, work)


@njit(cache=True, _nrt=False, inline="always")
def _solve_step(laws, S, S_trial, S_probe, y_free, D, r, mode, sigma, g, x, v, F, work, jac, jac_valid, J):
    """Step-end element forces with stick/slip decided for every friction element.

    Active-set iteration: solve with the modes fixed, then let a stuck element slip
    when its constraint force exceeds its stick limit (in the direction of that
    force) and stop a sliding element whose velocity would reverse. Commits the law
    states. Returns False if the Newton iteration failed.
    """
    limit = work[10]
    k0 = laws.k0
    ok = True
    for _ in range(2 + 4 * r):
        if (_newton(laws, S, S_trial, S_probe, y_free, D, r, mode, sigma, g, x, v, F, work, jac, jac_valid, J) < 0
                and not _bracket_fallback(laws, S, S_trial, S_probe, y_free, D, r, mode, sigma, g, x, v, F, work,
                                          jac_valid)):
            ok = False
        changed = False
        _stick_limits(laws, x, limit)
        for e in range(r):
            if not laws.has_friction[e]:
                continue
            if mode[e] == STICK:
                # friction force needed to hold the element: total force minus the other laws
                needed = g[e] + k0[e] * x[e] - F[e]
                if abs(needed) > limit[e]:
                    mode[e] = SLIP
                    sigma[e] = 1.0 if needed > 0.0 else -1.0
                    changed = True
            elif sigma[e] * v[e] < 0.0:
                mode[e] = STICK
                changed = True
        if not changed:
            break
        jac_valid[0] = 0
    _commit(laws, S, S_trial)
    return ok


@njit(cache=True, _nrt=False, inline="always")
def _channel_outputs(Co, Dou, Dog, z, g, u0, channels):
    """The channels at one step, ``Dou u0 + Co z + Dog g``, each summed in that order over ascending indices.

    Four channels at a time side by side (``Co`` column-major: their four coefficients of a state are
    adjacent), so their sums do not wait on one another's additions; the rest one by one."""
    nch = channels.shape[0]
    nz = z.shape[0]
    r = g.shape[0]
    c = 0
    while c + 4 <= nch:
        a0 = Dou[c] * u0
        a1 = Dou[c + 1] * u0
        a2 = Dou[c + 2] * u0
        a3 = Dou[c + 3] * u0
        for i in range(nz):
            zi = z[i]
            a0 += Co[c, i] * zi
            a1 += Co[c + 1, i] * zi
            a2 += Co[c + 2, i] * zi
            a3 += Co[c + 3, i] * zi
        for e in range(r):
            ge = g[e]
            a0 += Dog[c, e] * ge
            a1 += Dog[c + 1, e] * ge
            a2 += Dog[c + 2, e] * ge
            a3 += Dog[c + 3, e] * ge
        channels[c] = a0
        channels[c + 1] = a1
        channels[c + 2] = a2
        channels[c + 3] = a3
        c += 4
    for k in range(c, nch):
        acc = Dou[k] * u0
        for i in range(nz):
            acc += Co[k, i] * z[i]
        for e in range(r):
            acc += Dog[k, e] * g[e]
        channels[k] = acc


# --- the block loop ----------------------------------------------------------------
@njit(cache=True, _nrt=False, inline="always")
def _leading_pairs(edges):
    """How many diagonal blocks of Phi, from the first, are 2 x 2 (a modal basis puts its complex pole pairs
    first: :func:`drivers.simulation.simulator._modal_basis`)."""
    n = 0
    while n + 1 < edges.shape[0] and edges[n + 1] - edges[n] == 2:
        n += 1
    return n


def typed_entry(dispatcher, args):
    """The compiled function a numba dispatcher runs for the types of ``args`` (compiled or loaded if needed).

    The dispatcher types every array inside record arguments at each call (about 10 us per call of
    :func:`integrate_block`, more than integrating 10 ms of a 2-DOF rig). A caller whose arguments keep
    their types (dtypes, dimensions, layouts) from call to call resolves them once and calls the result.
    """
    return dispatcher.compile(tuple(dispatcher.typeof_pyval(a) for a in args))


def kernel_signatures() -> dict:
    """The simulator's compiled kernels other than :func:`integrate_block`, each with the argument types it is
    called with, which no rig changes: the loop's calls of their own (the laws' forces, the residual, the Jacobian,
    the bracketed fallback, the stick limits, the commit), the generator's sine, the anti-alias filter and the
    converter."""
    ints, flags = np.zeros(0, np.int64), np.zeros(0, bool)
    laws = typeof(LawTable(ints, ints, ints, 0, ints, flags, np.zeros((0, 0)), ints, ints, np.zeros(0),
                           np.zeros(0), flags))
    v, m, i = types.float64[::1], types.float64[:, ::1], types.int64[::1]
    return {_element_forces: (laws, m, m, v, v, i, v, v),
            _residual: (v, v, v, v, v, v, i, v, m, types.int64, v),
            _jacobian: (laws, m, m, m, types.int64, i, v, v, v, v, m, m),
            _signed_residual: (laws, m, m, v, m, i, v, types.float64, m),
            _bracketed: (laws, m, m, m, v, m, i, v, v, v, v, v, m),
            _bracket_fallback: (laws, m, m, m, v, m, types.int64, i, v, v, v, v, v, m, i),
            _stick_limits: (laws, v, v),
            _commit: (laws, m, m),
            fir_decimate: (m, m, v, types.int64),
            ramped_sine: (types.int64,) + (types.float64,) * 3 + (v, v) + (types.float64,) * 3,
            adc: (m, v, v, types.float64, i)}


def compile_kernels() -> None:
    """The kernels of :func:`kernel_signatures` compiled, or loaded from the disk cache. :func:`integrate_block`
    types its calls as calls and loads any the cache holds: a process that compiles them while another compiles
    the loop takes their part off a fresh checkout's first simulation (the demo's compiling ahead,
    :mod:`app.compile_ahead`)."""
    for kernel, signature in kernel_signatures().items():
        kernel.compile(signature)


def scratch_space(nz: int, r: int, law_states: np.ndarray) -> Scratch:
    """Work arrays for :func:`integrate_block` (state size nz, r elements, law-state rows)."""
    return Scratch(np.empty(nz), np.empty(2 * r), np.empty(r), np.empty(r), np.empty(r), np.empty(r),
                   np.empty((11, max(r, 1))), np.empty((r, r)), np.empty_like(law_states),
                   np.empty_like(law_states))


@njit(cache=True, _nrt=False)
def integrate_block(n_steps, oversample, system, laws, state, u, record, scratch):
    """Advance the rig by ``n_steps`` internal steps.

    Parameters
    ----------
    n_steps : int
        Internal steps (a multiple of ``oversample``).
    oversample : int
        Internal steps per DAQ sample; the state and the element forces are recorded at
        the first step of every group.
    system : StepMatrices
        The discretised linear part.
    laws : LawTable
        The law terms and the elements' small-amplitude stiffness and damping.
    state : SolverState
        State, residual forces, committed law states, friction modes and Jacobian; updated.
    u : (2 n_steps + 1,)
        Drive at every half step, V (shaker) or drive units of an ideal source.
    record : Recording
        Filled with the channels at every internal step and the state (in the coordinates of
        ``system``) and element law forces at the DAQ instants.
    scratch : Scratch
        Work space from :func:`scratch_space`.

    Returns
    -------
    (int, int)
        Index of the step where the integration stopped (-1: all done) and whether it
        stopped because the implicit solve failed (1) rather than on a non-finite state (0).
    """
    Phi, edges, Qu, Pg0, Pg1, Cy, D, Co, Dou, Dog = system
    z, g, g_prev, S, mode, sigma, jac, jac_valid = state
    out, z_daq, f_daq = record
    zf, y_free, x, v, F, g_new, work, J, S_trial, S_probe = scratch
    k0, c0 = laws.k0, laws.c0
    nz = z.shape[0]
    r = k0.shape[0]
    n_pairs = _leading_pairs(edges)
    for m in range(n_steps):
        u0 = u[2 * m]
        um = u[2 * m + 1]
        u1 = u[2 * m + 2]
        _channel_outputs(Co, Dou, Dog, z, g, u0, out[m])
        if m % oversample == 0:
            row = m // oversample
            for i in range(nz):
                z_daq[row, i] = z[i]
            for e in range(r):
                xe = 0.0
                ve = 0.0
                for i in range(nz):
                    xe += Cy[e, i] * z[i]
                    ve += Cy[r + e, i] * z[i]
                f_daq[row, e] = g[e] + k0[e] * xe + c0[e] * ve
            total = 0.0
            for i in range(nz):
                total += z[i]
            if not math.isfinite(total):
                return m, 0
        for p in range(n_pairs):
            # a mode's 2 x 2 block written out, indexed from the loop counter: the general loop's index
            # bookkeeping, and indices read from ``edges`` (checked for negative values), cost more than its
            # arithmetic (the same sums in the same order)
            lo = 2 * p
            z0 = z[lo]
            z1 = z[lo + 1]
            a0 = Qu[lo, 0] * u0 + Qu[lo, 1] * um + Qu[lo, 2] * u1
            a1 = Qu[lo + 1, 0] * u0 + Qu[lo + 1, 1] * um + Qu[lo + 1, 2] * u1
            a0 += Phi[lo, lo] * z0
            a0 += Phi[lo, lo + 1] * z1
            a1 += Phi[lo + 1, lo] * z0
            a1 += Phi[lo + 1, lo + 1] * z1
            for e in range(r):
                a0 += Pg0[lo, e] * g[e]
                a1 += Pg0[lo + 1, e] * g[e]
            zf[lo] = a0
            zf[lo + 1] = a1
        for b in range(n_pairs, edges.shape[0] - 1):
            lo = edges[b]
            hi = edges[b + 1]
            for i in range(lo, hi):
                acc = Qu[i, 0] * u0 + Qu[i, 1] * um + Qu[i, 2] * u1
                for j in range(lo, hi):
                    acc += Phi[i, j] * z[j]
                for e in range(r):
                    acc += Pg0[i, e] * g[e]
                zf[i] = acc
        if r > 0:
            # the element motion of the free state; an element's displacement and velocity summed side by side
            for e in range(r):
                xe = 0.0
                ve = 0.0
                for i in range(nz):
                    xe += Cy[e, i] * zf[i]
                    ve += Cy[r + e, i] * zf[i]
                y_free[e] = xe
                y_free[r + e] = ve
            for e in range(r):
                # cubic extrapolation: the Newton start is O(h^4) off on a smooth path, so one iterate
                # reaches the tolerance where a start O(h^3) off often needed two
                g_new[e] = 4.0 * (g[e] + g_prev[1, e]) - 6.0 * g_prev[0, e] - g_prev[2, e]
            if not _solve_step(laws, S, S_trial, S_probe, y_free, D, r, mode, sigma, g_new, x, v, F, work, jac,
                               jac_valid, J):
                return m, 1
            for e in range(r):
                g_prev[2, e] = g_prev[1, e]
                g_prev[1, e] = g_prev[0, e]
                g_prev[0, e] = g[e]
                g[e] = g_new[e]
            # element by element, each over all states (the same sums in the same order; the loop over the
            # states vectorises, one over a single element did not)
            for e in range(r):
                ge = g[e]
                for i in range(nz):
                    zf[i] += Pg1[i, e] * ge
        for i in range(nz):
            z[i] = zf[i]
    total = 0.0
    for i in range(nz):
        total += z[i]
    if not math.isfinite(total):
        return n_steps, 0
    return -1, 0


def ramp_level(level, target, rate, tau):
    """A level moving linearly from ``level`` to ``target`` at ``rate`` per second (>= 0) and staying there, at
    ``tau`` s from now (>= 0; a float, or an array in NumPy): the generator's amplitude ramp, written once for the
    compiled sine and for NumPy."""
    if target > level:
        return np.minimum(level + rate * tau, target)
    if target < level:
        return np.maximum(level - rate * tau, target)
    return level + 0.0 * tau


_ramp_level = njit(cache=True, inline="always")(ramp_level)


@njit(cache=True)
def ramped_sine(n, spacing, phase, omega, cos_offset, sin_offset, level, target, rate):
    """The generator's sine ``a(tau) sin(phase + omega tau)`` at ``tau = k spacing``, ``k = 0 .. n - 1``, its
    amplitude ``a`` moving from ``level`` to ``target`` at ``rate`` per second and staying there.

    Angle addition over rows of ``R = len(cos_offset)`` samples: a sine and a cosine per row start
    ``phase + omega spacing R i``, the offsets' tabulated by the caller (``cos_offset[j] = cos(omega spacing j)``,
    ``sin_offset`` alike, the same for every block of a line). Each sample is then right to round-off of its
    argument at two multiply-adds, where a sine per sample cost ten times more than the rest of a block outside the
    integration loop.

    Parameters
    ----------
    n : int
    spacing, phase, omega : float
        s, rad, rad/s.
    cos_offset, sin_offset : (R,)
    level, target, rate : float
        Amplitude now and where it goes (drive units), its rate (drive units per s, >= 0).

    Returns
    -------
    (n,)
    """
    out = np.empty(n)
    row = cos_offset.shape[0]
    for start in range(0, n, row):
        angle = phase + omega * spacing * row * (start // row)
        s, c = math.sin(angle), math.cos(angle)
        for j in range(min(row, n - start)):
            a = _ramp_level(level, target, rate, (start + j) * spacing)
            out[start + j] = a * (s * cos_offset[j] + c * sin_offset[j])
    return out


@njit(cache=True)
def adc(y, lsb, ranges, half_codes, clip_counts):
    """ADC of every channel: codes of ``lsb`` (round half to even), saturating at
    ``-half_codes .. half_codes - 1``; samples beyond ``ranges`` count in ``clip_counts``.

    Parameters
    ----------
    y : (n, nch)
        Input in physical units.
    lsb, ranges : (nch,)
    half_codes : float
        2^(bits - 1).
    clip_counts : (nch,) int64
        Updated.

    Returns
    -------
    (n, nch)
        The quantised samples in physical units.
    """
    n, nch = y.shape
    out = np.empty((n, nch))
    for i in range(n):
        for c in range(nch):
            value = y[i, c]
            if abs(value) > ranges[c]:
                clip_counts[c] += 1
            code = min(max(np.rint(value / lsb[c]), -half_codes), half_codes - 1.0)
            out[i, c] = code * lsb[c]
    return out


@njit(cache=True, fastmath={"reassoc"})
def fir_decimate(samples, history, taps, factor):
    """Low-pass FIR filter and keep every ``factor``-th output (polyphase: only kept outputs).

    Parameters
    ----------
    samples : (n, nch)
        New input at the internal rate; n is a multiple of ``factor``.
    history : (len(taps) - 1, nch)
        The previous inputs (oldest first); updated.
    taps : (L,)
    factor : int

    Returns
    -------
    (n // factor, nch)
        Output at the inputs 0, factor, 2 factor, ... of this block.
    """
    n, nch = samples.shape
    L = taps.shape[0]
    H = L - 1
    # each channel joined to its history in one contiguous row: every output is then a dot product of
    # contiguous vectors, which the compiler vectorises (allowed to reassociate the sum; no other fast-math
    # assumption, so a non-finite sample stays non-finite)
    joined = np.empty((nch, n + H))
    for i in range(H):
        for c in range(nch):
            joined[c, i] = history[i, c]
    for i in range(n):
        for c in range(nch):
            joined[c, H + i] = samples[i, c]
    reversed_taps = taps[::-1].copy()
    n_out = n // factor
    out = np.empty((n_out, nch))
    for c in range(nch):
        row = joined[c]
        k = 0
        # two outputs at a time: their sums are independent, so neither waits on the other's additions; each
        # output's inputs as a view indexed from 0 (an index m + j, which numba must check for negative
        # values, kept the loads scalar)
        while k + 2 <= n_out:
            m = k * factor  # the output at joined index m + H
            first = row[m:m + L]
            second = row[m + factor:m + factor + L]
            acc0 = 0.0
            acc1 = 0.0
            for j in range(L):
                acc0 += reversed_taps[j] * first[j]
                acc1 += reversed_taps[j] * second[j]
            out[k, c] = acc0
            out[k + 1, c] = acc1
            k += 2
        if k < n_out:
            m = k * factor
            first = row[m:m + L]
            acc = 0.0
            for j in range(L):
                acc += reversed_taps[j] * first[j]
            out[k, c] = acc
    # the last H inputs become the history, element by element: a slice assignment would compile numba's
    # shape-mismatch message (string formatting, seconds of compilation on a fresh install)
    for i in range(H):
        for c in range(nch):
            history[i, c] = joined[c, n + i]
    return out
