"""SIGKILL of a real ``contactid simulate`` run at random moments: the session then opens in plain h5py (any
HDF5 tool) with every line that was in the file before the kill."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from analysis import InputError
from app.session.writer import open_session, recover_session
from session_helpers import ROOT, plain_open

RUN = "sine_0.8N_up"
PLAN = ("[[stepped_sine]]\nforce = 0.8\nstart = 0.8\nstop = 3.2\nstep = 0.025\n[limits]\nmax_force = 5.0\n"
        "max_acceleration = 50.0\n")


def lines_so_far(path) -> dict | None:
    """The run's frequencies and FRFs as a reader sees them while the campaign writes (None before)."""
    try:
        with open_session(path) as s:
            if RUN in s.run_names():
                r = s.run(RUN)
                return {"frequency": r.frequency, "x1": r.frf["x1"], "x2": r.frf["x2"]}
    except InputError:                        # not there yet, or locked for a moment while a run is created
        pass
    return None


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2))
def test_sigkill_of_simulate_leaves_a_session_any_hdf5_reader_opens(tmp_path, seed):
    rng = np.random.default_rng(seed)
    out, plan = tmp_path / "k.h5", tmp_path / "p.toml"
    plan.write_text(PLAN)
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "simulate", "paper-2dof", str(plan), "-o", str(out),
                             "--quiet"], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = int(rng.integers(2, 12))
    seen = None
    try:
        while proc.poll() is None:
            seen = lines_so_far(out) or seen
            if seen is not None and len(seen["frequency"]) >= target:
                break
            time.sleep(0.02)
        time.sleep(float(rng.uniform(0, 0.2)))           # anywhere in the next line
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL, "the campaign ended before the kill"
    with plain_open(out) as f:
        g = f[f"runs/{RUN}"]
        n = g["frequency"].shape[0]
        assert n >= len(seen["frequency"])
        for key, where in (("frequency", "frequency"), ("x1", "frf/x1"), ("x2", "frf/x2")):
            np.testing.assert_array_equal(g[where][:len(seen[key])], seen[key])   # what was there stays
            assert g[where].shape[0] == n                                         # and every line is whole
        assert g["raw/line_start"].shape[0] == g["force_amplitude"].shape[0] == n
        assert np.all(np.isfinite(g["frf/x1"][()])) and np.all(np.diff(g["frequency"][()]) > 0)
        assert g.attrs["status"] == "aborted" and g.attrs["incomplete"]
    assert recover_session(out) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.h5", "p.toml"]
