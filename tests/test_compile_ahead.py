"""The law library's compiled code made ahead in a process of its own (analysis/prediction/compile_ahead.py), as the
demo does while it measures: what it makes, a later process loads from the disk cache without compiling."""
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
def test_a_later_process_loads_what_was_compiled_ahead_without_compiling(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "analysis.prediction.compile_ahead"], cwd=ROOT, env=env, check=True)
    counted = textwrap.dedent("""
        from numba.core import event

        compiled = []

        class Count(event.Listener):
            def on_start(self, ev):
                pass

            def on_end(self, ev):
                compiled.append(ev.data["dispatcher"].py_func.__qualname__)

        event.register("numba:compile", Count())
        from analysis.prediction.compile_ahead import compile_library
        compile_library()
        print(len(compiled), compiled)
    """)
    out = subprocess.run([sys.executable, "-c", counted], cwd=ROOT, env=env, check=True, capture_output=True,
                         text=True).stdout
    assert out.startswith("0 "), out


def test_the_demo_compiles_ahead_while_its_block_runs_and_ends_it_after(monkeypatch):
    monkeypatch.setattr(app.demo.os, "cpu_count", lambda: 2)
    with compiling_ahead() as ahead:
        assert ahead.args[-2:] == ["-m", "analysis.prediction.compile_ahead"] and ahead.poll() is None
    assert ahead.poll() is not None
    monkeypatch.setattr(app.demo.os, "cpu_count", lambda: 1)     # no idle core to compile on
    with compiling_ahead() as ahead:
        assert ahead is None
