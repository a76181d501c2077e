"""Opening the instruments for a campaign: emulated in-process (a rig) or real (URLs).

Either way the campaign gets driver objects opened by URL -- the emulated ones through ``sim://`` -- so the
same code path runs in CI, in the demo and at the bench.
"""
from __future__ import annotations

import itertools
import os
from contextlib import contextmanager
from dataclasses import dataclass

from typing import Any, Mapping

import drivers
from analysis.common.errors import InputError
from drivers.emulator import EmulatedRig, register, set_backend_factory
from drivers.simulation.rig import Rig, builtin_rigs, load_rig
from drivers.simulation.simulator import RigSimulator

from app.campaign.plan import Placement

_names = itertools.count()


def builtin_backend(name: str, seed: int | None) -> tuple[Any, Mapping[str, Any]]:
    """The rig simulator of built-in rig ``name`` and its ``[faults]`` table: what a ``sim://NAME/...`` URL
    reaches when no rig of that name runs in this process."""
    if name not in builtin_rigs():
        raise InputError(f"no emulated rig named {name!r} is running in this process, and no built-in rig "
                         f"has that name (built-in: {', '.join(builtin_rigs())})")
    rig = load_rig(name)
    return RigSimulator(rig, seed=seed), rig.faults


# the emulator is handed its physics here, so that drivers/ never imports the simulation it emulates
set_backend_factory(builtin_backend)


@dataclass
class Instruments:
    shaker: object
    daq: object
    excitation_dof: str
    sensor_dofs: list[str]
    rig: Rig | None = None
    emulator: EmulatedRig | None = None

    def identities(self) -> dict:
        return {"shaker": {"url": self.shaker.url, "idn": str(self.shaker.identity)},
                "daq": {"url": self.daq.url, "idn": str(self.daq.identity)}}


@contextmanager
def emulated_instruments(rig: Rig, seed: int = 0, paced: bool = False, faults: dict | None = None,
                         shaker_model: str = "SC-1"):
    """The rig's emulated shaker controller (``shaker_model``: SC-1 or a 33500B generator) and DAQ, opened
    through ``sim://`` URLs."""
    name = f"{rig.name}-{os.getpid()}-{next(_names)}"
    simulator = RigSimulator(rig, seed=seed)
    # compile (or load) the physics kernels now, at rest with the output off: a first compile inside the
    # running emulator would stall its replies for seconds
    simulator.advance(1)
    with EmulatedRig(simulator, paced=paced, name=name,
                     faults=rig.faults if faults is None else faults, shaker_model=shaker_model) as emulator:
        register(emulator)
        shaker = daq = None
        try:
            shaker = drivers.open_shaker(f"sim://{name}/shaker")
            daq = drivers.open_daq(f"sim://{name}/daq")
            yield Instruments(shaker, daq, rig.excitation_dof, list(rig.sensor_dofs), rig, emulator)
        finally:
            for instrument in (shaker, daq):
                if instrument is not None:
                    instrument.close()


@contextmanager
def real_instruments(shaker_url: str, daq_url: str, excitation_dof: str | None = None,
                     sensor_dofs: list[str] | None = None, placement: Placement | None = None,
                     unguarded: bool = False):
    """Instruments at ``shaker_url`` and ``daq_url`` (port names or pyserial URLs).

    The DOFs come from ``placement`` (a plan's, with flags applied) or else from ``excitation_dof`` and
    ``sensor_dofs``; the accelerometer DOFs default to the DAQ's ``acc:<dof>`` channel names. They are checked
    against the DAQ's channels before anything is measured (:func:`check_placement`). ``unguarded`` lets a bench
    generator arm although nothing would switch it off if this process were killed (docs/protocol.md, 9)."""
    if placement is None:
        placement = Placement(excitation_dof, sensor_dofs, excitation_field="excitation DOF",
                              sensors_field="sensor DOFs")
    shaker = daq = None
    try:
        shaker = drivers.open_shaker(shaker_url, unguarded=unguarded)
        daq = drivers.open_daq(daq_url)
        excitation, sensors = check_placement(daq.channels, daq.url, placement)
        yield Instruments(shaker, daq, excitation, sensors)
    finally:
        for instrument in (shaker, daq):
            if instrument is not None:
                instrument.close()


def check_placement(channels, daq_url: str, place: Placement) -> tuple[str, list[str]]:
    """The excitation and sensor DOFs of a campaign on real instruments, checked against the DAQ's channels.

    Every sensor DOF needs an ``acc:<dof>`` channel and the force gauge a ``force`` channel; the excitation DOF
    must carry an accelerometer too (the driving-point FRF every modal test measures) unless
    ``place.driving_point`` is false -- that is what catches a misspelt excitation DOF before the first line
    rather than at analysis. Sensors default to the DAQ's accelerometers.
    """
    channels = list(channels)
    accelerometers = [c.split(":", 1)[1] for c in channels if c.startswith("acc:")]
    have = f"the DAQ at {daq_url} has channels {', '.join(channels)}"
    if "force" not in channels:
        raise InputError(f"{have}: none is the force gauge (a channel named force)")
    sensors = list(place.sensor_dofs) if place.sensor_dofs else accelerometers
    if not sensors:
        raise InputError(f"{have}: no accelerometer (acc:<dof>)")
    missing = [d for d in sensors if d not in accelerometers]
    if missing:
        raise InputError(f"sensor DOF {missing[0]!r} has no accelerometer channel acc:{missing[0]} ({have})",
                         place.origin(place.sensors_field), place.sensors_field)
    excitation = place.excitation_dof
    if not excitation:
        raise InputError("no excitation DOF: say where the force gauge sits with [excitation] dof = \"...\" in "
                         "the plan or --excitation DOF", place.source)
    if place.driving_point and excitation not in sensors:
        raise InputError(f"excitation DOF {excitation!r} carries no accelerometer (sensors: {', '.join(sensors)}): "
                         "a misspelt DOF? If the force gauge really sits where nothing is measured, set "
                         "[excitation] driving_point = false in the plan",
                         place.origin(place.excitation_field), place.excitation_field)
    return excitation, sensors
