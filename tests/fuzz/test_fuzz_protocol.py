"""Fuzz corpus: raw protocol bytes. Hostile bytes sent to the emulated instruments leave them answering (and the
output off); hostile replies and stream bytes reaching the drivers raise an instrument error or a stream format
error -- never another exception, never a hang."""
import itertools
import time

import numpy as np
import pytest
import serial

from drivers.emulator import EmulatedRig, register
from drivers.errors import InstrumentError
from drivers.scpi import PortIO, ScpiInstrument
from drivers.stream import FrameDecoder, StreamFormatError, encode_end, encode_frame
from fuzz_runner import FAST_PER_GROUP
from rig_double import RigDouble

_names = itertools.count()

TO_INSTRUMENT = [
    b"", b"\n\n\n", b"\x00" * 64, bytes(range(256)), b"\xff\xfe garbage \x80\n", b"A" * 5000, b"A" * 70000 + b"\n",
    b"*IDN", b"*IDN?;" * 2000, b";;;;\n", b":::\n", b"FREQ 1e999", b"FREQ nan", b"FREQ -5", b"FREQ inf",
    b"VOLT 1e308", b"VOLT -1", b"OUTP maybe", b"OUTP ON;OUTP ON;OUTP ON", b"FUNC:NOIS:BAND 5,1", b"VOLT:UNIT FURLONG",
    b"SENS:CHAN999:NAME?", b"SENS:CHAN0:SENS 1", b"SENS:CHAN1:SENS 1e-300", b"ROUT:SCAN (@9:1)", b"ROUT:SCAN (@)",
    b"READ? 99999999999", b"READ? -1", b"READ? 0", b"STR:POIN -1", b"STR:POIN 1e12", b"INIT;INIT;INIT",
    b"ABOR;ABOR", b"SRAT 1", b'SYST:ERR? "', b"\r\r\r\n", b"*RST\r\n*CLS\r\n" * 100, b"#9999999999",
]
ROLES = ("shaker", "daq")


def _params(items, group):
    return [pytest.param(item, id=f"{group}{i}", marks=() if i < FAST_PER_GROUP else (pytest.mark.slow,))
            for i, item in enumerate(items)]


@pytest.fixture(scope="module")
def rig():
    with EmulatedRig(RigDouble(), paced=False, name="fuzz") as emulated:
        name = f"fuzz{next(_names)}"
        register(emulated, name)
        emulated.url_name = name
        yield emulated


@pytest.mark.parametrize("role", ROLES)
@pytest.mark.parametrize("data", _params(TO_INSTRUMENT, "bytes"))
def test_hostile_bytes_leave_the_emulated_instrument_answering_with_its_output_off(rig, role, data):
    port = serial.serial_for_url(f"sim://{rig.url_name}/{role}", timeout=0.05)
    try:
        port.write(data + b"\n")
        port.write(b"ABOR\n" if role == "daq" else b"OUTP OFF\n")
        port.write(b"*IDN?\n")
        deadline, reply = time.monotonic() + 20, b""
        while time.monotonic() < deadline and b"contactid," not in reply:
            reply = (reply + port.read(65536))[-100_000:]
        assert b"contactid," in reply, f"no identity after {data[:40]!r}"
    finally:
        port.close()
    assert not rig.shaker.output_on and rig.failure is None


class _ReplyPort:
    """A port answering every query with ``reply``."""

    def __init__(self, reply):
        self.timeout = 0.01
        self.reply = reply
        self.rx = bytearray()

    def write(self, data):
        self.rx += self.reply
        return len(data)

    def read(self, size):
        out = bytes(self.rx[:size])
        del self.rx[:size]
        if not out:
            time.sleep(self.timeout)
        return out

    def reset_input_buffer(self):
        self.rx.clear()


TO_DRIVER = [b"", b"\n", b"nan\n", b"1e999\n", b"\xff\xfe\n", b"0,1,2,3\n", b"A" * 70000, b"#\n", b"#0\n",
             b"#9\n", b"#15abc\n", b"#2xx" + b"0" * 10 + b"\n", b"#15abcdeEXTRA\n", b'-222,"x\n', b'abc,"x"\n',
             b"1;2;3\n", b"\r\n\r\n", b"\x00" * 10 + b"\n"]


@pytest.mark.parametrize("reply", _params(TO_DRIVER, "reply"))
def test_a_hostile_reply_is_an_instrument_error_for_the_driver(reply):
    scpi = ScpiInstrument(link=type("Link", (), {"url": "fuzz://"})(), timeout=0.05)
    for ask in (lambda io: float(scpi.ask(io, "VOLT:ACT?")), lambda io: scpi.ask_block(io, "READ? 4"),
                lambda io: scpi.execute(io, "OUTP OFF"), lambda io: scpi.drain_errors(io)):
        io = PortIO(_ReplyPort(reply), "fuzz://", lambda: None)
        try:
            ask(io)
        except (InstrumentError, ValueError):    # ValueError: float() of a reply, as query_float reports it
            pass


def _frames() -> bytes:
    counts = np.arange(12, dtype=np.int32).reshape(4, 3)
    return encode_frame(0, 0, counts) + encode_frame(1, 4, counts) + encode_end(2, 8, 3)


def _stream_mutations():
    good = _frames()
    yield good[: len(good) // 2]
    yield good[::-1]
    yield bytes(len(good))
    yield b"\xff" * 200
    for position in np.linspace(0, len(good) - 1, 16).astype(int):
        flipped = bytearray(good)
        flipped[position] ^= 0x01
        yield bytes(flipped)


@pytest.mark.parametrize("data", _params(list(_stream_mutations()), "stream"))
def test_hostile_stream_bytes_are_skipped_or_a_format_error(data):
    decoder = FrameDecoder(3, 16)
    try:
        for i in range(0, len(data), 7):
            for frame in decoder.feed(data[i:i + 7]):
                assert frame.counts.shape[1] == 3
    except StreamFormatError:
        pass
