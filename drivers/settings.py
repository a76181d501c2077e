"""Every SCPI setting of the shaker dialects, declared once: header, limits, meaning.

Both sides read this table: the drivers build their commands from :meth:`Setting.command`
and refuse a value outside the declared limits before it is sent; the emulated
instruments register the same headers and reject the same values (error -222). A
limit of ``None`` is the instrument's own (``FREQ? MAX`` reads it).

``SC1`` is the project's shaker controller; ``GENERATOR`` the core that Keysight
33210A/33220A/33500B/33600A and Rigol DG generators share (docs/protocol.md, section 9).
"""
from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Setting:
    """One SCPI setting.

    Attributes
    ----------
    header : str
        Header pattern, short form in capitals, optional nodes in ``[ ]`` (as the emulator registers it).
    low, high : float or None
        Accepted range (None: the instrument's own, read with ``? MIN`` / ``? MAX``).
    unit : str
        Unit of the value as sent.
    doc : str
        What the setting does.
    choices : tuple of str
        Keywords accepted instead of a number (empty for numeric settings).
    """

    header: str
    low: float | None
    high: float | None
    unit: str
    doc: str
    choices: tuple[str, ...] = ()

    @property
    def short(self) -> str:
        """The short form the drivers send (``[SOURce:]FREQuency`` -> ``FREQ``)."""
        required = re.sub(r"\[[^\]]*\]", "", self.header)
        return ":".join("".join(ch for ch in node if ch.isupper() or ch == "*") for node in required.split(":"))

    def check(self, value: float) -> float:
        """``value`` as a float; ValueError naming the setting if outside its declared limits."""
        value = float(value)
        if (self.low is not None and value < self.low) or (self.high is not None and value > self.high):
            raise ValueError(f"{self.short} {value:g} {self.unit} is outside {self.low:g} to {self.high:g}")
        return value

    def command(self, value: float | str) -> str:
        """The program message unit setting ``value`` (a number checked against the limits, or a choice)."""
        if self.choices:
            if value not in self.choices:
                raise ValueError(f"{self.short} takes {'|'.join(self.choices)}, not {value!r}")
            return f"{self.short} {value}"
        return f"{self.short} {self.check(value)!r}"


@dataclass(frozen=True)
class Dialect:
    """The settings of one shaker dialect."""

    function: Setting
    frequency: Setting
    voltage: Setting
    unit: Setting
    output: Setting
    noise_band: Setting | None
    ramp: Setting | None
    watchdog: Setting | None


SC1 = Dialect(
    function=Setting("[SOURce:]FUNCtion", None, None, "", "waveform", ("SIN", "NOIS")),
    frequency=Setting("[SOURce:]FREQuency", 0.01, None, "Hz", "sine frequency; MAX is min(20 kHz, 0.45 fs)"),
    voltage=Setting("[SOURce:]VOLTage[:AMPLitude]", 0.0, 20.0, "Vpp",
                    "amplitude the output ramps to, in VOLT:UNIT (limit given in Vpp: 10 V peak)"),
    unit=Setting("[SOURce:]VOLTage:UNIT", None, None, "", "unit of VOLT", ("VPP", "VRMS")),
    output=Setting("OUTPut[:STATe]", None, None, "", "output switch", ("ON", "OFF")),
    noise_band=Setting("[SOURce:]FUNCtion:NOISe:BANDwidth", 0.01, None, "Hz", "noise pass band <low>,<high>"),
    ramp=Setting("[SOURce:]VOLTage:RAMP", 0.001, 1000.0, "V/s", "largest rate of change of the peak amplitude"),
    watchdog=Setting("SYSTem:WDOG[:TIME]", 0.0, 3600.0, "s",
                     "output off after this long without a host message; 0 off, else at least 0.01"),
)
"""The SC-1 shaker controller (docs/protocol.md, section 5)."""

GENERATOR = Dialect(
    function=Setting("[SOURce:]FUNCtion", None, None, "", "waveform", ("SIN", "NOIS")),
    frequency=Setting("[SOURce:]FREQuency", 1e-6, None, "Hz", "sine frequency (MAX: the model's bandwidth)"),
    voltage=Setting("[SOURce:]VOLTage[:AMPLitude]", None, None, "Vpp",
                    "amplitude, applied at once (no ramp), in VOLT:UNIT; MIN/MAX are the model's"),
    unit=Setting("[SOURce:]VOLTage:UNIT", None, None, "", "unit of VOLT", ("VPP", "VRMS")),
    output=Setting("OUTPut[:STATe]", None, None, "", "output switch", ("ON", "OFF")),
    noise_band=Setting("[SOURce:]FUNCtion:NOISe:BANDwidth", 1e-3, None, "Hz",
                       "upper edge of the noise band (33500B/33600A only; noise starts at DC)"),
    ramp=None,
    watchdog=None,
)
"""The bench function generator core (docs/protocol.md, section 9): no ramp, no watchdog."""
