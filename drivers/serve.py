"""Serving the emulated instruments to other processes: pseudo terminals or TCP.

``contactid emulate RIG --pty`` and ``--tcp HOST:PORT`` call
:func:`serve_emulator`, which prints one line per instrument::

    shaker: /dev/pts/5                   (--pty: open it like a serial port)
    daq: /dev/pts/6
    shaker: socket://127.0.0.1:5025      (--tcp: the shaker on PORT, the DAQ on PORT+1)
    daq: socket://127.0.0.1:5026

and serves until interrupted (SIGINT or SIGTERM). A pseudo terminal keeps its
path for the whole session; a TCP port serves one host at a time and the next one
after it disconnects. A host that connects while another is served is refused: it
gets a one-line explanation (:data:`BUSY`), again for every line it sends, and is
disconnected after :data:`REFUSE_SECONDS`. Every TCP connection starts and ends
with a device clear of its instrument. An injected disconnect closes the pseudo
terminal (the port disappears) or the TCP connection.
"""
from __future__ import annotations

import errno
import os
import select
import signal
import socket
import threading
import time
import tty
from typing import Any, Callable, Mapping

from analysis.common.errors import InputError

from .emulator.core import EmulatedRig
from .emulator.link import InstrumentLink, LinkDropped
from .faults import ROLES

POLL = 0.05
"""Longest a serving thread blocks before it re-checks for shutdown (s)."""
CHUNK = 1 << 16
REFUSE_SECONDS = 3.0
"""How long a refused host is kept connected, so that it reads the refusal (s)."""
HANDOVER_SECONDS = 3.0
"""How long a new host waits for the connection of a host that has hung up to wind down (s)."""
TCP_ESTABLISHED = 1
"""Linux TCP state of an open connection (``tcpi_state`` in TCP_INFO)."""
BUSY = "busy: this {role} is in use by {peer} (connected at {since}); one host at a time\n"
"""The line a refused host receives."""


def parse_tcp_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (PORT 0 picks free ports) to a (host, port) pair; InputError if malformed."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65534:
        raise InputError(f"expected HOST:PORT with PORT 0..65534, got {text!r}", "--tcp")
    return host.strip("[]"), int(port)


def _pump_to_link(receive: Callable[[], bytes | None], link: InstrumentLink, stop: threading.Event) -> None:
    """Host bytes into the instrument until the host goes away (receive returns None) or stop."""
    while not stop.is_set():
        data = receive()
        if data is None:
            break
        if data:
            link.write(data)


def _pump_from_link(link: InstrumentLink, send: Callable[[bytes], bool], stop: threading.Event) -> None:
    """Instrument bytes to the host until the host goes away (send returns False) or stop."""
    while not stop.is_set():
        data = link.read(CHUNK, POLL)
        if data and not send(data):
            break


class PtyEndpoint:
    """One instrument on a pseudo terminal; :attr:`url` is the path the host opens."""

    def __init__(self, rig: EmulatedRig, role: str):
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)          # no echo or line editing between host and instrument
        os.set_blocking(self.master, False)
        self.url = os.ttyname(self._slave)
        self.link = rig.connect(role)
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._serve, args=(target,), daemon=True,
                                          name=f"{role} pty {name}")
                         for name, target in (("in", self._inbound), ("out", self._outbound))]
        for thread in self._threads:
            thread.start()

    def _serve(self, target: Callable[[], None]) -> None:
        try:
            target()
        except (LinkDropped, OSError):
            # the cable is pulled: both pumps stop, then the terminal disappears
            self._stop.set()
            threading.Thread(target=self._teardown, daemon=True).start()

    def _teardown(self) -> None:
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(2.0)
        self._close_fds()

    def _receive(self) -> bytes | None:
        ready, _, _ = select.select([self.master], [], [], POLL)
        if not ready:
            return b""
        try:
            return os.read(self.master, CHUNK)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no host has the terminal open right now
                return b""
            raise

    def _send(self, data: bytes) -> bool:
        view = memoryview(data)
        while view and not self._stop.is_set():
            _, ready, _ = select.select([], [self.master], [], POLL)
            if ready:
                try:
                    view = view[os.write(self.master, view):]
                except BlockingIOError:
                    continue
        return True

    def _inbound(self) -> None:
        _pump_to_link(self._receive, self.link, self._stop)

    def _outbound(self) -> None:
        _pump_from_link(self.link, self._send, self._stop)

    def _close_fds(self) -> None:
        for attr in ("master", "_slave"):
            fd = getattr(self, attr)
            if fd >= 0:
                setattr(self, attr, -1)
                try:
                    os.close(fd)
                except OSError:
                    pass  # the descriptor is gone already

    def close(self) -> None:
        self._stop.set()
        self._teardown()
        self.link.close()


class TcpEndpoint:
    """One instrument on a TCP port; :attr:`url` is its ``socket://`` URL."""

    def __init__(self, rig: EmulatedRig, role: str, host: str, port: int):
        self.rig = rig
        self.role = role
        self.server = socket.create_server((host, port))
        bound = self.server.getsockname()
        self.url = f"socket://{host}:{bound[1]}"
        self._stop = threading.Event()
        self._connection_over = threading.Event()
        self._holder: str | None = None          # the served host, as the refusal names it
        self._connection: socket.socket | None = None
        self._serving: threading.Thread | None = None
        self._thread = threading.Thread(target=self._accept, daemon=True, name=f"{role} tcp")
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.server], [], [], POLL)
            if not ready:
                continue
            connection, peer = self.server.accept()
            peer_text = f"{peer[0]}:{peer[1]}"
            if self._serving is not None and self._previous_host_left():
                self._serving.join(HANDOVER_SECONDS)   # a host that just hung up is not refused its successor
            if self._serving is not None and self._serving.is_alive():
                threading.Thread(target=self._refuse, args=(connection,), daemon=True,
                                 name=f"{self.role} tcp refusal").start()
                continue
            self._holder = BUSY.format(role=self.role, peer=peer_text, since=time.strftime("%H:%M:%S"))
            self._serving = threading.Thread(target=self._serve_connection, args=(connection,), daemon=True,
                                             name=f"{self.role} tcp host {peer_text}")
            self._serving.start()

    def _previous_host_left(self) -> bool:
        """Whether the served host has closed its end (its connection may still be winding down here)."""
        connection = self._connection
        if connection is None:
            return True
        try:
            if hasattr(socket, "TCP_INFO"):   # Linux: no longer ESTABLISHED once the host's FIN (or RST) came
                return connection.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)[0] != TCP_ESTABLISHED
            ready, _, _ = select.select([connection], [], [], 0)
            return bool(ready) and connection.recv(1, socket.MSG_PEEK) == b""
        except OSError:
            return True   # closed here already

    def _refuse(self, connection: socket.socket) -> None:
        """Tell a second host why it is not served (once, then once per line it sends), then hang up."""
        message = (self._holder or BUSY).encode("ascii", "replace")
        deadline = time.monotonic() + REFUSE_SECONDS
        with connection:
            try:
                connection.sendall(message)
                while (left := deadline - time.monotonic()) > 0 and not self._stop.is_set():
                    ready, _, _ = select.select([connection], [], [], min(left, POLL))
                    if ready:
                        data = connection.recv(CHUNK)
                        if not data:
                            return
                        connection.sendall(message * data.count(b"\n"))
                connection.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass  # the refused host hung up first

    def _serve_connection(self, connection: socket.socket) -> None:
        self._connection = connection
        with connection:
            self._serve(connection)

    def _serve(self, connection: socket.socket) -> None:
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        connection.settimeout(POLL)
        link = self.rig.connect(self.role)
        gone = self._connection_over = threading.Event()
        if self._stop.is_set():
            gone.set()

        def receive() -> bytes | None:
            try:
                data = connection.recv(CHUNK)
            except socket.timeout:
                return b""
            except OSError:
                return None
            return data if data else None

        def send(data: bytes) -> bool:
            view = memoryview(data)
            while view and not gone.is_set():
                try:
                    view = view[connection.send(view):]
                except socket.timeout:
                    continue
                except OSError:
                    return False
            return not gone.is_set()

        def inbound() -> None:
            try:
                _pump_to_link(receive, link, gone)
            except LinkDropped:
                pass  # the injected disconnect: closing the connection below is the effect
            gone.set()

        reader = threading.Thread(target=inbound, daemon=True, name=f"{self.role} tcp in")
        reader.start()
        try:
            _pump_from_link(link, send, gone)
        except LinkDropped:
            pass  # as above
        finally:
            gone.set()
            reader.join(2.0)
            link.close()
            try:
                connection.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass  # the host closed first

    def close(self) -> None:
        self._stop.set()
        self._connection_over.set()
        self._thread.join(2.0)
        if self._serving is not None:
            self._serving.join(2.0)
        self.server.close()


class EmulatorServer:
    """Serve a running :class:`EmulatedRig`'s instruments over pseudo terminals or TCP.

    Parameters
    ----------
    rig : EmulatedRig
        A started rig.
    transport : {"pty", "tcp"}
        Pseudo terminals or TCP ports.
    host : str
        TCP address to listen on (loopback by default).
    port : int
        TCP port of the shaker; the DAQ listens on ``port + 1``; 0 picks free ports.
    """

    def __init__(self, rig: EmulatedRig, transport: str = "pty", host: str = "127.0.0.1", port: int = 0):
        if transport not in ("pty", "tcp"):
            raise ValueError(f"transport must be 'pty' or 'tcp', got {transport!r}")
        self.endpoints: dict[str, PtyEndpoint | TcpEndpoint] = {}
        try:
            for offset, role in enumerate(ROLES):
                if transport == "pty":
                    self.endpoints[role] = PtyEndpoint(rig, role)
                else:
                    self.endpoints[role] = TcpEndpoint(rig, role, host, port + offset if port else 0)
        except BaseException:
            self.close()
            raise

    @property
    def urls(self) -> dict[str, str]:
        """``{"shaker": url, "daq": url}``: what the drivers open."""
        return {role: endpoint.url for role, endpoint in self.endpoints.items()}

    def close(self) -> None:
        for endpoint in self.endpoints.values():
            endpoint.close()

    def __enter__(self) -> "EmulatorServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def serve_emulator(backend: Any, *, transport: str = "pty", host: str = "127.0.0.1", port: int = 0,
                   fast: bool = False, faults: Mapping[str, Any] | None = None, name: str = "emulator",
                   announce: Callable[[str], None] | None = None, stop: threading.Event | None = None,
                   shaker_model: str = "SC-1") -> None:
    """Run the emulated instruments of ``backend`` until interrupted.

    Parameters
    ----------
    backend : object
        The rig physics (rig simulator interface).
    transport, host, port :
        As :class:`EmulatorServer`.
    fast : bool
        As fast as the DAQ's reader instead of real time.
    faults : mapping, optional
        The rig file's ``[faults]`` table.
    name : str
        Rig name (serial-number field of ``*IDN?``).
    announce : callable, optional
        Receives the ``shaker: URL`` and ``daq: URL`` lines (default: print and flush).
    stop : threading.Event, optional
        Serving ends when it is set (also on SIGINT / SIGTERM).
    shaker_model : str
        ``"SC-1"`` or ``"33500B"`` (the shaker controller as a bench generator, :mod:`drivers.emulator.generator`).
    """
    if announce is None:
        def announce(line: str) -> None:
            print(line, flush=True)
    stop = stop or threading.Event()
    restore = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            restore[signum] = signal.signal(signum, lambda *_: stop.set())
    try:
        with EmulatedRig(backend, paced=not fast, name=name, faults=faults,
                         shaker_model=shaker_model) as rig, \
                EmulatorServer(rig, transport, host, port) as server:
            for role, url in server.urls.items():
                announce(f"{role}: {url}")
            while not stop.wait(0.2):
                pass
    finally:
        for signum, handler in restore.items():
            signal.signal(signum, handler)
