"""Cost of writing sessions through the writer process against writing in the acquiring process.

Writes the same stepped-sine run -- the per-line quantities a campaign stores (2 sensor DOFs, harmonics, THD,
control data) and a raw block per line -- once with :class:`app.session.file.SessionFile` in this process (the
baseline: how sessions were written before the writer process, SWMR, flush per line) and once through
:class:`app.session.writer.SessionWriter` (every call sent to the writer process, returning when the line is flushed).
Prints the time per line of each, their ratio, and the writer process's start-up (once per session).

Run: ``python benchmarks/session_writer.py [--lines 300] [--raw 2048] [--repeats 3]``
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from app.session.outputs import temporary_path
from app.session.writer import SessionWriter
from app.session.file import RunSpec, SessionFile, SessionHeader

DOFS = ["x1", "x2"]
CHANNELS = ["force", "acc:x1", "acc:x2"]
HARMONICS = 6


def spec() -> RunSpec:
    extras = {"force_amplitude": ("N", (), "f8"), "force_target": ("N", (), "f8"),
              "force_phasor": ("N", (), "c16"), "measured_frequency": ("Hz", (), "f8"), "drive": ("V", (), "f8"),
              "settle_time": ("s", (), "f8"), "settle_periods": ("1", (), "f8"), "steady": ("bool", (), "?"),
              "control_steps": ("1", (), "i4")}
    extras.update({f"frf_std/{d}": ("m/N", (), "f8") for d in DOFS})
    for c in CHANNELS:
        extras[f"harmonics/{c}"] = ("N", (HARMONICS,), "c16")
        extras[f"thd/{c}"] = ("1", (), "f8")
    return RunSpec("sine_0.8N_up", "stepped_sine", 0.8, "up", "x2", DOFS, 256.0, CHANNELS, ["N", "m/s^2", "m/s^2"],
                   extras)


def lines(n: int, raw_samples: int, seed: int = 0) -> list[tuple]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        extras = {"force_amplitude": 0.8, "force_target": 0.8, "force_phasor": 0.8 + 0.01j,
                  "measured_frequency": 1.0 + 0.01 * i, "drive": 0.1, "settle_time": 2.0, "settle_periods": 40.0,
                  "steady": True, "control_steps": 3}
        extras.update({f"frf_std/{d}": 1e-6 for d in DOFS})
        for c in CHANNELS:
            extras[f"harmonics/{c}"] = rng.normal(size=HARMONICS) + 1j * rng.normal(size=HARMONICS)
            extras[f"thd/{c}"] = 0.01
        raw = rng.normal(size=(raw_samples, len(CHANNELS))).astype(np.float32)
        out.append((1.0 + 0.01 * i, {d: complex(rng.normal(), rng.normal()) for d in DOFS}, extras, raw))
    return out


def in_process(path: Path, data) -> tuple[float, float]:
    t0 = time.perf_counter()
    f = SessionFile(path, temporary_path(path), False, SessionHeader())
    f.begin_run(spec(), 0.0)
    t1 = time.perf_counter()
    for line in data:
        f.append_line(*line)
    t2 = time.perf_counter()
    f.end_run("complete", "", 1.0)
    f.close(1.0)
    return t1 - t0, (t2 - t1) / len(data)


def writer_process(path: Path, data) -> tuple[float, float]:
    t0 = time.perf_counter()
    w = SessionWriter(path)
    w.begin_run(spec())
    t1 = time.perf_counter()
    for line in data:
        w.append_line(*line)
    t2 = time.perf_counter()
    w.end_run("complete")
    w.close()
    return t1 - t0, (t2 - t1) / len(data)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=300)
    ap.add_argument("--raw", type=int, default=2048, help="raw samples per line (3 channels, float32)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    data = lines(args.lines, args.raw)
    ratios = []
    with tempfile.TemporaryDirectory() as folder:
        for k in range(args.repeats):
            start_a, line_a = in_process(Path(folder) / f"a{k}.h5", data)
            start_b, line_b = writer_process(Path(folder) / f"b{k}.h5", data)
            print(f"run {k}: in process {1e3 * line_a:.2f} ms/line (start {1e3 * start_a:.0f} ms); writer process "
                  f"{1e3 * line_b:.2f} ms/line (start {1e3 * start_b:.0f} ms); ratio {line_b / line_a:.2f}")
            ratios.append(line_b / line_a)
    print(f"median ratio writer process / in process: {np.median(ratios):.2f} ({args.lines} lines, "
          f"{args.raw} raw samples per line, {args.repeats} repeats)")


if __name__ == "__main__":
    main()
