"""Helpers of the session tests: opening a file as any HDF5 tool would, running the CLI in a subprocess."""
import os
import subprocess
import sys
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]


def plain_open(path, timeout=120.0) -> h5py.File:
    """The file opened with plain h5py (no SWMR, no recovery), as HDFView would, once the writer process has
    let go of it (it closes the file after the acquiring process died)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return h5py.File(path, "r")
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def cli(*args, cwd=None, prefix=()) -> subprocess.CompletedProcess:
    """``python -m app.cli ARGS`` in a subprocess (``prefix`` wraps it, e.g. in ``unshare``)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([*prefix, sys.executable, "-m", "app.cli", *map(str, args)], cwd=cwd or ROOT, env=env,
                          capture_output=True, text=True)
