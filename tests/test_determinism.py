"""A fast in-process run is a function of the plan and the seed only: not of the load on the machine.

The same short plan (a random run with its drive calibration, then stepped-sine lines with force control) runs
twice on paper-2dof, the second time beside four busy processes; every dataset of every run must be the same bit for
bit -- the FRFs, the settling times, the raw samples. What made runs differ: wall-clock timers in the emulator,
a DAQ reader running ahead of the campaign by however far the scheduler let it when a generator command went
out, and reads of the in-process port ending on a timeout.
"""
import subprocess
import sys
import tomllib

import h5py
import numpy as np
import pytest

from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from drivers.simulation.rig import load_rig

PLAN = """
[random]
force_rms = 0.05
band = [0.5, 5.0]
duration = 8.0

[[stepped_sine]]
force = 0.8
start = 1.0
stop = 1.05
step = 0.025
direction = "up"

[limits]
max_force = 5.0
max_acceleration = 50.0
"""
BUSY = "import time\nend = time.monotonic() + 120\nwhile time.monotonic() < end: pass"
"""A busy process, bounded in time even if the test dies before it kills it."""


def campaign(path):
    with emulated_instruments(load_rig("paper-2dof"), seed=0) as inst:
        return run_plan(parse_plan(tomllib.loads(PLAN), PLAN), inst, path)


def datasets(path):
    found = {}
    with h5py.File(path, "r") as f:
        f["runs"].visititems(lambda name, obj: found.__setitem__(name, obj[()])
                             if isinstance(obj, h5py.Dataset) else None)
    return found


@pytest.mark.slow
def test_the_same_plan_gives_the_same_session_on_an_idle_and_a_loaded_machine(tmp_path):
    first = campaign(tmp_path / "idle.h5")
    busy = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(4)]
    try:
        second = campaign(tmp_path / "loaded.h5")
    finally:
        for child in busy:
            child.kill()
            child.wait()
    assert first.runs == second.runs == {"random": "complete", "sine_0.8N_up": "complete"}
    assert first.shaker_seconds == second.shaker_seconds
    a, b = datasets(tmp_path / "idle.h5"), datasets(tmp_path / "loaded.h5")
    assert a.keys() == b.keys() and any(name.endswith("frf/x2") for name in a)
    for name in a:
        # NaN marks a quantity a line does not have (no transient estimate on a line that waited): same places
        assert np.array_equal(a[name], b[name], equal_nan=a[name].dtype.kind in "fc"), name
