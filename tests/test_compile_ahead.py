"""What the demo compiles ahead in a process of its own while it measures (app/compile_ahead.py): the rig
simulator's kernels besides its integration loop, the emulated DAQ's converter, and the law library's kernels. What
it makes, a later process loads from the disk cache without compiling."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import app.demo
from app.demo import compiling_ahead

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_a_later_process_loads_what_was_compiled_ahead_and_compiles_only_the_loop_itself(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "app.compile_ahead"], cwd=ROOT, env=env, check=True)
    counted = textwrap.dedent("""
        from numba.core import event

        compiled = []

        class Count(event.Listener):
            def on_start(self, ev):
                pass

            def on_end(self, ev):
                f = ev.data["dispatcher"].py_func
                compiled.append(f"{f.__module__}:{f.__qualname__}")

        event.register("numba:compile", Count())
        from analysis.prediction.compile_ahead import compile_library
        import numpy as np
        from drivers.emulator.daq import counts_of
        from drivers.simulation.simulator import RigSimulator
        compile_library()
        sim = RigSimulator("paper-2dof", seed=0)
        sim.set_sine(10.0, 0.1)
        sim.set_output(True)
        sim.advance(64)
        counts_of(sim.advance(64), np.arange(3), np.ones(3), np.ones(3))
        print(" ".join(compiled))
    """)
    compiled = subprocess.run([sys.executable, "-c", counted], cwd=ROOT, env=env, check=True, capture_output=True,
                              text=True).stdout.split()
    # of the simulator's kernels only the loop itself: a call of it not compiled ahead would be here too
    assert [c for c in compiled if c.startswith("drivers.")] == ["drivers.simulation.kernels:integrate_block"]
    assert not [c for c in compiled if "march" in c or "newton" in c or "jumps" in c], compiled


def test_the_demo_compiles_ahead_while_its_block_runs_and_ends_it_after(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))            # not the user's cache
    monkeypatch.setattr(app.demo, "usable_cores", lambda: 2)
    with compiling_ahead() as ahead:
        assert ahead.args[-2:] == ["-m", "app.compile_ahead"] and ahead.poll() is None
    assert ahead.poll() is not None
    monkeypatch.setattr(app.demo, "usable_cores", lambda: 1)       # no idle core to compile on
    with compiling_ahead() as ahead:
        assert ahead is None
