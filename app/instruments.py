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
from analysis.errors import InputError
from drivers.emulator import EmulatedRig, register, set_backend_factory
from drivers.simulation.rig import Rig, builtin_rigs, load_rig
from drivers.simulation.simulator import RigSimulator

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
def real_instruments(shaker_url: str, daq_url: str, excitation_dof: str, sensor_dofs: list[str] | None = None,
                     unguarded: bool = False):
    """Instruments at ``shaker_url`` and ``daq_url`` (port names or pyserial URLs).

    The accelerometer DOFs default to the DAQ's ``acc:<dof>`` channel names. ``unguarded`` lets a bench
    generator arm although nothing would switch it off if this process were killed (docs/protocol.md, 9)."""
    shaker = daq = None
    try:
        shaker = drivers.open_shaker(shaker_url, unguarded=unguarded)
        daq = drivers.open_daq(daq_url)
        dofs = sensor_dofs or [c.split(":", 1)[1] for c in daq.channels if c.startswith("acc:")]
        yield Instruments(shaker, daq, excitation_dof, dofs)
    finally:
        for instrument in (shaker, daq):
            if instrument is not None:
                instrument.close()
