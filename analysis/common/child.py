"""A Python process of this checkout's own, started by any of its rooms: the session writer, the salvage of a
session, a port's guardian, the compiling ahead.

``python -m module`` puts the working directory first on the child's import path, so a child started from another
checkout's folder would run that checkout's modules, not the ones of the process that started it; ``-P`` keeps it
off. The checkout itself goes first on ``PYTHONPATH``, so that the child imports this checkout's modules whether or
not it is installed."""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]          # the checkout holding analysis/, drivers/ and app/


def python_child(module: str, *args: str) -> tuple[list[str], dict[str, str]]:
    """The command line and environment that run ``python -m module args`` on this checkout's modules."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    return [sys.executable, "-P", "-m", module, *args], env
