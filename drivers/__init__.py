"""contactid drivers: bytes <-> instruments.

- :func:`open_shaker` / :func:`open_daq`: the serial drivers (:class:`SerialShaker`,
  :class:`SerialDaq`) for a port name or any pyserial URL.
- :class:`OutputGuard`, :class:`AbortLimits`: the output-off guarantees (:mod:`drivers.safety`).
- :mod:`drivers.emulator`: the emulated instruments; :mod:`drivers.serve`: serving them
  over pseudo terminals or TCP.
- docs/protocol.md: the instrument protocol.

Importing this package registers the ``sim://`` pyserial URL handler, so every
driver (and plain ``serial.serial_for_url``) can open in-process emulated
instruments the same way as ports, ``socket://`` and ``rfc2217://`` URLs.
"""
import serial

if "drivers.urlhandler" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("drivers.urlhandler")

from .daq import SerialDaq
from .errors import (ArmingRefused, DeviceError, InstrumentError, LinkError, LinkLost, LinkTimeout,
                     OutputTripped, ProtocolError, WrongDevice)
from .interfaces import Block, Daq, Identity, ShakerController
from .safety import AbortLimits, LimitExceeded, OutputGuard, check_limits
from .generator import GeneratorShaker, generator_family, open_generator, read_identity
from .scpi import SerialLink
from .shaker import SerialShaker


def open_shaker(url: str, *, baudrate: int = 115200, timeout: float = 1.0, port=None, guardian: bool = True,
                unguarded: bool = False, **options) -> SerialShaker:
    """Open the shaker controller at ``url`` (port name or pyserial URL).

    The ``*IDN?`` reply chooses the driver: a supported bench function generator gets a
    :class:`GeneratorShaker` behind a guardian process (options as it; :func:`drivers.generator.open_generator`),
    anything else a :class:`SerialShaker` (options as it; another instrument is refused there with WrongDevice).
    ``guardian=False`` opens a generator without its guardian and ``unguarded=True`` lets it arm all the same
    (both mean nothing to an SC-1, whose own watchdog switches it off).
    """
    link = SerialLink(url, name="shaker", baudrate=baudrate, port=port)
    try:
        if generator_family(read_identity(link, timeout)) is not None:
            return open_generator(url, link, baudrate=baudrate, timeout=timeout, guardian=guardian,
                                  unguarded=unguarded, **options)
        return SerialShaker(url, timeout=timeout, link=link, **options)
    except BaseException:
        link.close()
        raise


def open_daq(url: str, **options) -> SerialDaq:
    """Open the DAQ at ``url`` (port name or pyserial URL); options as SerialDaq."""
    return SerialDaq(url, **options)


__all__ = ["AbortLimits", "ArmingRefused", "Block", "Daq", "DeviceError", "GeneratorShaker", "Identity",
           "InstrumentError", "LimitExceeded", "LinkError", "LinkLost", "LinkTimeout", "OutputGuard", "OutputTripped",
           "ProtocolError", "SerialDaq", "SerialShaker", "ShakerController", "WrongDevice", "check_limits",
           "open_daq", "open_shaker"]
