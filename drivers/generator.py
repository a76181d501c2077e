"""A bench function generator as the shaker controller (Keysight 33210A/33220A/33500B/33600A, Rigol DG).

These generators speak the core of :data:`drivers.settings.GENERATOR` and have neither an
output ramp nor a host watchdog. The driver makes up for the first itself: while the output
is on, every amplitude change is sent as steps of at most ``ramp_rate x RAMP_STEP`` every
:data:`RAMP_STEP` seconds (the call returns when the new amplitude is reached), and the
output switches on at the generator's minimum amplitude, then ramps. While the output is
off the amplitude is held at that minimum, so an ``OUTP ON`` by anyone never jumps.

Nothing on the instrument switches the output off when this process dies. What does is
described by :class:`~drivers.interfaces.Protection`; arming is refused where nothing does unless the driver
was opened with ``unguarded=True`` (docs/protocol.md, section 9).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

from .errors import ArmingRefused, InstrumentError, ProtocolError, WrongDevice
from .guardian import Guardian
from .interfaces import Identity, Protection, in_process
from .scpi import PortIO, ScpiInstrument, SerialLink
from .settings import GENERATOR
from .shaker import SerialShaker, ask_numbers, output_state

RAMP_STEP = 0.02
"""Seconds between two amplitude steps of the driver's ramp."""
DEFAULT_RAMP_RATE = 2.0
"""V peak per second (as the SC-1 after ``*RST``)."""
NOISE_CREST = 3.0
"""Peak-to-rms ratio of noise: a noise rms ramps at ramp_rate / NOISE_CREST (as on the SC-1)."""
HEARTBEAT = 0.25
"""Seconds of silence after which the owner thread asks ``OUTP?`` (link check, output switched off by hand)."""


@dataclass(frozen=True)
class Family:
    """A generator family: how its ``*IDN?`` reads and what it can do.

    Attributes
    ----------
    name : str
        As docs/protocol.md names it.
    manufacturers : tuple of str
        ``*IDN?`` manufacturer fields (case-insensitive).
    model_prefixes : tuple of str
        Model fields start with one of these.
    noise_band : bool
        Has ``FUNC:NOIS:BAND`` (the upper edge of the noise band can be set).
    """

    name: str
    manufacturers: tuple[str, ...]
    model_prefixes: tuple[str, ...]
    noise_band: bool

    def matches(self, identity: Identity) -> bool:
        return (identity.manufacturer.lower() in self.manufacturers
                and identity.model.upper().startswith(self.model_prefixes))


_KEYSIGHT = ("agilent technologies", "keysight technologies")
FAMILIES = (
    Family("Keysight 33500B/33600A", _KEYSIGHT, ("335", "336"), True),
    Family("Keysight 33210A/33220A", _KEYSIGHT, ("3321", "3322"), False),
    Family("Rigol DG", ("rigol technologies",), ("DG",), False),
)
"""The generator families the driver accepts (the ``*IDN?`` reply chooses)."""


def generator_family(identity: Identity) -> Family | None:
    """The family of a generator identity, or None (not a supported generator)."""
    return next((family for family in FAMILIES if family.matches(identity)), None)


def read_identity(link: SerialLink, timeout: float) -> Identity:
    """Clear the line and ask ``*IDN?``: which shaker dialect answers at ``link``."""
    scpi = ScpiInstrument(link, timeout)

    def ask(io: PortIO) -> str:
        scpi.clear(io)
        return scpi.ask(io, "*IDN?", 2 * timeout)

    reply = link.call(ask, 4 * timeout + 2)
    identity = Identity.parse(reply)
    if identity is None:
        raise WrongDevice(link.url, f"*IDN? answered {reply!r}, which is not an IEEE 488.2 identity: not a shaker")
    return identity


class GeneratorShaker(SerialShaker):
    """A :class:`~drivers.interfaces.ShakerController` on a bench function generator.

    Parameters
    ----------
    url : str
        Port name or pyserial URL (``socket://host:5025`` for a LAN generator).
    baudrate, timeout, port, link :
        As :class:`~drivers.shaker.SerialShaker`.
    ramp_rate : float
        V peak per second of the driver's ramp.
    unguarded : bool
        Arm although nothing would switch the output off if this process were killed.
    guardian : Guardian, optional
        The guardian process ``link`` goes through (:func:`open_generator` starts it); waited for on close.

    Raises
    ------
    LinkLost, LinkTimeout, WrongDevice, DeviceError
        As :class:`~drivers.shaker.SerialShaker`; WrongDevice for an instrument of no
        supported family.
    """

    def __init__(self, url: str, *, baudrate: int = 115200, timeout: float = 1.0,
                 ramp_rate: float = DEFAULT_RAMP_RATE, unguarded: bool = False, port=None,
                 link: SerialLink | None = None, guardian: Guardian | None = None):
        self.unguarded = bool(unguarded)
        self.guardian = guardian
        self.family: Family | None = None
        self._sent = 0.0          # amplitude last sent, in the function's unit (V peak sine, V rms noise)
        self._target = 0.0        # amplitude asked for, same unit
        self._floor = 0.0         # the generator's minimum amplitude, same unit
        super().__init__(url, baudrate=baudrate, timeout=timeout, watchdog=0.0, port=port, link=link)
        self.set_ramp_rate(ramp_rate)
        self.protection = Protection(instrument_ramp=False, instrument_watchdog=False,
                                     dies_with_host=in_process(url), guardian=guardian is not None)

    def heartbeat_interval(self) -> float:
        return HEARTBEAT

    def _connect(self, io: PortIO, models: tuple[str, ...]) -> Identity:
        scpi = self._scpi
        scpi.clear(io)
        reply = scpi.ask(io, "*IDN?", 2 * scpi.timeout)
        identity = Identity.parse(reply)
        self.family = generator_family(identity) if identity is not None else None
        if self.family is None:
            raise WrongDevice(self.url, f"*IDN? answered {reply!r}: not a supported function generator "
                                        f"({', '.join(f.name for f in FAMILIES)})")
        scpi.execute(io, "*RST;*CLS")
        scpi.execute(io, "OUTP OFF;:FUNC SIN;:VOLT:UNIT VPP;:VOLT MIN")
        scpi.expect(io, {"OUTP?": lambda r: output_state(self.url, r) is False}, "*RST")
        f_min, f_max, vpp_min, vpp_max = ask_numbers(scpi, io, "FREQ? MIN;:FREQ? MAX;:VOLT? MIN;:VOLT? MAX")
        self.frequency_range = (f_min, f_max)
        self.amplitude_range = (0.0, vpp_max / 2)
        self._floor = self._sent = vpp_min / 2
        return identity

    # ----- settings ------------------------------------------------------------------------
    def _level_command(self, level: float) -> str:
        """``VOLT`` of a level in the function's unit (sine: V peak sent as Vpp; noise: V rms)."""
        value = max(level, self._floor)
        return GENERATOR.voltage.command(2.0 * value if self._function == "SIN" else value)

    def _check_level(self, level: float, what: str) -> float:
        """``level`` within [0, the generator's maximum]: the generator would clip it without stopping."""
        level = float(level)
        high = self.amplitude_range[1] if self._function == "SIN" else self.amplitude_range[1] / NOISE_CREST
        if not 0.0 <= level <= high:
            raise InstrumentError(self.url, f"{what} {level:g} V is outside 0 to {high:g} V")
        return level

    def set_sine(self, frequency: float, amplitude: float) -> None:
        """Sine of ``frequency`` Hz and ``amplitude`` V peak; while armed the driver ramps to it."""
        self._require_function("SIN")
        low, high = self.frequency_range
        if not low <= float(frequency) <= high:     # the generator would clip it and carry on
            raise InstrumentError(self.url, f"frequency {float(frequency):g} Hz is outside {low:g} to {high:g} Hz")
        frequency = GENERATOR.frequency.command(frequency)
        if self._function != "SIN":
            self._function = "SIN"
            self._select("FUNC SIN;:VOLT:UNIT VPP;:VOLT MIN;:VOLT? MIN")
        self._target = self._check_level(amplitude, "sine amplitude")
        self._scpi.command(frequency)
        self._follow()

    def set_noise(self, rms: float, band: tuple[float, float]) -> None:
        """Noise of ``rms`` V from DC to ``band[1]`` Hz (the generator cannot set a low edge); families without
        a noise band setting refuse it."""
        self._require_function("NOIS")
        if self.family is None or not self.family.noise_band:
            raise InstrumentError(self.url, f"a {self.family.name if self.family else 'generator'} cannot limit "
                                            "its noise band: random excitation needs a 33500B/33600A")
        if self._function != "NOIS":
            self._function = "NOIS"
            self._select("FUNC NOIS;:VOLT:UNIT VRMS;:VOLT MIN;:VOLT? MIN")
        self._target = self._check_level(rms, "noise rms")
        self._scpi.command(GENERATOR.noise_band.command(float(band[1])))
        self._follow()

    def _select(self, message: str) -> None:
        """Switch the function (output off) at the minimum amplitude; reads that minimum in the new unit."""
        reply = self._scpi.query(message)
        try:
            self._floor = self._sent = float(reply) / (2.0 if self._function == "SIN" else 1.0)
        except ValueError:
            raise ProtocolError(self.url, f"VOLT? MIN answered {reply!r}") from None

    def set_ramp_rate(self, volts_per_second: float) -> None:
        """Largest rate of change of the peak amplitude (V/s) of the driver's ramp."""
        rate = float(volts_per_second)
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"ramp rate must be > 0 V/s, got {volts_per_second!r}")
        self.ramp_rate = rate

    def _follow(self) -> None:
        """Bring the generator to the target level: ramped while armed, held at the minimum otherwise."""
        if self._armed:
            self._ramp_to(self._target)
        elif self._sent != self._floor:
            self._scpi.command(self._level_command(self._floor))
            self._sent = self._floor

    def _ramp_to(self, target: float) -> None:
        """Steps of at most ramp_rate x RAMP_STEP (V peak) every RAMP_STEP s; stops if disarmed meanwhile."""
        rate = self.ramp_rate if self._function == "SIN" else self.ramp_rate / NOISE_CREST
        start = self._sent
        steps = max(1, math.ceil(abs(target - start) / (rate * RAMP_STEP)))
        began = time.monotonic()
        for step in range(1, steps + 1):
            if not self._armed:
                return
            level = start + (target - start) * step / steps
            self._scpi.command(self._level_command(level))
            self._sent = max(level, self._floor)
            pause = began + step * RAMP_STEP - time.monotonic()
            if step < steps and pause > 0:
                time.sleep(pause)

    # ----- output --------------------------------------------------------------------------
    def arm(self) -> None:
        """Switch the output on at the minimum amplitude and ramp to the set one (only inside an OutputGuard,
        and only where something switches it off if this process dies, unless ``unguarded``)."""
        if self._guard is not None and not self.protection.survives_kill and not self.unguarded:
            raise ArmingRefused(self.url, f"nothing switches this {self.family.name} off if this process is "
                                          "killed (no instrument watchdog): arm with --unguarded to accept it")
        super().arm()
        self._ramp_to(self._target)

    def disarm(self) -> None:
        """Switch the output off, verify it, and set the minimum amplitude for the next switch-on."""
        super().disarm()
        self._scpi.command(self._level_command(self._floor))
        self._sent = self._floor

    def output_level(self) -> float:
        """The amplitude the generator outputs now: V peak (sine) or V rms (noise); 0 when off."""
        reply = self._scpi.query("OUTP?;:VOLT?")
        try:
            state, volts = reply.split(";")
            value = float(volts)
        except ValueError:
            raise ProtocolError(self.url, f"OUTP?;:VOLT? answered {reply!r}") from None
        if not output_state(self.url, state):
            return 0.0
        return value / 2 if self._function == "SIN" else value

    def close(self) -> None:
        """Switch the output off and release the port; the guardian then switches off once more and exits."""
        try:
            super().close()
        finally:
            if self.guardian is not None:
                self.guardian.wait()


def open_generator(url: str, link: SerialLink, *, baudrate: int, timeout: float, guardian: bool = True,
                   unguarded: bool = False, **options) -> GeneratorShaker:
    """The generator identified on ``link``: through a guardian process unless it lives in this process (or
    ``guardian`` is False: it then arms only if ``unguarded``).

    ``link`` is handed over (closed here before the guardian opens the instrument: many generators serve one
    connection only). A guardian that does not start is an InstrumentError, unless ``unguarded``: the generator
    is then opened directly."""
    if in_process(url) or not guardian:
        return GeneratorShaker(url, timeout=timeout, link=link, unguarded=unguarded, **options)
    link.close()
    try:
        process = Guardian.start(url, baudrate)
    except OSError as exc:
        if not unguarded:
            raise InstrumentError(url, f"{exc}; without it nothing switches the output off if this process is "
                                       "killed (--unguarded runs without it)") from None
        return GeneratorShaker(url, timeout=timeout, baudrate=baudrate, unguarded=True, **options)
    try:
        return GeneratorShaker(url, timeout=timeout, link=SerialLink(process.url, name="shaker"),
                               guardian=process, unguarded=unguarded, **options)
    except BaseException:
        process.wait()
        raise
