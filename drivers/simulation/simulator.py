"""Time-domain simulator of a nonlinear test rig, streaming what a DAQ would record.

Physics: ``M x'' + C x' + K x + sum_e f_e(x_e, x_e', state) = F(t)`` (docs/contracts.md §1)
for lumped and beam rigs, with the element laws of analysis.laws integrated through
their own numba kernels (see :mod:`drivers.simulation.kernels` for the integration scheme
and the true stick-slip of dry friction). Beam rigs are reduced (Craig-Bampton
type: element and excitation DOFs stay physical, the rest follows their static
shapes plus the lowest normal modes). The excitation is an ideal force source or an
electrodynamic shaker driven by the generator's voltage; the sensors are a force
gauge and accelerometers seen through an anti-alias filter, noise, an ADC of finite
resolution and range, and a DAQ clock that may run off the generator's by some ppm.

Streaming API (used by the instrument emulator and the campaign)::

    sim = RigSimulator(rig, seed=0)
    sim.set_sine(frequency_hz, amplitude)    # V with a shaker, drive units of an ideal source
    sim.set_noise(rms, (f_low, f_high))      # band-limited random drive
    sim.set_output(True)
    block = sim.advance(n)                   # (n, len(sim.channels)) in sim.units

The structure, law states, generator phase and filter states carry across calls and
generator changes, so up and down sweeps show the jumps and hysteresis of the rig.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal

from analysis.mechanics.elements import Element

from . import kernels
from .linear_model import LinearModel
from .rig import Rig, load_rig

# Stop-band attenuation of the anti-alias filter, dB
_ANTI_ALIAS_DB = 90.0
# Largest number of DAQ samples integrated in one kernel call (bounds the work arrays)
_CHUNK = 1 << 15
# Modal coordinates are used only while the eigenvector basis is this well conditioned (round-off of the
# change of coordinates stays below 1e-10 relative); beyond it (rigid-body or other defective modes) Phi
# stays dense
_MAX_MODAL_CONDITION = 1e6
# ... and while the transformed Phi is block diagonal to this relative tolerance
_BLOCK_DIAGONAL_TOLERANCE = 1e-12
# ... and for this many states or more: a smaller dense Phi costs fewer multiply-adds per step than the
# change of coordinates costs per call (measured: 4 states gain nothing in one-second blocks and lose a
# quarter in 10 ms chunks; the 11-13 states of a reduced beam gain 13-29 %)
_MODAL_MIN_STATES = 6


class SimulationError(RuntimeError):
    """The integration failed: the response diverged (e.g. a softening element escaped)."""


# --- state space and its exact discretisation --------------------------------------
@dataclass
class _Discrete:
    """One step of the state-space model (amplifier enabled or disabled), in the integration's
    coordinates ``w``: the physical state is ``z = T w`` (T = I where Phi stays dense)."""

    steps: kernels.StepMatrices
    T: np.ndarray
    T_inv: np.ndarray
    modal: bool     # T is not the identity


def _state_space(rig: Rig, model: LinearModel, enabled: bool, elements: np.ndarray | None = None):
    """Continuous model ``z' = A z + b_u u + B_g g`` with outputs, z = [q, q', (coil current)].

    Returns A, b_u, B_g, Cy (element x and v), Co, dou, Dog (channels: gauge force, accelerations);
    g and the element motion of the ``elements`` given (indices; default all).
    """
    vectors = model.element_vectors if elements is None else model.element_vectors[elements]
    nq, r = model.n, len(vectors)
    shaker = rig.shaker
    nz = 2 * nq + (1 if shaker else 0)
    Minv = np.linalg.inv(model.M)
    b = model.excitation_vector
    A = np.zeros((nz, nz))
    A[:nq, nq:2 * nq] = np.eye(nq)
    A[nq:2 * nq, :nq] = -Minv @ model.K
    A[nq:2 * nq, nq:2 * nq] = -Minv @ model.C
    b_u = np.zeros(nz)
    if shaker is None:
        b_u[nq:2 * nq] = Minv @ b * rig.source_gain
    elif enabled:
        A[nq:2 * nq, 2 * nq] = Minv @ b * shaker.force_factor
        A[2 * nq, nq:2 * nq] = -shaker.force_factor / shaker.inductance * b
        A[2 * nq, 2 * nq] = -shaker.resistance / shaker.inductance
        b_u[2 * nq] = 1.0 / shaker.inductance
    # disabled amplifier: open coil, the current stays zero and the drive does nothing
    B_g = np.zeros((nz, r))
    B_g[nq:2 * nq] = -Minv @ vectors.T
    Cy = np.zeros((2 * r, nz))
    Cy[:r, :nq] = vectors
    Cy[r:, nq:2 * nq] = vectors
    qdd = slice(nq, 2 * nq)
    n_s = model.sensor_rows.shape[0]
    Co = np.zeros((1 + n_s, nz))
    dou = np.zeros(1 + n_s)
    Dog = np.zeros((1 + n_s, r))
    Co[1:] = model.sensor_rows @ A[qdd]
    dou[1:] = model.sensor_rows @ b_u[qdd]
    Dog[1:] = model.sensor_rows @ B_g[qdd]
    if shaker is None:
        dou[0] = rig.source_gain
    else:
        # force into the structure = coil force - suspension - armature inertia
        Co[0, 2 * nq] = shaker.force_factor
        Co[0, :nq] -= shaker.suspension_stiffness * b
        Co[0, nq:2 * nq] -= shaker.suspension_damping * b
        Co[0] -= shaker.armature_mass * (b @ A[qdd])
        dou[0] = -shaker.armature_mass * (b @ b_u[qdd])
        Dog[0] = -shaker.armature_mass * (b @ B_g[qdd])
    return A, b_u, B_g, Cy, Co, dou, Dog


def _discretise(A, b_u, B_g, Cy, Co, dou, Dog, h: float) -> _Discrete:
    """Exact step of length h for a drive held quadratically and forces held linearly.

    Van Loan: the blocks of expm([[A, B, 0, 0], [0, 0, I, 0], [0, 0, 0, I], 0] h) are
    Phi and J_k = int_0^h e^{A (h - s)} B s^k / k! ds, k = 0, 1, 2; the hold
    polynomials are combinations of them. Where A has a well-conditioned real modal basis
    (:func:`_modal_basis`) the step is expressed in it: Phi is then block diagonal and costs
    O(nz) per step instead of O(nz^2).
    """
    nz = A.shape[0]
    B = np.column_stack([b_u, B_g])
    m = B.shape[1]
    N = nz + 3 * m
    aug = np.zeros((N, N))
    aug[:nz, :nz] = A
    aug[:nz, nz:nz + m] = B
    aug[nz:nz + m, nz + m:nz + 2 * m] = np.eye(m)
    aug[nz + m:nz + 2 * m, nz + 2 * m:] = np.eye(m)
    E = scipy.linalg.expm(aug * h)
    Phi = E[:nz, :nz]
    J0, J1, J2 = (E[:nz, nz + k * m:nz + (k + 1) * m] for k in range(3))
    # quadratic hold through (0, h/2, h) for the drive
    Q0 = J0[:, 0] - 3 * J1[:, 0] / h + 4 * J2[:, 0] / h**2
    Qm = 4 * J1[:, 0] / h - 8 * J2[:, 0] / h**2
    Q1 = -J1[:, 0] / h + 4 * J2[:, 0] / h**2
    Qu = np.column_stack([Q0, Qm, Q1])
    # first-order hold for the residual element forces
    Pg1 = J1[:, 1:] / h
    Pg0 = J0[:, 1:] - Pg1
    D = Cy @ Pg1  # physical, whatever the coordinates: the element motion does not depend on them
    T, T_inv, edges = _modal_basis(A, Phi)
    modal = edges is not None
    if modal:
        Phi = np.where(_block_mask(edges), T_inv @ Phi @ T, 0.0)
        Qu, Pg0, Pg1, Cy, Co = T_inv @ Qu, T_inv @ Pg0, T_inv @ Pg1, Cy @ T, Co @ T
    else:
        edges = np.array([0, nz])
    c = np.ascontiguousarray
    return _Discrete(kernels.StepMatrices(c(Phi), edges.astype(np.int64), c(Qu), c(Pg0), c(Pg1), c(Cy), c(D),
                                          np.asfortranarray(Co), c(dou), c(Dog)), T, T_inv, modal)


def _modal_basis(A, Phi):
    """Real modal basis of A: ``A = T Lambda T^-1`` with a 2 x 2 block per complex pole pair (spanned by
    the real and imaginary parts of its eigenvector) and a 1 x 1 block per real pole, and the block edges.

    Returns (I, I, None) -- keep the dense step -- for fewer than ``_MODAL_MIN_STATES`` states, and unless
    the basis is well conditioned
    (``_MAX_MODAL_CONDITION``: not so for a defective A, e.g. a rigid-body mode) and carries Phi to
    block-diagonal form to round-off (``_BLOCK_DIAGONAL_TOLERANCE``).
    """
    nz = A.shape[0]
    dense = (np.eye(nz), np.eye(nz), None)
    if nz < _MODAL_MIN_STATES:
        return dense
    poles, vectors = scipy.linalg.eig(A)
    columns, edges = [], [0]
    for k in np.argsort(-poles.imag, kind="stable"):
        if poles[k].imag < 0.0:
            continue  # the conjugate of a pole already taken
        v = vectors[:, k]
        # an orthonormal basis of the pole's invariant subspace: the real and imaginary parts themselves
        # are nearly parallel for a light damping once the velocities dominate the vector
        block = np.linalg.qr(np.column_stack([v.real, v.imag] if poles[k].imag > 0.0 else [v.real]))[0]
        columns += list(block.T)
        edges.append(edges[-1] + block.shape[1])
    if edges[-1] != nz or len(edges) == 2:
        return dense  # a pole lost to round-off, or a single block: the dense step itself
    T = np.column_stack(columns)
    if not np.linalg.cond(T) <= _MAX_MODAL_CONDITION:
        return dense
    T_inv = np.linalg.inv(T)
    modal = T_inv @ Phi @ T
    edges = np.array(edges)
    off_block = np.abs(np.where(_block_mask(edges), 0.0, modal)).max(initial=0.0)
    if off_block > _BLOCK_DIAGONAL_TOLERANCE * np.abs(modal).max():
        return dense
    return T, T_inv, edges


def _block_mask(edges: np.ndarray) -> np.ndarray:
    """Where a block-diagonal matrix with diagonal blocks ``edges[b]:edges[b + 1]`` may be nonzero."""
    block = np.repeat(np.arange(len(edges) - 1), np.diff(edges))
    return block[:, None] == block[None, :]


# --- the element laws as arrays ---------------------------------------------------
def _solved_elements(elements: list[Element]) -> np.ndarray:
    """Indices of the elements the implicit solve needs: those with a law whose force is not exactly its
    small-amplitude tangent. The others -- an element without laws (a place the analysis model names, where
    the rig has nothing) or with springs and dampers only -- are wholly in the linear part (their ``k0`` and
    ``c0``), so their residual force is zero and solving for it would only cost a Newton row per step."""
    return np.array([e for e, el in enumerate(elements) if any(not term.law.tangent_exact for term in el.laws)],
                    np.int64)


def _springs(model: LinearModel, solved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The elements outside the solve with a force of their own (springs and dampers, not the empty ones),
    and the matrix that gives their whole force ``k0 x + c0 x'`` from the state rows ``[q, q']``."""
    outside = np.setdiff1d(np.arange(len(model.k0)), solved)
    springs = outside[(model.k0[outside] != 0.0) | (model.c0[outside] != 0.0)].astype(np.int64)
    vectors = model.element_vectors[springs]
    return springs, np.vstack([vectors.T * model.k0[springs], vectors.T * model.c0[springs]])


@dataclass
class _Terms:
    """The law terms of all elements as the arrays the integration kernel takes."""

    force_address: np.ndarray
    limit_address: np.ndarray
    commit_address: np.ndarray
    count: int
    element: np.ndarray
    friction: np.ndarray
    P: np.ndarray
    n_params: np.ndarray
    S: np.ndarray
    n_state: np.ndarray
    has_friction: np.ndarray


def _law_terms(elements: list[Element]) -> _Terms:
    rows = [(e, term) for e, el in enumerate(elements) for term in el.laws]
    params = [term.law.parameter_vector(**term.values) for _, term in rows]
    states = [np.asarray(term.law.initial_state(p), float) for (_, term), p in zip(rows, params)]
    callbacks = [kernels.law_callbacks(term.law) for _, term in rows]
    n = len(rows)
    P = np.zeros((max(n, 1), max([len(p) for p in params], default=1)))
    S = np.zeros((max(n, 1), max([len(s) for s in states], default=1)))
    for k, (p, s) in enumerate(zip(params, states)):
        P[k, :len(p)] = p
        S[k, :len(s)] = s
    friction = np.array([term.law.stick_limit is not None for _, term in rows], bool)
    has_friction = np.zeros(len(elements), bool)
    for (e, _), fr in zip(rows, friction):
        has_friction[e] |= fr
    return _Terms(np.array([force.address for force, _, _ in callbacks], np.int64),
                  np.array([limit.address if limit is not None else 0 for _, limit, _ in callbacks], np.int64),
                  np.array([commit.address for _, _, commit in callbacks], np.int64), n,
                  np.array([e for e, _ in rows], np.int64), friction, P,
                  np.array([len(p) for p in params], np.int64), S,
                  np.array([len(s) for s in states], np.int64), has_friction)


# --- generator ----------------------------------------------------------------------
@dataclass
class _Ramp:
    """A level that moves linearly to a target at a fixed rate (per second)."""

    level: float = 0.0
    target: float = 0.0
    rate: float = 0.0

    def set(self, target: float, duration: float) -> None:
        """Move from the present level to ``target`` in ``duration`` s (> 0)."""
        self.target = target
        self.rate = abs(target - self.level) / duration

    def values(self, tau: np.ndarray) -> np.ndarray:
        """The level at times ``tau`` (s, >= 0) from now."""
        return kernels.ramp_level(self.level, self.target, self.rate, tau)

    def advance(self, dt: float) -> None:
        self.level = float(kernels.ramp_level(self.level, self.target, self.rate, dt))


@dataclass
class _NoiseSource:
    """Band-limited Gaussian noise of unit rms, scaled by a ramped level."""

    band: tuple[float, float]
    sos: np.ndarray
    zi: np.ndarray
    gain: float
    ramp: _Ramp
    last: float = 0.0


@dataclass
class SimulatorState:
    """Everything that evolves in a :class:`RigSimulator` (see ``state_snapshot``)."""

    samples: int
    z: np.ndarray
    g: np.ndarray
    g_prev: np.ndarray
    law_states: np.ndarray  # one row per law term of the elements in the implicit solve (_solved_elements)
    mode: np.ndarray
    sigma: np.ndarray
    fir_history: np.ndarray
    mean_square: np.ndarray
    generator: dict
    output_on: bool
    clip_counts: np.ndarray
    time: float


@dataclass(frozen=True)
class _ChunkRecord:
    """What one chunk of :meth:`RigSimulator.advance` keeps for its :class:`BlockTruth`, built only if read: the
    state in the integration's coordinates (n, nz) and the law forces (n, r) at the DAQ instants, the unfiltered
    channels (n, n_channels), the generator output (n,), the system integrated and the chunk's first sample."""

    first_sample: int
    w_daq: np.ndarray
    f_daq: np.ndarray
    channels: np.ndarray
    drive: np.ndarray
    system: object


@dataclass
class BlockTruth:
    """Noise-free truth of the last block, at the DAQ instants (before the anti-alias filter).

    Attributes
    ----------
    time : (n,)
        DAQ clock, s.
    q, qdot : (n, n_q)
        Generalised coordinates and velocities.
    element_force : (n, r)
        Law force of each element (the force it adds to the left side of the equation of motion).
    channels : (n, n_channels)
        Unfiltered, noise-free channel values (gauge force, accelerations).
    drive : (n,)
        Generator output, V (shaker) or drive units of the ideal source.
    """

    time: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    element_force: np.ndarray
    channels: np.ndarray
    drive: np.ndarray
    _model: LinearModel = field(repr=False)
    _dofs: list[str] = field(repr=False)

    def displacement(self, dof: str) -> np.ndarray:
        """Displacement history of a physical DOF, m or rad."""
        return self.q @ self.model_row(dof)

    def velocity(self, dof: str) -> np.ndarray:
        """Velocity history of a physical DOF, m/s or rad/s."""
        return self.qdot @ self.model_row(dof)

    def model_row(self, dof: str) -> np.ndarray:
        return self._model.T[self._dofs.index(dof)]

    @property
    def element_displacement(self) -> np.ndarray:
        """(n, r): x_e of every element, m or rad."""
        return self.q @ self._model.element_vectors.T

    @property
    def element_velocity(self) -> np.ndarray:
        """(n, r): x_e' of every element."""
        return self.qdot @ self._model.element_vectors.T


class RigSimulator:
    """Streaming simulation of a rig as its DAQ sees it.

    Parameters
    ----------
    rig : Rig, str or Path
        A loaded rig, a rig file or a built-in rig name.
    seed : int, optional
        Seed of the measurement noise and the random drive; default the rig's ``[noise].seed``.

    Attributes
    ----------
    sample_rate : float
        DAQ sample rate, Hz (DAQ clock).
    channels : list of str
        ``["force", "acc:<dof>", ...]``.
    units : list of str
        Unit of each channel.
    lsb : ndarray
        ADC step of each channel, in its unit.
    ranges : ndarray
        ADC full scale (+-) of each channel.
    clip_counts : ndarray of int
        Samples per channel that exceeded the ADC range since the start (or the last reset).
    filter_delay : int
        Group delay of the anti-alias filter, DAQ samples (channels lag the truth by it).
    truth : BlockTruth or None
        Truth of the last block.
    """

    def __init__(self, rig: Rig | str | Path, seed: int | None = None):
        self.rig = rig if isinstance(rig, Rig) else load_rig(rig)
        rig = self.rig
        self.model: LinearModel = rig.linear
        daq = rig.daq
        self.sample_rate = daq.sample_rate
        self.oversample = daq.oversample
        self.step = 1.0 / daq.internal_rate          # generator seconds
        self.channels = rig.channels
        n_s = len(rig.sensor_dofs)
        self.units = ["N"] + ["m/s^2"] * n_s
        self.ranges = np.array([daq.force_range] + [daq.acceleration_range] * n_s)
        self.lsb = 2.0 * self.ranges / 2.0**daq.resolution
        self._relative_noise = np.array([rig.noise.force] + [rig.noise.acceleration] * n_s)
        self._noisy = bool(np.any(self._relative_noise > 0))
        noise_seq, drive_seq = np.random.SeedSequence(rig.noise.seed if seed is None else seed).spawn(2)
        self._noise_rng = np.random.default_rng(noise_seq)
        self._drive_rng = np.random.default_rng(drive_seq)

        # the implicit solve and the state arrays below cover these elements only
        self._active = _solved_elements(rig.elements)
        self._springs, self._spring_rows = _springs(self.model, self._active)
        self._terms = _law_terms([rig.elements[e] for e in self._active])
        t = self._terms
        self._laws = kernels.LawTable(t.force_address, t.limit_address, t.commit_address, t.count, t.element,
                                      t.friction, t.P,
                                      t.n_params, t.n_state, self.model.k0[self._active],
                                      self.model.c0[self._active], t.has_friction)
        self._on = _discretise(*_state_space(rig, self.model, True, self._active), self.step)
        self._off = (_discretise(*_state_space(rig, self.model, False, self._active), self.step) if rig.shaker
                     else self._on)
        self._nz = self._on.T.shape[0]
        self._taps = _anti_alias_taps(daq.sample_rate, daq.oversample, daq.passband)
        self.filter_delay = (len(self._taps) - 1) // (2 * daq.oversample)

        r = len(self._active)
        self._z = np.zeros(self._nz)   # physical state [q, q', (coil current)]
        self._w = np.zeros(self._nz)   # ... in the integration's coordinates during a call
        self._g = np.zeros(r)
        self._g_prev = np.zeros((3, r))  # residual forces one, two and three steps earlier
        self._mode = np.where(self._terms.has_friction, kernels.STICK, kernels.FREE).astype(np.int64)
        self._sigma = np.zeros(r)
        self._jacobian = np.zeros((r, r))
        self._jacobian_valid = np.zeros(1, np.int64)
        self._scratch = kernels.scratch_space(self._nz, r, self._terms.S)
        self._integrate = self._integrate_layout = None
        self._fir_history = np.zeros((len(self._taps) - 1, 1 + n_s))
        self._mean_square = np.zeros(1 + n_s)
        self._samples = 0
        self.clip_counts = np.zeros(1 + n_s, np.int64)
        self._truth: BlockTruth | None = None
        self._truth_chunks: list[_ChunkRecord] = []
        # generator
        self._frequency = 0.0
        self._phase = 0.0
        self._sine = _Ramp()
        self._sine_offsets: tuple = (None,)   # (omega, cos, sin) of the offsets within a row of the sine
        self._noise_sources: list[_NoiseSource] = []
        self._output_on = False
        self._rest = self.state_snapshot()

    # --- properties ---------------------------------------------------------------
    @property
    def time(self) -> float:
        """Time of the next sample on the DAQ clock, s."""
        return self._samples / self.sample_rate

    @property
    def output_on(self) -> bool:
        return self._output_on

    @property
    def frequency(self) -> float:
        """Current sine frequency of the generator, Hz (generator clock)."""
        return self._frequency

    @property
    def element_names(self) -> list[str]:
        return [el.name for el in self.rig.elements]

    # --- generator ----------------------------------------------------------------
    def set_sine(self, frequency_hz: float, amplitude: float) -> None:
        """Sine drive: the frequency changes at once with continuous phase; the amplitude
        ramps linearly to ``amplitude`` over ``[generator].ramp_cycles`` cycles.

        Parameters
        ----------
        frequency_hz : float
            Hz, above 0 and below the DAQ's Nyquist frequency.
        amplitude : float
            Peak drive: V with a shaker; with an ideal force source, V of drive into its
            gain (``[excitation].gain`` N/V, default 1: newtons). 0 ramps the sine out.
        """
        frequency_hz, amplitude = float(frequency_hz), float(amplitude)
        if not (0.0 < frequency_hz < 0.5 * self.sample_rate):
            raise ValueError(f"sine frequency must be in (0, {0.5 * self.sample_rate:g}) Hz, got {frequency_hz!r}")
        if not (math.isfinite(amplitude) and amplitude >= 0.0):
            raise ValueError(f"sine amplitude must be a finite number >= 0, got {amplitude!r}")
        self._frequency = frequency_hz
        self._sine.set(amplitude, self.rig.generator.ramp_cycles / frequency_hz)

    def set_noise(self, rms: float, band_hz: tuple[float, float]) -> None:
        """Band-limited Gaussian random drive (4th-order Butterworth band-pass of white noise).

        The rms ramps over ``[generator].ramp_time``; a new band fades the old noise out
        while the new one fades in. ``rms = 0`` ramps the noise out.

        Parameters
        ----------
        rms : float
            Drive rms (V with a shaker; drive units of an ideal source).
        band_hz : (float, float)
            Pass band, Hz, inside (0, Nyquist of the DAQ).
        """
        rms = float(rms)
        low, high = (float(b) for b in band_hz)
        if not (math.isfinite(rms) and rms >= 0.0):
            raise ValueError(f"noise rms must be a finite number >= 0, got {rms!r}")
        if not (0.0 < low < high < 0.5 * self.sample_rate):
            raise ValueError(f"noise band must satisfy 0 < low < high < {0.5 * self.sample_rate:g} Hz, "
                             f"got {band_hz!r}")
        duration = self.rig.generator.ramp_time
        for source in self._noise_sources:
            source.ramp.set(rms if source.band == (low, high) else 0.0, duration)
        if rms > 0.0 and not any(s.band == (low, high) for s in self._noise_sources):
            rate = 2.0 / self.step  # noise is drawn at every half step
            sos = scipy.signal.butter(4, [low, high], btype="bandpass", fs=rate, output="sos")
            _, response = scipy.signal.sosfreqz(sos, worN=1 << 14, fs=rate)
            gain = 1.0 / math.sqrt(float(np.mean(np.abs(response) ** 2)))
            source = _NoiseSource((low, high), sos, np.zeros((sos.shape[0], 2)), gain, _Ramp())
            source.ramp.set(rms, duration)
            self._noise_sources.append(source)

    def set_output(self, on: bool) -> None:
        """Arm or disarm the output. Off: zero drive at once and the amplifier disabled
        (open coil). On: the sine and noise ramp up from zero to their set levels."""
        on = bool(on)
        if on == self._output_on:
            return
        self._output_on = on
        self._sine.level = 0.0
        self._sine.set(self._sine.target, self.rig.generator.ramp_cycles / self._frequency
                       if self._frequency > 0 else self.rig.generator.ramp_time)
        for source in self._noise_sources:
            source.ramp.level = 0.0
            source.ramp.set(source.ramp.target, self.rig.generator.ramp_time)
        if not on and self.rig.shaker is not None:
            self._z[-1] = 0.0  # the coil circuit opens: no current

    def _drive(self, n_steps: int) -> np.ndarray:
        """Generator output at every half step of the next ``n_steps`` internal steps."""
        n, spacing = 2 * n_steps + 1, 0.5 * self.step
        if not self._output_on:
            return np.zeros(n)
        omega, sine = 2 * np.pi * self._frequency, self._sine
        if self._sine_offsets[0] != omega:
            offset = omega * spacing * np.arange(_SINE_ROW)
            self._sine_offsets = (omega, np.cos(offset), np.sin(offset))
        u = kernels.ramped_sine(n, spacing, self._phase, omega, *self._sine_offsets[1:], sine.level, sine.target,
                                sine.rate)
        if self._noise_sources:
            tau = np.arange(n) * spacing
        for source in self._noise_sources:
            white = self._drive_rng.standard_normal(2 * n_steps)
            filtered, source.zi = scipy.signal.sosfilt(source.sos, white, zi=source.zi)
            unit = np.concatenate([[source.last], filtered * source.gain])
            u += source.ramp.values(tau) * unit
            source.last = float(unit[-1])
        return u

    def _advance_generator(self, n_steps: int) -> None:
        duration = n_steps * self.step
        self._phase = math.fmod(self._phase + 2 * np.pi * self._frequency * duration, 2 * np.pi)
        self._sine.advance(duration)
        for source in self._noise_sources:
            source.ramp.advance(duration)
        self._noise_sources = [s for s in self._noise_sources if s.ramp.level > 0 or s.ramp.target > 0]

    # --- integration --------------------------------------------------------------
    def advance(self, n: int) -> np.ndarray:
        """Acquire the next ``n`` DAQ samples.

        Returns
        -------
        ndarray, shape (n, len(channels))
            Physical units (``units``) after the anti-alias filter, noise and ADC.

        Raises
        ------
        SimulationError
            If the response diverges.
        """
        n = int(n)
        if n < 0:
            raise ValueError("n must be >= 0")
        blocks, records = [], []
        done = 0
        while done < n or (n == 0 and not blocks):
            chunk = min(_CHUNK, n - done)
            block, record = self._advance_chunk(chunk)
            blocks.append(block)
            records.append(record)
            done += chunk
        self._truth, self._truth_chunks = None, records
        return blocks[0] if len(blocks) == 1 else np.concatenate(blocks)

    @property
    def truth(self) -> BlockTruth | None:
        """Noise-free truth of the last :meth:`advance` (None before the first). Built when read: an emulated
        campaign never reads it, and the coordinates and element forces at the DAQ instants cost a tenth of
        a modal rig's block."""
        if self._truth is None and self._truth_chunks:
            truths = [self._chunk_truth(record) for record in self._truth_chunks]
            self._truth = truths[0] if len(truths) == 1 else BlockTruth(
                *(np.concatenate([getattr(t, name) for t in truths])
                  for name in ("time", "q", "qdot", "element_force", "channels", "drive")),
                self.model, self.rig.structure.dofs)
        return self._truth

    def _advance_chunk(self, n: int) -> tuple[np.ndarray, _ChunkRecord]:
        n_steps = n * self.oversample
        self._jacobian_valid[0] = 0  # the step matrices may have changed (amplifier on/off)
        u = self._drive(n_steps)
        internal = np.empty((n_steps, len(self.channels)))
        w_daq = np.empty((n, self._nz))
        f_daq = np.empty((n, len(self._g)))
        system = self._on if self._output_on else self._off
        w = self._z  # the dense step advances the physical state itself
        if system.modal:
            w = self._w
            np.dot(system.T_inv, self._z, out=w)
        args = (n_steps, self.oversample, system.steps, self._laws,
                kernels.SolverState(w, self._g, self._g_prev, self._terms.S, self._mode, self._sigma,
                                    self._jacobian, self._jacobian_valid),
                u, kernels.Recording(internal, w_daq, f_daq), self._scratch)
        layout = _layout(args[4])
        if layout != self._integrate_layout:
            # the other records keep their arrays' dtypes and layouts by construction: resolve the types once
            # (again only if a state array was replaced by one of another kind)
            self._integrate = kernels.typed_entry(kernels.integrate_block, args)
            self._integrate_layout = layout
        stop, solve_failed = self._integrate(*args)
        if system.modal:
            np.dot(system.T, w, out=self._z)
        if stop >= 0:
            cause = ("the element forces have no solution (a softening element may have lost its stability, "
                     "or a law force jumps)" if solve_failed else
                     "the state is no longer finite (a softening element may have lost its stability)")
            raise SimulationError(f"the response diverged at t = {self.time + stop * self.step:.6g} s: {cause}; "
                                  "restart_from_rest() starts it again")
        self._advance_generator(n_steps)
        clean = kernels.fir_decimate(internal, self._fir_history, self._taps, self.oversample)
        block = self._sensors(clean)
        # the DAQ instants are the first internal step of every group: their channels are already computed (views:
        # internal and u are made afresh for every chunk)
        record = _ChunkRecord(self._samples, w_daq, f_daq, internal[::self.oversample],
                              u[: 2 * n_steps: 2 * self.oversample], system)
        self._samples += n
        return block, record

    def _chunk_truth(self, record: _ChunkRecord) -> BlockTruth:
        """The :class:`BlockTruth` of one chunk from what :meth:`_advance_chunk` kept of it."""
        n, nq = len(record.w_daq), self.model.n
        time = (record.first_sample + np.arange(n)) / self.sample_rate
        system = record.system
        z_daq = record.w_daq @ system.T[:2 * nq].T if system.modal else record.w_daq
        element_force = record.f_daq
        if len(self._active) < len(self.rig.elements):
            element_force = np.zeros((n, len(self.rig.elements)))
            element_force[:, self._active] = record.f_daq
            if len(self._springs):
                element_force[:, self._springs] = z_daq[:, :2 * nq] @ self._spring_rows
        return BlockTruth(time, z_daq[:, :nq].copy(), z_daq[:, nq:2 * nq].copy(), element_force,
                          record.channels.copy(), record.drive, self.model, self.rig.structure.dofs)

    def _sensors(self, clean: np.ndarray) -> np.ndarray:
        """Noise relative to each channel's running rms, then the ADC (range, resolution)."""
        y = clean
        if self._noisy and len(y):
            alpha = 1.0 - math.exp(-1.0 / (self.rig.noise.averaging_time * self.sample_rate))
            mean_square, zf = scipy.signal.lfilter([alpha], [1.0, alpha - 1.0], clean**2, axis=0,
                                                   zi=((1.0 - alpha) * self._mean_square)[None, :])
            self._mean_square = zf[0] / (1.0 - alpha)
            noise = self._noise_rng.standard_normal(clean.shape)
            y = clean + noise * np.sqrt(mean_square) * self._relative_noise
        return kernels.adc(y, self.lsb, self.ranges, 2.0 ** (self.rig.daq.resolution - 1), self.clip_counts)

    def reset_clip_counts(self) -> None:
        self.clip_counts[:] = 0

    # --- truth and state ----------------------------------------------------------
    def displacements(self) -> dict[str, float]:
        """Current displacement of every physical DOF, m or rad."""
        x = self.model.T @ self._z[: self.model.n]
        return dict(zip(self.rig.structure.dofs, x.tolist()))

    def element_states(self) -> dict[str, dict]:
        """Current displacement, velocity and friction mode of every element."""
        nq = self.model.n
        x = self.model.element_vectors @ self._z[:nq]
        v = self.model.element_vectors @ self._z[nq:2 * nq]
        mode = np.full(len(self.rig.elements), kernels.FREE)
        mode[self._active] = self._mode
        modes = {kernels.FREE: "free", kernels.STICK: "stick", kernels.SLIP: "slip"}
        return {el.name: {"displacement": float(x[e]), "velocity": float(v[e]), "mode": modes[int(mode[e])]}
                for e, el in enumerate(self.rig.elements)}

    def state_snapshot(self) -> SimulatorState:
        """A deep copy of everything that evolves (restore it with :meth:`restore_state`)."""
        generator = {"frequency": self._frequency, "phase": self._phase, "sine": copy.deepcopy(self._sine),
                     "noise": copy.deepcopy(self._noise_sources),
                     "rng": (self._noise_rng.bit_generator.state, self._drive_rng.bit_generator.state)}
        state = SimulatorState(self._samples, self._z.copy(), self._g.copy(), self._g_prev.copy(),
                               self._terms.S.copy(), self._mode.copy(), self._sigma.copy(),
                               self._fir_history.copy(), self._mean_square.copy(), generator, self._output_on,
                               self.clip_counts.copy(), self.time)
        return state

    def restart_from_rest(self) -> None:
        """After a divergence (:class:`SimulationError`): the structure at rest, the output off and the
        generator silent, as when built; the clock, the random streams and the clip counts run on."""
        samples, clips = self._samples, self.clip_counts.copy()
        streams = (self._noise_rng.bit_generator.state, self._drive_rng.bit_generator.state)
        self.restore_state(self._rest)
        self._samples = samples
        self.clip_counts[:] = clips
        self._noise_rng.bit_generator.state, self._drive_rng.bit_generator.state = streams
        self._jacobian_valid[0] = 0

    def restore_state(self, state: SimulatorState) -> None:
        """Return to a state taken with :meth:`state_snapshot` of this simulator."""
        self._samples = state.samples
        self._z[:] = state.z
        self._g[:] = state.g
        self._g_prev[:] = state.g_prev
        self._terms.S[:] = state.law_states
        self._mode[:] = state.mode
        self._sigma[:] = state.sigma
        self._fir_history[:] = state.fir_history
        self._mean_square = state.mean_square.copy()
        gen = state.generator
        self._frequency, self._phase = gen["frequency"], gen["phase"]
        self._sine = copy.deepcopy(gen["sine"])
        self._noise_sources = copy.deepcopy(gen["noise"])
        self._noise_rng.bit_generator.state, self._drive_rng.bit_generator.state = gen["rng"]
        self._output_on = state.output_on
        self.clip_counts[:] = state.clip_counts


# samples per row of the generator's sine (kernels.ramped_sine): a sine and a cosine per row start
_SINE_ROW = 128


def _layout(arrays) -> tuple:
    """Dtype, dimensions and contiguity of each array: what a compiled numba function was typed for."""
    return tuple((a.dtype.char, a.ndim, a.flags.c_contiguous) for a in arrays)


def _anti_alias_taps(sample_rate: float, oversample: int, passband: float) -> np.ndarray:
    """Linear-phase low-pass FIR at the internal rate: flat to ``passband`` fs, stopping
    from ``(1 - passband)`` fs (so nothing aliases into the pass band), with a group
    delay of a whole number of DAQ samples."""
    if oversample == 1:
        return np.ones(1)
    internal = sample_rate * oversample
    width = (1.0 - 2.0 * passband) * sample_rate / (0.5 * internal)
    numtaps, beta = scipy.signal.kaiserord(_ANTI_ALIAS_DB, width)
    delay = math.ceil((numtaps - 1) / (2 * oversample))
    numtaps = 2 * oversample * delay + 1
    return scipy.signal.firwin(numtaps, 0.5 * sample_rate, window=("kaiser", beta), fs=internal)
