"""What the rest of the application may rely on from a shaker controller and a DAQ.

Campaigns, the GUI and the command line are written against these protocols only;
the serial implementations (:mod:`drivers.shaker`, :mod:`drivers.daq`) satisfy them
whatever the transport (a port name, ``socket://``, ``rfc2217://`` or ``sim://``).

Units: frequencies in Hz, drive amplitudes in volts (peak for a sine, rms for
noise), ramp rates in volts of peak amplitude per second, samples in the physical
unit of their channel (``Daq.units``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator, Protocol, Sequence, runtime_checkable
from urllib.parse import urlsplit

import numpy as np

from .stream import Gap


@dataclass(frozen=True)
class Identity:
    """The four fields of an IEEE 488.2 ``*IDN?`` reply."""

    manufacturer: str
    model: str
    serial: str
    firmware: str

    @classmethod
    def parse(cls, reply: str) -> "Identity | None":
        """Split an ``*IDN?`` reply; None if it does not have four comma-separated fields."""
        parts = [p.strip() for p in reply.split(",")]
        if len(parts) != 4 or not all(parts[:2]):
            return None
        return cls(*parts)

    def __str__(self) -> str:
        return f"{self.manufacturer},{self.model},{self.serial},{self.firmware}"


@dataclass(frozen=True)
class Protection:
    """What switches the output off, on this connection, when something goes wrong.

    Attributes
    ----------
    instrument_ramp, instrument_watchdog : bool
        The instrument ramps amplitude changes itself / switches off a silent host.
    dies_with_host : bool
        The instrument lives in the host process (``sim://``): killing the process ends the output.
    guardian : bool
        A guardian process (:mod:`drivers.guardian`) owns the connection and switches off when the host dies.
    """

    instrument_ramp: bool
    instrument_watchdog: bool
    dies_with_host: bool
    guardian: bool = False

    @property
    def survives_kill(self) -> bool:
        """Whether the output goes off when the host process is killed (SIGKILL, a crash)."""
        return self.instrument_watchdog or self.dies_with_host or self.guardian

    def lines(self) -> list[tuple[str, str | None]]:
        """``(event, what switches the output off or ramps; None: nothing)`` pairs, as the Rig tab shows them."""
        hung = "instrument watchdog" if self.instrument_watchdog else "guardian process" if self.guardian else None
        killed = hung or ("the instrument dies with the process" if self.dies_with_host else None)
        return [("error, abort, limit, SIGTERM/SIGINT, exit", "OutputGuard"),
                ("amplitude changes ramped", "instrument" if self.instrument_ramp else "driver (host)"),
                ("host hung", hung),
                ("host killed", killed)]


def in_process(url: str) -> bool:
    """Whether the instrument at ``url`` lives in this process (``sim://``) and dies with it."""
    return urlsplit(url).scheme.lower() == "sim"


@dataclass(frozen=True)
class Block:
    """A run of contiguous samples from the DAQ.

    Attributes
    ----------
    data : ndarray, shape (n, n_channels), float64
        Samples in physical units (``units``), one column per channel.
    channels, units : tuple of str
        Channel names and their units, in column order.
    sample_rate : float
        Hz.
    first_sample : int
        Index of ``data[0]`` counted per channel since the acquisition started.
    gaps : tuple of Gap
        Samples lost between the previous block and this one (empty if contiguous).
    overload : bool
        A channel reached its range limit somewhere in this block.
    """

    data: np.ndarray
    channels: tuple[str, ...]
    units: tuple[str, ...]
    sample_rate: float
    first_sample: int
    gaps: tuple[Gap, ...] = ()
    overload: bool = False

    def __len__(self) -> int:
        return self.data.shape[0]

    @property
    def time(self) -> float:
        """Time of the first sample since the acquisition started (s)."""
        return self.first_sample / self.sample_rate

    @property
    def lost_samples(self) -> int:
        """Samples per channel lost just before this block."""
        return sum(g.samples for g in self.gaps)

    def channel(self, name: str) -> np.ndarray:
        """The column of channel ``name``, shape (n,)."""
        try:
            return self.data[:, self.channels.index(name)]
        except ValueError:
            raise KeyError(f"no channel {name!r}; channels are {', '.join(self.channels)}") from None


@runtime_checkable
class ShakerController(Protocol):
    """A signal source driving the shaker amplifier, with an output switch.

    The output starts OFF. ``arm`` switches it on and is only accepted inside an
    :class:`drivers.safety.OutputGuard`; the amplitude then ramps from zero at
    ``ramp_rate``, so it never jumps. ``disarm`` switches it off at once.
    """

    url: str
    identity: Identity
    frequency_range: tuple[float, float]
    amplitude_range: tuple[float, float]
    armed: bool
    protection: Protection

    def set_sine(self, frequency: float, amplitude: float) -> None:
        """Sine of ``frequency`` Hz and ``amplitude`` V peak (phase-continuous, ramped)."""

    def set_noise(self, rms: float, band: tuple[float, float]) -> None:
        """Gaussian noise of ``rms`` V in the pass band ``(low, high)`` Hz (switch from sine only while disarmed)."""

    def set_ramp_rate(self, volts_per_second: float) -> None:
        """Largest rate of change of the peak amplitude (V/s)."""

    def arm(self) -> None:
        """Switch the output on (only inside an OutputGuard)."""

    def disarm(self) -> None:
        """Switch the output off and verify it is off."""

    def output_enabled(self) -> bool:
        """Whether the instrument reports its output on."""

    def output_level(self) -> float:
        """The amplitude being output now (V peak for sine, V rms for noise; 0 when off)."""

    def emergency_off(self, timeout: float = 0.25) -> bool:
        """Send output-off ahead of anything queued; safe to call from a signal handler."""

    def check(self) -> None:
        """Raise the fault the instrument supervision found (output tripped, link lost), if any."""

    def attach_guard(self, guard: object | None) -> None:
        """Called by the OutputGuard on entry (the guard) and exit (None)."""

    def add_fault_listener(self, listener: Callable[[Exception], None]) -> None:
        """Call ``listener(error)`` when the supervision finds a fault."""

    def remove_fault_listener(self, listener: Callable[[Exception], None]) -> None:
        """Stop calling ``listener``."""

    def close(self) -> None:
        """Switch the output off and release the port."""


class BlockStream(Protocol):
    """A running acquisition: blocks in time order until stopped."""

    def read(self, timeout: float | None = None) -> Block:
        """The next block; raises a LinkError if none arrives in time."""

    def pending(self) -> int:
        """Blocks received and waiting to be read: they were sampled before this call."""

    def sync(self, timeout: float = 5.0) -> bool:
        """Wait until what the instrument sampled so far is received or queued (call it before a generator
        change); whether that came within ``timeout`` s."""

    def stop(self) -> object:
        """End the acquisition and return its statistics; later reads return the blocks still queued."""

    def __iter__(self) -> Iterator[Block]: ...

    def __enter__(self) -> "BlockStream": ...

    def __exit__(self, *exc) -> None: ...


@runtime_checkable
class Daq(Protocol):
    """A multichannel acquisition unit with a streaming mode and an on-demand block read."""

    url: str
    identity: Identity
    channels: tuple[str, ...]
    units: tuple[str, ...]
    sample_rate: float

    def configure(self, *, channels: Sequence[str] | None = None,
                  sensitivities: dict[str, float] | None = None,
                  ranges: dict[str, float] | None = None,
                  frame_points: int | None = None) -> None:
        """Select channels (by name) and set sensitivities (V/unit), ranges (V) and frame size."""

    def stream(self, block_size: int, *, buffered_blocks: int = 4, timeout: float | None = None,
               no_data_timeout: float = 2.0) -> BlockStream:
        """Start streaming; blocks of ``block_size`` samples per channel (shorter at a gap)."""

    def read(self, points: int) -> Block:
        """Acquire ``points`` samples per channel now and return them (not while streaming)."""

    def close(self) -> None:
        """Stop any acquisition and release the port."""
