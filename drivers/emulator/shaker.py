"""Firmware of the emulated shaker controller (model SC-1).

A bench-generator command set (``FUNCtion``, ``FREQuency``, ``VOLTage``,
``OUTPut``) mapped onto the rig backend's ``set_sine`` / ``set_noise`` /
``set_output``. The amplitude is held internally as a peak voltage (for noise,
three times the rms: a crest factor of 3) and follows its set value at the ramp
rate, so it never jumps; switching the output off is immediate. Every program
message feeds the watchdog; when the host stays silent longer than the watchdog
time the controller switches its output off by itself and queues error 201.

The host counts as silent when no message arrived for the watchdog time by the
emulated clock *and* by the wall clock. In paced mode the two agree (the wall clock
only keeps a starved emulator from tripping a host whose messages wait to be
processed). In fast mode the emulated clock runs ahead of a host that feeds the
watchdog in real time, and stands still while nobody reads the DAQ; the wall clock
there only tells a host that is gone (silent for FAST_HOST_SILENCE) from one that
is slow. The output goes off at a chunk boundary of the physics.
"""
from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

from ..settings import SC1, Dialect
from .firmware import Firmware
from .scpi_server import (ScpiError, action, expect_one, format_number, limit_query, parse_bool, parse_choice,
                          parse_number, reply_with)

if TYPE_CHECKING:
    from .core import EmulatedRig

MAX_PEAK = SC1.voltage.high / 2
"""Largest drive amplitude (V peak; 20 Vpp)."""
NOISE_CREST = 3.0
"""Peak-to-rms ratio used for noise amplitudes (VPP of noise = 6 x rms)."""
MIN_FREQUENCY = SC1.frequency.low
"""Hz; the upper limit is min(20 kHz, 0.45 x the rig's sample rate)."""
RAMP_LIMITS = (SC1.ramp.low, SC1.ramp.high)
"""Ramp rates accepted (V peak per second)."""
WATCHDOG_LIMITS = (0.01, SC1.watchdog.high)
"""Watchdog times accepted (s); 0 disables the watchdog."""
FAST_HOST_SILENCE = 10.0
"""Fast mode: wall-clock silence (s) after which a host counts as gone. Far above a heartbeat interval: on a
loaded machine a host starved of CPU for a second is slow, not gone, and a fast run must not depend on it."""
DEFAULTS = {"function": "SIN", "frequency": 10.0, "peak": 0.05, "unit": "VPP", "ramp": 2.0,
            "watchdog": 10.0, "band_low": 1.0}
"""The *RST state (output OFF); the noise band is 1 Hz to the upper frequency limit."""
RAMP_STEP = 0.002
"""Ramp update interval (s of emulated time)."""
HOLD_STEP = 0.01
"""Physics chunk in paced mode while no ramp runs (s of emulated time): the watchdog's resolution."""


class ShakerFirmware(Firmware):
    """The shaker controller: source settings, output switch, ramp, watchdog."""

    model = "SC-1"
    min_frequency = MIN_FREQUENCY
    min_peak = 0.0
    max_peak = MAX_PEAK
    dialect: Dialect = SC1

    def __init__(self, rig: "EmulatedRig"):
        super().__init__(rig, "shaker")
        self.max_frequency = min(20e3, 0.45 * rig.sample_rate)
        self.output_on = False
        self.level = 0.0
        self.last_feed = 0.0                      # emulated time of the last message (s)
        self.last_feed_wall = time.monotonic()    # and wall-clock time
        self._defaults()
        self._add_commands()

    def _defaults(self) -> None:
        if self.output_on:
            self.switch_off("*RST")
        self.function = DEFAULTS["function"]
        self.frequency = DEFAULTS["frequency"]
        self.peak = DEFAULTS["peak"]
        self.unit = DEFAULTS["unit"]
        self.ramp_rate = DEFAULTS["ramp"]
        self.watchdog_time = DEFAULTS["watchdog"]
        self.band = (DEFAULTS["band_low"], self.max_frequency)

    # ----- units ---------------------------------------------------------------------------
    def _per_unit(self) -> float:
        """Peak volts per unit of the active VOLTage:UNIT for the active function."""
        if self.unit == "VPP":
            return 0.5
        return NOISE_CREST if self.function == "NOIS" else math.sqrt(2.0)

    def to_unit(self, peak: float) -> float:
        return peak / self._per_unit()

    # ----- physics side (rig lock held) -----------------------------------------------------
    def message_received(self) -> None:
        self.last_feed = self.rig.time
        self.last_feed_wall = time.monotonic()

    def _host_silent(self) -> bool:
        """No message for the watchdog time by the emulated clock, and by the wall clock for the watchdog time
        (paced) or for FAST_HOST_SILENCE at least (fast: only a sign that the host is gone)."""
        wall = self.watchdog_time if self.rig.paced else max(self.watchdog_time, FAST_HOST_SILENCE)
        return (self.rig.time - self.last_feed > self.watchdog_time
                and time.monotonic() - self.last_feed_wall > wall)

    def check_watchdog(self) -> None:
        if self.output_on and self.watchdog_time > 0 and self._host_silent():
            self.switch_off("watchdog")
            self.scpi.errors.push(ScpiError(201))

    @property
    def ramping(self) -> bool:
        return self.output_on and self.level != self.peak

    def chunk_limit(self) -> int:
        """Most samples the physics may advance before the next :meth:`before_chunk`.

        Short while ramping; in paced mode also short otherwise (the watchdog's
        resolution). In fast mode the DAQ asks for one frame at a time, which bounds
        a steady chunk.
        """
        if not self.ramping and not self.rig.paced:
            return 1 << 30
        step = RAMP_STEP if self.ramping else HOLD_STEP
        return max(1, round(step * self.rig.sample_rate))

    def before_chunk(self, duration: float) -> None:
        """Advance the watchdog and the ramp over the next ``duration`` s of physics."""
        self.check_watchdog()
        if self.ramping:
            step = self.ramp_rate * duration
            self.level = min(self.peak, self.level + step) if self.level < self.peak \
                else max(self.peak, self.level - step)
            self._apply()

    def _apply(self) -> None:
        backend = self.rig.backend
        if self.function == "SIN":
            backend.set_sine(self.frequency, self.level)
        else:
            backend.set_noise(self.level / NOISE_CREST, self.band)

    def _silence_other(self) -> None:
        """Zero the generator of the function not in use (the backend keeps both)."""
        backend = self.rig.backend
        if self.function == "SIN":
            backend.set_noise(0.0, self.band)
        else:
            backend.set_sine(self.frequency, 0.0)

    def switch_on(self) -> None:
        if self.output_on:
            return
        self.level = self.start_level()
        self._silence_other()
        self._apply()
        self.rig.backend.set_output(True)
        self.output_on = True
        self.rig.log("shaker", "output", "on")

    def start_level(self) -> float:
        """Peak amplitude at the moment the output switches on: 0, then the ramp."""
        return 0.0

    def switch_off(self, reason: str) -> None:
        if not self.output_on:
            return
        self.rig.backend.set_output(False)
        self.output_on = False
        self.level = 0.0
        self.rig.log("shaker", "output", f"off: {reason}")

    # ----- commands ------------------------------------------------------------------------
    def _add_commands(self) -> None:
        self._add_source_commands()
        add, d = self.scpi.add, self.dialect
        add(d.ramp.header, write=self._set_ramp,
            query=lambda a: format_number(limit_query(a, *RAMP_LIMITS, self.ramp_rate)))
        add("[SOURce:]VOLTage:ACTual", query=reply_with(lambda: format_number(self.to_unit(self.level))))
        add(d.noise_band.header, write=self._set_band,
            query=reply_with(lambda: ",".join(format_number(f) for f in self.band)))
        add(d.watchdog.header, write=self._set_watchdog,
            query=lambda a: format_number(limit_query(a, 0.0, WATCHDOG_LIMITS[1], self.watchdog_time)))
        add("SYSTem:WDOG:FEED", write=action(lambda: None))

    def _add_source_commands(self) -> None:
        """What both dialects share: function, frequency, amplitude and its unit, output switch."""
        add, d = self.scpi.add, self.dialect
        add(d.function.header, write=self._set_function, query=reply_with(lambda: self.function))
        add(d.frequency.header, write=self._set_frequency,
            query=lambda a: format_number(limit_query(a, self.min_frequency, self.max_frequency, self.frequency)))
        add(d.voltage.header, write=self._set_voltage,
            query=lambda a: format_number(self.to_unit(limit_query(a, self.min_peak, self.max_peak, self.peak))))
        add(d.unit.header, write=self._set_unit, query=reply_with(lambda: self.unit))
        add(d.output.header, write=self._set_output, query=reply_with(lambda: "1" if self.output_on else "0"))

    def _set_function(self, args: list[str]) -> None:
        function = parse_choice(expect_one(args), {"SINusoid": "SIN", "NOISe": "NOIS"})
        if function != self.function and self.output_on:
            raise ScpiError(-221, "switch the output off before changing the function")
        self.function = function

    def _set_frequency(self, args: list[str]) -> None:
        self.frequency = parse_number(expect_one(args), self.min_frequency, self.max_frequency,
                                      DEFAULTS["frequency"])
        if self.output_on:
            self._apply()

    def _set_voltage(self, args: list[str]) -> None:
        per_unit = self._per_unit()
        value = parse_number(expect_one(args), self.min_peak / per_unit, self.max_peak / per_unit,
                             DEFAULTS["peak"] / per_unit)
        self.peak = min(self.max_peak, value * per_unit)

    def _set_unit(self, args: list[str]) -> None:
        self.unit = parse_choice(expect_one(args), {"VPP": "VPP", "VRMS": "VRMS"})

    def _set_ramp(self, args: list[str]) -> None:
        self.ramp_rate = parse_number(expect_one(args), *RAMP_LIMITS, DEFAULTS["ramp"])

    def _set_band(self, args: list[str]) -> None:
        if len(args) != 2:
            raise ScpiError(-109 if len(args) < 2 else -108, "expected <low Hz>,<high Hz>")
        low, high = (parse_number(a, MIN_FREQUENCY, self.max_frequency) for a in args)
        if not low < high:
            raise ScpiError(-222, "the low edge must be below the high edge")
        self.band = (low, high)
        if self.output_on and self.function == "NOIS":
            self._apply()

    def _set_output(self, args: list[str]) -> None:
        if parse_bool(expect_one(args)):
            self.rig.recover()
            self.switch_on()
        else:
            self.switch_off("command")

    def _set_watchdog(self, args: list[str]) -> None:
        text = expect_one(args)
        value = parse_number(text, 0.0, WATCHDOG_LIMITS[1], DEFAULTS["watchdog"])
        if 0.0 < value < WATCHDOG_LIMITS[0]:
            raise ScpiError(-222, f"0 (off) or {format_number(WATCHDOG_LIMITS[0])} to {format_number(WATCHDOG_LIMITS[1])} s")
        self.watchdog_time = value
