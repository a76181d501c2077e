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
