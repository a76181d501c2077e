"""The guardian: a small process that owns a generator's connection and switches it off when its host dies.

A bench generator has no host watchdog, and a LAN generator often serves one connection
only. So the driver does not connect to it itself: it starts a guardian
(``python -m drivers.guardian URL``) in its own session (a Ctrl-C or a signal to the
host's process group does not reach it), which opens the instrument, listens on a
loopback port it prints as ``port N`` and relays bytes both ways for the one host that
connects. A host silent for HOST_SILENCE (hung: its heartbeat stopped) gets its output switched off, as
an SC-1's watchdog would. When that connection ends -- the host closed it, or the host died and the
kernel closed it (SIGKILL, a crash) -- or the host process is no longer its parent, the
guardian sends a line end (ending any half-written command) and ``OUTP OFF``, reads
``OUTP?`` back, says so on stderr and exits.

Not protected: the guardian killed together with its host (``kill -9`` of both, the
machine losing power), or the link to the instrument lost while the host is gone.
"""
from __future__ import annotations

import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

import serial

from analysis.common.child import python_child

POLL = 0.05
"""Longest the relay blocks before it checks that its host still lives (s)."""
HOST_SILENCE = 1.0
"""Seconds without a byte from the host after which the guardian switches the output off (the driver's heartbeat
comes every 0.25 s of silence): the watchdog the generator lacks."""
START_TIMEOUT = 20.0
"""Longest the driver waits for a starting guardian to announce its port (s)."""
OFF_LINE = b"\nOUTP OFF\n"


@dataclass
class Guardian:
    """A running guardian process; :attr:`url` is what the driver opens instead of the instrument."""

    process: subprocess.Popen
    url: str

    @classmethod
    def start(cls, instrument_url: str, baudrate: int = 115200) -> "Guardian":
        """Start a guardian for ``instrument_url`` and wait until it has opened the instrument."""
        command, env = python_child("drivers.guardian", instrument_url, str(baudrate))
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                   start_new_session=True)
        ready, _, _ = select.select([process.stdout], [], [], START_TIMEOUT)
        line = process.stdout.readline().decode("ascii", "replace").strip() if ready else ""
        if not line.startswith("port "):
            process.kill()
            detail = process.stderr.read().decode("utf-8", "replace").strip().splitlines()
            raise OSError(f"the guardian of {instrument_url} did not start: "
                          f"{detail[-1] if detail else 'no answer within ' + format(START_TIMEOUT, 'g') + ' s'}")
        return cls(process, f"socket://127.0.0.1:{int(line.split()[1])}")

    def wait(self, timeout: float = 5.0) -> None:
        """Wait for the guardian to exit after its host hung up (it kills it if it does not)."""
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for stream in (self.process.stdout, self.process.stderr):
            stream.close()


# ----- the guardian process ------------------------------------------------------------------
def _relay_instrument(port: serial.SerialBase, host: socket.socket, over: threading.Event) -> None:
    """Instrument bytes to the host until the relay ends."""
    while not over.is_set():
        try:
            data = port.read(port.in_waiting or 1)
            if data:
                host.sendall(data)
        except (OSError, serial.SerialException):
            over.set()


def _relay_host(port: serial.SerialBase, host: socket.socket, parent: int, over: threading.Event) -> None:
    """Host bytes to the instrument until the host hangs up or is gone; output off when it is silent."""
    heard = time.monotonic()
    while not over.is_set() and os.getppid() == parent:
        ready, _, _ = select.select([host], [], [], POLL)
        if not ready:
            if heard is not None and time.monotonic() - heard > HOST_SILENCE:
                port.write(b"OUTP OFF\n")   # once per silence; the host's heartbeat then finds the output off
                heard = None
            continue
        heard = time.monotonic()
        try:
            data = host.recv(1 << 16)
        except OSError:
            data = b""
        if not data:
            break
        port.write(data)
    over.set()


def switch_off(port: serial.SerialBase) -> str:
    """``OUTP OFF`` and the instrument's ``OUTP?`` reply (empty if none came)."""
    port.reset_input_buffer()
    port.write(OFF_LINE + b"OUTP?\n")
    deadline = time.monotonic() + 2.0
    reply = b""
    while time.monotonic() < deadline and not reply.endswith(b"\n"):
        reply += port.read(1)
    return reply.decode("ascii", "replace").strip()


def serve(url: str, baudrate: int) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # Ctrl-C is for the host; it switches off itself
    parent = os.getppid()
    port = serial.serial_for_url(url, baudrate=baudrate, timeout=POLL)
    listener = socket.create_server(("127.0.0.1", 0))
    print(f"port {listener.getsockname()[1]}", flush=True)
    listener.settimeout(START_TIMEOUT)
    try:
        host, _ = listener.accept()
    except OSError:
        host = None
    listener.close()
    if host is not None:
        host.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        over = threading.Event()
        reader = threading.Thread(target=_relay_instrument, args=(port, host, over), daemon=True)
        reader.start()
        _relay_host(port, host, parent, over)
        reader.join(1.0)
        host.close()
    reply = switch_off(port)
    port.close()
    try:
        print(f"guardian: host gone; OUTP OFF sent to {url}, OUTP? answered {reply!r}", file=sys.stderr, flush=True)
    except OSError:
        pass  # a killed host no longer reads this; the output is off all the same
    return 0


if __name__ == "__main__":
    sys.exit(serve(sys.argv[1], int(sys.argv[2])))
