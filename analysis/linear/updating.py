"""Updating uncertain structure parameters to measured natural frequencies (the paper's section 4.2).

The parameters the user marks as uncertain are paths into the ``[structure]`` table, e.g. ``"youngs_modulus"``,
``"springs[1].k"``, ``"masses[0].m"`` or ``"stiffness[0][1]"``. Each is updated on a log scale (it stays
positive) by Gauss-Newton / Levenberg-Marquardt on the relative frequency errors
``(f_model,i - f_measured,i) / f_measured,i`` of the chosen modes. The sensitivities are eigenvalue
derivatives ``d lambda / d p = phi^T (dK/dp - lambda dM/dp) phi`` for mass-normalised modes, with dK/dp and
dM/dp from the assembled matrices (exact for parameters that enter the matrices linearly, such as springs,
masses and E).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from ..common.errors import InputError
from ..mechanics.structures import Structure, load_structure, split_parameter_path, structure_parameter

# the paths into ``[structure]`` are read where the model is (analysis/mechanics/structures.py), and checked then


def set_parameter(table: dict, path: str, value: float) -> dict:
    """A deep copy of ``table`` with the number at ``path`` replaced."""
    out = copy.deepcopy(table)
    parts = split_parameter_path(path)
    node = out
    for part in parts[:-1]:
        node = node[part]
    node[parts[-1]] = float(value)
    return out


@dataclass
class UpdateResult:
    """Outcome of updating.

    Attributes
    ----------
    structure : Structure
        The updated structure.
    table : dict
        The updated ``[structure]`` table (write it back into a model file).
    parameters : list of str
    before, after : ndarray, shape (k,)
        Parameter values.
    measured_hz, before_hz, after_hz : ndarray, shape (m,)
        Measured and model natural frequencies of the matched modes, Hz.
    modes : list of int
        1-based model mode numbers matched to the measured frequencies.
    sensitivity : ndarray, shape (m, k)
        Normalised sensitivities ``(p / f) df/dp`` at the start values: how many percent the frequency moves
        for one percent of the parameter.
    """

    structure: Structure
    table: dict
    parameters: list[str]
    before: np.ndarray
    after: np.ndarray
    measured_hz: np.ndarray
    before_hz: np.ndarray
    after_hz: np.ndarray
    modes: list[int]
    sensitivity: np.ndarray

    def table_text(self) -> str:
        """The before/after frequency table, as printed by the CLI."""
        lines = ["mode   measured Hz   before Hz  error %    after Hz  error %"]
        for i, m in enumerate(self.modes):
            eb = 100 * (self.before_hz[i] / self.measured_hz[i] - 1)
            ea = 100 * (self.after_hz[i] / self.measured_hz[i] - 1)
            lines.append(f"{m:4d} {self.measured_hz[i]:13.4f} {self.before_hz[i]:11.4f} {eb:8.3f} "
                         f"{self.after_hz[i]:11.4f} {ea:8.3f}")
        for name, b, a in zip(self.parameters, self.before, self.after):
            lines.append(f"{name}: {b:.6g} -> {a:.6g}")
        return "\n".join(lines + self.worse_notes())

    def worse_notes(self) -> list[str]:
        """A line for each matched mode the update moved away from its measured frequency: the least-squares
        fit of the relative errors trades it against the others, and the reader must not take it for a match."""
        eb = 100 * (self.before_hz / self.measured_hz - 1)
        ea = 100 * (self.after_hz / self.measured_hz - 1)
        notes = []
        for i, m in enumerate(self.modes):
            if abs(ea[i]) <= abs(eb[i]):
                continue
            others = ", ".join(f"mode {n}: {eb[j]:.3f} % -> {ea[j]:.3f} %" for j, n in enumerate(self.modes) if j != i)
            notes.append(f"note: the update moved mode {m} away from its measured frequency (error {eb[i]:.3f} % -> "
                         f"{ea[i]:.3f} %): fitting {', '.join(self.parameters)} to the relative errors of all matched "
                         f"modes by least squares traded it against the others"
                         + (f" ({others})" if others else "")
                         + "; the reference cannot match them all")
        return notes


def frequency_sensitivity(structure_of, values: np.ndarray, modes: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Model frequencies (Hz) of ``modes`` and their log-sensitivities ``d ln f / d ln p`` (m, k).

    ``structure_of(values)`` builds the structure; dK/dp and dM/dp come from central differences of the
    assembled matrices, the eigenvalue derivative from the modes of the base structure.
    """
    base = structure_of(values)
    freqs, phi = base.modes()
    idx = np.array(modes) - 1
    lam = (2 * np.pi * freqs[idx]) ** 2
    sens = np.empty((len(modes), len(values)))
    for j, p in enumerate(values):
        h = 1e-6 * p
        up, dn = values.copy(), values.copy()
        up[j] += h
        dn[j] -= h
        s_up, s_dn = structure_of(up), structure_of(dn)
        dK, dM = (s_up.K - s_dn.K) / (2 * h), (s_up.M - s_dn.M) / (2 * h)
        dlam = np.einsum("im,ij,jm->m", phi[:, idx], dK, phi[:, idx]) - lam * np.einsum(
            "im,ij,jm->m", phi[:, idx], dM, phi[:, idx])
        sens[:, j] = 0.5 * dlam / lam * p          # d ln f = d ln lambda / 2
    return freqs[idx], sens


def update_parameters(table: dict, parameters: list[str], measured_hz, modes: list[int] | None = None,
                      source: str | None = None, bounds_factor: float = 100.0) -> UpdateResult:
    """Update ``parameters`` of the structure table so its natural frequencies match ``measured_hz``.

    Parameters
    ----------
    table : dict
        The ``[structure]`` table.
    parameters : list of str
        Paths of the uncertain parameters (see module docstring).
    measured_hz : array_like, shape (m,)
        Measured natural frequencies, Hz, matched in order to ``modes``.
    modes : list of int, optional
        1-based model modes to match (default 1..m).
    bounds_factor : float
        Each parameter may move by at most this factor up or down.
    """
    measured = np.atleast_1d(np.asarray(measured_hz, float))
    modes = list(range(1, len(measured) + 1)) if modes is None else list(modes)
    if len(modes) != len(measured):
        raise InputError(f"{len(measured)} measured frequencies but {len(modes)} modes to match", source,
                         "[updating].modes")
    if not parameters:
        raise InputError("name at least one parameter to update", source, "[updating].parameters")
    if len(parameters) > len(measured):
        raise InputError(f"{len(parameters)} parameters cannot be found from {len(measured)} frequencies",
                         source, "[updating].parameters")
    start = np.array([structure_parameter(table, p, source) for p in parameters])

    def structure_of(values):
        t = table
        for path, v in zip(parameters, values):
            t = set_parameter(t, path, v)
        return load_structure(t, source)

    n_modes = structure_of(start).n
    if max(modes) > n_modes:
        raise InputError(f"the model has only {n_modes} modes", source, "[updating].modes")
    f0, sens0 = frequency_sensitivity(structure_of, start, modes)

    def residual(logp):
        f, _ = frequency_sensitivity(structure_of, np.exp(logp), modes)
        return f / measured - 1.0

    def jacobian(logp):
        f, s = frequency_sensitivity(structure_of, np.exp(logp), modes)
        return (f / measured)[:, None] * s

    lo, hi = np.log(start / bounds_factor), np.log(start * bounds_factor)
    sol = scipy.optimize.least_squares(residual, np.log(start), jac=jacobian, bounds=(lo, hi),
                                       xtol=1e-12, ftol=1e-14, gtol=1e-14)
    after = np.exp(sol.x)
    updated = table
    for path, v in zip(parameters, after):
        updated = set_parameter(updated, path, v)
    s_after = load_structure(updated, source)
    return UpdateResult(s_after, updated, list(parameters), start, after, measured, f0,
                        s_after.natural_frequencies()[np.array(modes) - 1], modes, sens0)
