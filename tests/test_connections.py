"""The emulated instruments as a host meets them over TCP: what one connection leaves, the next never sees.

Raw sockets against :class:`drivers.serve.EmulatorServer`, as a hostile or careless client would use them
(docs/protocol.md section 1, "Connections").
"""
import itertools
import socket
from contextlib import contextmanager

import numpy as np
import pytest
import serial

import drivers  # noqa: F401  (registers sim://)
from drivers.daq import SerialDaq
from drivers.emulator import EmulatedRig, register
from drivers.errors import DeviceError
from drivers.safety import OutputGuard
from drivers.serve import EmulatorServer
from drivers.shaker import SerialShaker
from drivers.simulation.simulator import RigSimulator, SimulationError
from rig_double import RigDouble
from test_emulator import FailingRig
from test_simulator import sdof_rig

_names = itertools.count()
WAIT = 30.0
"""Longest a reply may take before the instrument counts as hung (s); generous for a loaded machine."""


@contextmanager
def served(paced=True, backend=None):
    """A rig served over TCP: (rig, {"shaker": (host, port), "daq": (host, port)})."""
    with EmulatedRig(backend or RigDouble(), paced=paced, name=f"conn{next(_names)}") as rig, \
            EmulatorServer(rig, "tcp") as server:
        yield rig, {role: tuple(url[len("socket://"):].rsplit(":", 1)) for role, url in server.urls.items()}


def connect(address):
    host, port = address
    return socket.create_connection((host, int(port)), timeout=WAIT)


def ask(sock, text):
    """Send one line and return the reply line (without LF)."""
    sock.sendall(text.encode() + b"\n")
    return readline(sock)


def readline(sock):
    data = bytearray()
    while not data.endswith(b"\n"):
        chunk = sock.recv(1)
        assert chunk, f"connection closed after {bytes(data)!r}"
        data += chunk
    return data[:-1].decode()


@pytest.mark.parametrize("paced", [True, False])
def test_a_read_abandoned_by_its_host_does_not_block_the_next_one(paced):
    with served(paced) as (rig, where):
        first = connect(where["daq"])
        first.sendall(b"READ? 1048576\n")   # 17 minutes of samples at 1 kHz
        first.close()
        second = connect(where["daq"])
        assert ask(second, "*IDN?").startswith("contactid,DAQ-1,")
        assert ask(second, "ABOR;*RST;*OPC?") == "1"
        assert ask(second, "SYST:ERR?") == '0,"No error"'
        second.close()


def test_half_a_command_does_not_survive_its_host():
    with served() as (rig, where):
        first = connect(where["shaker"])
        first.sendall(b"FREQ 1")
        first.close()
        second = connect(where["shaker"])
        second.sendall(b"5\n")
        assert ask(second, "FREQ?") == "10"
        assert ask(second, "SYST:ERR?").startswith("-102,")   # "5" alone is not a command
        second.close()


def test_replies_and_streams_of_a_previous_host_are_not_delivered_to_the_next():
    with served() as (rig, where):
        first = connect(where["shaker"])
        first.sendall(b"*IDN?\n" * 200)
        daq = connect(where["daq"])
        daq.sendall(b"INIT\n")
        assert ask(first, "*OPC?").startswith("contactid,SC-1")   # the replies queued ahead of it
        first.close()
        daq.close()
        second = connect(where["shaker"])
        assert ask(second, "FREQ?") == "10"
        daq = connect(where["daq"])
        assert ask(daq, "*IDN?").startswith("contactid,DAQ-1,")   # no frames ahead of the reply
        assert not rig.daq.acquiring
        second.close()
        daq.close()


def test_a_message_over_4096_bytes_is_refused_whole_with_error_363():
    message = b"FREQ 15" + b";" * 5000 + b";FREQ 16\n"
    longest = b"FREQ 12" + b";" * (4096 - 7) + b"\n"   # the limit itself is accepted
    with served() as (rig, where):
        sock = connect(where["shaker"])
        sock.sendall(message)
        assert ask(sock, "FREQ?;:SYST:ERR?") == '10;-363,"Input buffer overrun"'
        sock.sendall(longest)
        assert ask(sock, "FREQ?;:SYST:ERR?") == '12;0,"No error"'
        sock.close()
    with EmulatedRig(RigDouble(), name=f"pieces{next(_names)}") as rig:
        register(rig)
        port = serial.serial_for_url(f"sim://{rig.name}/shaker", timeout=WAIT)
        for piece in (message[:3000], message[3000:4500], message[4500:]):   # arriving in pieces
            port.write(piece)
        port.write(b"FREQ?;:SYST:ERR?;:SYST:ERR?\n")
        assert port.readline() == b'10;-363,"Input buffer overrun";0,"No error"\n'
        port.close()


def test_a_second_host_is_refused_with_a_message_and_served_once_the_first_leaves():
    with served() as (rig, where):
        idle = connect(where["shaker"])
        assert ask(idle, "*IDN?").startswith("contactid,SC-1,")
        other = connect(where["shaker"])
        local = "%s:%d" % idle.getsockname()
        busy = readline(other)
        assert busy.startswith("busy: this shaker is in use by ") and local in busy and "one host at a time" in busy
        assert ask(other, "*IDN?") == busy   # every line it sends gets the same answer
        other.close()
        idle.close()
        third = connect(where["shaker"])
        assert ask(third, "*IDN?").startswith("contactid,SC-1,")
        third.close()


@pytest.mark.slow
def test_the_driver_names_the_busy_instrument():
    with served() as (rig, where):
        holder = connect(where["shaker"])
        with pytest.raises(Exception, match="busy: this shaker is in use by"):
            SerialShaker("socket://%s:%s" % where["shaker"])
        holder.close()


class FailingOnce(FailingRig):
    """Diverges once, then restarts from rest like :meth:`RigSimulator.restart_from_rest`."""

    restarts = 0

    def restart_from_rest(self):
        self.limit = np.inf
        self.restarts += 1


@pytest.mark.parametrize("how", ["OUTP ON", "*RST", "connection"])
@pytest.mark.slow
def test_after_a_physics_failure_the_instrument_recovers(how):
    with EmulatedRig(FailingOnce(3000), paced=False, name=f"recover{next(_names)}") as rig:
        register(rig)
        shaker = SerialShaker(f"sim://{rig.name}/shaker")
        daq = SerialDaq(f"sim://{rig.name}/daq")
        shaker.set_sine(10.0, 0.5)
        with OutputGuard(shaker) as guard:
            guard.arm()
            with pytest.raises(DeviceError, match="physics stopped"):
                with daq.stream(500) as stream:
                    for _ in range(100):
                        stream.read()
        assert not rig.shaker.output_on and rig.failure is not None
        if how == "connection":
            shaker.close()
            daq.close()
            shaker = SerialShaker(f"sim://{rig.name}/shaker")
            daq = SerialDaq(f"sim://{rig.name}/daq")
        elif how == "*RST":
            shaker._scpi.command("*RST")
        with OutputGuard(shaker) as guard:
            shaker.set_sine(10.0, 0.5)
            guard.arm()
            with daq.stream(500) as stream:
                block = stream.read()
            assert np.ptp(block.data[:, 0]) > 0
        assert rig.backend.restarts == 1 and rig.failure is None
        assert [e.kind for e in rig.events if e.instrument == "rig"][:2] == ["failure", "recovered"]
        shaker.close()
        daq.close()


def test_the_rig_simulator_restarts_from_rest_after_a_divergence():
    """A softening spring driven past its stability limit diverges; after the restart the structure is at
    rest (output off: zero response), the clock runs on and it can be driven again."""
    sim = RigSimulator(sdof_rig(100.0, '{ law = "cubic", k3 = -1.0e6 }', damping=0.5))
    sim.set_sine(2.0, 50.0)
    sim.set_output(True)
    with pytest.raises(SimulationError):
        sim.advance(int(20 * sim.sample_rate))
    before = sim.time
    sim.restart_from_rest()
    assert sim.time == before and not sim.output_on
    assert np.all(sim.advance(64) == 0.0)
    sim.set_sine(2.0, 0.01)
    sim.set_output(True)
    assert np.ptp(sim.advance(256)[:, 1]) > 0


def test_a_fast_rig_left_by_its_hosts_is_at_rest_for_the_next_one():
    """No time passes between two hosts of a fast rig: the next one must not find the structure still ringing
    from the last one's drive (a repeated acquisition then measured a free vibration instead of its FRF)."""
    with EmulatedRig(RigSimulator("paper-2dof"), paced=False, name=f"rest{next(_names)}") as rig:
        register(rig)
        for host in ("first", "next"):
            shaker = SerialShaker(f"sim://{rig.name}/shaker")
            daq = SerialDaq(f"sim://{rig.name}/daq")
            if host == "first":
                shaker.set_sine(2.3, 0.8)
                with OutputGuard(shaker) as guard:
                    guard.arm()
                    with daq.stream(256) as stream:
                        moving = np.concatenate([stream.read().data for _ in range(20)])
                assert np.ptp(moving[:, 1]) > 0.1
            else:
                with daq.stream(256) as stream:
                    still = np.concatenate([stream.read().data for _ in range(4)])
                assert np.all(still == 0.0)
            shaker.close()
            daq.close()
