"""The DAQ-1 firmware core (firmware/core), built for the host, through the DAQ driver over a pty.

The command/reply transcripts run against it in tests/test_protocol.py (``daq_url``); here the stream,
block reads, overruns and saturation, checked sample by sample against the host board's test signal.
"""
import time

import numpy as np
import pytest
import serial

from drivers.daq import SerialDaq
from drivers.errors import DeviceError
from firmware_host import firmware_binary, host_signal, serve_firmware  # noqa: F401  (a fixture)

LOST_MARK = -(1 << 31)


def truth(first, n, scan):
    """The counts the host board produces for samples first .. first+n-1 of the scanned channels."""
    index = np.arange(first, first + n)
    return np.column_stack([host_signal(index, c) for c in scan])


def counts_of(block, daq):
    return np.rint(block.data / daq.lsb).astype(np.int64)


def collect(stream, blocks_before_stop):
    """Blocks read before and after stopping the stream, and the stream's stats."""
    blocks = [stream.read() for _ in range(blocks_before_stop)]
    stats = stream.stop()
    return blocks + list(stream), stats


@pytest.mark.slow
def test_a_stream_delivers_every_sample_in_scan_order_with_a_balanced_end(firmware_binary):
    with serve_firmware(firmware_binary) as url:
        daq = SerialDaq(url, timeout=2.0)
        daq.configure(channels=["acc:x2", "force"], frame_points=7)
        with daq.stream(50) as stream:
            blocks, stats = collect(stream, 6)
        assert stats.balanced and stats.end_frame_received
        assert (stats.gaps, stats.corrupt_frames, stats.skipped_bytes, stats.overrun_frames) == ([], 0, 0, 0)
        assert stats.samples_sent >= 300
        assert blocks[0].first_sample == 0 and all(not b.gaps and not b.overload for b in blocks)
        received = np.concatenate([counts_of(b, daq) for b in blocks])
        np.testing.assert_array_equal(received, truth(0, stats.samples_sent, [2, 0]))
        assert daq._scpi.query("STR:COUN?") == str(stats.samples_sent)
        assert daq.errors() == []
        daq.close()


@pytest.mark.slow
def test_a_host_too_slow_for_the_fifo_sees_gaps_overrun_flags_and_error_301_once_per_episode(firmware_binary):
    with serve_firmware(firmware_binary, "--rates", "20000") as url:
        daq = SerialDaq(url, timeout=2.0)
        with daq.stream(2000, buffered_blocks=1) as stream:
            blocks = [stream.read()]
            time.sleep(2.0)    # 480 kB sampled meanwhile: more than the 96 KiB FIFO and the pty hold
            more, stats = collect(stream, 10)
        blocks += more
        assert stats.balanced and stats.gaps and stats.overrun_frames >= 1
        assert stats.corrupt_frames == 0
        assert all(gap.samples % daq.frame_points == 0 for gap in stats.gaps)   # whole frames are lost
        for block in blocks:
            np.testing.assert_array_equal(counts_of(block, daq), truth(block.first_sample, len(block.data), [0, 1, 2]))
        assert sum(len(b.data) for b in blocks) == stats.samples_received
        assert [e.code for e in daq.errors()] == [301] * stats.overrun_frames
        daq.close()


def test_saturated_samples_are_clipped_at_the_range_and_flag_their_frames(firmware_binary):
    with serve_firmware(firmware_binary) as url:
        daq = SerialDaq(url, timeout=2.0)
        # acc:x1 saturates at 0.1 V / 0.01 V per unit = 10 m/s^2 = 10000 counts; force counts halve
        daq.configure(ranges={"acc:x1": 0.1}, sensitivities={"force": 0.02})
        with daq.stream(daq.frame_points) as stream:
            blocks, stats = collect(stream, 30)
        assert stats.balanced and not stats.gaps
        for block in blocks:
            expected = truth(block.first_sample, len(block.data), [0, 1, 2])
            expected[:, 0] = np.rint(expected[:, 0] * 0.5)
            saturated = np.abs(expected[:, 1]) > 10000
            expected[:, 1] = np.clip(expected[:, 1], -10000, 10000)
            np.testing.assert_array_equal(counts_of(block, daq), expected)
            assert block.overload == bool(saturated.any())   # blocks are whole frames here
        assert any(b.overload for b in blocks) and not all(b.overload for b in blocks)
        daq.close()


def test_a_block_read_returns_the_next_samples_exactly(firmware_binary):
    with serve_firmware(firmware_binary) as url:
        daq = SerialDaq(url, timeout=2.0)
        daq.configure(channels=["acc:x1", "force"])
        block = daq.read(300)
        np.testing.assert_array_equal(counts_of(block, daq), truth(0, 300, [1, 0]))
        assert daq.errors() == []
        daq.close()


@pytest.mark.slow
def test_a_block_read_the_host_does_not_take_marks_its_lost_samples_and_queues_200(firmware_binary):
    with serve_firmware(firmware_binary, "--rates", "20000") as url:
        port = serial.serial_for_url(url, timeout=10.0)
        port.write(b"READ? 40000;*OPC?\n")
        time.sleep(2.5)     # the FIFO and the pty fill up
        assert port.read(8) == b"#6480000"
        rows = np.frombuffer(port.read(480000), dtype="<i4").reshape(40000, 3)
        assert port.readline() == b";1\n"
        port.write(b"SYST:ERR?;:SYST:ERR?\n")
        reply = port.readline().decode()
        port.close()
    lost = np.all(rows == LOST_MARK, axis=1)
    assert 0 < lost.sum() < 40000
    np.testing.assert_array_equal(rows[~lost], truth(0, 40000, [0, 1, 2])[~lost])
    assert reply == (f'-200,"Execution error;READ? lost {lost.sum()} samples (FIFO or ADC overrun), '
                     f'marked {LOST_MARK}";0,"No error"\n')


def test_a_message_with_a_nul_byte_is_not_executed(firmware_binary):
    with serve_firmware(firmware_binary) as url:
        port = serial.serial_for_url(url, timeout=2.0)
        port.write(b"STR:POIN 30;\x00;:STR:POIN 40\nSTR:POIN?;:SYST:ERR?;:SYST:ERR?\n")
        assert port.readline() == b'20;-102,"Syntax error;NUL byte";0,"No error"\n'
        port.close()


RATE_PAIRS = [
    ("SRAT?;:SRAT:LIST?;:STR:POIN?", "1000;1000,2000;20"),
    ("SRAT 2000;:SRAT?", "2000"),
    ("SRAT 1500;:SYST:ERR?", '-222,"Data out of range;supported rates 1000,2000 Hz"'),
    ("*RST;:SRAT?", "1000"),
]


def test_a_board_with_several_rates_lists_and_switches_them(firmware_binary):
    from test_protocol import replay

    with serve_firmware(firmware_binary, "--rates", "1000,2000") as url:
        assert replay(url, RATE_PAIRS) == [r for _, r in RATE_PAIRS]


def test_the_host_build_refuses_a_bad_command_line(firmware_binary):
    import subprocess

    run = subprocess.run([str(firmware_binary), "--rates", "fast"], capture_output=True, text=True)
    assert run.returncode == 2 and "--rates" in run.stderr


def test_conversions_the_adc_lost_end_a_stream_with_the_reason(firmware_binary):
    with serve_firmware(firmware_binary, "--lose-row", "100") as url:
        daq = SerialDaq(url, timeout=2.0)
        stream = daq.stream(20)
        blocks = []
        with pytest.raises(DeviceError) as info:
            while True:
                blocks.append(stream.read())
        assert info.value.codes == [-300] and "ADC conversions lost" in str(info.value)
        received = np.concatenate([counts_of(b, daq) for b in blocks])
        np.testing.assert_array_equal(received, truth(0, 100, [0, 1, 2]))   # nothing past the loss
        with pytest.raises(DeviceError):
            stream.stop()           # the stream's failure, again
        assert stream.stats.samples_received == 100 and stream.stats.samples_sent == 100
        assert daq._scpi.query("STR:COUN?") == "100"
        daq.close()


def test_conversions_the_adc_lost_mark_the_rest_of_a_block_read(firmware_binary):
    with serve_firmware(firmware_binary, "--lose-row", "100") as url:
        port = serial.serial_for_url(url, timeout=2.0)
        port.write(b"READ? 150;:SYST:ERR?\n")
        assert port.read(6) == b"#41800"
        rows = np.frombuffer(port.read(1800), dtype="<i4").reshape(150, 3)
        assert port.readline() == (f';-200,"Execution error;READ? lost 50 samples (FIFO or ADC overrun), '
                                   f'marked {LOST_MARK}"\n').encode()
        port.close()
    np.testing.assert_array_equal(rows[:100], truth(0, 100, [0, 1, 2]))
    assert np.all(rows[100:] == LOST_MARK)
