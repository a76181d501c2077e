"""``contactid demo``: the whole job on the built-in paper-beam rig, telling the story as it goes.

1. campaign through the real drivers on the emulated rig: random run, stepped sine at several force levels;
2. the reference model updated to the random run's natural frequencies;
3. complex stiffness of the two contact elements identified at every line and level, with verdicts;
4. the missing-effect loop from a model with no laws (:func:`analysis.loop.auto.run_auto`, as ``analyze --auto``):
   linear corrections, then rank, add the top significant candidate, refit, repeat;
5. the session (with the model history), the fitted model and report plots written to the output folder.
"""
from __future__ import annotations

import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from analysis.loop.auto import run_auto
from analysis.common.child import python_child
from analysis.common.errors import InputError
from analysis.common.parallel import usable_cores
from analysis.mechanics.model import load_model
from analysis.common.tables import load_toml
from analysis.loop.workbench import Workbench
from drivers.simulation.rig import load_rig

from app.analyze import SessionNotes, report_text, store_history
from app.campaign import CampaignIncomplete, ProgressBar, emulated_instruments, load_plan, run_plan
from app.models import asset, builtin_plan_path
from app.session import atomic_output, measurements_from_session, open_session
from app.report import REPORT_FILES, write_report

SESSION = "paper-beam.h5"
FITTED = "paper-beam.fitted.toml"
ANALYSIS = "report/analysis.txt"
#: Seconds the compiling process may take to end once asked
AHEAD_EXIT_S = 5.0


def check_demo_outputs(out: Path, overwrite: bool) -> None:
    """Refuse (InputError, before anything is measured) a folder holding an earlier demo's files unless
    ``overwrite``; the files an earlier demo wrote are replaced only once their successors are complete."""
    if out.exists() and not out.is_dir():
        raise InputError("is not a folder", str(out), "--out")
    if overwrite:
        return
    found = [name for name in (SESSION, FITTED, ANALYSIS, *(f"report/{n}" for n in REPORT_FILES))
             if (out / name).exists()]
    if found:
        raise InputError(f"holds an earlier demo ({', '.join(found)}); pass --overwrite to replace it (the "
                         f"session only once the new campaign is complete) or choose another folder",
                         str(out), "--out")


def run_demo(out: Path, quick: bool = False, seed: int = 0, software_version: str = "", say=print,
             overwrite: bool = False) -> Workbench:
    """Run the demo into ``out``; returns the final workbench. An earlier demo there is refused unless
    ``overwrite`` (:func:`check_demo_outputs`)."""
    check_demo_outputs(out, overwrite)
    with compiling_ahead():
        return _demo(out, quick, seed, software_version, say, overwrite)


@contextmanager
def compiling_ahead() -> Iterator[subprocess.Popen | None]:
    """Within the block, the compiled code of the campaign's loop and of the law library made in a process of its
    own (:mod:`app.compile_ahead`) on the core the campaign leaves idle; not at all (None) where the process may
    run on one core only, or cannot be started: it only saves time. Ended at the block's end if still running."""
    if usable_cores() < 2:
        yield None
        return
    command, env = python_child("app.compile_ahead")
    try:
        ahead = subprocess.Popen(command, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
    except OSError:
        yield None
        return
    try:
        yield ahead
    finally:
        ahead.terminate()           # a save under way ends first (analysis.common.compiled)
        try:
            ahead.wait(AHEAD_EXIT_S)
        except subprocess.TimeoutExpired:
            ahead.kill()
            ahead.wait()


def _demo(out: Path, quick: bool, seed: int, software_version: str, say, overwrite: bool) -> Workbench:
    out.mkdir(parents=True, exist_ok=True)
    session = out / SESSION
    rig = load_rig("paper-beam")
    plan = load_plan(asset("paper-beam.quick.plan.toml") if quick else builtin_plan_path("paper-beam"))
    model_path = asset("paper-beam.model.toml")
    say("contactid demo: the frictionally supported clamped beam of the method paper (section 4), on the "
        "built-in simulated rig 'paper-beam'.")
    say("The rig's contact at the free end O is unknown to the analysis: it sees only what the emulated shaker "
        "controller and DAQ deliver over their serial protocol.\n")
    say(f"1. Measuring: {'random run, ' if plan.random else ''}stepped sine at "
        f"{', '.join(f'{s.force:g}' for s in plan.sine)} N around the first mode ...")
    t0 = time.monotonic()
    with emulated_instruments(rig, seed=seed) as inst:
        summary = run_plan(plan, inst, session, overwrite=overwrite, command="contactid demo",
                           software_version=software_version, listener=ProgressBar())
    say(summary.text())
    say(f"   ({time.monotonic() - t0:.0f} s)\n")
    if not summary.complete:
        raise CampaignIncomplete(f"the campaign is incomplete, nothing is identified from it: "
                                 f"{summary.aborted or '; '.join(summary.failed.values())}"
                                 + (f"; {summary.replaced} ({summary.session})" if summary.replaced else ""))

    with open_session(session) as s:
        measurements = measurements_from_session(s)
    wb = Workbench(load_model(load_toml(model_path), str(model_path)), measurements)
    say("2. Reference model: a clamped Euler-Bernoulli beam with the handbook lateral stiffness k_w = 1e7 N/m "
        "at O and the torsional stiffness updated to the random run.")
    say(wb.update_reference().text() + "\n")
    say("3. Identification of the equivalent complex stiffness of each contact element at every line and level:")
    wb.start()
    for el in wb.model.elements:
        r = wb.reports[el.name]
        if r.samples is None or r.verdict is None:
            say(f"   {el.name}: no verdict ({r.lines_used} usable lines)")
            continue
        k_u, _ = r.samples.units
        kind = "LINEAR" if r.verdict.linear else "NONLINEAR"
        say(f"   {el.name} ({el.dofs[0]}): {kind}, mean kbar {r.verdict.mean_kbar.real:.4g} "
            f"{r.verdict.mean_kbar.imag:+.4g}j {k_u}")
        say(f"     {r.verdict.evidence}")
    normal = wb.reports.get("normal")
    if normal is not None and normal.verdict is not None:
        k = normal.verdict.mean_kbar.real
        say(f"   The normal kbar is constant and {'negative' if k < 0 else 'positive'}: the reference normal "
            f"stiffness is {'too high' if k < 0 else 'too low'}; the contact behaves as k_w + kbar = "
            f"{1e7 + k:.3g} N/m. Its imaginary part, {normal.verdict.mean_kbar.imag:.3g} N/m, takes back the "
            "damping the reference gives the handbook spring (C = 1e-5 K, springs included: 1e-5 x k_w x w).")
    say(f"\n4. What is missing, starting from no laws at all (FRF error {wb.history[-1].error:.3g}):")
    result = run_auto(wb, progress=lambda step: say(f"   {step.text()}"), note=lambda line: say(f"   {line}"))
    say(f"   {result.stopped}")
    say("   error history: " + " -> ".join(f"{h.error:.3g}" for h in wb.history) + "\n")
    notes = SessionNotes()
    store_history(session, wb, model_path, notes)
    if notes.not_stored:            # as `analyze`: the analysis is not lost for want of its copy in the session
        say(f"   {notes.text()}")
        print(notes.warning(), file=sys.stderr)
    fitted = out / FITTED
    with atomic_output(fitted, overwrite=overwrite, field="--out") as temp:
        temp.write_text(wb.model.to_toml(), encoding="utf-8")
    plots = write_report(wb, out / "report", overwrite=overwrite)
    with atomic_output(out / ANALYSIS, overwrite=overwrite, field="--out") as temp:
        temp.write_text(report_text(wb, []) + "\n", encoding="utf-8")
    say("5. Written:")
    for p in [session, fitted, *plots, out / ANALYSIS]:
        say(f"   {p}")
    return wb


def main_demo(out: str, quick: bool, software_version: str, overwrite: bool = False) -> int:
    run_demo(Path(out), quick=quick, software_version=software_version,
             say=lambda text: print(text, flush=True, file=sys.stdout), overwrite=overwrite)
    return 0
