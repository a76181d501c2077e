"""Finding the instruments: list serial ports and ask each one ``*IDN?``.

Probing only sends ``*IDN?`` (harmless to any SCPI instrument) and reads one line
with a deadline, so a port with nothing behind it, or with another kind of device,
costs at most the timeout.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from serial.tools import list_ports

from .daq import DAQ_MODELS
from .daq import MANUFACTURER as DAQ_MANUFACTURER
from .errors import InstrumentError
from .generator import generator_family
from .interfaces import Identity
from .scpi import ScpiInstrument, SerialLink
from .shaker import MANUFACTURER as SHAKER_MANUFACTURER
from .shaker import SHAKER_MODELS


@dataclass(frozen=True)
class Probe:
    """What one port answered.

    Attributes
    ----------
    url : str
        Port name or URL probed.
    role : str or None
        ``"shaker"``, ``"daq"`` or None (not a contactid instrument, or no answer).
    identity : Identity or None
        The parsed ``*IDN?`` reply.
    detail : str
        The port description, or why it was not recognised.
    """

    url: str
    role: str | None
    identity: Identity | None
    detail: str


def serial_ports() -> list[tuple[str, str]]:
    """``(device, description)`` of every serial port the operating system lists."""
    return [(p.device, p.description or "") for p in sorted(list_ports.comports(), key=lambda p: p.device)]


def role_of(identity: Identity) -> str | None:
    """``"shaker"`` or ``"daq"`` for a contactid instrument's identity (a supported bench function generator is a
    shaker controller), else None."""
    if identity.manufacturer.lower() == SHAKER_MANUFACTURER and identity.model in SHAKER_MODELS \
            or generator_family(identity) is not None:
        return "shaker"
    if identity.manufacturer.lower() == DAQ_MANUFACTURER and identity.model in DAQ_MODELS:
        return "daq"
    return None


def probe(url: str, *, baudrate: int = 115200, timeout: float = 0.5, description: str = "") -> Probe:
    """Open ``url``, ask ``*IDN?`` and classify the answer (never raises for port problems)."""
    try:
        link = SerialLink(url, name="probe", baudrate=baudrate)
    except InstrumentError as exc:
        return Probe(url, None, None, exc.message)
    try:
        scpi = ScpiInstrument(link, timeout)
        reply = link.call(lambda io: scpi.ask(io, "*IDN?", timeout), scpi.reply_wait(1, timeout))
    except InstrumentError as exc:
        return Probe(url, None, None, exc.message)
    finally:
        link.close()
    identity = Identity.parse(reply)
    if identity is None:
        return Probe(url, None, None, f"answered {reply[:60]!r}, not an IEEE 488.2 identity")
    role = role_of(identity)
    return Probe(url, role, identity, description if role else f"{identity} is not a shaker controller or DAQ "
                                                                 "contactid drives")


def find_instruments(urls: Iterable[str] | None = None, *, baudrate: int = 115200,
                     timeout: float = 0.5) -> tuple[dict[str, str], list[Probe]]:
    """Probe ``urls`` (default: every listed serial port).

    Returns
    -------
    found : dict
        ``{"shaker": url, "daq": url}`` for the first port of each role.
    probes : list of Probe
        Every port's result, to show the user what was tried.
    """
    targets = [(u, "") for u in urls] if urls is not None else serial_ports()
    probes = [probe(url, baudrate=baudrate, timeout=timeout, description=desc) for url, desc in targets]
    found: dict[str, str] = {}
    for result in probes:
        if result.role is not None:
            found.setdefault(result.role, result.url)
    return found, probes
