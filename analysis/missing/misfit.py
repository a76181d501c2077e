"""A systematic misfit the fitted laws leave in an element's kbar: a long run of same-sign residuals.

The fit's chi-square says how large the residuals are, not whether they are noise; a law that lies above the data
over a whole range of amplitudes is a misfit the user must see even when the fit is accepted. The rule
(docs/identification.md, "Systematic misfit"): sort the element's samples by amplitude X; for Re and Im kbar
separately, find the longest run of consecutive samples whose residual (data - model) has one sign. Under noise
alone the signs are independent coin flips and a run of L or more among n samples has probability below
``n 2^(1-L)``; the run is named when that bound is below ``RUN_FALSE_ALARM`` and, where the samples carry standard
deviations, its mean residual exceeds ``MISFIT_SIGMA`` standard errors.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common.wording import engineering, significant

RUN_FALSE_ALARM = 1e-3     # the chance that noise alone makes a run this long somewhere among the samples
MISFIT_SIGMA = 3.0         # the run's mean residual against its standard error


ENDS = 5                   # samples averaged at each end of a run to say where data and law stand there


@dataclass(frozen=True)
class Misfit:
    """One run of same-sign residuals: where, how long, and how large."""
    element: str
    part: str                          # "Re" or "Im"
    X_range: tuple[float, float]       # m (rad)
    count: int                         # samples in the run
    total: int                         # samples of the element
    data_ends: tuple[float, float]     # the data at the run's small- and large-amplitude end (ENDS samples each)
    model_ends: tuple[float, float]    # the fitted model there
    misfit: float                      # mean of data - model over the run, N/m (N·m/rad)
    sigma: float | None                # mean residual / its standard error (None without sample deviations)
    units: tuple[str, str]             # (stiffness, amplitude)

    def text(self) -> str:
        k_u, x_u = self.units
        where = "below" if self.misfit < 0 else "above"
        evidence = f", {self.sigma:.1f} sigma" if self.sigma is not None else ""
        return (f"{self.element} {self.part} kbar: the data lie {where} the fitted laws at X "
                f"{engineering(self.X_range[0], x_u)}..{engineering(self.X_range[1], x_u)} ({self.count} of "
                f"{self.total} samples in a row by amplitude): data {significant(self.data_ends[0])} against law "
                f"{significant(self.model_ends[0])} {k_u} at the small end, {significant(self.data_ends[1])} "
                f"against {significant(self.model_ends[1])} at the large end; mean misfit "
                f"{significant(self.misfit, 2)} {k_u}{evidence}")

    def to_json(self) -> dict:
        return {"element": self.element, "part": self.part, "X_range": list(self.X_range), "count": self.count,
                "total": self.total, "data_ends": list(self.data_ends), "model_ends": list(self.model_ends),
                "misfit": self.misfit, "sigma": self.sigma}


def shortest_telling_run(n: int) -> int:
    """The shortest run of one sign that noise alone makes among ``n`` samples with probability below
    RUN_FALSE_ALARM (``n 2^(1-L) <= RUN_FALSE_ALARM``)."""
    return math.ceil(1 + math.log2(max(n, 1) / RUN_FALSE_ALARM))


def _longest_run(signs: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest run of equal non-zero signs."""
    best, start = (0, 0), 0
    for i in range(1, len(signs) + 1):
        if i == len(signs) or signs[i] != signs[start] or signs[i] == 0:
            if signs[start] != 0 and i - start > best[1]:
                best = (start, i - start)
            start = i
    return best


def systematic_misfits(element: str, X, kbar, model, kbar_std=None,
                       units: tuple[str, str] = ("N/m", "m")) -> list[Misfit]:
    """The runs of same-sign residuals of ``kbar`` against ``model`` (both complex, at the samples ``X``) that
    noise does not explain (module docstring): at most one for Re and one for Im."""
    order = np.argsort(np.asarray(X, float), kind="stable")
    X, kbar, model = (np.asarray(a)[order] for a in (X, kbar, model))
    std = None if kbar_std is None else np.asarray(kbar_std, float)[order]
    n, found = len(X), []
    for part, take in (("Re", np.real), ("Im", np.imag)):
        residual = take(kbar) - take(model)
        start, length = _longest_run(np.sign(residual))
        if length < shortest_telling_run(n):
            continue
        run = slice(start, start + length)
        sigma = None
        if std is not None:
            # each part of a complex sample carries std / sqrt(2), the convention of the fits
            error = math.sqrt(float(np.sum(std[run] ** 2) / 2)) / length
            sigma = abs(float(residual[run].mean())) / error if error > 0 else math.inf
            if sigma <= MISFIT_SIGMA:
                continue
        data, law = take(kbar[run]), take(model[run])
        ends = min(ENDS, length)
        found.append(Misfit(element, part, (float(X[run][0]), float(X[run][-1])), length, n,
                            (float(data[:ends].mean()), float(data[-ends:].mean())),
                            (float(law[:ends].mean()), float(law[-ends:].mean())), float(residual[run].mean()),
                            sigma, units))
    return found
