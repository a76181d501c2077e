"""What a session must hold before its measurements are used (docs/session-format.md, "Checks on reading").

A file can be a well-formed HDF5 session and still hold impossible contents: a format version this program
does not know, real numbers where receptances are complex, datasets of different lengths, negative or
non-finite frequencies. Each is refused with one line naming the file, the run and the dataset or attribute;
nothing is repaired or guessed.

A run still being written, or one whose writer died (``incomplete``), may end with a line that reached some of
its datasets but not all: only the lines present in every per-line dataset are used. A run that ended
("complete", "failed" -- measured to its end but missing the plan -- or "aborted" by the campaign) must have the same number of lines in every per-line dataset.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from analysis.common.errors import InputError
from analysis.common.measurements import CONTROL_MODES, CONTROL_UNITS, Control, RunNote
from analysis.common.quantities import (FREQUENCY_RANGE, control_dof_problem, dof_name_problem, force_problem,
                                       forces_outside, frequency_problem, phase_problem, phases_outside,
                                       response_target_problem, coherence_problem, coherences_outside)

from app.session.writer import FORMAT_VERSION, RunData

KINDS = ("random", "stepped_sine", "phase_resonance")
STATUSES = ("running", "complete", "failed", "aborted")
DIRECTIONS = {"stepped_sine": ("up", "down"), "random": ("none",), "phase_resonance": ("up",)}
PER_HARMONIC = "harmonics/"
MAX_RUNS = 500          # runs a session may hold for the analysis and export (plans: at most 200 force levels)
MIN_FREQUENCY, MAX_FREQUENCY = FREQUENCY_RANGE    # Hz: a line beyond is a damaged dataset, not a vibration


def check_run_count(names: list[str], source: str | None) -> None:
    """Refuse a session of more than MAX_RUNS runs before reading them (their analysis would take hours)."""
    if len(names) > MAX_RUNS:
        raise InputError(f"holds {len(names)} runs; contactid reads sessions of at most {MAX_RUNS} runs "
                         "(docs/session-format.md, limits)", source, "/runs")


def check_format(attrs: dict, source: str | None) -> None:
    """Refuse a session whose ``format_version`` is missing or not one this program reads."""
    version = attrs.get("format_version")
    if isinstance(version, np.integer):
        version = int(version)
    if not isinstance(version, int) or isinstance(version, bool):
        raise InputError(f"must be a whole number, got {version!r}", source, "root attribute format_version")
    if version != FORMAT_VERSION:
        raise InputError(f"format version {version} is not one this contactid reads (it reads {FORMAT_VERSION}); "
                         "a newer contactid wrote it", source, "root attribute format_version")


@dataclass
class CheckedRun:
    """A run whose contents passed the checks, how many of its lines are whole, and how it was controlled."""

    run: RunData
    lines: int
    sensor_dofs: list[str]
    control: Control
    # per whole line: some sensor saw nothing there (FRF and standard deviation NaN, as a campaign stores a
    # fundamental below one count of the DAQ): the line holds no FRF to analyse
    unresolved: np.ndarray | None = None

    @property
    def unfinished(self) -> bool:
        return self.run.status != "complete" or self.run.incomplete

    def note(self) -> RunNote:
        return RunNote(self.run.name, self.run.status, self.run.incomplete, self.lines,
                       str(self.run.attrs.get("end_reason", "")))


def check_run(run: RunData, source: str | None) -> CheckedRun:
    """Check one run's attributes and per-line datasets; InputError naming file, run and dataset/attribute."""
    def error(what: str, message: str) -> InputError:
        return InputError(message, source, f"run {run.name}, {what}")

    attrs = run.attrs
    kind = _choice(attrs, "kind", KINDS, error)
    status = _choice(attrs, "status", STATUSES, error)
    _choice(attrs, "direction", DIRECTIONS[kind], error)
    force = attrs.get("force")
    if not _positive_number(force):
        shown = force.item() if isinstance(force, np.generic) else force        # nan, not np.float64(nan)
        raise error("attribute force", f"must be a finite force > 0 N, got {shown!r}")
    if force_problem(force):
        raise error("attribute force", force_problem(force))
    excitation = attrs.get("excitation_dof")
    if not isinstance(excitation, str) or not excitation:
        raise error("attribute excitation_dof", f"must name a DOF, got {excitation!r}")
    if dof_name_problem(excitation):
        raise error("attribute excitation_dof", dof_name_problem(excitation))
    sensors = _sensor_dofs(attrs.get("sensor_dofs"), error)
    control = check_control(attrs, excitation, float(force), error)
    if control_dof_problem(control.mode, control.dof, sensors, excitation):    # (analysis/common/quantities.py)
        raise error("attribute control_dof", control_dof_problem(control.mode, control.dof, sensors, excitation))

    frequency = np.asarray(run.frequency)
    if frequency.ndim != 1 or frequency.dtype.kind not in "fi":
        raise error("dataset frequency", f"must be a list of real frequencies in Hz, got {frequency.dtype} "
                                         f"of shape {frequency.shape}")
    for d in sensors:
        if d not in run.frf:
            raise error(f"dataset frf/{d}", "is missing (attribute sensor_dofs names this DOF)")
        if not np.iscomplexobj(run.frf[d]):
            raise error(f"dataset frf/{d}", f"holds real numbers ({run.frf[d].dtype}); receptances are complex")
        if np.ndim(run.frf[d]) != 1:
            raise error(f"dataset frf/{d}", f"has shape {np.shape(run.frf[d])}; an FRF holds one value a line")
    for name, values in run.arrays.items():
        per_line = 2 if name.startswith(PER_HARMONIC) else 1     # a row of harmonics a line, else one value
        if np.ndim(values) != per_line:
            raise error(f"dataset {name}", f"has shape {np.shape(values)}; it holds "
                                           f"{'a row of harmonics' if per_line == 2 else 'one value'} a line")
    lines = _whole_lines(run, sensors, status == "running" or run.incomplete, error)
    bad = np.flatnonzero(~np.isfinite(frequency[:lines]) | (frequency[:lines] < MIN_FREQUENCY)
                         | (frequency[:lines] > MAX_FREQUENCY))
    if len(bad):
        raise error("dataset frequency", f"line {bad[0]} is {frequency_problem(float(frequency[bad[0]]))}")
    _check_order(frequency[:lines], kind, run.attrs.get("direction"), error)
    saw_nothing = {d: _saw_nothing(run, d, lines) for d in sensors}
    for d in sensors:
        bad = np.flatnonzero(~np.isfinite(run.frf[d][:lines]) & ~saw_nothing[d])
        if len(bad):
            raise error(f"dataset frf/{d}", f"line {bad[0]} is {complex(run.frf[d][bad[0]])}; FRFs must be finite")
    for name, values in sorted(run.arrays.items()):
        rule = _line_rule(name)
        if rule is not None:
            excused = saw_nothing.get(name.split("/", 1)[1]) if name.startswith("frf_std/") else None
            _check_lines(np.asarray(values)[:lines], rule, lambda message, name=name: error(f"dataset {name}",
                                                                                            message), excused)
    if kind == "phase_resonance" and lines:      # (a run just begun holds no point yet)
        _check_lock(run, sensors, error)
    unresolved = np.any([saw_nothing[d] for d in sensors], axis=0) if sensors and lines else None
    return CheckedRun(run, lines, sensors, control, unresolved if unresolved is not None and unresolved.any()
                      else None)


def refuse_saw_nothing(checked: CheckedRun, source: str | None, form: str) -> None:
    """InputError naming the first line where a sensor saw nothing (:attr:`CheckedRun.unresolved`), for an
    export to ``form``: no interchange format has a cell its import reads as "saw nothing" (a NaN FRF is refused
    there as no number), so every export refuses such a run in these words rather than write what its own
    import refuses (docs/session-format.md, "Quantities")."""
    if checked.unresolved is None:
        return
    line = int(np.flatnonzero(checked.unresolved)[0])
    dof = next(d for d in checked.sensor_dofs if np.isnan(complex(checked.run.frf[d][line])))
    raise InputError(f"line {line}: the sensor at {dof} saw nothing there (its FRF and standard deviation are NaN, "
                     f"{int(checked.unresolved.sum())} line(s) of the run): {form} has no value its import reads as "
                     "such; nothing exported (the analysis reads the session as it is)", source,
                     f"run {checked.run.name}, dataset frf/{dof}")


def _saw_nothing(run: RunData, dof: str, lines: int) -> np.ndarray:
    """The lines where the sensor at ``dof`` saw nothing: its FRF and its standard deviation both NaN, the mark a
    campaign stores for a fundamental below one count of the DAQ (docs/campaigns.md). A NaN FRF with a finite
    standard deviation, or without one, is no such mark and stays refused."""
    std = run.arrays.get(f"frf_std/{dof}")
    if std is None or np.asarray(std).dtype.kind != "f":
        return np.zeros(lines, bool)
    return np.isnan(np.asarray(run.frf[dof])[:lines]) & np.isnan(np.asarray(std, float)[:lines])


def _check_lock(run: RunData, sensors: list[str], error) -> None:
    """What a phase-resonance run's points are read by: the locked DOF among the sensors, its target phase, its
    acceleration harmonics and the lock's convergence per point."""
    dof, phase = run.attrs.get("phase_dof"), run.attrs.get("target_phase")
    if dof not in sensors:
        raise error("attribute phase_dof", f"must name one of the sensor DOFs {sensors}, got {dof!r}")
    if isinstance(phase, bool) or not isinstance(phase, (int, float, np.number)) or not 0 < phase < 180:
        raise error("attribute target_phase", f"must be a lag from 0 to 180 degrees, got {phase!r}")
    for name in (f"harmonics/acc:{dof}", "lock_converged"):
        if name not in run.arrays:
            raise error(f"dataset {name}", "is missing (a phase-resonance run reads its points from it)")


def check_control(attrs: dict, excitation_dof: str, force: float, error) -> Control:
    """A run's control from its ``control*`` attributes (docs/session-format.md); force control at the run's
    force where they are absent (sessions written before they were recorded)."""
    mode = attrs.get("control", "force")
    if mode not in CONTROL_MODES:
        raise error("attribute control", f"must be one of {', '.join(CONTROL_MODES)}, got {mode!r}")
    dof = attrs.get("control_dof", excitation_dof)
    if not isinstance(dof, str) or not dof:
        raise error("attribute control_dof", f"must name a DOF, got {dof!r}")
    if dof_name_problem(dof):
        raise error("attribute control_dof", dof_name_problem(dof))
    if mode != "response":
        return Control(mode, dof, "force", force)
    quantity, target = attrs.get("control_quantity"), attrs.get("control_target")
    if quantity not in CONTROL_UNITS or quantity == "force":
        raise error("attribute control_quantity", "must be displacement, velocity or acceleration for a "
                                                  f"response-controlled run, got {quantity!r}")
    if not _positive_number(target):
        shown = target.item() if isinstance(target, np.generic) else target      # -5.0, not np.float64(-5.0)
        raise error("attribute control_target", f"must be a finite amplitude > 0, got {shown!r}")
    if response_target_problem(quantity, float(target)):      # the range of every door (quantities.py)
        raise error("attribute control_target", response_target_problem(quantity, float(target)))
    return Control("response", dof, quantity, float(target))


def _positive_number(value) -> bool:
    """A finite number > 0 (an attribute read back from HDF5: a numpy scalar, never a bool)."""
    return not isinstance(value, bool) and isinstance(value, (int, float, np.number)) and math.isfinite(value) \
        and value > 0


def _check_order(frequency: np.ndarray, kind: str, direction: str, error) -> None:
    """A sweep measures its lines one after the other in its direction, a random run's lines rise: each
    frequency strictly beyond the one before. Equal or reversed frequencies are a frequency dataset that does
    not belong to the run's FRFs. A phase-resonance run's points follow its mode, not a sweep: any order."""
    if kind == "phase_resonance":
        return
    sign = -1.0 if kind == "stepped_sine" and direction == "down" else 1.0
    wrong = np.flatnonzero(sign * np.diff(frequency) <= 0)
    if len(wrong):
        i = int(wrong[0])
        order = "falling" if sign < 0 else "rising"
        raise error("dataset frequency", f"line {i + 1} is {float(frequency[i + 1]):g} Hz after "
                                         f"{float(frequency[i]):g} Hz; this run's lines must be strictly {order} "
                                         "(its frequencies do not match its FRFs)")


@dataclass(frozen=True)
class LineRule:
    """What every line of a per-line quantity the analysis uses must be: finite, and above (or at) a bound."""

    quantity: str
    above: float
    inclusive: bool
    force: bool = False             # a force amplitude: also within FORCE_RANGE (analysis/common/quantities.py)
    phase: bool = False             # a phase: within +-MAX_PHASE, and any sign (analysis/common/quantities.py)
    coherence: bool = False         # a coherence: also within COHERENCE_RANGE (analysis/common/quantities.py)

    def wrong(self, values: np.ndarray) -> np.ndarray:
        if self.phase:
            return ~np.isfinite(values)
        low = values < self.above if self.inclusive else values <= self.above
        return ~np.isfinite(values) | low

    def text(self) -> str:
        if self.phase:
            return f"{self.quantity} must be finite"
        return f"{self.quantity} must be finite and {'>=' if self.inclusive else '>'} {self.above:g}"


# the per-line quantities the analysis reads besides the FRFs (app/session_data.py)
LINE_RULES = {"force_amplitude": LineRule("a force amplitude", 0.0, False, force=True),
              "frf_std": LineRule("a standard deviation", 0.0, True),
              "distortion": LineRule("a distortion", 0.0, True),
              "force_phase": LineRule("a force phase", 0.0, True, phase=True),
              "coherence": LineRule("a coherence", 0.0, True, coherence=True)}


def _line_rule(name: str) -> LineRule | None:
    return LINE_RULES.get(name.split("/")[0])


def _check_lines(values: np.ndarray, rule: LineRule, error, excused: np.ndarray | None = None) -> None:
    if values.dtype.kind not in "fiu":
        raise error(f"holds {values.dtype} values; {rule.text()}")
    wrong = rule.wrong(values.astype(float))
    bad = np.flatnonzero(wrong if excused is None else wrong & ~excused)
    if len(bad):
        raise error(f"line {bad[0]} is {float(values[bad[0]])!r}; {rule.text()}")
    if rule.force:                                   # the range a force has at every door (quantities.py)
        bad = np.flatnonzero(forces_outside(values.astype(float)))
        if len(bad):
            raise error(f"line {bad[0]}: {force_problem(float(values[bad[0]]))}")
    if rule.coherence:                               # 0 to 1 at every door (quantities.py)
        bad = np.flatnonzero(coherences_outside(values.astype(float)))
        if len(bad):
            raise error(f"line {bad[0]}: {coherence_problem(float(values[bad[0]]))}")
    if rule.phase:                                   # one turn either way at every door (quantities.py)
        bad = np.flatnonzero(phases_outside(values.astype(float)))
        if len(bad):
            raise error(f"line {bad[0]}: {phase_problem(float(values[bad[0]]))}")


def _choice(attrs: dict, key: str, choices: tuple[str, ...], error) -> str:
    value = attrs.get(key)
    if value not in choices:
        raise error(f"attribute {key}", f"must be one of {', '.join(choices)}; got {value!r}")
    return value


def _sensor_dofs(raw, error) -> list[str]:
    try:
        dofs = json.loads(raw) if isinstance(raw, str) else None
    except json.JSONDecodeError:
        dofs = None
    if not isinstance(dofs, list) or not dofs or not all(isinstance(d, str) and d for d in dofs) \
            or len(set(dofs)) != len(dofs):
        raise error("attribute sensor_dofs", f"must be a JSON list of distinct DOF names, got {raw!r}")
    for d in dofs:
        if dof_name_problem(d):
            raise error("attribute sensor_dofs", dof_name_problem(d))
    return dofs


def _whole_lines(run: RunData, sensors: list[str], unfinished: bool, error) -> int:
    """Lines present in every per-line dataset: all of them must agree unless the run is unfinished."""
    stored = dict(run.lines) or {"frequency": len(run.frequency), **{f"frf/{d}": len(h) for d, h in run.frf.items()},
                                 **{k: len(np.atleast_1d(v)) for k, v in run.arrays.items()}}
    stored.setdefault("frequency", len(run.frequency))
    lines = min(stored.values())
    if not unfinished:
        n = stored["frequency"]
        for name, count in sorted(stored.items(), key=lambda item: (not item[0].startswith("frf/"), item[0])):
            if count != n:
                raise error(f"dataset {name}", f"has {count} lines but dataset frequency has {n}: a finished run "
                                               "stores every quantity on every line")
    return lines
