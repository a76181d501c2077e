"""Timeouts on a busy machine: an in-process emulated instrument is never late by the wall clock, and a real
instrument's one late reply is waited for (and logged) before the run is given up."""
import logging
import threading
import time

import pytest

from app.campaign.instruments import emulated_instruments
from drivers.emulator.shaker import ShakerFirmware
from drivers.errors import LinkTimeout
from drivers.scpi import PortIO, ScpiInstrument
from drivers.simulation.rig import load_rig


class _SlowPort:
    """A port that answers each query ``delay`` s (wall clock) after it was written."""

    def __init__(self, delay):
        self.timeout = 0.01
        self.delay = delay
        self.due = []            # (time, reply)
        self.rx = bytearray()

    def write(self, data):
        self.due.append((time.monotonic() + self.delay, b"0\n"))
        return len(data)

    def read(self, size):
        now = time.monotonic()
        while self.due and self.due[0][0] <= now:
            self.rx += self.due.pop(0)[1]
        if not self.rx:
            time.sleep(self.timeout)
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def reset_input_buffer(self):
        self.rx.clear()


def _instrument(delay, timeout=0.2):
    port = _SlowPort(delay)
    return ScpiInstrument(link=type("Link", (), {"url": "slow://"})(), timeout=timeout), PortIO(port, "slow://",
                                                                                              lambda: None)


def test_a_real_instruments_late_reply_is_waited_for_once_and_the_wait_is_logged(caplog):
    scpi, io = _instrument(delay=0.3)              # later than its 0.2 s, within a second 0.2 s
    with caplog.at_level(logging.WARNING, logger="contactid.drivers"):
        assert scpi.ask(io, "OUTP?") == "0"
    assert any("slow://" in r.message and "'OUTP?'" in r.message and "late" in r.message for r in caplog.records)
    assert not io.desynced


def test_a_reply_late_twice_over_fails_the_request_naming_both_waits():
    scpi, io = _instrument(delay=0.6)
    with pytest.raises(LinkTimeout, match=r"'OUTP\?' within 0.2 s \(and 0.2 s more after it was late\)"):
        scpi.ask(io, "OUTP?")


@pytest.mark.slow
def test_an_in_process_instrument_slower_than_the_timeout_by_the_wall_clock_is_not_late(monkeypatch):
    """A reply the emulator takes 2.5 s of wall time to make -- as on a machine busy with other work -- is
    not late: the host's deadline counts the emulator's idle time only (without that, 1 s and 1 s more)."""
    slow = threading.Event()
    handle = ShakerFirmware.handle_line

    def handle_slowly(self, line, generation=None):
        if line == b"OUTP?" and not slow.is_set():
            slow.set()
            time.sleep(2.5)
        return handle(self, line, generation)

    with emulated_instruments(load_rig("paper-2dof")) as inst:
        monkeypatch.setattr(ShakerFirmware, "handle_line", handle_slowly)
        assert inst.shaker.output_enabled() is False
    assert slow.is_set()


@pytest.mark.slow
def test_an_in_process_instrument_that_stays_silent_still_times_out():
    with emulated_instruments(load_rig("paper-2dof")) as inst:
        inst.emulator.inject("shaker", {"drop": 1.0})
        began = time.monotonic()
        with pytest.raises(LinkTimeout):
            inst.shaker.output_enabled()
        assert time.monotonic() - began < 30
        inst.emulator.inject("shaker", {})      # the link back, for closing
