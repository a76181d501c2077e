"""A small stand-in for the rig simulator, with the same interface, for the driver tests.

Physics: the amplifier output is ``v(t) = amplitude sin(phase) + rms N(0, 1)`` while
on (phase continuous across frequency changes), 0 while off; the force gauge
reads ``FORCE_GAIN * v`` and accelerometer k reads ``ACC_GAIN[k] * v``. Every
channel also carries a *signature*: a deterministic pseudo-random integer number
of LSBs that depends only on the absolute sample index, so a test can check that
every delivered sample is exactly the one the backend produced.

:func:`bench` serves a fresh rig over a transport and opens both drivers on it.
"""
from __future__ import annotations

import itertools
from contextlib import contextmanager

import numpy as np

from drivers.daq import SerialDaq
from drivers.emulator import EmulatedRig, register
from drivers.serve import EmulatorServer
from drivers.shaker import SerialShaker

FORCE_GAIN = 2.0          # N per V
ACC_GAIN = (30.0, -12.0)  # m/s^2 per V
SIGNATURE_SPAN = 50       # signature is in [-SIGNATURE_SPAN, SIGNATURE_SPAN] LSB


def signature(index: np.ndarray, channel: int) -> np.ndarray:
    """Signature of channel ``channel`` at absolute sample indices ``index``, in LSB."""
    mixed = (np.asarray(index, dtype=np.int64) * 2654435761 + 97531 * (channel + 1)) % 1000003
    return mixed % (2 * SIGNATURE_SPAN + 1) - SIGNATURE_SPAN


class RigDouble:
    """Backend with the rig simulator's interface (see drivers.emulator.core)."""

    def __init__(self, sample_rate: float = 1000.0, lsb=(1e-4, 1e-3, 1e-3), seed: int = 0):
        self.sample_rate = float(sample_rate)
        self.channels = ["force", "acc:x1", "acc:x2"]
        self.units = ["N", "m/s^2", "m/s^2"]
        self.lsb = np.asarray(lsb, dtype=float)
        self.samples = 0
        self.output = False
        self.sine = (1.0, 0.0)      # frequency (Hz), amplitude (V)
        self.noise = (0.0, (1.0, 2.0))  # rms (V), band (Hz)
        self.phase = 0.0
        self.calls: list[tuple[float, str, tuple]] = []
        self._rng = np.random.default_rng(seed)

    @property
    def time(self) -> float:
        return self.samples / self.sample_rate

    def set_sine(self, frequency_hz: float, amplitude_volts: float) -> None:
        self.calls.append((self.time, "set_sine", (frequency_hz, amplitude_volts)))
        self.sine = (float(frequency_hz), float(amplitude_volts))

    def set_noise(self, rms_volts: float, band_hz: tuple[float, float]) -> None:
        low, high = band_hz
        if not 0 < low < high < self.sample_rate / 2:
            raise ValueError(f"noise band {band_hz} outside (0, Nyquist)")
        self.calls.append((self.time, "set_noise", (rms_volts, (low, high))))
        self.noise = (float(rms_volts), (low, high))

    def set_output(self, on: bool) -> None:
        self.calls.append((self.time, "set_output", (bool(on),)))
        self.output = bool(on)

    def drive(self, n: int) -> np.ndarray:
        """The amplifier voltage over the next ``n`` samples (advances the phase).

        The noise is white (its band is only recorded): the tests check its rms.
        """
        frequency, amplitude = self.sine
        phases = self.phase + 2 * np.pi * frequency / self.sample_rate * np.arange(n)
        self.phase = float((self.phase + 2 * np.pi * frequency / self.sample_rate * n) % (2 * np.pi))
        voltage = amplitude * np.sin(phases) + self.noise[0] * self._rng.standard_normal(n)
        return voltage if self.output else np.zeros(n)

    def advance(self, n: int) -> np.ndarray:
        voltage = self.drive(n)
        index = np.arange(self.samples, self.samples + n)
        gains = (FORCE_GAIN,) + ACC_GAIN
        out = np.empty((n, 3))
        for k, gain in enumerate(gains):
            counts = np.rint(gain * voltage / self.lsb[k]) + signature(index, k)
            out[:, k] = counts * self.lsb[k]
        self.samples += n
        return out


_names = itertools.count()


@contextmanager
def bench(transport="sim", paced=False, faults=None):
    """A rig served over ``transport`` with both drivers open: (rig, shaker, daq)."""
    name = f"emu{next(_names)}"
    with EmulatedRig(RigDouble(), paced=paced, name=name, faults=faults) as rig:
        server = None
        if transport == "sim":
            register(rig)
            urls = {role: f"sim://{name}/{role}" for role in ("shaker", "daq")}
        else:
            server = EmulatorServer(rig, transport)
            urls = server.urls
        shaker = daq = None
        try:
            shaker = SerialShaker(urls["shaker"])
            daq = SerialDaq(urls["daq"])
            yield rig, shaker, daq
        finally:
            for instrument in (shaker, daq):
                if instrument is not None:
                    instrument.close()
            if server is not None:
                server.close()


def stream_start(rig):
    """Backend sample index at which the last acquisition started."""
    start = [e for e in rig.events if e.instrument == "daq" and e.detail == "start"][-1]
    return round(start.time * rig.sample_rate)
