"""Rig files: the truth a simulated test rig obeys (docs/contracts.md §3).

:func:`load_rig` reads a rig TOML file (or a built-in rig by name) into a
:class:`Rig` and refuses, before any integration, everything that cannot be
simulated faithfully: non-physical or unstable structures, unknown laws or
parameters, sensors and excitation at impossible places, and a sample rate whose
internal time step cannot resolve the highest mode the simulator keeps. The tables
beyond docs/contracts.md (``[shaker]``, ``[daq]``, ``[generator]``, ``[simulation]``) are
documented in docs/rig-simulator.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path


from analysis.mechanics.elements import Element, load_elements
from analysis.common.errors import InputError
from analysis.mechanics.model import RIG_TABLES
from analysis.mechanics.structures import Structure, load_structure
from analysis.common.tables import Fields, parse_toml, read_toml_text

from .linear_model import LinearModel, build_linear_model

REDUCTIONS = ("craig-bampton", "none")
DEFAULT_SAMPLE_RATE = 1024.0  # Hz, when a rig has no [daq].sample_rate
MIN_SAMPLE_RATE, MAX_SAMPLE_RATE = 1.0, 1e6   # Hz: what a rig's DAQ may sample at


@dataclass(frozen=True)
class NoiseSpec:
    """Measurement noise: Gaussian, relative to the running rms of each channel.

    Attributes
    ----------
    force, acceleration : float
        Noise rms as a fraction of the channel's running rms (0 = none).
    seed : int
        Seed of the noise (and of the random drive) unless the simulator is given one.
    averaging_time : float
        Time constant of the running rms, s.
    """

    force: float = 0.0
    acceleration: float = 0.0
    seed: int = 0
    averaging_time: float = 1.0


@dataclass(frozen=True)
class ShakerSpec:
    """Electrodynamic shaker driven by a voltage amplifier (``L di/dt + R i + Bl v = V``).

    Attributes
    ----------
    resistance : float
        Coil plus amplifier output resistance, ohm.
    inductance : float
        Coil inductance, H.
    force_factor : float
        Bl, N/A.
    armature_mass : float
        kg, rigidly attached at the excitation DOF (outside the force gauge).
    suspension_stiffness : float
        N/m, to ground.
    suspension_damping : float
        N·s/m, to ground.
    """

    resistance: float
    inductance: float
    force_factor: float
    armature_mass: float
    suspension_stiffness: float
    suspension_damping: float


@dataclass(frozen=True)
class DaqSpec:
    """Acquisition: sample rate, converter, anti-alias filter and clock.

    Attributes
    ----------
    sample_rate : float
        Hz (DAQ clock).
    resolution : int
        ADC bits.
    force_range, acceleration_range : float
        Full scale (+-), N and m/s^2.
    clock_offset_ppm : float
        DAQ clock error relative to the generator: the DAQ takes ``sample_rate (1 + ppm 1e-6)``
        samples per generator second.
    oversample : int
        Internal integration steps per DAQ sample; the anti-alias filter runs at that rate.
        1 means no anti-alias filter.
    passband : float
        Anti-alias passband edge as a fraction of the sample rate (< 0.5); the filter
        stops from ``1 - passband`` of the sample rate, so nothing aliases into the passband.
    """

    sample_rate: float = DEFAULT_SAMPLE_RATE
    resolution: int = 24
    force_range: float = 10.0
    acceleration_range: float = 500.0
    clock_offset_ppm: float = 0.0
    oversample: int = 4
    passband: float = 0.4

    @property
    def internal_rate(self) -> float:
        """Internal integration rate in generator time, Hz."""
        return self.sample_rate * self.oversample * (1.0 + 1e-6 * self.clock_offset_ppm)


@dataclass(frozen=True)
class GeneratorSpec:
    """Signal generator behaviour.

    Attributes
    ----------
    ramp_cycles : float
        A sine amplitude change ramps linearly over this many cycles.
    ramp_time : float
        A random-drive level change (and the ramp after arming the output) lasts this long, s.
    """

    ramp_cycles: float = 3.0
    ramp_time: float = 0.1


@dataclass(frozen=True)
class SimulationSpec:
    """How the structure is integrated.

    Attributes
    ----------
    reduction : {"craig-bampton", "none"}
        Beam rigs are reduced by default; lumped rigs are never reduced.
    mode_cutoff : float or None
        Keep the normal modes below this frequency (Hz) in the reduction; default the
        anti-alias passband edge.
    """

    reduction: str = "craig-bampton"
    mode_cutoff: float | None = None


@dataclass
class Rig:
    """A simulated test rig, validated and ready for :class:`drivers.simulation.simulator.RigSimulator`.

    Attributes
    ----------
    name : str
    structure : Structure
        The linear structure (without the elements).
    elements : list of Element
        The nonlinear (or linear) elements with every law parameter given.
    excitation_dof : str
        Where the shaker (or ideal force source) acts; a force gauge measures the force there.
    sensor_dofs : list of str
        Accelerometer DOFs (translational).
    noise, daq, generator, simulation : specs
    shaker : ShakerSpec or None
        None = ideal force source of ``source_gain`` N per volt of drive.
    source_gain : float
        N/V of the ideal source (unused with a shaker).
    faults : dict
        The ``[faults]`` table, kept for the instrument emulator.
    text : str
        The rig file text (stored in sessions as provenance).
    source : str
        File name or ``builtin:NAME``.
    """

    name: str
    structure: Structure
    elements: list[Element]
    excitation_dof: str
    sensor_dofs: list[str]
    noise: NoiseSpec
    shaker: ShakerSpec | None
    source_gain: float
    daq: DaqSpec
    generator: GeneratorSpec
    simulation: SimulationSpec
    faults: dict = field(default_factory=dict)
    text: str = ""
    source: str = "<rig>"
    linear: LinearModel | None = None  # built by load_rig

    @property
    def channels(self) -> list[str]:
        """Channel names: the force gauge, then one accelerometer per sensor DOF."""
        return ["force"] + [f"acc:{d}" for d in self.sensor_dofs]


# --- built-in rigs ---------------------------------------------------------------
def _rig_folder():
    return resources.files("drivers.simulation.rigs")


def builtin_rigs() -> list[str]:
    """Names of the rigs shipped with the package."""
    return sorted(p.name[: -len(".toml")] for p in _rig_folder().iterdir()
                  if p.name.endswith(".toml") and not p.name.endswith(".plan.toml"))


def builtin_rig_path(name: str) -> Path:
    if name not in builtin_rigs():
        raise InputError(f"no built-in rig {name!r} (built-in rigs: {', '.join(builtin_rigs())})")
    return Path(str(_rig_folder().joinpath(f"{name}.toml")))


# --- loading ----------------------------------------------------------------------
def load_rig(path_or_name: str | Path) -> Rig:
    """Read a rig file, or a built-in rig by name, and validate it.

    Parameters
    ----------
    path_or_name : str or Path
        A rig TOML file, or the name of a built-in rig (:func:`builtin_rigs`).

    Raises
    ------
    InputError
        One line naming the file and the field, for anything that cannot be simulated.
    """
    path = Path(path_or_name)
    if not path.is_file():
        name = str(path_or_name)
        if name in builtin_rigs():
            return parse_rig(builtin_rig_path(name).read_text(encoding="utf-8"), f"builtin:{name}")
        raise InputError(f"no such rig file, and no built-in rig of that name "
                         f"(built-in rigs: {', '.join(builtin_rigs())})", str(path_or_name))
    return parse_rig(read_toml_text(path), str(path))


def parse_rig(text: str, source: str = "<rig>") -> Rig:
    """Build and validate a :class:`Rig` from rig-file text (e.g. a session's provenance)."""
    document = parse_toml(text, source)
    root = Fields(document, source, "")
    root.unknown_keys(set(RIG_TABLES))
    name = root.string("name")
    structure = load_structure(root.require("structure"), source)
    elements = load_elements(document, structure, source, complete=True)

    excitation = _table(root, "excitation", required=True)
    excitation.unknown_keys({"dof", "gain"})
    excitation_dof = excitation.string("dof")
    structure.index(excitation_dof, excitation.path("dof"))
    if structure.is_rotational(excitation_dof):
        raise excitation.error("dof", f"{excitation_dof!r} is a rotation: the shaker and force gauge "
                                      "act on a displacement DOF")
    shaker = _shaker(_table(root, "shaker")) if root.has("shaker") else None
    if shaker is not None and excitation.has("gain"):
        raise excitation.error("gain", "the gain of an ideal force source has no meaning with a [shaker]")
    gain = excitation.number("gain", 1.0, positive=True)

    sensors = _table(root, "sensors", required=True)
    sensors.unknown_keys({"dofs"})
    sensor_dofs = sensors.strings("dofs")
    if not sensor_dofs:
        raise sensors.error("dofs", "name at least one accelerometer DOF")
    if len(set(sensor_dofs)) != len(sensor_dofs):
        raise sensors.error("dofs", "each DOF may carry one accelerometer")
    for dof in sensor_dofs:
        structure.index(dof, sensors.path("dofs"))
        if structure.is_rotational(dof):
            raise sensors.error("dofs", f"{dof!r} is a rotation: accelerometers measure displacement DOFs")

    rig = Rig(name=name, structure=structure, elements=elements, excitation_dof=excitation_dof,
              sensor_dofs=sensor_dofs, noise=_noise(_table(root, "noise")),
              shaker=shaker, source_gain=gain, daq=_daq(_table(root, "daq")),
              generator=_generator(_table(root, "generator")),
              simulation=_simulation(_table(root, "simulation"), structure.description.startswith("beam")),
              faults=dict(_table(root, "faults").table), text=text, source=source)
    # the linear model checks stability and time-step resolution before any integration
    rig.linear = build_linear_model(rig)
    return rig


def _table(root: Fields, name: str, required: bool = False) -> Fields:
    """The top-level table ``[name]`` (empty when optional and absent), fields named ``[name].key``."""
    if name not in root.table:
        if required:
            raise root.error(f"[{name}]", "this table is required")
        return Fields({}, root.source, f"[{name}]")
    return Fields(root.table[name], root.source, f"[{name}]")


def _noise(f: Fields) -> NoiseSpec:
    f.unknown_keys({"force", "acceleration", "seed", "averaging_time"})
    seed = f.table.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise f.error("seed", f"must be a whole number >= 0, got {seed!r}")
    return NoiseSpec(f.number("force", 0.0, nonnegative=True), f.number("acceleration", 0.0, nonnegative=True),
                     seed, f.number("averaging_time", 1.0, positive=True))


def _shaker(f: Fields) -> ShakerSpec:
    f.unknown_keys({"resistance", "inductance", "force_factor", "armature_mass", "suspension_stiffness",
                    "suspension_damping"})
    return ShakerSpec(f.number("resistance", positive=True), f.number("inductance", positive=True),
                      f.number("force_factor", positive=True), f.number("armature_mass", nonnegative=True),
                      f.number("suspension_stiffness", 0.0, nonnegative=True),
                      f.number("suspension_damping", 0.0, nonnegative=True))


def _daq(f: Fields) -> DaqSpec:
    f.unknown_keys({"sample_rate", "resolution", "force_range", "acceleration_range", "clock_offset_ppm",
                    "oversample", "passband"})
    whole = {}
    for key, default, low, high in (("resolution", 24, 8, 32), ("oversample", 4, 1, 64)):
        value = f.table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise f.error(key, f"must be a whole number in [{low}, {high}], got {value!r}")
        whole[key] = value
    ppm = f.number("clock_offset_ppm", 0.0)
    if abs(ppm) >= 1e4:
        raise f.error("clock_offset_ppm", f"{ppm} ppm is not a clock offset (|ppm| < 10000)")
    passband = f.number("passband", 0.4, positive=True)
    if passband >= 0.5:
        raise f.error("passband", f"must be below 0.5 (the Nyquist frequency), got {passband}")
    rate = f.number("sample_rate", DEFAULT_SAMPLE_RATE, positive=True)
    if not MIN_SAMPLE_RATE <= rate <= MAX_SAMPLE_RATE:
        raise f.error("sample_rate", f"{rate:g} Hz is not a DAQ's sample rate ({MIN_SAMPLE_RATE:g} to "
                                     f"{MAX_SAMPLE_RATE:g} Hz)")
    return DaqSpec(rate, whole["resolution"],
                   f.number("force_range", 10.0, positive=True), f.number("acceleration_range", 500.0, positive=True),
                   ppm, whole["oversample"], passband)


def _generator(f: Fields) -> GeneratorSpec:
    f.unknown_keys({"ramp_cycles", "ramp_time"})
    return GeneratorSpec(f.number("ramp_cycles", 3.0, positive=True), f.number("ramp_time", 0.1, positive=True))


def _simulation(f: Fields, beam: bool) -> SimulationSpec:
    f.unknown_keys({"reduction", "mode_cutoff"})
    reduction = f.string("reduction", "craig-bampton" if beam else "none", REDUCTIONS)
    if reduction != "none" and not beam:
        raise f.error("reduction", "only beam structures are reduced; a lumped rig is integrated as given")
    cutoff = f.number("mode_cutoff", positive=True) if f.has("mode_cutoff") else None
    return SimulationSpec(reduction, cutoff)
