"""The SCPI protocol as command/reply pairs.

Each transcript is checked from both sides: the drivers must send exactly these
commands and accept these replies (through a scripted port), and the emulated
instruments must answer these commands with exactly these replies.
"""
import itertools
import time

import numpy as np
import pytest
import serial

import drivers  # noqa: F401  (registers sim://)
from drivers.daq import SerialDaq
from drivers.emulator import EmulatedRig, register
from drivers.emulator.scpi_server import (ScpiError, ScpiServer, block_data, compile_header, parse_channel_list,
                                          parse_number, split_outside)
from drivers.errors import DeviceError, LinkTimeout, ProtocolError, WrongDevice
from drivers.shaker import SerialShaker
from firmware_host import firmware_binary, serve_firmware  # noqa: F401  (a fixture)
from rig_double import RigDouble, signature

_names = itertools.count()

SHAKER_CONNECT = [
    ("", None),
    ("*IDN?", "contactid,SC-1,proto,1.0"),
    ("*RST;*CLS;:SYST:WDOG 1.0;:SYST:ERR?", '0,"No error"'),
    ("OUTP?;:VOLT:ACT?;:SYST:ERR:COUN?;:SYST:WDOG?", "0;0;0;1"),
    ("FREQ? MIN;:FREQ? MAX;:VOLT:UNIT VPP;:VOLT? MAX;:VOLT:RAMP?", "0.01;450;20;2"),
]
SHAKER_SESSION = [
    ("FUNC SIN;:VOLT:UNIT VPP;:FREQ 12.5;:VOLT 1.0;:SYST:ERR?", '0,"No error"'),
    ("VOLT:RAMP 5.0;:SYST:ERR?", '0,"No error"'),
    ("OUTP ON;:SYST:ERR?", '0,"No error"'),
    ("OUTP?", "1"),
    ("OUTP OFF;:SYST:ERR?", '0,"No error"'),
    ("OUTP?", "0"),
    ("FUNC NOIS;:VOLT:UNIT VRMS;:FUNC:NOIS:BAND 0.5,100.0;:VOLT 0.2;:SYST:ERR?", '0,"No error"'),
]
DAQ_CONNECT = [
    ("", None),
    ("ABOR", None),
    ("", None),
    ("*IDN?", "contactid,DAQ-1,proto,1.0"),
    ("*RST;*CLS;:SYST:ERR?", '0,"No error"'),
    ("SYST:ERR:COUN?", "0"),
    ("SYST:CHAN:COUN?", "3"),
    ("SENS:CHAN1:NAME?", "force"), ("SENS:CHAN1:UNIT?", "N"), ("SENS:CHAN1:LSB?", "0.0001"),
    ("SENS:CHAN2:NAME?", "acc:x1"), ("SENS:CHAN2:UNIT?", "m/s^2"), ("SENS:CHAN2:LSB?", "0.001"),
    ("SENS:CHAN3:NAME?", "acc:x2"), ("SENS:CHAN3:UNIT?", "m/s^2"), ("SENS:CHAN3:LSB?", "0.001"),
    ("ROUT:SCAN?", "(@1,2,3)"),
    ("SRAT?", "1000"),
    ("STR:POIN?", "20"),
]
SHAKER_PAIRS = [
    ("*RST;:OUTP?;:FUNC?;:FREQ?;:VOLT?;:VOLT:UNIT?;:VOLT:RAMP?;:SYST:WDOG?", "0;SIN;10;0.1;VPP;2;10"),
    ("sour:freq 12.5;:FREQ?", "12.5"),
    ("SOURCE:FREQUENCY? MAX;:SOUR:FREQ? MIN", "450;0.01"),
    ("FREQU 3;:SYST:ERR?", '-113,"Undefined header;FREQU"'),
    ("FREQ 1kHz;:SYST:ERR?", '-131,"Invalid suffix;values are in SI base units without suffix"'),
    ("FREQ 451;:SYST:ERR?", '-222,"Data out of range;valid range 0.01 to 450"'),
    ("FREQ;:SYST:ERR?", '-109,"Missing parameter"'),
    ("FREQ 1,2;:SYST:ERR?", '-108,"Parameter not allowed"'),
    ("FREQ abc;:SYST:ERR?", "-104,\"Data type error;expected a number, got 'abc'\""),
    ("FREQ? 3;:SYST:ERR?", '-224,"Illegal parameter value;expected MIN|MAX"'),
    ("FUNC SQU;:SYST:ERR?", '-224,"Illegal parameter value;expected SINusoid|NOISe"'),
    ("VOLT 21;:SYST:ERR?", '-222,"Data out of range;valid range 0 to 20"'),
    ("VOLT:UNIT VRMS;:VOLT MAX;:VOLT?", "7.071067811865475"),
    ("FUNC NOIS;:VOLT?;:VOLT:UNIT VPP;:VOLT?", "3.3333333333333335;20"),
    ("FUNC:NOIS:BAND 2,100;:FUNC:NOIS:BAND?", "2,100"),
    ("FUNC:NOIS:BAND 100;:SYST:ERR?", '-109,"Missing parameter;expected <low Hz>,<high Hz>"'),
    ("FUNC:NOIS:BAND 5,2;:SYST:ERR?", '-222,"Data out of range;the low edge must be below the high edge"'),
    ("OUTP ON;:OUTP?;:VOLT:ACT?", "1;0"),
    ("FUNC SIN;:SYST:ERR?", '-221,"Settings conflict;switch the output off before changing the function"'),
    ("OUTP OFF;:OUTP?;:FUNC SIN;:FUNC?", "0;SIN"),
    ("VOLT:RAMP 0;:SYST:ERR?", '-222,"Data out of range;valid range 0.001 to 1000"'),
    ("SYST:WDOG 0.001;:SYST:ERR?", '-222,"Data out of range;0 (off) or 0.01 to 3600 s"'),
    ("SYST:WDOG 0;:SYST:WDOG?;:SYST:WDOG:FEED", "0"),
    ("OUTP MAYBE;:SYST:ERR?", '-224,"Illegal parameter value;expected ON|OFF|1|0"'),
    ("*IDN? 1;:SYST:ERR?", '-108,"Parameter not allowed"'),
    ("*OPC?;*TST?;:SYST:VERS?", "1;0;1999.0"),
    ("SYST:ERR:COUN?", "0"),
]
DAQ_PAIRS = [
    ("SENS:CHAN2:NAME?;:SENS:CHAN2:UNIT?;:SENSE:CHANNEL3:LSB?", "acc:x1;m/s^2;0.001"),
    ("SENS:CHAN4:NAME?;:SYST:ERR?", '-114,"Header suffix out of range;channels are 1 to 3"'),
    ("ROUT:SCAN (@3,1);:ROUT:SCAN?", "(@3,1)"),
    ("ROUT:SCAN (@1:4);:SYST:ERR?", '-222,"Data out of range;channels are 1 to 3"'),
    ("ROUT:SCAN (@1,1);:SYST:ERR?", '-224,"Illegal parameter value;channel listed twice"'),
    ("ROUT:SCAN 1,2;:SYST:ERR?", '-108,"Parameter not allowed"'),
    ("SRAT 500;:SYST:ERR?", '-222,"Data out of range;this DAQ samples at 1000 Hz only"'),
    ("SRAT 1000;:SRAT?;:SRAT:LIST?", "1000;1000"),
    ("STR:POIN 0;:SYST:ERR?", '-222,"Data out of range;valid range 1 to 4096"'),
    ("STR:POIN 2.5;:SYST:ERR?", '-104,"Data type error;expected an integer"'),
    ("STR:POIN 64;:STR:POIN?", "64"),
    ("SENS:CHAN1:SENS 0.02;:SENS:CHAN1:SENS?;:SENS:CHAN1:RANG 5;:SENS:CHAN1:RANG?", "0.02;5"),
    ("*RST;:ROUT:SCAN?;:STR:POIN?;:SENS:CHAN1:SENS?;:SENS:CHAN1:RANG?", "(@1,2,3);20;0.01;10"),
    ("STR:COUN?", "0"),
    ("READ? 0;:SYST:ERR?", '-222,"Data out of range;valid range 1 to 1048576"'),
]

DAQ_BAD_INPUT = [
    ("NOPE;:SYST:ERR?", '-113,"Undefined header;NOPE"'),
    ("SENS:CHAN1:SENSI?;:SYST:ERR?", '-113,"Undefined header;SENS:CHAN1:SENSI"'),
    ("SENS:CHAN1:NAME;:SYST:ERR?", '-113,"Undefined header;SENS:CHAN1:NAME is query only"'),
    ("*RST?;:SYST:ERR?", '-113,"Undefined header;*RST? is not a query"'),
    ("READ?;:SYST:ERR?", '-109,"Missing parameter"'),
    ("READ? 1 s;:SYST:ERR?", '-131,"Invalid suffix;values are in SI base units without suffix"'),
    ("SENS:CHAN1:SENS 1e3;:SYST:ERR?", '-222,"Data out of range;valid range 1e-06 to 100"'),
    ("SENS:CHAN0:SENS?;:SYST:ERR?", '-114,"Header suffix out of range;channels are 1 to 3"'),
    ("SENS:CHAN99999999999:NAME?;:SYST:ERR?", '-114,"Header suffix out of range;channels are 1 to 3"'),
    ("SENS:CHAN1:RANG? MAX;:SENS:CHAN1:RANG? MIN;:SENS:CHAN1:SENS? MAX", "50;0.001;100"),
    ("SENS:CHAN1:RANG 2;:SENS:CHAN1:RANG DEF;:SENS:CHAN1:RANG?", "10"),
    ("ROUT:SCAN @1;:SYST:ERR?", '-104,"Data type error;expected a channel list such as (@1,2:4)"'),
    ("ROUT:SCAN (@2:1);:SYST:ERR?", '-222,"Data out of range;channels are 1 to 3"'),
    ("ROUT:SCAN (@1234567);:SYST:ERR?", '-222,"Data out of range;channels are 1 to 3"'),
    ("ROUT:SCAN (@);:SYST:ERR?", '-104,"Data type error;expected a channel list such as (@1,2:4)"'),
    ("ROUT:SCAN (@1:2:3);:SYST:ERR?", "-104,\"Data type error;bad channel range '1:2:3'\""),
    ("ROUT:SCAN (@1,,2);:SYST:ERR?", "-104,\"Data type error;bad channel range ''\""),
    ("ROUT:SCAN (@ 2 : 3 ,1) ;:ROUT:SCAN?;:ROUT:SCAN (@1:3)", "(@2,3,1)"),
    ("SYST:ERR:COUN? 1;:SYST:ERR?", '-108,"Parameter not allowed"'),
    ("SRAT? MAX;:SYST:ERR?", '-108,"Parameter not allowed"'),
    ("STR:POIN? MAX;:STR:POIN MIN;:STR:POIN?", "4096;1"),
    ("sens:chan3:lsb?;:SENSE:CHANNEL3:UNIT?", "0.001;m/s^2"),
    ("  ;; STR:COUN? ;*TST?;:SYSTEM:ERROR:NEXT?;:SYST:VERS?;*OPC?", '0;0;0,"No error";1999.0;1'),
    ("SYST:ERR:COUN?;SENS:CHAN1:RANG 0.0001;SENS:CHAN1:RANG 1e-3;SYST:ERR?",
     '0;-222,"Data out of range;valid range 0.001 to 50"'),
    ("SENS:CHAN1:NAME?\xb5;:SYST:ERR?;:SYST:ERR?", None),      # not executed: non-ASCII
    ("SYST:ERR?;:SYST:ERR?", '-102,"Syntax error;non-ASCII byte";0,"No error"'),
]


class ScriptedPort(serial.SerialBase):
    """A port that checks every line the driver writes against a script and answers it.

    ``OUTP?`` heartbeats that the script does not expect are answered ``0``.
    """

    def __init__(self, script):
        self.script = list(script)
        self.rx = bytearray()
        super().__init__()
        self.port = "script://"
        self.is_open = True

    def _reconfigure_port(self):
        pass

    def write(self, data):
        for line in bytes(data).decode().split("\n")[:-1]:
            if self.script and self.script[0][0] == line:
                _, reply = self.script.pop(0)
                if reply is not None:
                    self.rx += reply.encode() + b"\n"
            elif line == "OUTP?":
                self.rx += b"0\n"
            else:
                expected = self.script[0][0] if self.script else "nothing"
                raise AssertionError(f"driver wrote {line!r}, script expected {expected!r}")
        return len(data)

    def read(self, size=1):
        if not self.rx and self._timeout:
            time.sleep(self._timeout)
        data = bytes(self.rx[:size])
        del self.rx[:size]
        return data

    def reset_input_buffer(self):
        self.rx.clear()

    def close(self):
        self.is_open = False


@pytest.fixture
def rig():
    with EmulatedRig(RigDouble(), paced=False, name="proto") as emulated:
        name = f"proto{next(_names)}"
        register(emulated, name)
        emulated.url_name = name
        yield emulated


@pytest.fixture(params=["emulator", "firmware"])
def daq_url(request):
    """The DAQ's URL: the emulated DAQ-1, or the firmware core built for the host on a pty."""
    if request.param == "emulator":
        yield f"sim://{request.getfixturevalue('rig').url_name}/daq"
    else:
        with serve_firmware(request.getfixturevalue("firmware_binary")) as url:
            yield url


def replay(url, pairs):
    """Send each command over a raw port; the replies in order (None where none came)."""
    port = serial.serial_for_url(url, timeout=0.2)
    try:
        replies = []
        for command, expected in pairs:
            port.write(command.encode() + b"\n")
            if expected is None:
                port.write(b"*OPC?\n")  # a reply that proves the command was processed
                assert port.readline() == b"1\n"
                replies.append(None)
            else:
                replies.append(port.readline().decode().rstrip("\n"))
        return replies
    finally:
        port.close()


# ----- driver side ------------------------------------------------------------------------------
def test_shaker_driver_sends_the_documented_commands():
    port = ScriptedPort(SHAKER_CONNECT + SHAKER_SESSION)
    shaker = SerialShaker("script://", port=port, timeout=0.5)
    assert (shaker.frequency_range, shaker.amplitude_range, shaker.ramp_rate) == ((0.01, 450.0), (0.0, 10.0), 2.0)
    shaker.set_sine(12.5, 0.5)
    shaker.set_ramp_rate(5.0)
    shaker.attach_guard(object())
    shaker.arm()
    assert shaker.output_enabled()
    shaker.disarm()
    shaker.set_noise(0.2, (0.5, 100.0))
    assert port.script == []
    port.script = [("OUTP OFF;:SYST:ERR?", '0,"No error"'), ("OUTP?", "0")]
    shaker.close()
    assert port.script == []


def test_daq_driver_sends_the_documented_commands():
    port = ScriptedPort(DAQ_CONNECT)
    daq = SerialDaq("script://", port=port, timeout=0.5)
    assert daq.channels == ("force", "acc:x1", "acc:x2")
    assert daq.units == ("N", "m/s^2", "m/s^2")
    np.testing.assert_array_equal(daq.lsb, [1e-4, 1e-3, 1e-3])
    assert (daq.sample_rate, daq.frame_points) == (1000.0, 20)
    assert port.script == []
    counts = np.arange(6, dtype="<i4").reshape(2, 3)
    reply = block_data(counts.tobytes()).decode("latin-1")
    port.script = [("READ? 2", reply)]
    block = daq.read(2)
    np.testing.assert_allclose(block.data, counts * daq.lsb)
    daq.close()


def test_the_emulator_answers_the_driver_transcripts(rig):
    base = f"sim://{rig.url_name}"
    assert replay(f"{base}/shaker", SHAKER_CONNECT + SHAKER_SESSION) == [r for _, r in SHAKER_CONNECT + SHAKER_SESSION]


def test_the_daq_answers_the_driver_transcript(daq_url):
    assert replay(daq_url, DAQ_CONNECT) == [r for _, r in DAQ_CONNECT]


def test_a_rejected_setting_raises_device_error_with_the_whole_queue():
    port = ScriptedPort(SHAKER_CONNECT + [
        ("FUNC SIN;:VOLT:UNIT VPP;:FREQ 900.0;:VOLT 1.0;:SYST:ERR?", '-222,"Data out of range"'),
        ("SYST:ERR?", '-221,"Settings conflict"'),
        ("SYST:ERR?", '0,"No error"'),
    ])
    shaker = SerialShaker("script://", port=port, timeout=0.5)
    with pytest.raises(DeviceError) as info:
        shaker.set_sine(900.0, 0.5)
    assert info.value.codes == [-222, -221]
    assert "FREQ 900.0" in str(info.value) and str(info.value).startswith("script://:")


@pytest.mark.parametrize("reply, error", [
    ("Keysight Technologies,33522B,MY12345,4.03", WrongDevice),
    ("\x15\x7f garbage", WrongDevice),
    ("contactid,DAQ-1,bench,1.0", WrongDevice),
    (None, LinkTimeout),
])
@pytest.mark.slow
def test_wrong_or_silent_device_is_a_clear_error(reply, error):
    port = ScriptedPort([("", None), ("*IDN?", reply)])
    with pytest.raises(error) as info:
        SerialShaker("script://", port=port, timeout=0.2)
    message = str(info.value)
    assert message.startswith("script://:")
    assert ("not a contactid shaker controller" in message) if error is WrongDevice else ("*IDN?" in message)


def test_malformed_replies_are_protocol_errors():
    port = ScriptedPort(SHAKER_CONNECT + [("VOLT:RAMP 1.0;:SYST:ERR?", "all good")])
    shaker = SerialShaker("script://", port=port, timeout=0.5)
    with pytest.raises(ProtocolError):
        shaker.set_ramp_rate(1.0)
    port = ScriptedPort(DAQ_CONNECT + [("READ? 2", "#0 indefinite")])
    daq = SerialDaq("script://", port=port, timeout=0.5)
    with pytest.raises(ProtocolError):
        daq.read(2)


# ----- instrument side --------------------------------------------------------------------------
def test_shaker_command_reply_pairs(rig):
    pairs = SHAKER_PAIRS
    assert replay(f"sim://{rig.url_name}/shaker", pairs) == [r for _, r in pairs]


def test_daq_command_reply_pairs(daq_url):
    pairs = DAQ_PAIRS
    assert replay(daq_url, pairs) == [r for _, r in pairs]


def test_daq_bad_input_pairs(daq_url):
    pairs = DAQ_BAD_INPUT
    assert replay(daq_url, pairs) == [r for _, r in pairs]


def test_daq_refuses_a_message_over_4096_bytes_whole_even_in_pieces(daq_url):
    message = b"STR:POIN 30" + b";" * 5000 + b";STR:POIN 40\n"
    longest = b"STR:POIN 50" + b";" * (4096 - 11) + b"\n"   # the limit itself is accepted
    port = serial.serial_for_url(daq_url, timeout=2.0)
    for piece in (message[:3000], message[3000:4500], message[4500:]):
        port.write(piece)
    port.write(b"STR:POIN?;:SYST:ERR?;:SYST:ERR?\n")
    assert port.readline() == b'20;-363,"Input buffer overrun";0,"No error"\n'
    port.write(longest + b"STR:POIN?;:SYST:ERR?\n")
    assert port.readline() == b'50;0,"No error"\n'
    port.write(b"NOPE;" * 25 + b"SYST:ERR:COUN?\n")
    assert port.readline() == b"20\n"
    port.write(b"SYST:ERR?;" * 20 + b"SYST:ERR?\n")
    assert port.readline() == b";".join([b'-113,"Undefined header;NOPE"'] * 19
                                        + [b'-350,"Queue overflow"', b'0,"No error"']) + b"\n"
    port.close()


def test_daq_block_read_returns_definite_length_block_of_exact_counts(rig):
    port = serial.serial_for_url(f"sim://{rig.url_name}/daq", timeout=0.5)
    start = rig.daq.rig.samples
    port.write(b"READ? 4\n")
    head = port.read(4)
    assert head == b"#248"
    counts = np.frombuffer(port.read(48), dtype="<i4").reshape(4, 3)
    assert port.read(1) == b"\n"
    index = np.arange(start, start + 4)
    np.testing.assert_array_equal(counts, np.column_stack([signature(index, k) for k in range(3)]))
    port.close()


def test_daq_rejects_commands_while_streaming_and_reports_them_after_abort(daq_url):
    port = serial.serial_for_url(daq_url, timeout=0.2)
    port.write(b"INIT\nINIT\nROUT:SCAN?\nSTR:POIN 8\n")
    port.read(2000)
    port.write(b"ABOR\n")
    port.read(100000)
    port.write(b"SYST:ERR?;:SYST:ERR?;:SYST:ERR?;:SYST:ERR?\n")
    assert port.readline() == (b'-213,"Init ignored;acquisition already running";'
                               b'-221,"Settings conflict;acquisition running; send ABORt first";'
                               b'-221,"Settings conflict;acquisition running; send ABORt first";'
                               b'0,"No error"\n')
    port.close()


def test_a_message_that_stops_the_stream_runs_as_sent_while_streaming(daq_url):
    from drivers.stream import FrameDecoder

    port = serial.serial_for_url(daq_url, timeout=0.3)
    port.write(b"INIT\n")
    data = port.read(3000)
    port.write(b"ABOR;*IDN?\n")
    data += port.read(1000000)
    decoder = FrameDecoder(3, 20)
    frames = decoder.feed(data)
    assert decoder.ended and frames[-1].is_end
    assert sum(f.points for f in frames) == frames[-1].first_sample > 0
    assert [f.gap for f in frames] == [None] * len(frames)
    assert bytes(decoder.remainder()) == b""
    port.write(b"SYST:ERR?;:SYST:ERR?\n")
    assert port.readline() == b'-221,"Settings conflict;acquisition running; send ABORt first";0,"No error"\n'
    port.close()


def test_error_queue_overflow_keeps_the_oldest_and_marks_the_newest():
    server = ScpiServer()
    for _ in range(25):
        server.execute("NOPE")
    entries = [server.errors.pop() for _ in range(21)]
    assert [e.code for e in entries[:19]] == [-113] * 19
    assert entries[19].code == -350 and entries[20].code == 0


def test_header_patterns_accept_short_long_optional_and_suffix_forms():
    frequency = compile_header("[SOURce:]FREQuency")
    for header in ("FREQ", "FREQUENCY", "SOUR:FREQ", "SOURCE:FREQUENCY", ":SOUR:FREQ"):
        assert frequency.match(header)
    for header in ("FRE", "FREQU", "SOURC:FREQ", "SOUR:FREQ:X"):
        assert not frequency.match(header)
    channel = compile_header("SENSe:CHANnel#:RANGe")
    assert channel.match("SENS:CHAN12:RANG").groups() == ("12",)
    assert channel.match("SENSE:CHANNEL:RANGE").groups() == ("",)
    assert compile_header("OUTPut[:STATe]").match("OUTP:STAT")


def test_parameter_parsing():
    assert parse_number("MAX", 0.0, 5.0) == 5.0 and parse_number("min", 0.0, 5.0) == 0.0
    assert parse_number("DEF", 0.0, 5.0, 2.0) == 2.0
    assert parse_number("+1.5e0", 0.0, 5.0) == 1.5 and parse_number(".5", 0.0, 5.0) == 0.5
    for text, code in (("6", -222), ("1 V", -131), ("one", -104), ("1.2.3", -104)):
        with pytest.raises(ScpiError) as info:
            parse_number(text, 0.0, 5.0)
        assert info.value.code == code
    assert parse_channel_list("(@1,3:4)", 4) == [0, 2, 3]
    assert split_outside('A "x;y";B (@1,2);C', ";") == ['A "x;y"', "B (@1,2)", "C"]
    assert block_data(b"abc") == b"#13abc" and block_data(b"x" * 12) == b"#212" + b"x" * 12


class _LatePort:
    """A port whose replies arrive only when released: the reply to a timed-out query comes late."""

    def __init__(self):
        self.timeout = 0.01
        self.pending = bytearray()
        self.held = []
        self.written = []

    def write(self, data):
        self.written.append(bytes(data))
        command = bytes(data).strip()
        reply = {b"OUTP?": b"0\n", b"*IDN?": b"contactid,shaker,emu1,1.0\n",
                 b"SYST:ERR?": b'0,"No error"\n'}[command]
        self.held.append(reply)
        return len(data)

    def release(self):
        while self.held:
            self.pending += self.held.pop(0)

    def read(self, size):
        self.release() if len(self.written) > 1 else None     # the first reply is late
        out = bytes(self.pending[:size])
        del self.pending[:size]
        return out

    def reset_input_buffer(self):
        self.pending.clear()


def test_a_late_reply_after_a_timeout_is_not_taken_for_the_next_answer():
    from drivers.errors import LinkTimeout
    from drivers.scpi import PortIO, ScpiInstrument

    port = _LatePort()
    io = PortIO(port, "late://", lambda: None)
    scpi = ScpiInstrument(link=type("Link", (), {"url": "late://"})(), timeout=0.05)
    with pytest.raises(LinkTimeout):
        scpi.ask(io, "OUTP?")                    # its reply "0" arrives only after the next write
    assert io.desynced
    assert scpi.ask(io, "SYST:ERR?") == '0,"No error"'
    assert port.written[1].strip() == b"*IDN?"   # resynchronised on a reply no other query gives
