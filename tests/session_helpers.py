"""Helpers of the session tests: opening a file as any HDF5 tool would."""
import time
from pathlib import Path

import h5py

from app.session.writer import _process_alive
from paper_structure import PAPER_STRUCTURE

ROOT = Path(__file__).resolve().parents[1]


def plain_open(path, timeout=120.0) -> h5py.File:
    """The file opened with plain h5py (no SWMR, no recovery), as HDFView would, once the writer process has
    let go of it (it closes the file after the acquiring process died)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            f = h5py.File(path, "r")
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
            continue
        # the file can also be opened in the moment between the writer's last two writes: wait for it to exit
        if not _process_alive(int(f.attrs.get("writer_pid", -1))) or time.monotonic() > deadline:
            return f
        f.close()
        time.sleep(0.05)


# the paper's 2-DOF structure with a cubic at each element: a model file the session tests analyse with
MODEL = PAPER_STRUCTURE + """
[[element]]
name = "left"
dof = "x1"
laws = ["cubic"]

[[element]]
name = "right"
dof = "x2"
laws = ["cubic"]
"""
