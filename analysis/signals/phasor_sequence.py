"""The steady state a sequence of harmonic phasors converges to, with its uncertainty: a transient model that holds
for nonlinear structures.

A structure driven by a sine of period ``T`` that approaches a stable periodic steady state deviates from it, once
the deviation is small, by the response of the structure linearised about that orbit: a linear system with
T-periodic coefficients. By Floquet theory its state, seen once per period, evolves by a fixed matrix -- the
monodromy matrix, whose eigenvalues are the Floquet multipliers -- so every harmonic phasor ``P_n`` of every
channel, taken over windows of whole periods that follow one another, converges as

    P_n = P_inf + sum_k a_k mu_k^n,        n = 0 .. N-1,  |mu_k| < 1,                                 (1)

with multipliers ``mu_k`` shared by all channels and harmonics (one orbit) and amplitudes ``a_k`` per phasor. A
linear structure is the special case ``mu_k = exp(s_k W)`` (``s_k`` its poles, ``W`` the window length); a
hardening spring, a friction joint that sticks and slips, a contact that opens, each move the multipliers with
the amplitude, which is why the line is fitted on its own and no poles are carried from the lines before. Near a
jump or a bifurcation a multiplier approaches the unit circle, and the model says so instead of extrapolating.

The linearisation holds to first order in the deviation. A nonlinear structure's deviation of relative size e
also makes terms of size e^2 (the square of the deviation in a cubic spring's force, for one), and the product
of two terms ``mu_k^n`` and ``mu_l^n`` decays as ``(mu_k mu_l)^n``:

    P_n = P_inf + sum_k a_k mu_k^n + sum_{k <= l} b_kl (mu_k mu_l)^n.                                       (2)

Products of a multiplier with its conjugate are real and slower than either (``|mu|^2``): a lightly damped mode
beating with the drive leaves a term that does not beat but drifts, which (1) alone misreads as a moving limit
until the deviation is down to where its square is within the noise. (2) is the same linear solve with the
products as further multipliers -- those of the largest terms first, no parameters of their own in the
covariance -- and a line with harmonics is fitted by it; a linear structure makes no such terms.

The multipliers come from a matrix pencil (Hua and Sarkar 1990) on the differences ``P_{n+1} - P_n``, which
removes ``P_inf``: every phasor weighed by its noise, the order from the singular values above that noise. Given
them, ``P_inf`` and the ``a_k`` follow from one weighted linear least-squares solve, and ``P_inf``'s standard
deviation from its covariance.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.signals.harmonics import HarmonicProjector

MAX_MULTIPLIERS = 8        # Floquet multipliers fitted at most (two per mode of the lowest four)
NOISE_EDGE = 2.0           # a singular value counts as signal above this many times the noise's largest
UNIT_CIRCLE = 0.999        # a multiplier this close to 1 in magnitude decays too slowly to extrapolate


@dataclass
class SequenceFit:
    """The limit of a phasor sequence by (1).

    Attributes
    ----------
    limit : ndarray, complex, shape of one phasor block (e.g. (n_harmonics + 1, channels))
        ``P_inf``, in the phasors' units and at their time origin.
    std : ndarray, float, same shape
        Standard deviation of each element of ``limit`` (the larger of the noise given and the misfit).
    multipliers : ndarray, complex, (K,)
        The ``mu_k``, per window.
    residual : float
        Root-mean-square misfit of (1) in units of the given noise (about 1 where the model holds).
    last_terms : ndarray, float, (K,)
        Largest ``|a_k mu_k^(N-1)|`` over the phasors, in units of the noise: what each multiplier's term still
        holds in the last window.
    """

    limit: np.ndarray
    std: np.ndarray
    multipliers: np.ndarray
    residual: float
    last_terms: np.ndarray

    @property
    def converging(self) -> bool:
        """Every multiplier whose term is still above the noise lies well inside the unit circle: the sequence
        has a limit (1) can extrapolate to. (A term within the noise is no finding, whatever its multiplier.)"""
        return bool(np.all((np.abs(self.multipliers) < UNIT_CIRCLE) | (self.last_terms <= 1.0)))

    @property
    def slowest(self) -> float:
        """The largest magnitude of a multiplier whose term is above the noise (0 where none is)."""
        return float(np.max(np.abs(self.multipliers)[self.last_terms > 1.0], initial=0.0))


def fit_sequence(phasors, noise, products: bool = False) -> SequenceFit | None:
    """Fit (1) to ``phasors`` (N, ...) complex, window by window, each element with the standard deviation
    ``noise`` (broadcast to ``phasors``, > 0). None when the sequence is too short to hold a multiplier and
    still leave a degree of freedom per phasor (N < 4). ``products``: the multipliers of (1) include the
    products of pairs of those found (2)."""
    P = np.asarray(phasors, complex)
    N = P.shape[0]
    if N < 4:
        return None
    shape = P.shape[1:]
    sigma = np.broadcast_to(np.asarray(noise, float), P.shape).reshape(N, -1)
    # the smallest: a window's noise estimate (its residual) also holds what of the transient its harmonics do
    # not describe, most in the first windows; an underestimate only raises the order, and the misfit below
    # puts the standard deviation back where it belongs
    scale = np.maximum(np.min(sigma, axis=0), np.finfo(float).tiny)
    Z = P.reshape(N, -1) / scale                     # each phasor in units of its noise
    mu = _multipliers(np.diff(Z, axis=0), max_order=min(MAX_MULTIPLIERS, (N - 2) // 2))
    n = np.arange(N)
    V = np.column_stack([np.ones(N), *(m ** n for m in mu)])
    coef, *_ = np.linalg.lstsq(V, Z, rcond=None)
    chain = np.eye(len(mu))
    if products:
        mu, chain = _with_products(mu, coef, N)
        V = np.column_stack([np.ones(N), *(m ** n for m in mu)])
        coef, *_ = np.linalg.lstsq(V, Z, rcond=None)
    misfit = Z - V @ coef
    m_count, K = Z.shape[1], len(mu)
    dof = max(N * m_count - m_count * (K + 1) - chain.shape[1], 1)
    residual = float(np.sqrt(np.sum(np.abs(misfit) ** 2) / dof))
    # the misfit inflates the noise where the model does not hold, never deflates it below what was measured
    std = scale * np.sqrt(_limit_variance(V, coef, mu, chain)) * max(residual, 1.0)
    last_terms = np.max(np.abs(V[-1, 1:, None] * coef[1:]), axis=1) if K else np.empty(0)
    return SequenceFit((coef[0] * scale).reshape(shape), std.reshape(shape), mu, residual, last_terms)


def _with_products(mu: np.ndarray, coef: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """``mu`` and the products of its pairs (2), those of the largest terms first -- a second-order term grows
    with the product of the two first-order terms it comes from -- up to 2 MAX_MULTIPLIERS and (N - 2) / 2
    multipliers in all (the pencil's bound: a degree of freedom per phasor); and the derivatives of them all by
    the ``mu`` ((K', K): a product is no parameter of its own). ``coef`` ((K + 1, phasors)) holds the limit and
    the amplitudes of (1) with ``mu`` alone. A product that N windows cannot tell from a multiplier already in
    the set (within 1 / N: their powers differ by less than the terms themselves over the sequence) is that
    multiplier."""
    K = len(mu)
    size = np.max(np.abs(coef[1:]), axis=1)
    pairs = sorted(((size[i] * size[j], i, j) for i in range(K) for j in range(i, K)), reverse=True)
    out, chain = list(mu), list(np.eye(K, dtype=complex))
    for _, i, j in pairs:
        p = mu[i] * mu[j]
        if len(out) >= min(2 * MAX_MULTIPLIERS, (N - 2) // 2):
            break
        if np.min(np.abs(np.array(out) - p)) * N >= 1.0:
            out.append(p)
            row = np.zeros(K, complex)
            row[i] += mu[j]
            row[j] += mu[i]
            chain.append(row)
    return np.array(out, complex), np.array(chain).reshape(len(out), K)


def _limit_variance(V: np.ndarray, coef: np.ndarray, mu: np.ndarray, chain: np.ndarray) -> np.ndarray:
    """Variance of each ``P_inf`` (unit noise) from the covariance of the whole problem -- limits, amplitudes and
    multipliers together -- so that a multiplier the sequence determines poorly (a short sequence, two close
    multipliers) widens the limit's uncertainty as it should. (1) is analytic in every parameter, so with
    circular complex noise the covariance is (J^H J)^-1; the multipliers' block is eliminated (Schur
    complement) phasor by phasor. ``chain`` (K, K_free): the derivatives of the ``mu`` by the free multipliers
    (the identity where every one is free; a product's by its factors)."""
    N, m = V.shape[0], coef.shape[1]
    K = len(mu)
    if K == 0:
        return np.full(m, 1.0 / N)
    G = np.linalg.pinv(V.conj().T @ V)                # (K + 1, K + 1): the linear block, the same for every phasor
    n = np.arange(N)[:, None]
    dV = n * mu ** np.maximum(n - 1, 0)               # (N, K): d mu_k^n / d mu_k
    # per phasor j the multipliers' columns are dV * a_kj; the coupling to its linear parameters V^H dV a_j
    B = np.einsum("nl,nk,kj->jlk", V.conj(), dV, coef[1:]) @ chain                  # (m, K + 1, K_free)
    D = chain.conj().T @ ((dV.conj().T @ dV) * np.einsum("kj,lj->kl", coef[1:].conj(), coef[1:])) @ chain
    S = D - np.einsum("jlk,lp,jpq->kq", B.conj(), G, B)             # Schur complement of the linear blocks
    S_inv = np.linalg.pinv(S)
    GB = np.einsum("lp,jpk->jlk", G, B)[:, 0, :]                    # (m, K_free): row 0 of G B_j
    variance = np.real(G[0, 0] + np.einsum("jk,kq,jq->j", GB, S_inv, GB.conj()))
    return np.where(variance > 0, variance, np.inf)     # below round-off the covariance determines nothing


def _multipliers(D: np.ndarray, max_order: int) -> np.ndarray:
    """The ``mu`` of ``D_n = sum_k b_k mu_k^n`` (D: (N - 1, m), unit noise per element before differencing) by a
    matrix pencil over every column at once; the order is the number of singular values above the noise's edge
    (a Gaussian matrix of r x c entries of standard deviation s has singular values up to about
    s (sqrt(r) + sqrt(c))), at most ``max_order``."""
    M = D.shape[0]
    if max_order < 1 or M < 3:
        return np.empty(0, complex)
    L = max(min(M // 2, M - 2), 1)
    H = _hankel(D, L)
    _, s, Vh = np.linalg.svd(H, full_matrices=False)
    edge = NOISE_EDGE * np.sqrt(2.0) * (np.sqrt(H.shape[0]) + np.sqrt(H.shape[1]))
    order = min(int(np.sum(s > edge)), max_order, L)
    if order == 0:
        return np.empty(0, complex)
    # rows of H are sums of b mu^i [1, mu, .., mu^L]: the first rows of Vh span them (unconjugated), and the
    # shift between their first L and last L entries is the multipliers
    V = Vh[:order].T                                  # (L + 1, order)
    mu = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    return mu[np.abs(mu) > 0]


def _hankel(D: np.ndarray, L: int) -> np.ndarray:
    """The Hankel matrices of ``D``'s columns (M, m) with ``L + 1`` columns each, stacked: row ``c (M - L) + i``
    holds ``D[i:i + L + 1, c]``; shape (m (M - L), L + 1)."""
    return np.lib.stride_tricks.sliding_window_view(D, L + 1, axis=0).transpose(1, 0, 2).reshape(-1, L + 1)


def window_phasors(data, sample_rate: float, frequency: float, window_periods: int, n_harmonics: int,
                   origin: int, last: int | None = None):
    """Harmonic phasors of consecutive windows of ``window_periods`` periods of ``data`` (samples, channels),
    uniformly sampled. Every window's phasors are referred to one time origin, the sample ``origin`` of
    ``data`` (so a steady state gives the same phasor in every window); windows start at the nearest sample to
    a whole number of periods and hold the same number of samples (least squares, so a fraction of a sample is
    no leakage). ``last``: only the last so many windows (the same windows, not placed anew).

    Returns (phasors (N, n_harmonics + 1, channels), noise (N, 1, channels): each fundamental's standard
    deviation from its window's residual, 2 rms / sqrt(samples))."""
    y = np.asarray(data, float)
    per_window = window_periods * sample_rate / frequency
    n = int(np.ceil(per_window))                      # at least the periods asked
    starts = np.round(np.arange(int(y.shape[0] // per_window) + 1) * per_window).astype(int)
    starts = starts[starts + n <= y.shape[0]]
    if last is not None:
        starts = starts[max(len(starts) - last, 0):]
    if not len(starts):
        return np.empty((0, n_harmonics + 1, y.shape[1]), complex), np.empty((0, 1, y.shape[1]))
    amplitudes, rms = HarmonicProjector(frequency, sample_rate, n, n_harmonics).batch(
        y[starts[:, None] + np.arange(n)])
    # each window's phasors are at its first sample: moved to the common origin
    h = np.arange(n_harmonics + 1)
    P = amplitudes * np.exp(1j * 2 * np.pi * frequency * np.outer(origin - starts, h) / sample_rate)[:, :, None]
    return P, (2 * rms / np.sqrt(n))[:, None, :]
