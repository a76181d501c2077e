"""Measured data as the analysis sees it: arrays with their meaning, no files.

The application reads sessions into these containers (app/session_data.py); tests and scripts can build them
from any source. Receptances are ``X/F`` in m/N (rad/N on rotations) in the phasor convention of
docs/contracts.md §1.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

CONTROL_MODES = ("force", "response", "open_loop")
# what a level holds -> its SI unit (docs/session-format.md, run attributes control_*)
CONTROL_UNITS = {"force": "N", "displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}
# ...and the unit token of a response-controlled run's name (sine_<dof>_<target><token>_<direction>)
NAME_UNITS = {"displacement": "m", "velocity": "mps", "acceleration": "mps2"}


@dataclass(frozen=True)
class Control:
    """How a stepped-sine level was held (docs/session-format.md, run attributes ``control*``).

    ``mode`` is "force" (the force amplitude held at ``target`` N), "response" (the amplitude of ``quantity`` at
    ``dof`` held at ``target`` in SI units, the force left to vary) or "open_loop" (the drive held, ``target`` the
    nominal force)."""

    mode: str = "force"
    dof: str = ""
    quantity: str = "force"
    target: float = 0.0

    @property
    def units(self) -> str:
        return CONTROL_UNITS[self.quantity]

    @property
    def response(self) -> bool:
        return self.mode == "response"

    def label(self) -> str:
        """How a test engineer names the level: ``0.8 N`` or ``20 m/s^2 at x1``."""
        if self.mode == "response":
            return f"{self.target:g} {self.units} at {self.dof}"
        return f"{self.target:g} N" + (" (open loop)" if self.mode == "open_loop" else "")

    def key(self) -> tuple:
        """Runs of one level (both sweep directions) share this key."""
        return (self.mode, self.dof if self.mode == "response" else "", self.quantity, round(self.target, 12))

    def order(self) -> tuple:
        """Where the level stands in every list of levels: force-controlled levels first by force, then the
        others by their control DOF, quantity and target (the order ``--fit-levels`` numbers them in)."""
        return (self.mode != "force", self.key())

    def to_json(self) -> dict:
        return {"control": self.mode, "control_dof": self.dof, "control_quantity": self.quantity,
                "control_target": self.target, "control_units": self.units, "label": self.label()}


def response_amplitude(acceleration: np.ndarray, w: np.ndarray, quantity: str) -> np.ndarray:
    """The amplitude of ``quantity`` from the fundamental of an acceleration (harmonic motion: a velocity is
    the acceleration over w, a displacement over w^2)."""
    power = {"acceleration": 0, "velocity": 1, "displacement": 2}[quantity]
    return np.abs(acceleration) / np.asarray(w, float) ** power


@dataclass
class SineRun:
    """One stepped-sine run at one force level and sweep direction.

    Attributes
    ----------
    name : str
    force : float
        Force amplitude of the level, N: the one held, or for a response-controlled level the median of the
        measured force per line.
    direction : str
        "up" or "down".
    excitation_dof : str
    sensor_dofs : list of str
    frequency_hz : ndarray, shape (L,)
        In the order measured.
    receptance : ndarray, shape (L, P), complex
        Fundamental receptance per sensor, m/N.
    receptance_std : ndarray, shape (L, P), optional
        Its standard deviation ``sqrt(E|n|^2)``, m/N.
    force_achieved : ndarray, shape (L,), optional
        Force amplitude measured at each line, N: every amplitude is computed with it (identification, fit,
        prediction, error).
    distortion : ndarray, shape (L,), optional
        Largest total harmonic distortion of the measured displacements at each line: a describing function
        describes a harmonic motion, so lines far from harmonic (stick-slip with stops, impacts) are left out
        of the identification. None when the harmonics were not measured (imported FRFs).
    noise_estimated : bool
        ``receptance_std`` was not measured but estimated from the FRFs themselves (:mod:`analysis.signals.frf_noise`).
    control : Control, optional
        How the level was held; default force control at ``force``.
    """

    name: str
    force: float
    direction: str
    excitation_dof: str
    sensor_dofs: list[str]
    frequency_hz: np.ndarray
    receptance: np.ndarray
    receptance_std: np.ndarray | None = None
    force_achieved: np.ndarray | None = None
    distortion: np.ndarray | None = None
    noise_estimated: bool = False
    control: Control | None = None

    def __post_init__(self):
        if self.control is None:
            self.control = Control("force", self.excitation_dof, "force", float(self.force))

    @property
    def w(self) -> np.ndarray:
        return 2 * np.pi * np.asarray(self.frequency_hz, float)

    @property
    def force_per_line(self) -> np.ndarray:
        if self.force_achieved is not None:
            return np.asarray(self.force_achieved, float)
        return np.full(len(self.frequency_hz), float(self.force))


@dataclass
class RandomRun:
    """The low-level random run: H1 per sensor with coherence and random error."""

    excitation_dof: str
    sensor_dofs: list[str]
    frequency_hz: np.ndarray
    receptance: np.ndarray                 # (L, P) H1, m/N
    coherence: np.ndarray | None = None    # (L, P)
    random_error: np.ndarray | None = None  # (L, P) normalised random error of |H1|
    force_rms: float = 0.0
    resolution: float | None = None        # Hz, of the Hann-windowed Welch estimate (None: not known)


@dataclass
class RunNote:
    """A run that did not finish as planned, whose lines are used all the same (each line was measured whole).

    Attributes
    ----------
    run : str
    status : str
        "running" (still being measured) or "aborted".
    incomplete : bool
        The process writing the run stopped without closing it (crash, kill, power cut).
    lines : int
        Lines used.
    reason : str
        Why the run ended, as recorded (may be empty).
    """

    run: str
    status: str
    incomplete: bool
    lines: int
    reason: str = ""

    def text(self) -> str:
        if self.incomplete:
            what = "is incomplete: the process writing it stopped during the run (crash or kill)"
        elif self.status == "running":
            what = "is still being measured"
        elif self.status == "failed":
            what = ("failed" + (f" ({self.reason})" if self.reason else "")
                    + " -- it ran to its end, but its data missed the plan")
        else:
            what = "was aborted" + (f" ({self.reason})" if self.reason else "")
        return f"run {self.run} {what}; its {self.lines} line{'s' * (self.lines != 1)} measured before are used"

    def to_json(self) -> dict:
        return {"run": self.run, "status": self.status, "incomplete": self.incomplete, "lines": self.lines,
                "reason": self.reason, "note": self.text()}


@dataclass
class PhaseRun:
    """A phase-resonance run: at each force level the point its lock ended at -- frequency (Hz), force amplitude
    (N), the fundamental displacement amplitude at ``dof`` (m), the lag it locked to (deg) and whether the lock
    converged; the force is applied at ``excitation_dof`` and ``lag`` is the measured lag of each point (deg;
    None: taken as ``target_phase``)."""

    name: str
    dof: str
    target_phase: float
    frequency_hz: np.ndarray
    force: np.ndarray
    amplitude: np.ndarray
    converged: np.ndarray
    excitation_dof: str = ""
    lag: np.ndarray | None = None
    # the locked points as lines, each at its own force: the element's kbar is identified at them as at any
    # line (they reach amplitudes no response level may), but they are no sweep and are not predicted as one
    lines: SineRun | None = None


@dataclass(frozen=True)
class UnresolvedLines:
    """Lines of a run left out of the analysis because a sensor saw nothing there: its fundamental was below one
    count of the DAQ (a DOF held by friction at a low level), stored as NaN."""

    run: str
    left_out: int
    lines: int

    def text(self) -> str:
        return (f"run {self.run}: {self.left_out} of {self.lines} line(s) left out: a sensor saw nothing there "
                "(below one count of the DAQ; its FRF is stored as NaN)")

    def to_json(self) -> dict:
        return {"run": self.run, "left_out": self.left_out, "lines": self.lines}


@dataclass
class Measurements:
    """Everything measured in a session, ready for the workbench; ``unfinished`` lists the runs that did not
    finish as planned; ``phase`` the phase-resonance runs (not sweeps: not identified from)."""

    sine: list[SineRun] = field(default_factory=list)
    random: RandomRun | None = None
    unfinished: list[RunNote] = field(default_factory=list)
    phase: list[PhaseRun] = field(default_factory=list)
    unresolved: list[UnresolvedLines] = field(default_factory=list)

    @property
    def levels(self) -> list[float]:
        return sorted({round(r.force, 12) for r in self.sine})

    def level_controls(self) -> list[Control]:
        """One Control per stepped-sine level (both sweep directions share it), in :meth:`Control.order`."""
        return sorted({r.control.key(): r.control for r in self.sine}.values(), key=Control.order)

    def at_levels(self, keys: set[tuple]) -> "Measurements":
        """The measurements a fit restricted to some levels sees: the stepped-sine runs of the levels whose
        :meth:`Control.key` is in ``keys``, and the random run (the linear reference, not a level). The
        phase-resonance runs are left out: their points span the same amplitudes, and a level held out must not
        be seen through them."""
        sine = [r for r in self.sine if r.control.key() in keys]
        names = {r.name for r in sine}
        return replace(self, sine=sine, phase=[], unfinished=[n for n in self.unfinished if n.run in names],
                       unresolved=[n for n in self.unresolved if n.run in names])

    def dofs(self) -> set[str]:
        out = set()
        for r in self.sine:
            out |= {r.excitation_dof, *r.sensor_dofs}
        if self.random is not None:
            out |= {self.random.excitation_dof, *self.random.sensor_dofs}
        return out
