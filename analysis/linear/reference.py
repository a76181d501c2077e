"""The reference from the random run: modes, how far to trust them, and the structure updated to them.

A random run is a low-level test: friction that sticks at that level holds its DOFs, and the run then sees
another structure (the one with the joint held) with a coherence that drops, because the little slip there is
does not follow the force linearly. This module fits every mode in the run's band (analysis/signals/modal_fit.py),
marks the modes whose coherence is low, says when a mode is the structure with an element held rather than the
structure itself (:func:`stuck_modes`), states the Hann leakage bias of each damping at the run's resolution,
and updates the parameters of the model's ``[updating]`` table to the modes that can be trusted
(docs/workbench.md, section 1).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..common.errors import InputError
from ..common.measurements import RandomRun
from ..mechanics.model import Model
from ..mechanics.structures import Structure
from ..signals.modal_fit import LOW_COHERENCE, LeakageBias, ModalFit, fit_modes, leakage_bias
from .updating import UpdateResult, update_parameters

STUCK_MATCH = 0.03      # a mode within 3 % of a held-structure frequency...
STUCK_CLOSER = 2.0      # ...and at least twice as close to it as to any free mode is the structure held


def held_frequencies(structure: Structure, vectors: list[np.ndarray]) -> np.ndarray:
    """Natural frequencies (Hz, ascending) of the structure with the motion ``e @ x`` of each vector held at
    zero (an element stuck): the eigenproblem on the null space of the constraints."""
    T = scipy.linalg.null_space(np.atleast_2d(np.array(vectors)))
    lam = scipy.linalg.eigvalsh(T.T @ structure.K @ T, T.T @ structure.M @ T)
    return np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi)


@dataclass
class StuckMode:
    """A mode of the random run that is the structure with ``elements`` held, not the structure itself."""

    frequency: float                # Hz, measured
    elements: list[str]
    held_hz: float                  # the model's frequency with those elements held
    free_hz: float                  # the model's nearest free frequency
    coherence: float

    def text(self) -> str:
        return (f"the random run saw the structure STUCK: the mode at {self.frequency:.4f} Hz (coherence "
                f"{self.coherence:.2f}) is the model with {', '.join(self.elements)} held ({self.held_hz:.4f} Hz), "
                f"not its free mode ({self.free_hz:.4f} Hz); friction held there at the random run's level")

    def to_json(self) -> dict:
        return {"frequency": self.frequency, "elements": self.elements, "held_hz": self.held_hz,
                "free_hz": self.free_hz, "coherence": self.coherence}


def stuck_modes(modal: ModalFit, model: Model) -> list[StuckMode]:
    """Modes that match the model with one element (or all of them) held much better than the model's free modes,
    whatever their coherence: a joint that slips now and then leaves its modes' coherence low, but one held for
    the whole run responds as the held structure does, linearly, and its modes are still not the free ones. A run
    without coherence (imported so) is not checked: nothing in it says the joint was excited at a level it holds."""
    if modal.coherence is None or not model.elements:
        return []
    free = model.structure.natural_frequencies()
    s = model.structure
    holds = [[el] for el in model.elements] + ([list(model.elements)] if len(model.elements) > 1 else [])
    held = [(group, held_frequencies(s, [el.vector(s) for el in group])) for group in holds]
    held = [(group, freqs) for group, freqs in held if len(freqs)]          # holding all may leave nothing
    out = []
    for f, coh in zip(modal.frequency, modal.coherence):
        d_free = np.abs(f / free - 1)
        best = None
        for group, freqs in held:
            d = np.abs(f / freqs - 1)
            j = int(d.argmin())
            if d[j] < STUCK_MATCH and STUCK_CLOSER * d[j] < d_free.min() and (best is None or d[j] < best[0]):
                best = (d[j], group, freqs[j])
        if best is not None:
            out.append(StuckMode(float(f), [el.name for el in best[1]], float(best[2]),
                                 float(free[int(d_free.argmin())]), float(coh)))
    return out


@dataclass
class ReferenceReport:
    """Modal fit of the random run, what to trust of it, and (optionally) the updating of the structure.

    ``leakage`` holds, per mode, the Hann leakage bias of its damping at the run's resolution (empty when the
    run's resolution is not known; None for a mode not trusted); ``trusted`` marks the modes the updating may use (coherence not low, not a
    held structure); ``notes`` say why the reference was not updated where it was not."""

    modal: ModalFit | None
    update: UpdateResult | None
    leakage: list[LeakageBias | None] = field(default_factory=list)
    stuck: list[StuckMode] = field(default_factory=list)
    trusted: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    def _trusted(self) -> np.ndarray:
        return np.ones(len(self.modal.frequency), bool) if self.trusted is None else self.trusted

    def warnings(self) -> list[str]:
        """Low coherence and stuck structure, one sentence each."""
        if self.modal is None:
            return []
        out = []
        if self.modal.coherence is not None:
            low = self.modal.low_coherence
            if low.any():
                out.append(f"LOW COHERENCE (below {LOW_COHERENCE:g} x what leakage alone leaves) at {low.sum()} mode(s), not "
                           "trusted: " + ", ".join(
                    f"{f:.4g} Hz ({c:.2f})" for f, c in zip(self.modal.frequency[low], self.modal.coherence[low])))
        return out + [m.text() for m in self.stuck]

    def text(self) -> str:
        lines = []
        if self.modal is not None:
            lines.append("modes from the random run (modal fit):")
            trusted = self._trusted()
            for n, i in enumerate(np.flatnonzero(trusted)):
                f, z = self.modal.frequency[i], self.modal.damping[i]
                line = f"  mode {n + 1}: {f:10.4f} Hz, damping {100 * z:.3f} %"
                if self.modal.coherence is not None:
                    line += f", coherence {self.modal.coherence[i]:.2f}"
                if self.leakage and self.leakage[i] is not None:
                    line += _leakage_text(self.leakage[i])
                lines.append(line)
            if not trusted.any():
                lines.append("  none to trust" if len(self.modal.frequency) else
                             "  none: no peak of the random run fits as a mode")
            if self.modal.rejected:
                lines.append(f"  {len(self.modal.rejected)} peak(s) not modes (pole on a bound of its search or "
                             "outside its band): " + ", ".join(f"{r.frequency:.4g}" for r in self.modal.rejected)
                             + " Hz")
            lines += ["  " + w for w in self.warnings()]
        lines += ["  " + n for n in self.notes]
        if self.update is not None:
            lines.append("reference model updated to the measured frequencies:")
            lines += ["  " + line for line in self.update.table_text().splitlines()]
        return "\n".join(lines)

    def to_json(self) -> dict:
        out: dict = {}
        if self.modal is not None:
            m = self.modal
            out["modes"] = []
            for i, (f, z) in enumerate(zip(m.frequency, m.damping)):
                entry = {"frequency": float(f), "damping": float(z),
                         "trusted": bool(self.trusted[i]) if self.trusted is not None else True}
                if m.coherence is not None:
                    entry["coherence"] = float(m.coherence[i])
                    entry["low_coherence"] = bool(m.low_coherence[i])
                if self.leakage and self.leakage[i] is not None:
                    b = self.leakage[i]
                    entry["leakage"] = {"resolution": b.resolution, "damping_bias": _finite(b.bias),
                                        "damping_corrected": _finite(b.corrected)}
                out["modes"].append(entry)
            out["rejected_peaks"] = [{"frequency": r.frequency, "reason": r.reason} for r in m.rejected]
            out["stuck"] = [s.to_json() for s in self.stuck]
            out["warnings"] = self.warnings()
        out["notes"] = list(self.notes)
        if self.update is not None:
            u = self.update
            out["updating"] = {"parameters": {p: {"before": float(b), "after": float(a)}
                                              for p, b, a in zip(u.parameters, u.before, u.after)},
                               "modes": u.modes, "measured_hz": u.measured_hz.tolist(),
                               "before_hz": u.before_hz.tolist(), "after_hz": u.after_hz.tolist()}
        return out


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _leakage_text(b: LeakageBias) -> str:
    if not np.isfinite(b.corrected):
        return (f" (narrower than the {b.resolution:.4g} Hz resolution can tell: the damping is an upper bound)")
    if abs(b.bias) < 0.005:
        return ""
    return f" (Hann leakage at {b.resolution:.4g} Hz: {100 * b.bias:+.0f} %, about {100 * b.corrected:.3f} % without)"


def reference_from_random(model: Model, run: RandomRun | None) -> ReferenceReport:
    """Fit every mode of the random run, judge them, and update the model's ``[updating]`` parameters to the
    trusted ones (``report.update``; the model itself is not changed)."""
    if run is None:
        return ReferenceReport(None, None)
    try:
        modal = fit_modes(run.frequency_hz, run.receptance, coherence=run.coherence, random_error=run.random_error,
                          resolution=run.resolution)
    except ValueError as exc:
        notes = [f"no modal fit of the random run: {exc}"]
        if run.coherence is not None and run.coherence.max() < LOW_COHERENCE:
            notes.append(f"LOW COHERENCE: at most {run.coherence.max():.2f} over the band: the structure did not "
                         "respond linearly to the random force (friction holding it at this level?)")
        return ReferenceReport(None, None, notes=notes)
    stuck = stuck_modes(modal, model)
    trusted = ~modal.low_coherence & ~np.isin(modal.frequency, [s.frequency for s in stuck])
    leakage = [] if run.resolution is None else [leakage_bias(f, z, run.resolution) if ok else None
                                                 for f, z, ok in zip(modal.frequency, modal.damping, trusted)]
    report = ReferenceReport(modal, None, leakage, stuck, trusted)
    if model.updating_modes and len(modal.frequency) < len(model.updating_modes):
        # the modes named are more than the measurement shows at all (not merely untrusted ones, which leave
        # the reference as given, with a note): a model written for another band or another structure
        raise InputError(f"{len(model.updating_modes)} modes to match, but the random run shows "
                         f"{len(modal.frequency)} (at {', '.join(f'{f:.4g}' for f in modal.frequency)} Hz over "
                         f"{run.frequency_hz.min():.4g}-{run.frequency_hz.max():.4g} Hz); name at most "
                         f"{len(modal.frequency)}", model.source, "[updating].modes")
    if model.updating_parameters:
        report.update = _update(model, modal.frequency[trusted], report.notes)
    return report


def _update(model: Model, measured: np.ndarray, notes: list[str]) -> UpdateResult | None:
    """The ``[updating]`` parameters updated to the lowest trusted modes, or None with a note saying why not."""
    modes = model.updating_modes or list(range(1, len(model.updating_parameters) + 1))
    if len(measured) < len(modes):
        notes.append(f"reference NOT updated: the random run shows {len(measured)} trusted mode(s) but "
                     f"{len(modes)} are to be matched ([updating] in {model.source or 'the model'}); the "
                     "structure is used as given")
        return None
    return update_parameters(model.structure_table, model.updating_parameters, measured[: len(modes)], modes,
                             model.source)
