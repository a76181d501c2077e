"""Emulated instruments: firmware-like behaviour of the shaker controller and the DAQ.

Both run on one physics backend (the rig simulator, or any object with its
interface, see :mod:`drivers.emulator.core`) and are reached through byte links:
in process by ``sim://<rig>/<instrument>`` URLs, out of process over pseudo
terminals or TCP (:mod:`drivers.serve`).

Example::

    rig = register(EmulatedRig(RigSimulator("paper-2dof"), paced=False, name="bench").start())
    shaker = drivers.open_shaker("sim://bench/shaker")
    daq = drivers.open_daq("sim://bench/daq")
"""
from .core import EmulatedRig, EmulatorEvent, LinkBusy
from .link import InstrumentLink, LinkDropped
from .registry import find_rig, open_sim_link, parse_sim_url, register, set_backend_factory

__all__ = ["EmulatedRig", "EmulatorEvent", "InstrumentLink", "LinkBusy", "LinkDropped", "find_rig",
           "open_sim_link", "parse_sim_url", "register", "set_backend_factory"]
