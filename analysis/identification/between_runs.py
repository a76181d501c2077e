"""The scatter between runs: how well the test repeats itself, measured from the kbar samples.

A line's noise (the FRF estimate's, carried through the identification) says how precisely one run measured that
line. It says nothing about how well a second run would repeat it: a bolted joint settles, the temperature drifts,
the fixture moves, and on a real structure the mode moves by a fraction of its half-power bandwidth between runs.
That spread is the yardstick a model of the joint has to be judged against; where it dwarfs the line noise, a
judgement against the line noise finds every law significant and every line an outlier.

The rule: **an element's kbar is a function of its amplitude at each line** (the describing-function hypothesis
every law of docs/laws.md obeys). Two runs that measured one line at nearly the same amplitude must agree within
their noise; how far they disagree beyond it is the scatter between runs. The same line measured by repeated
levels, by up and down sweeps, or by a force-controlled level crossing a response-controlled one all give such
pairs. This is :func:`analysis.identification.linearity.scatter_std` turned by ninety degrees: there, neighbouring
lines of one run give the line noise; here, neighbouring runs at one line give the scatter between runs.

At each line the samples are sorted by ``u = ln X`` and taken four at a time (disjoint groups, in order). Within a
group spanning at most a factor ``SPAN`` in amplitude, the combination ``c . kbar`` of the four that vanishes for
any quadratic in ``u`` (the third divided difference, ``|c| = 1``) leaves the noise and the scatter between runs:

    E|c . kbar|^2 = sum_i c_i^2 std_i^2 + tau^2,

with ``tau^2`` the variance of the scatter between runs (complex, circular, like ``std``). It leaves also the
cubic term of kbar's curvature in ``u``: at most about ``0.3 %`` of kbar for the steepest law over a factor of two
(Coulomb friction's ``1 / X``), so what it estimates is the test's own repeatability plus that small share of
model-form error. Over ``n`` groups:

- ``tau^2`` is estimated part by part, ``tau^2 = tau_re^2 + tau_im^2``, each the median of the part's square less
  its line noise ``sum c^2 std^2 / 2``, over the median of chi-square with one degree of freedom (0.455): a
  median, so a few groups across a jump between branches do not move it; part by part, because a test's scatter
  need not be circular -- a stiffness that wanders moves Re kbar alone, and a median of ``|c . kbar|^2`` taken as
  exponential would read it 19 % low;
- it **rules** where the groups depart from the line noise beyond chance (a sign test: under the line noise alone
  each ``|c . kbar|^2 / sum c^2 std^2`` exceeds ``ln 2`` with probability one half; the count above is binomial,
  judged at ``false_alarm``) *and* ``tau`` exceeds the median line noise. Otherwise the line noise rules.

Where it rules, each sample's standard deviation becomes ``sqrt(std^2 + tau^2)`` (:meth:`BetweenRuns.combined`):
significance, outliers and intervals are then relative to how well the test repeats, not to how precisely one run
measured a line. Its parts are reported (:attr:`BetweenRuns.tau_parts`): where the mode's frequency wanders
between runs the scatter lies in Re kbar, and the dissipation repeats better. The samples keep the circular sum
(docs/fitting.md, "The yardstick": weighing each part by its own scatter was measured and not taken). Where fewer
than four runs measured a line within a factor ``SPAN``, nothing is estimated: a plan of levels a factor of two
apart, one sweep each, cannot tell the joint from the test's drift, and the report says the line noise ruled for
want of runs that overlap.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

from ..common.wording import engineering
from .linearity import line_labels

GROUP = 4                 # samples per group: the combination cancels a quadratic in ln X
SPAN = 2.0                # the largest amplitude ratio within a group, where the cubic term stays small
DEFAULT_FALSE_ALARM = 1.0e-3
MEDIAN_CHI2_1 = float(scipy.stats.chi2.median(1))   # 0.455: median of a real Gaussian part squared, in its variance


@dataclass(frozen=True)
class BetweenRuns:
    """The scatter between runs of one element's kbar, and whether it rules over the line noise.

    Attributes
    ----------
    tau : float
        Standard deviation of the scatter between runs, ``sqrt(E|delta kbar|^2)``, N/m (N·m/rad); 0 when not
        estimated or below the noise.
    line_noise : float
        Median standard deviation of the samples' line noise over the groups, N/m.
    groups : int
        Groups of four runs at one line within a factor ``SPAN`` in amplitude.
    above : int
        Groups whose combination exceeds its line-noise median (``ln 2`` times its variance).
    p_value : float
        Probability of at least ``above`` of ``groups`` under the line noise alone (1 with no groups).
    rules : bool
        The scatter between runs is the yardstick: significant at the false alarm and larger than the line noise.
    im_share : float
        The imaginary part's share of ``tau^2`` (``tau_im^2 / tau^2``; 0.5: circular).
    """

    tau: float
    line_noise: float
    groups: int
    above: int
    p_value: float
    rules: bool
    im_share: float = 0.5

    @property
    def tau_parts(self) -> tuple[float, float]:
        """``(tau_re, tau_im)``, N/m."""
        return self.tau * math.sqrt(1.0 - self.im_share), self.tau * math.sqrt(self.im_share)

    def combined(self, std: np.ndarray) -> np.ndarray:
        """``sqrt(std^2 + tau^2)`` where the scatter between runs rules, else ``std`` unchanged; shape of ``std``."""
        std = np.asarray(std, float)
        return np.sqrt(std**2 + self.tau**2) if self.rules else std

    def text(self, stiffness_unit: str = "N/m") -> str:
        """One sentence: which yardstick ruled, and why."""
        if not self.groups:
            return (f"yardstick: the line noise ({engineering(self.line_noise)} {stiffness_unit}); the scatter "
                    f"between runs is not measurable: no four runs measured one line within a factor {SPAN:g} "
                    "in amplitude")
        if self.rules:
            re, im = self.tau_parts
            return (f"yardstick: the scatter between runs, {engineering(self.tau)} {stiffness_unit} "
                    f"(Re {engineering(re)}, Im {engineering(im)}; "
                    f"{self.tau / max(self.line_noise, 1e-300):.0f}x the line noise of "
                    f"{engineering(self.line_noise)} {stiffness_unit}; {self.above} of {self.groups} groups of "
                    f"four runs at one line depart from it, p = {self.p_value:.1g}): significance, outliers and "
                    "intervals are judged against it")
        return (f"yardstick: the line noise ({engineering(self.line_noise)} {stiffness_unit}); the runs repeat "
                f"within it ({self.above} of {self.groups} groups of four runs at one line above its median, "
                f"p = {self.p_value:.2g})")

    def to_json(self) -> dict:
        return {"ruled_by": "between_runs" if self.rules else "line_noise", "between_runs_std": self.tau,
                "between_runs_std_parts": list(self.tau_parts),
                "line_noise_std": self.line_noise, "groups": self.groups, "groups_above": self.above,
                "p_value": self.p_value}


def between_runs(X, w, kbar, kbar_std, *, false_alarm: float = DEFAULT_FALSE_ALARM) -> BetweenRuns:
    """The scatter between runs of one element's kbar samples (module docstring).

    Parameters
    ----------
    X, w : array_like, shape (N,)
        Amplitudes (m or rad, > 0) and angular frequencies (rad/s) of the samples.
    kbar : array_like, shape (N,), complex
        Identified complex stiffness, N/m (N·m/rad).
    kbar_std : array_like, shape (N,)
        Line noise ``sqrt(E|delta kbar|^2)`` of each sample.
    false_alarm : float
        Probability that runs repeating within their line noise are said to scatter.
    """
    X, w = np.asarray(X, float), np.asarray(w, float)
    kbar, std = np.asarray(kbar, complex), np.asarray(kbar_std, float)
    residual, variance = _groups(np.log(X), w, kbar, std)
    if not residual.size:
        return BetweenRuns(0.0, float(np.median(std)) if std.size else 0.0, 0, 0, 1.0, False)
    ratio = np.abs(residual) ** 2 / np.maximum(variance, 1e-300)
    above = int((ratio > math.log(2.0)).sum())
    p_value = float(scipy.stats.binom.sf(above - 1, residual.size, 0.5))
    tau_re2, tau_im2 = (max(float(np.median(part**2 - variance / 2)) / MEDIAN_CHI2_1, 0.0)
                        for part in (residual.real, residual.imag))
    tau = math.sqrt(tau_re2 + tau_im2)
    line_noise = float(np.sqrt(np.median(variance)))
    return BetweenRuns(tau, line_noise, int(residual.size), above, p_value,
                       rules=p_value < false_alarm and tau > line_noise,
                       im_share=tau_im2 / (tau_re2 + tau_im2) if tau > 0 else 0.5)


def _groups(u: np.ndarray, w: np.ndarray, kbar: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c . kbar`` (complex) and ``sum c^2 std^2`` of every disjoint group of ``GROUP`` samples at one line within a
    factor ``SPAN`` in amplitude, taken in order of ``u`` along each line; shapes (n,)."""
    line = line_labels(w)
    order = np.lexsort((u, line))          # by line, then by amplitude along it, whatever the last digits of w
    new_line = np.concatenate([[True], np.diff(line[order]) != 0])
    starts = np.flatnonzero(new_line)
    ends = np.append(starts[1:], order.size)
    residual, variance = [], []
    for start, end in zip(starts, ends):
        members = order[start:end]
        j = 0
        while j + GROUP <= members.size:
            group = members[j:j + GROUP]
            nodes = u[group]
            if not one_group(nodes):
                j += 1
                continue
            c = divided_difference(nodes)
            residual.append(c @ kbar[group])
            variance.append(float(np.sum(c**2 * std[group] ** 2)))
            j += GROUP
    return np.asarray(residual, complex), np.asarray(variance, float)


def one_group(nodes: np.ndarray) -> bool:
    """Whether ascending ``u = ln X`` ``nodes`` may form a group: distinct, within a factor ``SPAN`` in amplitude,
    where the divided difference's cubic term stays small."""
    return bool(nodes[-1] - nodes[0] <= math.log(SPAN) and np.diff(nodes).min() > 0)


def divided_difference(nodes: np.ndarray) -> np.ndarray:
    """Weights of the highest divided difference over ``nodes`` (distinct), scaled to unit length: the
    combination that vanishes for every polynomial of degree ``len(nodes) - 2``."""
    c = np.array([1.0 / np.prod([nodes[a] - nodes[b] for b in range(nodes.size) if b != a])
                  for a in range(nodes.size)])
    return c / np.linalg.norm(c)


@dataclass(frozen=True)
class RunSensitivity:
    """What one run's FRFs are and how they move with the elements' kbar, for :func:`frf_error_floor`.

    ``receptance`` (L, P) complex, m/N: the measured FRFs; ``std`` (L, P) or None: their noise, ``sqrt(E|n|^2)``;
    ``frf_per_kbar`` (L, P, r) complex, m/N per N/m: ``d hbar / d kbar`` of each element
    (:attr:`analysis.identification.identify.ComplexStiffnessIdentification.frf_per_kbar`)."""

    receptance: np.ndarray
    std: np.ndarray | None
    frf_per_kbar: np.ndarray


@dataclass(frozen=True)
class ErrorFloor:
    """The relative FRF error a model right in every law would still show against these runs: the FRFs' own noise
    and, where it rules, the scatter of the elements' kbar between runs carried to the FRFs (first order). A model
    at its floor describes the joint as well as the test repeats itself; a law cannot be told apart below it.

    ``between_runs`` and ``line_noise``: each part's share, in the FRF error's own measure (docs/workbench.md §5:
    ``sqrt(sum |delta h|^2 / sum |h|^2)`` over every line of every stepped-sine run); ``line_noise`` NaN where
    the runs carry no noise estimate; ``ruled_by`` the elements whose scatter between runs ruled."""

    between_runs: float
    line_noise: float
    ruled_by: tuple[str, ...]

    @property
    def total(self) -> float:
        return math.hypot(self.between_runs, np.nan_to_num(self.line_noise))

    def text(self, error: float) -> str:
        """One sentence: the floor beside the model's FRF error ``error``, and which part sets it."""
        noise = f"the FRFs' noise {self.line_noise:.3g}" if np.isfinite(self.line_noise) else "no FRF noise measured"
        parts = (f"the scatter between runs at {', '.join(self.ruled_by)} {self.between_runs:.3g}, {noise}"
                 if self.ruled_by else noise)
        if error <= FLOOR_REACHED * self.total:
            at = "the model is within what the test repeats: no law can be told apart below it"
        else:
            at = f"x{error / self.total:.3g} above it"
        return f"FRF error the test itself allows: {self.total:.3g} ({parts}); {at}"

    def to_json(self) -> dict:
        return {"total": _number(self.total), "between_runs": _number(self.between_runs),
                "line_noise": _number(self.line_noise), "ruled_by": list(self.ruled_by)}


# A model's error within this factor of its floor is at it (the floor is a first-order estimate)
FLOOR_REACHED = 1.1


def _number(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def frf_error_floor(runs: list[RunSensitivity], yardsticks: list[BetweenRuns | None],
                    names: list[str]) -> ErrorFloor | None:
    """The :class:`ErrorFloor` of ``runs`` with the elements' scatter between runs ``yardsticks`` (one per element,
    in the columns' order; None or not ruling: none carried), ``names`` the elements'. Each element's kbar is taken
    to scatter independently from run to run with variance ``tau^2``, so a line's FRFs scatter by
    ``sum_i |d hbar_p / d kbar_i|^2 tau_i^2`` (first order); a line where an element's kbar is not finite
    contributes no scatter, so the floor errs low. None where neither part is measured (no FRF noise and no
    scatter between runs ruling), where both are zero (noise-free FRFs: no floor to compare with), or there is
    no FRF."""
    tau2 = np.array([y.tau ** 2 if y is not None and y.rules else 0.0 for y in yardsticks])
    spread = noise = total = 0.0
    noise_known = bool(runs) and all(r.std is not None for r in runs)
    for run in runs:
        total += float(np.sum(np.abs(run.receptance) ** 2))
        moved = np.abs(np.nan_to_num(run.frf_per_kbar, nan=0.0)) ** 2 @ tau2
        spread += float(np.sum(moved))
        if noise_known:
            noise += float(np.sum(np.asarray(run.std, float) ** 2))
    ruled = tuple(n for n, y in zip(names, yardsticks) if y is not None and y.rules)
    if total <= 0.0 or not (ruled or noise_known):
        return None
    floor = ErrorFloor(math.sqrt(spread / total), math.sqrt(noise / total) if noise_known else float("nan"), ruled)
    return floor if floor.total > 0.0 else None
