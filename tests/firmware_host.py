"""The DAQ-1 firmware core (firmware/core) built for the host and served on a pseudo terminal.

``firmware_binary`` (session fixture) compiles the core with the host board (firmware/host) using the
system C compiler, or skips the test saying why it cannot; :func:`serve_firmware` runs it and yields the
pty path, which the drivers open like a serial port. The host board's test signal is
:func:`host_signal`, the same integers as ``host_signal`` in firmware/host/host_hal.c.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from rig_double import signature

FIRMWARE = Path(__file__).resolve().parent.parent / "firmware"
SOURCES = ["core/daq1.c", "core/scpi.c", "core/crc32.c", "host/host_hal.c", "host/main.c"]
CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
TRIANGLE_AMPLITUDE = 20000
TRIANGLE_PERIOD = 400


def host_signal(index, channel: int) -> np.ndarray:
    """ADC codes of the host board (= counts at the *RST sensitivity) at sample indices ``index``."""
    index = np.asarray(index, dtype=np.int64)
    phase = index % TRIANGLE_PERIOD
    triangle = np.abs(phase * 4 * TRIANGLE_AMPLITUDE // TRIANGLE_PERIOD - 2 * TRIANGLE_AMPLITUDE) - TRIANGLE_AMPLITUDE
    return signature(index, channel) + triangle


@pytest.fixture(scope="session")
def firmware_binary(tmp_path_factory) -> Path:
    if os.name != "posix":
        pytest.skip("the host build of the firmware is served on a POSIX pseudo terminal; this system has none")
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if compiler is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH: the firmware core cannot be built for the host")
    binary = tmp_path_factory.mktemp("firmware") / "daq1-host"
    build = subprocess.run([compiler, *CFLAGS, "-o", str(binary), *SOURCES, "-lm"], cwd=FIRMWARE,
                           capture_output=True, text=True)
    assert build.returncode == 0, f"the firmware core does not build:\n{build.stderr}"
    return binary


@contextmanager
def serve_firmware(binary: Path, *args: str):
    """Run the host firmware; yields its pty path. It must exit cleanly on SIGTERM."""
    process = subprocess.Popen([str(binary), "--serial", "proto", *args], stdout=subprocess.PIPE, text=True)
    try:
        announced = process.stdout.readline().split()
        assert announced[:1] == ["daq:"], f"daq1-host announced {announced!r}"
        yield announced[1]
    finally:
        process.send_signal(signal.SIGTERM)
        assert process.wait(10) == 0
