"""How the cost of ``contactid analyze`` grows with the number of lines and of runs.

    python benchmarks/analyze_scaling.py [--lines 250 500 1000 2000] [--runs 2 4 8] [--profile LINES RUNS]
                                         [--against-march LINES RUNS]

Sessions as an imported controller export gives them: stepped-sine runs of the paper's 2-DOF structure (K = 100
[[2, -1], [-1, 2]] N/m, M = diag(1, 2) kg, Rayleigh damping, a hardening cubic k3 = 400 N/m^3 at x2, force on
x2), receptances by the harmonic balance of analysis.prediction.harmonic_balance with 0.1 % complex noise, no measured
noise (the analysis estimates it) and no harmonics. Force levels spread over 0.1-1.0 N; lines over 0.8-3.2 Hz.
The model names one element at x2 with no law, so ``analyze`` runs the whole chain: identification, the
candidate ranking, the fit, the prediction.

Each figure is the CPU time of one ``analyze --no-history`` in this process (time.process_time, BLAS on one
thread), after one warm-up call that compiles and caches the kernels. The baseline of every ratio is the
smallest case in the same process, so the figures compare across machines: a cost linear in the lines gives
a ratio equal to the ratio of the lines.

``--against-march`` analyzes one case twice in the same process: with the sweeps solved as they are
(analysis.prediction.harmonic_balance: a long sweep solved at all its lines at once, checked against the march) and with
every sweep marched line by line; it prints both CPU times, their ratio, and the largest relative difference
between the numbers of the two ``analyze --json`` outputs.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis import load_elements, load_structure  # noqa: E402
from analysis.prediction.harmonic_balance import predict_sweep  # noqa: E402
from app.cli import main  # noqa: E402
from app.session.writer import RunSpec, SessionWriter  # noqa: E402

STRUCTURE = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
             "stiffness": [[200.0, -100.0], [-100.0, 200.0]], "rayleigh": [0.05, 0.002]}
TRUTH = {"element": [{"name": "right", "dof": "x2", "laws": [{"law": "cubic", "k3": 400.0}]}]}
MODEL = """[structure]
type = "lumped"
dofs = ["x1", "x2"]
mass = [[1.0, 0.0], [0.0, 2.0]]
stiffness = [[200.0, -100.0], [-100.0, 200.0]]
rayleigh = [0.05, 0.002]

[[element]]
name = "right"
dof = "x2"
laws = []
"""


def write_session(path: Path, lines: int, runs: int, seed: int = 1) -> None:
    structure = load_structure(STRUCTURE)
    elements = load_elements(TRUTH, structure)
    f = np.linspace(0.8, 3.2, lines)
    forces = np.linspace(0.1, 1.0, runs)
    H = predict_sweep(structure, elements, "x2", 2 * np.pi * f, forces).receptance   # (L, B, n)
    rng = np.random.default_rng(seed)
    w = SessionWriter(path, software_version="bench")
    for b, force in enumerate(forces):
        Hb = H[:, b, :] * (1 + 1e-3 * (rng.normal(size=(lines, 2)) + 1j * rng.normal(size=(lines, 2))))
        w.begin_run(RunSpec(f"sine_{force:.4g}N_up", "stepped_sine", float(force), "up", "x2", ["x1", "x2"], 0.0,
                            ["force"], ["N"], attrs={"imported": True}))
        w.write_arrays({"frequency": f, "frf/x1": Hb[:, 0], "frf/x2": Hb[:, 1],
                        "raw/line_start": np.zeros(lines, int), "raw/line_count": np.zeros(lines, int)})
        w.end_run("complete")
    w.close()


def analyze_cpu(folder: Path, lines: int, runs: int, extra: tuple[str, ...] = ()) -> tuple[float, str]:
    """CPU time of one ``analyze`` and what it printed."""
    session = folder / f"s_{lines}_{runs}.h5"
    if not session.exists():
        write_session(session, lines, runs)
    model = folder / "model.toml"
    model.write_text(MODEL)
    out = io.StringIO()
    start = time.process_time()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = main(["analyze", str(session), str(model), "--no-history", *extra])
    cpu = time.process_time() - start
    if code != 0:
        raise SystemExit(f"analyze failed on {lines} lines x {runs} runs (exit {code})")
    return cpu, out.getvalue()


def _numbers(value) -> list[float]:
    """Every number of a JSON value, in order."""
    if isinstance(value, dict):
        return [x for v in value.values() for x in _numbers(v)]
    if isinstance(value, list):
        return [x for v in value for x in _numbers(v)]
    return [float(value)] if isinstance(value, (int, float)) and not isinstance(value, bool) else []


def against_march(folder: Path, lines: int, runs: int) -> None:
    import json

    from analysis.prediction import harmonic_balance

    batch, out_batch = analyze_cpu(folder, lines, runs, ("--json",))
    marched_steps = harmonic_balance.MARCHED_STEPS
    harmonic_balance.MARCHED_STEPS = 10 ** 9
    try:
        march, out_march = analyze_cpu(folder, lines, runs, ("--json",))
    finally:
        harmonic_balance.MARCHED_STEPS = marched_steps
    a, b = np.array(_numbers(json.loads(out_batch))), np.array(_numbers(json.loads(out_march)))
    if a.shape != b.shape:
        raise SystemExit("the two analyses differ in what they report")
    scale = np.maximum(np.abs(b), 1e-300)
    print(f"{lines} lines x {runs} runs: sweeps solved at once {batch:.2f} s CPU, marched line by line "
          f"{march:.2f} s CPU, ratio {march / batch:.2f}; {len(a)} numbers of analyze --json, largest relative "
          f"difference {np.max(np.abs(a - b) / scale):.1e}")


def main_(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--lines", type=int, nargs="+", default=[250, 500, 1000, 2000])
    parser.add_argument("--runs", type=int, nargs="+", default=[2, 4, 8])
    parser.add_argument("--profile", type=int, nargs=2, metavar=("LINES", "RUNS"),
                        help="print a cProfile of one analyze instead")
    parser.add_argument("--against-march", type=int, nargs=2, metavar=("LINES", "RUNS"),
                        help="compare one analyze with every sweep marched line by line instead")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        analyze_cpu(folder, 100, 2)                              # warm-up: kernels compiled and cached
        if args.against_march:
            against_march(folder, *args.against_march)
            return
        if args.profile:
            import cProfile
            import pstats

            lines, runs = args.profile
            write_session(folder / f"s_{lines}_{runs}.h5", lines, runs)
            profile = cProfile.Profile()
            profile.enable()
            analyze_cpu(folder, lines, runs)
            profile.disable()
            pstats.Stats(profile).sort_stats("cumulative").print_stats(40)
            return
        base_lines, base_runs = args.lines[0], args.runs[0]
        base = analyze_cpu(folder, base_lines, base_runs)[0]
        print(f"baseline {base_lines} lines x {base_runs} runs: {base:.2f} s CPU")
        print("lines   runs   CPU s   ratio   lines x runs ratio")
        for runs in args.runs:
            for lines in args.lines:
                cpu = base if (lines, runs) == (base_lines, base_runs) else analyze_cpu(folder, lines, runs)[0]
                work = lines * runs / base_lines / base_runs
                print(f"{lines:6d} {runs:5d} {cpu:8.2f} {cpu / base:7.2f} {work:10.1f}")


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    main_()
