"""pyserial handler for ``sim://<rig>/<instrument>``: a port onto an in-process emulated instrument.

Registered by importing :mod:`drivers`, after which
``serial.serial_for_url("sim://bench/daq?fast=1")`` returns this port. The URL
syntax and options are described in :mod:`drivers.emulator.registry`. Line
settings (baud rate, parity, ...) are accepted and ignored: the link moves bytes
as fast as the emulated instrument produces them.
"""
from __future__ import annotations

import time

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, Timeout, to_bytes

from analysis.common.errors import InputError

from ..emulator.core import LinkBusy
from ..emulator.link import InstrumentLink, LinkDropped
from ..emulator.registry import open_sim_link


class Serial(SerialBase):
    """A serial port whose other end is an emulated instrument in this process."""

    def __init__(self, *args, **kwargs):
        self._link: InstrumentLink | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        try:
            self._link = open_sim_link(self.portstr)
        except (InputError, LinkBusy, ConnectionError) as exc:
            raise SerialException(f"could not open port {self.portstr}: {exc}") from None
        self.is_open = True

    def close(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None
        self.is_open = False

    def _reconfigure_port(self) -> None:
        """Line settings do not apply to an in-process link."""

    def _active_link(self) -> InstrumentLink:
        if not self.is_open or self._link is None:
            raise PortNotOpenError()
        return self._link

    def deadline_clock(self) -> float:
        """What the host's reply deadlines count (drivers/scpi.py): the emulated rig's idle time, so that a
        loaded machine slows the in-process instrument down without making its replies late."""
        link = self._link
        return link.clock() if link is not None else time.monotonic()

    @property
    def samples_on_demand(self) -> bool:
        """Whether the instrument samples only as the host reads (fast mode): a driver then reads no further ahead
        than its consumer asks (drivers/daq.py)."""
        link = self._link
        return link is not None and link.on_demand

    @property
    def in_waiting(self) -> int:
        return self._active_link().available()

    def read(self, size: int = 1) -> bytes:
        link = self._active_link()
        timeout = Timeout(self._timeout)
        data = bytearray()
        while len(data) < size:
            try:
                chunk = link.read(size - len(data), timeout.time_left())
            except LinkDropped as exc:
                raise SerialException(f"device disconnected: {exc}") from None
            data += chunk
            # an infinitely fast line: a read ends early only when the instrument has nothing more to send, so
            # how much one read takes from a fast emulator does not depend on the speed of the machine
            if (timeout.expired() and not chunk) or not self.is_open:
                break
        return bytes(data)

    def write(self, data) -> int:
        link = self._active_link()
        payload = to_bytes(data)
        try:
            link.write(payload)
        except LinkDropped as exc:
            raise SerialException(f"device disconnected: {exc}") from None
        return len(payload)

    def reset_input_buffer(self) -> None:
        self._active_link().discard()

    def reset_output_buffer(self) -> None:
        self._active_link()

    @property
    def out_waiting(self) -> int:
        self._active_link()
        return 0

    @property
    def cts(self) -> bool:
        self._active_link()
        return True

    @property
    def dsr(self) -> bool:
        self._active_link()
        return True

    @property
    def ri(self) -> bool:
        self._active_link()
        return False

    @property
    def cd(self) -> bool:
        self._active_link()
        return True

    def _update_break_state(self) -> None:
        """Break conditions have no meaning on an in-process link."""

    def _update_rts_state(self) -> None:
        """Modem lines are not modelled."""

    def _update_dtr_state(self) -> None:
        """Modem lines are not modelled."""
