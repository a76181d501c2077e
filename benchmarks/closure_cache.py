"""CPU of a fresh process with the compiled closures cached on disk against compiling them in the process.

A law's march, a placed contact's balance and the rig simulator's C callbacks are compiled by factories around the
laws' kernels (analysis/common/compiled.py, ``njit_fixed`` and ``cfunc_fixed``). Each command below runs in a new
interpreter, alternately as the code stands (their compiled code loaded from the disk cache) and with that cache
switched off in the child (``_fixed_cache`` returning None: compiled in the process, as every process did before);
every other cached kernel is loaded from disk either way. Printed: the child's CPU (user + system) per command and
mode, the median over ``--pairs`` pairs, and the ratio compiled / cached. One warm-up run of each command first
fills the cache.

Commands, on files made in a temporary folder:
- ``analyze`` of a linear 2-DOF session (two levels of 25 lines, the model two cubic joints): the laws' marches and
  the ranking's placed contacts;
- ``simulate`` of tests/rigs/stiff-sticking.toml (a cubic and Coulomb friction) over 12 lines: the rig's C
  callbacks.

Run: ``python benchmarks/closure_cache.py [--pairs 3]``
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from session_helpers import MODEL, write_session  # noqa: E402

PLAN = """[[stepped_sine]]
force = 0.5
start = 5.0
stop = 7.75
step = 0.25
refine = false
[limits]
max_force = 5.0
max_acceleration = 150.0
"""
_CHILD = """\
import sys
if sys.argv[1] == "compiled":
    import analysis.common.compiled as compiled
    compiled._fixed_cache = lambda py_func: None
from app.cli import main
sys.exit(main(sys.argv[2:]))
"""


def child_cpu(mode: str, args: list[str], cwd: Path) -> float:
    """CPU seconds (user + system) of one child running ``contactid args`` in ``mode``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-c", _CHILD, mode, *args], cwd=cwd, env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3)
    pairs = parser.parse_args().pairs
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        write_session(tmp / "s.h5")
        (tmp / "model.toml").write_text(MODEL, encoding="utf-8")
        (tmp / "plan.toml").write_text(PLAN, encoding="utf-8")
        rig = ROOT / "tests" / "rigs" / "stiff-sticking.toml"
        commands = {"analyze (marches, placed balances)": ["analyze", "s.h5", "model.toml", "--no-history"],
                    "simulate (the rig's C callbacks)": ["simulate", str(rig), "plan.toml", "-o", "sim.h5",
                                                         "--overwrite", "--quiet", "--seed", "1"]}
        for args in commands.values():
            child_cpu("cached", args, tmp)                  # fills the cache
        for name, args in commands.items():
            cpu = {"cached": [], "compiled": []}
            for _ in range(pairs):
                for mode in cpu:
                    cpu[mode].append(child_cpu(mode, args, tmp))
            cached, compiled = statistics.median(cpu["cached"]), statistics.median(cpu["compiled"])
            print(f"{name}: cached {cached:.2f} s, compiled in the process {compiled:.2f} s of CPU "
                  f"(medians of {pairs}); x{compiled / cached:.2f}")
            print(f"  cached {', '.join(f'{c:.2f}' for c in cpu['cached'])}; "
                  f"compiled {', '.join(f'{c:.2f}' for c in cpu['compiled'])}")


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    main()
