"""Plan files (docs/contracts.md §5): what a campaign runs, checked before the shaker is armed.

Beyond the contract's keys, each ``[[stepped_sine]]`` table may set ``refine`` (adaptive refinement near
resonance, default true), ``min_step`` (Hz, default step / 4) and ``force_drift`` (the force target wandering
+-that fraction around ``force`` line by line, as a real controller's does; default 0); ``[settle]`` tunes steady-state detection
(``tolerance`` relative change between successive blocks, default 2e-3; ``max_periods`` before a line is
measured anyway, default 600; ``block_periods``, default 5; ``fixed_periods`` replaces the detection by the
fixed-count practice, waiting that many periods after every change; ``method`` = ``"steady"`` waits for the
transient to die, ``"transient"`` estimates the steady state from records that still hold it, app/transient_line.py)
and ``[control]`` the force loop (``tolerance``,
default 0.01 = 1 %). ``[limits] max_lines`` caps the planned stepped-sine lines (default 10 000; a typo such
as ``step = 1e-9`` would plan billions). ``[excitation] dof`` and ``[sensors] dofs`` say where the force gauge and
the accelerometers sit, for real instruments. ``[random] resolution`` (Hz) sets the Welch line spacing of the
random run, automatic from the band and ``expected_damping`` (default 0.01) otherwise. docs/campaigns.md describes
them.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from analysis.common.errors import InputError
from analysis.common.measurements import CONTROL_UNITS, NAME_UNITS, Control
from analysis.common.quantities import (dof_name_problem, force_and_response, force_problem, held_without_target,
                                       response_target_problem)
from analysis.signals.frf_estimation import WelchResolution, auto_resolution, welch_averages
from analysis.common.tables import Fields, parse_toml, read_toml_text


DEFAULT_EXPECTED_DAMPING = 0.01   # lightest damping ratio a random run is planned to resolve, unless the plan says
MIN_RANDOM_AVERAGES = 2           # a [random] resolution whose segments the run holds fewer times is refused


@dataclass
class RandomSpec:
    force_rms: float            # N
    band: tuple[float, float]   # Hz
    duration: float             # s
    resolution: float | None = None          # Hz; None: automatic from the band and expected_damping
    expected_damping: float = DEFAULT_EXPECTED_DAMPING

    def welch(self) -> WelchResolution:
        """The Welch resolution of the run: the plan's, or the automatic one (docs/campaigns.md)."""
        if self.resolution is None:
            return auto_resolution(self.band, self.duration, self.expected_damping)
        return WelchResolution(self.resolution, self.resolution, welch_averages(self.duration, self.resolution),
                               False)


RESPONSE_QUANTITIES = ("displacement", "velocity", "acceleration")
DEFAULT_FORCE_LIMIT_SHARE = 0.5   # a response level's force_limit, unless it says: this share of max_force


@dataclass(frozen=True)
class ResponseLevel:
    """A level that holds the amplitude of ``quantity`` at ``dof`` (SI units) instead of a force; the loop
    never drives the force beyond ``force_limit`` N."""

    dof: str
    quantity: str
    target: float
    force_limit: float

    @property
    def name_token(self) -> str:
        return f"{self.dof}_{self.target:g}{NAME_UNITS[self.quantity]}"

    def text(self) -> str:
        return f"{self.target:g} {CONTROL_UNITS[self.quantity]} {self.quantity} at {self.dof}"


@dataclass
class SineSpec:
    """One level of stepped sine (one table of the plan): a force amplitude, or a response amplitude held at a
    DOF (``response``; ``force`` is then its force limit)."""

    force: float                # N amplitude (response control: the force limit)
    start: float                # Hz
    stop: float                 # Hz
    step: float                 # Hz
    direction: str              # up | down | both
    refine: bool = True
    min_step: float = 0.0
    force_drift: float = 0.0    # the force target drifts by up to this fraction around ``force`` (emulated rigs)
    response: ResponseLevel | None = None

    def line_target(self, index: int) -> float:
        """The force held at the run's line ``index``, N: ``force``, or with ``force_drift`` a target that wanders
        smoothly around it line by line, within +-force_drift, as a real controller's achieved force does
        across a resonance (docs/campaigns.md)."""
        return self.force * (1.0 + self.force_drift * np.sin(2 * np.pi * index / DRIFT_LINES))

    def control(self, excitation_dof: str) -> Control:
        """The level's control in the session's vocabulary (docs/session-format.md)."""
        if self.response is None:
            return Control("force", excitation_dof, "force", self.force)
        r = self.response
        return Control("response", r.dof, r.quantity, r.target)

    def level_text(self) -> str:
        return f"{self.force:g} N" if self.response is None else self.response.text()

    @property
    def directions(self) -> list[str]:
        return ["up", "down"] if self.direction == "both" else [self.direction]

    @property
    def steps(self) -> int:
        """Whole steps from start toward stop."""
        return int(np.floor((self.stop - self.start) / self.step + 1e-9))

    @property
    def line_count(self) -> int:
        """Planned lines of one sweep (before refinement), without building them."""
        return len(self.lines("up")) if self.steps < LARGEST_MAX_LINES else self.steps + 1

    def lines(self, direction: str) -> np.ndarray:
        """The planned lines of one sweep, in the order measured (refinement may add more)."""
        f = self.start + self.step * np.arange(self.steps + 1)
        if f[-1] < self.stop - 1e-9 * self.stop:
            f = np.append(f, self.stop)
        return f if direction == "up" else f[::-1]

    def run_name(self, direction: str) -> str:
        if self.response is not None:
            return f"sine_{self.response.name_token}_{direction}"
        return f"sine_{self.force:g}N_{direction}"


SETTLE_METHODS = ("steady", "transient")
DRIFT_LINES = 17.0              # lines per cycle of a drifting force target (SineSpec.line_target)
MAX_SINE_TABLES = 200           # [[stepped_sine]] tables (force levels) in one plan
MAX_RANDOM_SECONDS = 3600.0      # [random] duration: one hour of random excitation at most
MAX_BLOCK_PERIODS = 1000         # [settle] block_periods: periods in one record
MAX_SETTLE_PERIODS = 100_000     # [settle] max_periods and fixed_periods: periods a line may wait
MAX_MIN_BLOCKS = 1000            # [settle] min_blocks
MAX_SHAKER_SECONDS = 24 * 3600.0  # the least shaker time the whole plan takes (PlannedTime.least)
MAX_RECORD_SAMPLES = 1 << 22     # samples a channel in one record (block_periods at the lowest line)
DEFAULT_MAX_LINES = 10_000       # planned stepped-sine lines, all runs together, unless [limits] max_lines says
LARGEST_MAX_LINES = 1_000_000    # what max_lines may be raised to (each line is a record of its own)


@dataclass
class Limits:
    max_force: float                 # N
    max_acceleration: float          # m/s^2
    max_lines: int = DEFAULT_MAX_LINES


@dataclass
class SettleSpec:
    tolerance: float = 2e-3
    max_periods: int = 600
    block_periods: int = 5
    min_blocks: int = 2
    fixed_periods: int = 0       # > 0: the fixed-count practice, wait this many periods after every change
    method: str = "steady"       # "steady": wait for the transient to die; "transient": fit it (transient_line.py)


@dataclass
class Placement:
    """Where the force gauge and the accelerometers sit: the plan's ``[excitation]`` and ``[sensors]`` (None
    where it does not say), possibly overridden by command-line flags. ``driving_point = false`` allows a force
    gauge at a DOF without an accelerometer. ``source`` and the ``*_field`` names say where each value came
    from, for error messages (a flag's value is reported under the flag's name, without the plan file)."""

    excitation_dof: str | None = None
    sensor_dofs: list[str] | None = None
    driving_point: bool = True
    source: str | None = None
    excitation_field: str = "[excitation].dof"
    sensors_field: str = "[sensors].dofs"

    def overridden(self, excitation_dof: str | None, sensor_dofs: list[str] | None) -> "Placement":
        """This placement with ``--excitation`` / ``--sensors`` taking precedence where given."""
        out = replace(self)
        if excitation_dof:
            out.excitation_dof, out.excitation_field = excitation_dof, "--excitation"
        if sensor_dofs:
            out.sensor_dofs, out.sensors_field = list(sensor_dofs), "--sensors"
        return out

    def origin(self, field_name: str) -> str | None:
        """The file a field's value came from (None for a flag)."""
        return None if field_name.startswith("--") else self.source


@dataclass
class PhaseSpec:
    """A phase-resonance run (one ``[[phase_resonance]]`` table): at each force level (N, ascending) the frequency
    is tracked until the fundamental displacement at ``dof`` lags the force by ``phase`` degrees within
    ``tolerance``, starting near ``start`` Hz; ``max_iterations`` lines per level at most."""

    dof: str
    forces: list[float]
    start: float
    phase: float = 90.0
    tolerance: float = 1.0
    max_iterations: int = 30

    def run_name(self) -> str:
        return f"phase_{self.dof}_{self.phase:g}deg"


@dataclass(frozen=True)
class PlannedTime:
    """How long the shaker drives for a plan (s): ``least`` if every line settles at once (``min_blocks``
    records, or ``fixed_periods``), ``most`` if every line waits to ``max_periods``; the random run counts its
    duration. Refinement near resonance may add lines beyond both."""

    least: float
    most: float

    def text(self) -> str:
        return f"planned shaker time {_duration(self.least)} to {_duration(self.most)}"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


@dataclass
class Plan:
    random: RandomSpec | None
    sine: list[SineSpec]
    limits: Limits
    settle: SettleSpec = field(default_factory=SettleSpec)
    control_tolerance: float = 0.01
    text: str = ""
    source: str | None = None
    placement: Placement = field(default_factory=Placement)
    phase: list[PhaseSpec] = field(default_factory=list)

    @property
    def runs(self) -> list[tuple[SineSpec, str]]:
        return [(spec, d) for spec in self.sine for d in spec.directions]

    def planned_lines(self) -> int:
        """The lines the campaign's progress counts: every stepped-sine line, the random run as one and each
        phase-resonance force level as one (refinement may add more as it runs)."""
        return sum(len(spec.lines(d)) for spec, d in self.runs) + (1 if self.random else 0) \
            + sum(len(p.forces) for p in self.phase)

    def summary(self) -> str:
        """What the plan measures, for the plan check: runs, planned lines (as the progress counts them,
        :meth:`planned_lines`) and the planned shaker time."""
        lines = sum(len(spec.lines(d)) for spec, d in self.runs)
        total = self.planned_lines()
        extra = (["the random run"] if self.random else []) + \
            ([f"{total - lines - bool(self.random)} phase-resonance level(s)"] if self.phase else [])
        counted = f"{total} planned lines" + (f" ({' + '.join([f'{lines} stepped-sine', *extra])})" if extra else "")
        parts = [f"{len(self.runs)} stepped-sine run(s), {counted}", self.planned_time().text()]
        if self.random is not None:
            parts.insert(0, f"random run {self.random.duration:g} s")
        if self.phase:
            parts.insert(-1, f"{len(self.phase)} phase-resonance run(s), "
                             f"{sum(len(p.forces) for p in self.phase)} force level(s)")
        return ", ".join(parts)

    def planned_time(self) -> PlannedTime:
        """The shaker time the plan asks for (:class:`PlannedTime`)."""
        periods = sum(float(np.sum(1.0 / spec.lines(d))) for spec, d in self.runs)   # s per period, summed
        s = self.settle
        least = s.fixed_periods or s.min_blocks * s.block_periods
        most = max(s.max_periods, s.fixed_periods) + s.block_periods
        random = self.random.duration if self.random is not None else 0.0
        # a phase-resonance level takes one line when its start is already in phase, max_iterations at most
        locked = sum(len(p.forces) / p.start for p in self.phase)
        tracked = sum(len(p.forces) * p.max_iterations / p.start for p in self.phase)
        return PlannedTime(random + least * (periods + locked), random + most * (periods + tracked))


def load_plan(path) -> Plan:
    """Read and validate a plan file."""
    text = read_toml_text(path)
    return parse_plan(parse_toml(text, str(path)), text, str(path))


def parse_plan(doc: dict, text: str = "", source: str | None = None) -> Plan:
    root = Fields(doc, source, "")
    root.unknown_keys({"random", "stepped_sine", "phase_resonance", "limits", "settle", "control", "excitation",
                       "sensors"})
    random = None
    if root.has("random"):
        f = root.sub("random")
        f.where = "[random]"
        f.unknown_keys({"force_rms", "band", "duration", "resolution", "expected_damping"})
        band = f.require("band")
        if not isinstance(band, list) or len(band) != 2:
            raise f.error("band", "must be [low, high] in Hz")
        lo, hi = (f.check_number("band", b, positive=True) for b in band)
        if hi <= lo:
            raise f.error("band", f"high end {hi} Hz must exceed the low end {lo} Hz")
        random = RandomSpec(_force(f, "force_rms"), (lo, hi), f.number("duration", positive=True))
        if random.duration > MAX_RANDOM_SECONDS:
            raise f.error("duration", f"{random.duration:g} s is more than {MAX_RANDOM_SECONDS:g} s of random "
                                      "excitation (docs/campaigns.md, limits); split it into runs of another plan")
        _random_resolution(f, random)
    sines = []
    tables = root.list_of_tables("stepped_sine")
    if len(tables) > MAX_SINE_TABLES:
        raise InputError(f"{len(tables)} stepped-sine tables: at most {MAX_SINE_TABLES} force levels a plan "
                         "(docs/campaigns.md, limits)", source, "[[stepped_sine]]")
    for i, f in enumerate(tables):
        f.where = f"[[stepped_sine]][{i}]"
        f.unknown_keys({"force", "start", "stop", "step", "direction", "refine", "min_step", "force_drift",
                        *RESPONSE_KEYS})
        start, stop, step = f.number("start", positive=True), f.number("stop", positive=True), \
            f.number("step", positive=True)
        if stop <= start:
            raise f.error("stop", f"stop ({stop} Hz) must be above start ({start} Hz); use direction = \"down\" "
                                  "to sweep downwards")
        if step > stop - start:
            raise f.error("step", f"step {step} Hz is larger than the span {stop - start:g} Hz")
        refine = f.table.get("refine", True)
        if not isinstance(refine, bool):
            raise f.error("refine", "must be true or false")
        min_step = f.number("min_step", step / 4, positive=True)
        if min_step > step:
            raise f.error("min_step", f"must not exceed step ({step} Hz)")
        drift = f.number("force_drift", 0.0, nonnegative=True)
        if drift >= 1:
            raise f.error("force_drift", f"must be a fraction below 1 (0.25: +-25 % around force), got {drift:g}")
        response = _response_level(f)
        if response is not None and drift:
            raise f.error("force_drift", "drifts a held force: a response-controlled level lets its force vary "
                                         "already")
        force = response.force_limit if response is not None else _force(f, "force")
        sines.append(SineSpec(force, start, stop, step, f.string("direction", "up", ("up", "down", "both")),
                              refine, min_step, force_drift=drift, response=response))
    phases = [_phase_table(f, i) for i, f in enumerate(root.list_of_tables("phase_resonance"))]
    if random is None and not sines and not phases:
        raise InputError("plans nothing: give [random], [[stepped_sine]] and/or [[phase_resonance]] tables", source)
    names = Counter(spec.run_name(d) for spec in sines for d in spec.directions)
    dup = {n for n, count in names.items() if count > 1}
    if dup:
        raise InputError(f"two stepped-sine tables make the same run {sorted(dup)[0]} (same level and "
                         "direction)", source, "[[stepped_sine]]")
    lim = root.sub("limits")
    lim.where = "[limits]"
    lim.unknown_keys({"max_force", "max_acceleration", "max_lines"})
    limits = Limits(lim.number("max_force", positive=True), lim.number("max_acceleration", positive=True),
                    _max_lines(lim))
    sines = [_default_force_limit(spec, limits) for spec in sines]
    _check_response_targets(sines, limits, source)
    _check_line_count(sines, limits.max_lines, source)
    for i, spec in enumerate(sines):
        if spec.force * (1 + spec.force_drift) >= limits.max_force:
            key = "force" if spec.response is None else "force_limit"
            drifted = f" (drifting to {spec.force * (1 + spec.force_drift):g} N)" if spec.force_drift else ""
            raise InputError(f"{key} {spec.force} N{drifted} is not below the abort limit max_force = "
                             f"{limits.max_force} N", source, f"[[stepped_sine]][{i}].{key}")
    if random is not None and 3 * random.force_rms >= limits.max_force:
        raise InputError(f"force_rms {random.force_rms} N: its peaks (~3 x rms) would reach max_force = "
                         f"{limits.max_force} N", source, "[random].force_rms")
    settle = SettleSpec()
    if root.has("settle"):
        s = root.sub("settle")
        s.where = "[settle]"
        s.unknown_keys({"tolerance", "max_periods", "block_periods", "min_blocks", "fixed_periods", "method"})
        settle = SettleSpec(s.number("tolerance", settle.tolerance, positive=True),
                            _count(s, "max_periods", settle.max_periods, MAX_SETTLE_PERIODS),
                            _count(s, "block_periods", settle.block_periods, MAX_BLOCK_PERIODS),
                            _count(s, "min_blocks", settle.min_blocks, MAX_MIN_BLOCKS),
                            _count(s, "fixed_periods", 0, MAX_SETTLE_PERIODS, least=0),
                            s.string("method", settle.method, SETTLE_METHODS))
        if settle.method == "transient" and settle.fixed_periods:
            raise s.error("method", "\"transient\" estimates the steady state early; it cannot be combined with "
                                    "fixed_periods (the fixed-count practice)")
    control = 0.01
    if root.has("control"):
        c = root.sub("control")
        c.where = "[control]"
        c.unknown_keys({"tolerance"})
        control = c.number("tolerance", 0.01, positive=True)
    _check_phase_forces(phases, limits, source)
    plan = Plan(random, sines, limits, settle, control, text, source, _placement(root), phases)
    planned = plan.planned_time()
    if planned.least > MAX_SHAKER_SECONDS:
        raise InputError(f"{planned.text()}: even if every line settles at once the shaker drives for more than "
                         f"{MAX_SHAKER_SECONDS / 3600:g} h (docs/campaigns.md, limits); plan fewer lines or shorter "
                         "records", source)
    return plan


RESPONSE_KEYS = ("response", "quantity", "dof", "force_limit")


def _response_level(f: Fields) -> ResponseLevel | None:
    """A table's response control (``response``, ``quantity``, ``dof``, ``force_limit``), or None for a force
    level. A level holds one of the two: a force, or a response amplitude. A force limit not given is NaN
    here and :func:`_default_force_limit` sets it once ``[limits]`` is read."""
    if not f.has("response"):
        extra = [k for k in RESPONSE_KEYS if f.has(k)]
        if extra:
            raise f.error(extra[0], held_without_target("response = <amplitude>"))
        return None
    if f.has("force"):
        raise f.error("force", force_and_response("response"))
    quantity = f.string("quantity", "acceleration", RESPONSE_QUANTITIES)
    dof = _dof_name(f, f.string("dof"), "dof")
    limit = _force(f, "force_limit") if f.has("force_limit") else float("nan")
    return ResponseLevel(dof, quantity, f.number("response", positive=True), limit)


PHASE_KEYS = {"dof", "forces", "start", "phase", "tolerance", "max_iterations"}
MAX_PHASE_LEVELS = 200          # force levels of one phase-resonance run


def _phase_table(f: Fields, i: int) -> PhaseSpec:
    """One ``[[phase_resonance]]`` table (docs/campaigns.md, "Phase resonance")."""
    f.where = f"[[phase_resonance]][{i}]"
    f.unknown_keys(PHASE_KEYS)
    forces = f.table.get("forces")
    if not isinstance(forces, list) or not forces or len(forces) > MAX_PHASE_LEVELS:
        raise f.error("forces", f"must be a list of 1 to {MAX_PHASE_LEVELS} force amplitudes in N")
    forces = [_force(f, "forces", v) for v in forces]
    if any(b <= a for a, b in zip(forces, forces[1:])):
        raise f.error("forces", "must rise from level to level (the lock follows the mode up in amplitude)")
    phase = f.number("phase", 90.0, positive=True)
    if phase >= 180.0:
        raise f.error("phase", f"a phase lag from 0 to 180 degrees, got {phase:g}")
    tolerance = f.number("tolerance", 1.0, positive=True)
    if tolerance > 10.0:
        raise f.error("tolerance", f"at most 10 degrees, got {tolerance:g}")
    iterations = _count(f, "max_iterations", 30, 200)
    return PhaseSpec(_dof_name(f, f.string("dof"), "dof"), forces, f.number("start", positive=True), phase,
                     tolerance, iterations)


def _check_phase_forces(phases: list[PhaseSpec], limits: "Limits", source: str | None) -> None:
    for i, spec in enumerate(phases):
        if spec.forces[-1] >= limits.max_force:
            raise InputError(f"force {spec.forces[-1]:g} N is not below the abort limit max_force = "
                             f"{limits.max_force:g} N", source, f"[[phase_resonance]][{i}].forces")
    names = Counter(p.run_name() for p in phases)
    dup = sorted(n for n, count in names.items() if count > 1)
    if dup:
        raise InputError(f"two phase-resonance tables make the same run {dup[0]} (same DOF and phase)", source,
                         "[[phase_resonance]]")


def _default_force_limit(spec: SineSpec, limits: "Limits") -> SineSpec:
    if spec.response is None or not np.isnan(spec.force):
        return spec
    limit = DEFAULT_FORCE_LIMIT_SHARE * limits.max_force
    return replace(spec, force=limit, response=replace(spec.response, force_limit=limit))


def _count(f: Fields, key: str, default: int, largest: int, least: int = 1) -> int:
    """A whole number of periods or records from ``least`` to ``largest`` (docs/campaigns.md, limits)."""
    value = f.number(key, default, nonnegative=True)
    if value != int(value) or not least <= value <= largest:
        raise f.error(key, f"must be a whole number from {least} to {largest:,}, got {value:g}")
    return int(value)


def _random_resolution(f: Fields, spec: RandomSpec) -> None:
    """``[random] resolution`` (Hz) and ``expected_damping`` (ratio), checked against the run's duration."""
    spec.expected_damping = f.number("expected_damping", DEFAULT_EXPECTED_DAMPING, positive=True)
    if spec.expected_damping >= 0.5:
        raise f.error("expected_damping", f"must be a damping ratio below 0.5, got {spec.expected_damping:g}")
    if not f.has("resolution"):
        return
    spec.resolution = f.number("resolution", positive=True)
    if welch_averages(spec.duration, spec.resolution) < MIN_RANDOM_AVERAGES:
        raise f.error("resolution", f"{spec.resolution:g} Hz needs {1 / spec.resolution:g} s segments: a "
                                    f"{spec.duration:g} s run holds fewer than {MIN_RANDOM_AVERAGES} Welch averages "
                                    "(coarsen the resolution or lengthen duration)")
    if spec.resolution > (spec.band[1] - spec.band[0]) / 8:
        raise f.error("resolution", f"{spec.resolution:g} Hz leaves fewer than 8 lines in the band "
                                    f"{spec.band[0]:g}-{spec.band[1]:g} Hz")


def _max_lines(lim: Fields) -> int:
    value = lim.table.get("max_lines", DEFAULT_MAX_LINES)
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= LARGEST_MAX_LINES:
        raise lim.error("max_lines", f"must be a whole number from 1 to {LARGEST_MAX_LINES}, got {value!r}")
    return value


def _check_line_count(sines: list[SineSpec], max_lines: int, source: str | None) -> None:
    """Refuse a plan of more stepped-sine lines than ``max_lines``, naming the table that plans the most."""
    counts = [spec.line_count * len(spec.directions) for spec in sines]
    if sum(counts) <= max_lines:
        return
    i = int(np.argmax(counts))
    raise InputError(f"the plan has {sum(counts):,} stepped-sine lines ({counts[i]:,} from this table's step "
                     f"{sines[i].step:g} Hz), more than max_lines = {max_lines:,}; if that many is meant, "
                     f"raise [limits] max_lines (at most {LARGEST_MAX_LINES:,})", source,
                     f"[[stepped_sine]][{i}].step")


def _placement(root: Fields) -> Placement:
    place = Placement(source=root.source)
    if root.has("excitation"):
        f = root.sub("excitation")
        f.where = "[excitation]"
        f.unknown_keys({"dof", "driving_point"})
        place.excitation_dof = _dof_name(f, f.string("dof"), "dof")
        place.driving_point = f.table.get("driving_point", True)
        if not isinstance(place.driving_point, bool):
            raise f.error("driving_point", "must be true or false")
    if root.has("sensors"):
        f = root.sub("sensors")
        f.where = "[sensors]"
        f.unknown_keys({"dofs"})
        place.sensor_dofs = [_dof_name(f, d, "dofs") for d in f.strings("dofs")]
        if not place.sensor_dofs or len(set(place.sensor_dofs)) != len(place.sensor_dofs):
            raise f.error("dofs", "must name one or more distinct DOFs")
    return place


def _dof_name(f: Fields, name: str, key: str) -> str:
    problem = dof_name_problem(name)          # the one rule of every door (analysis/common/quantities.py)
    if problem:
        raise f.error(key, problem)
    return name


def _force(f: Fields, key: str, value=None) -> float:
    """A force amplitude (N) of the plan, ``f[key]`` or ``value``: a number within the range every door
    holds forces to (analysis/common/quantities.py)."""
    value = f.number(key) if value is None else f.check_number(key, value)
    problem = force_problem(value)
    if problem:
        raise f.error(key, problem)
    return value


def _check_response_targets(sines: list[SineSpec], limits: "Limits", source: str | None) -> None:
    """A response level holds its amplitude at every line: as an acceleration (``target * w^n`` for a
    displacement, n = 2, or a velocity, n = 1, at the level's highest frequency) it must stay below the abort
    limit ``max_acceleration``, as a force level's force stays below ``max_force``."""
    powers = {"displacement": 2, "velocity": 1, "acceleration": 0}
    for i, spec in enumerate(sines):
        r = spec.response
        if r is None:
            continue
        top = max(spec.start, spec.stop)
        with np.errstate(over="ignore"):
            acceleration = float(r.target * np.float64(2 * np.pi * top) ** powers[r.quantity])
        if not acceleration < limits.max_acceleration:
            at = "" if r.quantity == "acceleration" else f" ({acceleration:g} m/s^2 at {top:g} Hz)"
            raise InputError(f"response {r.target:g} {CONTROL_UNITS[r.quantity]}{at} is not below the abort limit "
                             f"max_acceleration = {limits.max_acceleration:g} m/s^2", source,
                             f"[[stepped_sine]][{i}].response")
        if response_target_problem(r.quantity, r.target):     # the range of every door (quantities.py)
            raise InputError(response_target_problem(r.quantity, r.target), source, f"[[stepped_sine]][{i}].response")


def check_against_instruments(plan: Plan, sample_rate: float, frequency_range: tuple[float, float],
                              n_harmonics: int = 5) -> None:
    """Refuse a plan the instruments cannot run: frequencies beyond the generator's range or too high for the
    DAQ to measure the fundamental (and, as far as possible, its harmonics) below Nyquist."""
    nyquist = sample_rate / 2
    lo, hi = frequency_range
    for i, spec in enumerate(plan.sine):
        where = f"[[stepped_sine]][{i}].stop"
        if spec.stop >= nyquist:
            raise InputError(f"{spec.stop} Hz is beyond the DAQ's Nyquist frequency ({nyquist:g} Hz at "
                             f"{sample_rate:g} Hz sampling)", plan.source, where)
        if spec.start < lo or spec.stop > hi:
            raise InputError(f"{spec.start}-{spec.stop} Hz is outside the generator's range {lo:g}-{hi:g} Hz",
                             plan.source, where)
    for i, spec in enumerate(plan.sine):
        samples = plan.settle.block_periods * sample_rate / spec.start
        if samples > MAX_RECORD_SAMPLES:
            raise InputError(f"a record of {plan.settle.block_periods} periods at {spec.start:g} Hz holds "
                             f"{samples:,.0f} samples a channel at {sample_rate:g} Hz, more than "
                             f"{MAX_RECORD_SAMPLES:,}: lower block_periods", plan.source, "[settle].block_periods")
    for i, spec in enumerate(plan.phase):
        if not lo <= spec.start <= hi or spec.start >= nyquist / 2:
            raise InputError(f"{spec.start:g} Hz is outside the generator's range {lo:g}-{hi:g} Hz or too near "
                             f"the DAQ's Nyquist frequency ({nyquist:g} Hz) for the lock to move around it",
                             plan.source, f"[[phase_resonance]][{i}].start")
    if plan.random is not None and plan.random.band[1] >= nyquist:
        raise InputError(f"band reaches {plan.random.band[1]} Hz, beyond the DAQ's Nyquist frequency "
                         f"({nyquist:g} Hz)", plan.source, "[random].band")
