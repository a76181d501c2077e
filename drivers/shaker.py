"""The shaker controller driver: SCPI over any pyserial URL.

Opening the driver clears the line (a previous client's half-written command and late
replies are dropped), identifies the instrument (``*IDN?``), resets it (``*RST;*CLS``),
sets the watchdog and reads back that the output is OFF at zero amplitude, the error
queue empty and the watchdog set -- every connection starts from the same known state --
then reads the ranges. While the port is otherwise
silent the owner thread sends a heartbeat (``OUTP?``) every quarter of the
watchdog time: it feeds the watchdog, detects a dead link and notices an output
the instrument switched off by itself (reported as :class:`OutputTripped`).
Sine amplitudes are given in volts peak (sent as VPP), noise in volts rms (sent as
VRMS). Commands come from the settings table :data:`drivers.settings.SC1`, which refuses
(ValueError) a value outside the limits it declares before anything is sent; every
setting is confirmed by reading the error queue in the same round trip, so a rejected
setting raises :class:`DeviceError` at once.
"""
from __future__ import annotations

from typing import Callable

import serial

from .errors import ArmingRefused, InstrumentError, LinkLost, OutputTripped, ProtocolError
from .interfaces import Identity, Protection, in_process
from .scpi import PortIO, ScpiInstrument, SerialLink
from .settings import SC1

MANUFACTURER = "contactid"
SHAKER_MODELS = ("SC-1",)


def _number(value) -> str:
    """A number as SCPI <NRf> text, whatever numeric type it arrives as (numpy's repr is not a number)."""
    return repr(float(value))


def _is_zero(reply: str) -> bool:
    return _close_to(reply, 0.0)


def _close_to(reply: str, value: float) -> bool:
    try:
        return abs(float(reply) - value) <= 1e-9 * max(1.0, abs(value))
    except ValueError:
        return False


def output_state(url: str, reply: str) -> bool:
    """An ``OUTP?`` reply as on (True) or off: ``0``/``1`` (SC-1, Keysight, sign allowed) or ``OFF``/``ON``
    (Rigol); ProtocolError otherwise."""
    text = reply.strip().lstrip("+").upper()
    if text in ("1", "ON"):
        return True
    if text in ("0", "OFF"):
        return False
    raise ProtocolError(url, f"OUTP? answered {reply!r}")


def ask_numbers(scpi: ScpiInstrument, io: PortIO, queries: str) -> list[float]:
    """The replies to a message of numeric queries (``FREQ? MIN;:FREQ? MAX``); ProtocolError if one is not."""
    reply = scpi.ask(io, queries)
    try:
        return [float(x) for x in reply.split(";")]
    except ValueError:
        raise ProtocolError(scpi.url, f"range queries answered {reply!r}") from None


class SerialShaker:
    """A :class:`~drivers.interfaces.ShakerController` on a serial link.

    Parameters
    ----------
    url : str
        Port name or pyserial URL (``/dev/ttyUSB0``, ``socket://host:5025``,
        ``sim://bench/shaker``).
    baudrate : int
        Line rate of a real serial port.
    timeout : float
        Deadline for each reply (s).
    watchdog : float
        Instrument watchdog time (s): the instrument switches its output off when
        the host is silent longer than this. 0 disables it (not recommended).
    models : tuple of str
        ``*IDN?`` model fields accepted.
    port : serial.SerialBase, optional
        An open port to use instead of opening ``url`` (scripted-port tests).
    link : SerialLink, optional
        An open link to own instead (``drivers.open_shaker`` identified the instrument on it).

    Raises
    ------
    LinkLost, LinkTimeout, WrongDevice, DeviceError
        The port cannot be opened, does not answer, is another instrument, or
        rejects the setup.
    """

    def __init__(self, url: str, *, baudrate: int = 115200, timeout: float = 1.0, watchdog: float = 1.0,
                 models: tuple[str, ...] = SHAKER_MODELS, port: serial.SerialBase | None = None,
                 link: SerialLink | None = None):
        self.url = url
        self.watchdog = float(watchdog)
        self._link = link if link is not None else SerialLink(url, name="shaker", baudrate=baudrate, port=port)
        self._scpi = ScpiInstrument(self._link, timeout)
        self._armed = False
        self._function = "SIN"
        self._guard: object | None = None
        self._listeners: list[Callable[[InstrumentError], None]] = []
        self.fault: InstrumentError | None = None
        try:
            self.identity: Identity = self._link.call(lambda io: self._connect(io, models), 4 * timeout + 2)
        except BaseException:
            self._link.close()
            raise
        self._link.set_idle_hook(self._heartbeat, self.heartbeat_interval())
        self.protection = Protection(instrument_ramp=True, instrument_watchdog=self.watchdog > 0,
                                     dies_with_host=in_process(url))

    def heartbeat_interval(self) -> float:
        """Seconds of silence after which the owner thread asks ``OUTP?``: a quarter of the watchdog time."""
        return self.watchdog / 4 if self.watchdog > 0 else 1.0

    def _connect(self, io: PortIO, models: tuple[str, ...]) -> Identity:
        scpi = self._scpi
        scpi.clear(io)
        identity = scpi.identify(io, MANUFACTURER, models, "contactid shaker controller", 2 * scpi.timeout)
        scpi.execute(io, f"*RST;*CLS;:{SC1.watchdog.command(self.watchdog)}")
        scpi.expect(io, {"OUTP?": lambda r: r == "0", "VOLT:ACT?": _is_zero, "SYST:ERR:COUN?": lambda r: r == "0",
                         "SYST:WDOG?": lambda r: _close_to(r, self.watchdog)}, "*RST")
        f_min, f_max, vpp_max, ramp = ask_numbers(scpi, io,
                                                  "FREQ? MIN;:FREQ? MAX;:VOLT:UNIT VPP;:VOLT? MAX;:VOLT:RAMP?")
        self.frequency_range = (f_min, f_max)
        self.amplitude_range = (0.0, vpp_max / 2)
        self.ramp_rate = ramp
        return identity

    # ----- settings ------------------------------------------------------------------------
    def set_sine(self, frequency: float, amplitude: float) -> None:
        """Sine of ``frequency`` Hz and ``amplitude`` V peak; the instrument ramps to it."""
        self._require_function("SIN")
        self._scpi.command(f"{SC1.function.command('SIN')};:{SC1.unit.command('VPP')};"
                           f":{SC1.frequency.command(frequency)};:{SC1.voltage.command(2.0 * amplitude)}")
        self._function = "SIN"

    def set_noise(self, rms: float, band: tuple[float, float]) -> None:
        """Gaussian noise of ``rms`` V in the pass band ``band = (low, high)`` Hz."""
        self._require_function("NOIS")
        low, high = (float(f) for f in band)
        self._scpi.command(f"FUNC NOIS;:VOLT:UNIT VRMS;:FUNC:NOIS:BAND {_number(low)},{_number(high)};"
                           f":VOLT {_number(rms)}")
        self._function = "NOIS"

    def _require_function(self, function: str) -> None:
        if self._armed and function != self._function:
            raise InstrumentError(self.url, "disarm before switching between sine and noise")

    def set_ramp_rate(self, volts_per_second: float) -> None:
        """Largest rate of change of the peak amplitude (V/s)."""
        self._scpi.command(SC1.ramp.command(volts_per_second))
        self.ramp_rate = float(volts_per_second)

    # ----- output --------------------------------------------------------------------------
    def attach_guard(self, guard: object | None) -> None:
        """Called by :class:`drivers.safety.OutputGuard` on entry (guard) and exit (None)."""
        self._guard = guard

    def arm(self) -> None:
        """Switch the output on; only inside an OutputGuard (ArmingRefused otherwise)."""
        if self._guard is None:
            raise ArmingRefused(self.url, "arming needs an active OutputGuard "
                                          "(with OutputGuard(shaker) as guard: guard.arm())")
        self.fault = None
        self._scpi.command("OUTP ON")
        self._armed = True

    def disarm(self) -> None:
        """Switch the output off and verify that it is off."""
        self._armed = False

        def off(io: PortIO) -> str:
            self._scpi.execute(io, "OUTP OFF")
            return self._scpi.ask(io, "OUTP?")

        if output_state(self.url, self._link.call(off, self._scpi.reply_wait(2))):
            raise InstrumentError(self.url, "output still on after OUTP OFF")

    @property
    def armed(self) -> bool:
        """Whether the host has armed the output and nothing has switched it off since."""
        return self._armed

    def output_enabled(self) -> bool:
        return output_state(self.url, self._scpi.query("OUTP?"))

    def output_level(self) -> float:
        """The amplitude being output now: V peak (sine) or V rms (noise); 0 when off."""
        level = self._scpi.query_float("VOLT:ACT?")
        return level / 2 if self._function == "SIN" else level

    def emergency_off(self, timeout: float = 0.25) -> bool:
        """Send ``OUTP OFF`` ahead of anything queued; True once written. Signal-handler safe."""
        self._armed = False
        return self._link.emergency_write(b"OUTP OFF\n", timeout)

    def errors(self) -> list:
        """Empty the instrument's error queue (entries oldest first)."""
        return self._scpi.errors()

    # ----- faults --------------------------------------------------------------------------
    def add_fault_listener(self, listener: Callable[[InstrumentError], None]) -> None:
        """Call ``listener(error)`` (on the port's thread) when the heartbeat finds a fault."""
        self._listeners.append(listener)

    def remove_fault_listener(self, listener: Callable[[InstrumentError], None]) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    def check(self) -> None:
        """Raise the fault the heartbeat found (output tripped, link lost), if any."""
        if self.fault is not None:
            raise self.fault
        if self._link.failure is not None:
            raise self._link.failure

    def _report(self, error: InstrumentError) -> None:
        self.fault = error
        for listener in list(self._listeners):
            listener(error)

    def _heartbeat(self, io: PortIO) -> None:
        try:
            on = output_state(self.url, self._scpi.ask(io, "OUTP?"))
            if self._armed and not on:
                self._armed = False
                errors = self._scpi.drain_errors(io)
                reason = "; ".join(str(e) for e in errors) or "no error reported"
                self._report(OutputTripped(self.url, f"output switched off by the instrument ({reason})"))
        except InstrumentError as exc:
            self._report(exc)
            raise

    def close(self) -> None:
        """Switch the output off (if the link still works) and release the port.

        A link found dead on the way is not an error here: the instrument's watchdog
        switches the output off when the heartbeats stop.
        """
        try:
            if self._link.alive:
                self.disarm()
        except LinkLost:
            pass  # see docstring
        finally:
            self._link.close()

    def __enter__(self) -> "SerialShaker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
