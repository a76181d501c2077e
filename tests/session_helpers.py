"""Helpers of the session tests: opening a file as any HDF5 tool would, a small session and a model to analyse it
with."""
import time
from pathlib import Path

import h5py
import numpy as np

from app.session.writer import RunSpec, SessionWriter, _process_alive
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


def write_session(path, forces=(0.4, 0.8)):
    """A small session of the paper's linear 2-DOF structure (25 lines per force level, no raw data)."""
    M, K = np.diag([1.0, 2.0]), np.array([[200.0, -100.0], [-100.0, 200.0]])
    w = SessionWriter(path, software_version="test", plan_text="synthetic")
    for force in forces:
        w.begin_run(RunSpec(f"sine_{force}N_up", "stepped_sine", force, "up", "x2", ["x1", "x2"], 100.0, ["force"],
                            ["N"], {"force_amplitude": ("N", (), "f8")}))
        for f in np.linspace(0.8, 3.2, 25):
            om = 2 * np.pi * f
            H = np.linalg.inv(K - om ** 2 * M + 0.02j * om * K)[:, 1]
            w.append_line(f, {"x1": H[0], "x2": H[1]}, {"force_amplitude": force})
        w.end_run("complete")
    w.close()
