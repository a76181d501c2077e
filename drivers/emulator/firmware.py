"""What both emulated instruments share: a command thread, IEEE 488.2 common commands.

Each instrument processes the host's lines in its own thread, in order, holding
the rig lock while a line executes, so a command takes effect between two chunks
of physics and never in the middle of one.

A *device clear* (:meth:`Firmware.device_clear`, done whenever a host connects or
disconnects) forgets everything in flight between a host and the instrument: bytes
received and not yet executed (a half-sent command), replies not yet read, an
operation still running (a ``READ?`` waiting for its samples, a stream). Settings
and the error queue stay, as after an IEEE 488.2 device clear.
"""
from __future__ import annotations

import queue
import threading
from typing import TYPE_CHECKING

from ..faults import FaultInjector
from .link import OutputFifo
from .scpi_server import ScpiError, ScpiServer, action, reply_with

if TYPE_CHECKING:
    from .core import EmulatedRig

MANUFACTURER = "contactid"
FIRMWARE_VERSION = "1.0"
SCPI_VERSION = "1999.0"
MAX_LINE = 4096
"""Longest program message the instruments accept (bytes); longer input is error -363."""


class Firmware:
    """Base of the emulated instruments.

    Parameters
    ----------
    rig : EmulatedRig
        The rig the instrument belongs to (its lock, clock and backend).
    role : str
        ``"shaker"`` or ``"daq"``.
    """

    model = ""
    manufacturer = MANUFACTURER

    def __init__(self, rig: "EmulatedRig", role: str):
        self.rig = rig
        self.role = role
        self.output = OutputFifo()
        self.scpi = ScpiServer()
        self.injector: FaultInjector | None = None
        self._input: queue.SimpleQueue[tuple[int, bytes] | None] = queue.SimpleQueue()
        self._unprocessed = 0
        self._count_lock = threading.Lock()
        self.generation = 0               # +1 per device clear: older input and replies are dropped
        self._line_buffer = bytearray()
        self._buffer_generation = 0
        self._overlong = False            # inside a message longer than MAX_LINE: dropped up to its LF
        self._thread = threading.Thread(target=self._run, name=f"{rig.name} {role} firmware", daemon=True)
        self._add_common_commands()

    # ----- lifecycle ---------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._input.put(None)
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(2.0)

    def receive(self, data: bytes) -> None:
        """Bytes from the host (called by the link, any thread)."""
        if b"\n" in data:
            self.message_received()
        with self._count_lock:
            self._unprocessed += 1
            self.rig.idle_clock.begin()
            self._input.put((self.generation, bytes(data)))

    def device_clear(self) -> None:
        """Forget the input, the replies and the operation in flight (see module docstring)."""
        with self.rig.lock:
            with self._count_lock:
                self.generation += 1
            self.clear_operations()
            self.output.clear()
            self.rig.changed.notify_all()

    def cleared_since(self, generation: int) -> bool:
        """Whether a device clear came after ``generation`` (an operation started then must stop)."""
        return self.generation != generation

    @property
    def pending(self) -> bool:
        """Whether host bytes are waiting or being processed (fast mode holds the physics meanwhile)."""
        return self._unprocessed > 0

    def _run(self) -> None:
        while True:
            item = self._input.get()
            if item is None:
                return
            try:
                generation, data = item
                if generation == self.generation:
                    self._process(generation, data)
            finally:
                with self._count_lock:
                    self._unprocessed -= 1
                    self.rig.idle_clock.end()
                self.rig.notify()

    def _process(self, generation: int, data: bytes) -> None:
        if generation != self._buffer_generation:   # a device clear since the last bytes: start afresh
            self._line_buffer.clear()
            self._overlong = False
            self._buffer_generation = generation
        self._line_buffer += data
        while not self.cleared_since(generation):
            end = self._line_buffer.find(b"\n")
            if end < 0:
                break
            line = bytes(self._line_buffer[:end])
            del self._line_buffer[:end + 1]
            if self._overlong or end > MAX_LINE:
                self._overrun()
                self._overlong = False
            else:
                self.handle_line(line.rstrip(b"\r"), generation)
        if len(self._line_buffer) > MAX_LINE:
            self._overrun()
            self._overlong = True   # the rest of this message, up to its LF, is dropped too
            self._line_buffer.clear()

    def _overrun(self) -> None:
        """A program message longer than MAX_LINE is not executed: error -363, once per message."""
        if not self._overlong:
            self.scpi.errors.push(ScpiError(-363))

    def handle_line(self, line: bytes, generation: int | None = None) -> None:
        """Execute one program message under the rig lock and queue its reply.

        The reply is dropped if a device clear came meanwhile (its host is gone)."""
        generation = self.generation if generation is None else generation
        with self.rig.lock:
            if self.cleared_since(generation):
                return
            try:
                text = line.decode("ascii")
            except UnicodeDecodeError:
                self.scpi.errors.push(ScpiError(-102, "non-ASCII byte"))
                return
            injector = self.injector
            reply = self.scpi.execute(text, busy=self.busy(),
                                      reject=injector.reject_command if injector is not None else None)
            if reply is not None and not self.cleared_since(generation):
                self.output.put(reply)

    # ----- hooks for the instruments ------------------------------------------------------
    def message_received(self) -> None:
        """Called (any thread) when bytes holding the end of a program message arrive (the shaker feeds its
        watchdog)."""

    def busy(self) -> bool:
        """Whether only ``while_busy`` commands are accepted now (the DAQ while streaming)."""
        return False

    def produce(self) -> bool:
        """Fast mode: make more output when the host finds none; whether output will follow."""
        return False

    def reset(self) -> None:
        """``*RST``: the power-on settings, and the rig back from any fault."""
        self._defaults()
        self.rig.recover()

    def _defaults(self) -> None:
        """The power-on settings of this instrument."""

    def clear_operations(self) -> None:
        """Device clear: end what runs for the host (rig lock held)."""

    # ----- common commands ----------------------------------------------------------------
    def identity(self) -> str:
        # the rig's name is the serial-number field: a comma or a semicolon there would split the IEEE 488.2 reply
        serial = self.rig.name.replace(",", " ").replace(";", " ").replace("\n", " ")
        return f"{self.manufacturer},{self.model},{serial},{FIRMWARE_VERSION}"

    def _add_common_commands(self) -> None:
        add = self.scpi.add
        add("*IDN", query=reply_with(self.identity))
        add("*RST", write=action(self.reset), while_busy=True)
        add("*CLS", write=action(self.scpi.errors.clear), while_busy=True)
        add("*OPC", query=reply_with(lambda: "1"))
        add("*TST", query=reply_with(lambda: "0"))
        add("SYSTem:ERRor[:NEXT]", query=reply_with(lambda: str(self.scpi.errors.pop())))
        add("SYSTem:ERRor:COUNt", query=reply_with(lambda: str(len(self.scpi.errors))))
        add("SYSTem:VERSion", query=reply_with(lambda: SCPI_VERSION))
