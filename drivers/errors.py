"""Errors raised by the instrument drivers.

Every message is one line that starts with the port URL, so the command line and
the session log can show it as it is. The hierarchy lets a caller react to the
kind of failure without parsing text:

``InstrumentError``
    ``LinkError`` -- the link failed: ``LinkTimeout`` (no complete answer before the
    deadline), ``LinkLost`` (the port disappeared or the connection dropped).
    ``WrongDevice`` -- something answers, but not the expected instrument.
    ``ProtocolError`` -- the instrument sent something the protocol does not allow.
    ``DeviceError`` -- the instrument reported errors in its SCPI error queue.
    ``OutputTripped`` -- the shaker output went off without the host asking.
    ``ArmingRefused`` -- arming was asked for outside an output guard.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ScpiErrorEntry:
    """One entry of an instrument's SCPI error queue, e.g. ``-222,"Data out of range"``."""

    code: int
    message: str

    def __str__(self) -> str:
        return f'{self.code},"{self.message}"'


class InstrumentError(RuntimeError):
    """Base class: a problem with one instrument, named by its port URL.

    Parameters
    ----------
    url : str
        The pyserial URL or port name the driver opened.
    message : str
        What went wrong, one sentence.
    """

    def __init__(self, url: str, message: str):
        self.url = url
        self.message = message
        super().__init__(f"{url}: {message}")


class LinkError(InstrumentError):
    """The link to the instrument failed (no answer, dropped connection)."""


class LinkTimeout(LinkError):
    """No complete answer arrived before the deadline."""


class LinkLost(LinkError):
    """The port disappeared, the connection dropped or the port could not be opened."""


class WrongDevice(InstrumentError):
    """The port answers ``*IDN?``, but not as the instrument the driver expects."""


class ProtocolError(InstrumentError):
    """The instrument sent bytes the protocol does not allow (bad reply, bad stream)."""


class DeviceError(InstrumentError):
    """The instrument reported one or more errors in its SCPI error queue.

    Parameters
    ----------
    url : str
        Port URL.
    errors : list of ScpiErrorEntry
        The queue entries, oldest first.
    command : str, optional
        The command after which the errors were read.
    """

    def __init__(self, url: str, errors: list[ScpiErrorEntry], command: str | None = None):
        self.errors = list(errors)
        self.command = command
        listed = "; ".join(str(e) for e in self.errors)
        after = f" after {command!r}" if command else ""
        super().__init__(url, f"instrument reported {listed}{after}")

    @property
    def codes(self) -> list[int]:
        """The SCPI error codes, oldest first."""
        return [e.code for e in self.errors]


class OutputTripped(InstrumentError):
    """The shaker output is off although the host armed it (watchdog, instrument fault)."""


class ArmingRefused(InstrumentError):
    """The shaker was asked to switch on outside an :class:`drivers.safety.OutputGuard`."""


def describe_instrument_error(error: InstrumentError, roles: dict[str, str]) -> str:
    """``<role> at <url>: <message>`` in plain words, the role (``shaker``, ``DAQ``) looked up by URL."""
    role = roles.get(error.url)
    return f"{role} at {error.url}: {error.message}" if role else str(error)
