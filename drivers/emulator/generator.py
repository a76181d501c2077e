"""Firmware of an emulated bench function generator (Keysight 33500B series, model 33521B).

It answers the generator dialect of :data:`drivers.settings.GENERATOR` and behaves as
such a generator does, not as the SC-1: no output ramp (a new amplitude applies at
once, and the output switches on at the set amplitude), no watchdog (a silent or dead
host leaves the output on), an out-of-range value is clipped to the limit and
queues ``-222,"Data out of range;value clipped to upper limit"`` (the SC-1 rejects
it), and the noise band has only an upper edge (``FUNC:NOIS:BAND <Hz>``). The load
is high impedance: amplitudes from 2 mVpp to 20 Vpp.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..settings import GENERATOR, Dialect
from .scpi_server import ScpiError, expect_one, format_number, match_keyword, parse_number, reply_with
from .shaker import ShakerFirmware

if TYPE_CHECKING:
    from .core import EmulatedRig

MANUFACTURER = "Keysight Technologies"
MODEL = "33521B"
BANDWIDTH = 30e6
"""Hz: the model's sine and noise bandwidth (the emulated rig's own limit, 0.45 fs, is lower)."""
AMPLITUDE_VPP = (0.002, 20.0)
"""Amplitude limits into a high-impedance load (Vpp)."""
NOISE_LOW_EDGE = 0.5
"""Hz: the generator's noise starts at DC; the rig physics needs a band inside (0, Nyquist)."""


class GeneratorFirmware(ShakerFirmware):
    """A 33500B-series generator: source settings and output switch, nothing that protects the shaker."""

    model = MODEL
    manufacturer = MANUFACTURER
    min_frequency = GENERATOR.frequency.low
    min_peak = AMPLITUDE_VPP[0] / 2
    max_peak = AMPLITUDE_VPP[1] / 2
    dialect: Dialect = GENERATOR

    def __init__(self, rig: "EmulatedRig"):
        super().__init__(rig)
        self.max_frequency = min(BANDWIDTH, 0.45 * rig.sample_rate)
        self.band = (NOISE_LOW_EDGE, self.max_frequency)

    def _defaults(self) -> None:
        super()._defaults()
        self.watchdog_time = 0.0
        self.band = (NOISE_LOW_EDGE, self.max_frequency)

    # ----- no ramp, no watchdog -----------------------------------------------------------
    def start_level(self) -> float:
        return self.peak

    def check_watchdog(self) -> None:
        """There is none: the output stays on whatever the host does."""

    def _add_commands(self) -> None:
        self._add_source_commands()
        self.scpi.add(self.dialect.noise_band.header, write=self._set_band,
                      query=reply_with(lambda: format_number(self.band[1])))

    # ----- values are clipped, not rejected ------------------------------------------------
    def _clipped(self, text: str, low: float, high: float, default: float) -> float:
        """The value of ``text`` clipped to [low, high]; the clip queues -222 as the 33500B does."""
        value = parse_number(text, float("-inf"), float("inf"), default)
        if match_keyword(text, {"MINimum": "MIN"}):
            value = low
        elif match_keyword(text, {"MAXimum": "MAX"}):
            value = high
        if value > high:
            self.scpi.errors.push(ScpiError(-222, "value clipped to upper limit"))
            return high
        if value < low:
            self.scpi.errors.push(ScpiError(-222, "value clipped to lower limit"))
            return low
        return value

    def _set_frequency(self, args: list[str]) -> None:
        self.frequency = self._clipped(expect_one(args), self.min_frequency, self.max_frequency, 1e3)
        if self.output_on:
            self._apply()

    def _set_voltage(self, args: list[str]) -> None:
        per_unit = self._per_unit()
        value = self._clipped(expect_one(args), self.min_peak / per_unit, self.max_peak / per_unit, 0.05)
        self.peak = value * per_unit
        if self.output_on:
            self.level = self.peak
            self._apply()

    def _set_band(self, args: list[str]) -> None:
        high = self._clipped(expect_one(args), self.dialect.noise_band.low, self.max_frequency, self.max_frequency)
        self.band = (NOISE_LOW_EDGE, max(high, 2 * NOISE_LOW_EDGE))
        if self.output_on and self.function == "NOIS":
            self._apply()
