"""Ctrl-C and SIGTERM at moments nobody picked: `contactid demo --quick --overwrite` over an earlier session,
interrupted at a random time, again and again, and every outcome checked.

    python benchmarks/interrupt_demo.py                       # 30 interrupts, seed from the clock (printed)
    python benchmarks/interrupt_demo.py --seed 7 --runs 80 --latest 6 --double 0.4
    python benchmarks/interrupt_demo.py --workers 1 --sigterm 0.3
    python benchmarks/interrupt_demo.py --busy 3 --earliest 4 --latest 14   # the cores kept busy meanwhile

Each run starts the demo in a process of its own (Ctrl-C as a shell delivers it), waits a random time, sends
SIGINT -- or SIGTERM (``--sigterm``, the share of runs), or two SIGINTs 0-50 ms apart (``--double``) -- and
checks what a test engineer relies on:
- the process ends within ``--limit`` s (else it is a hang: its threads' stacks are written beside the output
  with faulthandler, and the process is killed);
- a stop during the campaign exits 130 (``contactid: interrupted``) or 143 (``contactid: stopped``), leaves the
  earlier session as it was, keeps the new one beside it (``paper-beam.incomplete.h5``) and says so -- unless
  nothing was measured yet, when there is nothing to keep; its interrupted run is ``aborted`` with the reason
  (after a second Ctrl-C that cut a call to the session writer: closed by the writer, as after a crash, and said);
- a stop after the campaign (during the analysis) leaves the complete new session in place of the earlier one, as
  ``--overwrite`` asks;
- no process of the run is left behind (forked analysis workers, the compile-ahead process, the session writer).
``--busy N`` keeps N processes spinning on the CPU for the length of the runs: a race that depends on when the
signal meets a step shows on a loaded machine (as on CI), and seldom on an idle one, where the demo's steps follow
one another as they always do. One line per run, then the outcomes counted. Too long for the test suite
(tests/test_outputs.py interrupts the demo once per signal); its figures go to docs/campaigns.md.
"""
from __future__ import annotations

import argparse
import collections
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.session.file import CRASH_REASON  # noqa: E402

EARLIER = b"an earlier session"
STOP_REASONS = ("interrupted by Ctrl-C", "stopped, exit status")


def one_run(rng: random.Random, args, folder: Path, index: int) -> str:
    """One interrupted demo; its outcome class (``hang`` or a ``ok ...`` / ``WRONG ...`` word list)."""
    out = folder / f"run{index}"
    out.mkdir()
    (out / "paper-beam.h5").write_bytes(EARLIER)
    env = dict(os.environ, PYTHONFAULTHANDLER="1")
    if args.workers is not None:
        env["CONTACTID_WORKERS"] = str(args.workers)
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "demo", "--quick", "--overwrite", "--out", str(out)],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    delay = rng.uniform(args.earliest, args.latest)
    time.sleep(delay)
    term = rng.random() < args.sigterm
    double = not term and rng.random() < args.double
    proc.send_signal(signal.SIGTERM if term else signal.SIGINT)
    if double:
        time.sleep(rng.uniform(0.0, 0.05))
        proc.send_signal(signal.SIGINT)
    how = "SIGTERM" if term else "2 x SIGINT" if double else "SIGINT"
    try:
        _, err = proc.communicate(timeout=args.limit)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)            # faulthandler writes every thread's stack
        _, err = proc.communicate()
        (folder / f"hang{index}.txt").write_text(err)
        print(f"{index:3d} {how:10s} at {delay:5.2f} s: HANG (stacks in {folder / f'hang{index}.txt'})", flush=True)
        return "hang"
    (folder / f"run{index}.err").write_text(err)
    time.sleep(0.5)                                 # children ending after their parent
    left = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout.split()
    verdict = _verdict(proc.returncode, err, out, term, double, left)
    last = err.strip().splitlines()[-1][:100] if err.strip() else ""
    print(f"{index:3d} {how:10s} at {delay:5.2f} s: exit {proc.returncode:4d} {verdict}  | {last}", flush=True)
    return verdict


def _verdict(code: int, err: str, out: Path, term: bool, double: bool, left: list[str]) -> str:
    complete = "sine_1.2N_up: complete" in err
    earlier = (out / "paper-beam.h5").read_bytes() == EARLIER if (out / "paper-beam.h5").exists() else False
    kept = out / "paper-beam.incomplete.h5"
    wrong = []
    if left:
        wrong.append(f"{len(left)} process(es) left")
    if code == 0:
        return "ok ended before the signal" if not wrong else "WRONG " + "; ".join(wrong)
    if not complete:
        # a second Ctrl-C after the message may end Python by SIGINT itself (-2): a shell shows 130 for both; a
        # SIGTERM before the command set up its handlers (nothing armed, nothing started) ends it by the default
        # action (-15, 143 in a shell)
        started = "random: started" in err
        codes = ((143,) if started else (143, -signal.SIGTERM)) if term else (130, -signal.SIGINT)
        if code not in codes:
            wrong.append("exit status")
        if not earlier:
            wrong.append("earlier session changed")
        if "random: complete" not in err and not _measured(kept):   # nothing measured yet: nothing to keep
            if kept.exists():
                wrong.append("a session kept with nothing measured")
        elif not kept.exists() or str(kept) not in err:
            wrong.append("new session not kept beside, or not said")
        else:
            with h5py.File(kept, "r") as f:
                reasons = [str(g.attrs.get("end_reason", "")) for g in f["runs"].values()
                           if g.attrs["status"] != "complete"]
            # a second Ctrl-C that cuts a call to the session writer ends the writer, which closes the run as
            # after a death of the command (and the command says so)
            allowed = STOP_REASONS + ((CRASH_REASON,) if double and "cut short" in err else ())
            if reasons and not all(r.startswith(allowed) for r in reasons):
                wrong.append(f"run reason {reasons}")
        phase = "campaign" if started else "start-up"
    else:
        if earlier or kept.exists():
            wrong.append("complete session not in place")
        phase = "analysis"
    return ("WRONG " + "; ".join(wrong)) if wrong else f"ok stopped in the {phase}"


def _measured(kept: Path) -> bool:
    """Whether the session kept beside holds anything measured: a line, or samples of a run stopped before its
    first line (a random run's record, written as it comes)."""
    if not kept.exists():
        return False
    try:
        with h5py.File(kept, "r") as f:
            return any(g["frequency"].shape[0] or ("raw/data" in g and g["raw/data"].shape[0])
                       for g in f["runs"].values())
    except (OSError, KeyError):          # unreadable, or not a session: counted as holding nothing, so wrong
        return False


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=None, help="the draw of delays and signals (default: the clock)")
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--earliest", type=float, default=1.0, help="earliest signal, s after the start")
    ap.add_argument("--latest", type=float, default=25.0, help="latest signal, s after the start")
    ap.add_argument("--double", type=float, default=0.3, help="share of runs sent a second SIGINT")
    ap.add_argument("--sigterm", type=float, default=0.2, help="share of runs sent SIGTERM instead")
    ap.add_argument("--workers", type=int, default=None, help="CONTACTID_WORKERS for the demo (default: its own)")
    ap.add_argument("--limit", type=float, default=90.0, help="s after the signal that count as a hang")
    ap.add_argument("--busy", type=int, default=0, help="processes kept spinning on the CPU meanwhile")
    args = ap.parse_args()
    seed = args.seed if args.seed is not None else int(time.time()) % 1_000_000
    print(f"seed {seed}", flush=True)
    rng = random.Random(seed)
    folder = Path(tempfile.mkdtemp(prefix="interrupt-demo-"))
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        counts = collections.Counter(one_run(rng, args, folder, i) for i in range(args.runs))
    finally:
        for spinner in busy:
            spinner.kill()
            spinner.wait()
    print(f"\n{args.runs} runs (seed {seed}, {args.busy} busy processes, outputs in {folder}):")
    for verdict, n in counts.most_common():
        print(f"  {n:3d}  {verdict}")


if __name__ == "__main__":
    main()
