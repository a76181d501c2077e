"""The command line's light commands start without the heavy libraries (docs/performance.md, "Start-up"): what a
command imports is checked in a fresh interpreter, not timed (the time is measured by benchmarks/startup.py)."""
import json
import subprocess
import sys

import pytest

# numba itself imports the bare scipy package (cheap); the costly parts are its subpackages
HEAVY = ("scipy.stats", "scipy.special", "scipy.linalg", "scipy.interpolate", "numba", "h5py", "PySide6", "pyqtgraph")

CHILD = """
import contextlib, io, json, sys
from app.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main({argv!r})
    except SystemExit:
        pass
print(json.dumps(sorted(m for m in {heavy!r} if m in sys.modules)))
"""


def _heavy_imports(argv: list[str]) -> list[str]:
    out = subprocess.run([sys.executable, "-c", CHILD.format(argv=argv, heavy=HEAVY)], capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [["--help"], ["analyze", "--help"], ["import", "--help"], ["--version"]])
def test_help_imports_nothing_heavy(argv):
    assert _heavy_imports(argv) == []


def test_laws_imports_only_numba():
    # the laws are numba kernels, so the registry needs numba; scipy, HDF5 and Qt stay out
    assert _heavy_imports(["laws"]) == ["numba"]


def test_the_cli_spells_the_emulated_shaker_models_as_the_emulator_has_them():
    from app.cli import EMULATED_SHAKER_MODELS
    from drivers.emulator.core import SHAKER_MODELS
    assert EMULATED_SHAKER_MODELS == tuple(SHAKER_MODELS)


@pytest.mark.parametrize("asked, expected", [(None, "1"), ("3", "3")])
def test_the_command_line_runs_one_blas_thread_unless_the_environment_asks(asked, expected):
    """OpenBLAS reads its thread count once, when numpy loads it: the command line's module sets it before
    anything loads numpy, and keeps a count the user set."""
    import os
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if asked is not None:
        env["OPENBLAS_NUM_THREADS"] = asked
    probe = "import os, sys, app.cli; print('numpy' in sys.modules, os.environ.get('OPENBLAS_NUM_THREADS'))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.split() == ["False", expected]
