"""The ``contactid`` command line (docs/contracts.md §6).

Every command reports a problem as one line on stderr; the traceback is shown only with ``--debug``.

Exit status (docs/campaigns.md, "Exit status"):

- 0: done; for ``simulate``/``acquire``: every run complete
- 1: an unexpected internal error (a bug: run again with ``--debug`` and report the traceback)
- 2: bad input (a file, a field, a command-line value); nothing was armed or written
- 3: a campaign ended aborted (operator, abort limit, session write failure) or incomplete (a run failed:
  force off target, lines at the settling limit); the lines measured are in the session
- 4: a link or instrument failure (a port that cannot be opened, does not answer, is another instrument,
  or failed during the campaign); the message names the instrument and its port
- 130: interrupted (Ctrl-C)

Standard output that goes away (docs/contracts.md §6, "Standard output"): a reader that closes the pipe
(``| head -1``) does not stop a command; it finishes its work, writes its files and exits with the status it
would have had, what it could not print dropped. Standard output that cannot take more (``> /dev/full``, a full
disk) is the same, and then said in one line on stderr, exit 2 where the command itself succeeded: its files are
written, only its printed report is lost.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

# One BLAS thread, unless the environment asks for more: the numerics are many small matrices (a contact's balance
# at every sample, a stack of 17 x 17 solves), where OpenBLAS's threads wait more than they compute and take the
# core a campaign, the GUI or the session writer needs (the Brake-Reuss beam's loop: 479 -> 247 s of CPU, the same
# result; docs/performance.md, "One BLAS thread"). Set before anything loads numpy, which reads it once.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# Only light modules here: each command imports what it uses, so that `--help` and `laws` start fast
# (docs/performance.md, "Start-up"; tests/test_public_api.py checks what they import).
from analysis.common.errors import InputError

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_INCOMPLETE = 3
EXIT_INSTRUMENT = 4
EXIT_INTERRUPTED = 130
EXIT_CODES_HELP = ("exit status: 0 done (every run complete), 1 internal error, 2 bad input, 3 campaign aborted "
                   "or incomplete (lines kept in the session), 4 link or instrument failure, 130 interrupted")


def software_version() -> str:
    try:
        return version("contactid")
    except PackageNotFoundError:
        return "0+unknown"


def cmd_modes(args) -> int:
    """Print the DOFs and natural frequencies of a rig or model file, or of a built-in rig: by default with the
    elements' small-amplitude stiffness (the contact as a low-level test sees it), with --bare the structure
    alone."""
    from pathlib import Path

    from analysis.mechanics.model import load_model
    from analysis.common.tables import load_toml
    from drivers.simulation.linear_model import structure_at_rest
    from drivers.simulation.rig import builtin_rig_path, builtin_rigs

    if not Path(args.file).exists():
        if args.file not in builtin_rigs():
            raise InputError(f"no such file, and no built-in rig of that name (built-in rigs: "
                             f"{', '.join(builtin_rigs())})", args.file)
        source = f"builtin:{args.file}"
        doc = load_toml(builtin_rig_path(args.file))
    else:
        source = args.file
        doc = load_toml(args.file)
    model = load_model(doc, source)     # the whole file is checked, as analyze and simulate check it
    s = model.structure
    print(f"{source}: {s.description}, {s.n} DOFs")
    shown = s.dofs if args.all_dofs or s.n <= 12 else s.dofs[:12] + ["..."]
    print("DOFs: " + ", ".join(shown))
    if args.bare:
        print("natural frequencies of the structure alone (its [structure] springs included; the elements "
              "left out)")
    else:
        at_rest = structure_at_rest(s, model.elements)
        s = at_rest.structure
        print(_at_rest_words(at_rest))
    for i, f in enumerate(s.natural_frequencies()[: args.count], 1):
        print(f"  mode {i:2d}: {f:12.4f} Hz")
    return 0


def _at_rest_words(at_rest) -> str:
    """What ``modes`` shows by default: which elements' small-amplitude stiffness it adds, which it cannot."""
    from analysis.common.wording import engineering

    s = at_rest.structure
    added = "; ".join(f"{el.name} on {' - '.join(el.dofs)}: "
                      f"{engineering(k0, 'N·m/rad' if el.rotational(s) else 'N/m', 4)}" for el, k0 in at_rest.added)
    text = ("natural frequencies with the elements' small-amplitude stiffness (" + added + "); --bare for the "
            "structure alone" if at_rest.added else "natural frequencies of the structure, its [structure] springs "
            "included (no element law has values to add)")
    if at_rest.added and at_rest.without_values:
        text += f"; left out, their laws have no values: {', '.join(el.name for el in at_rest.without_values)}"
    return text


def cmd_laws(args) -> int:
    """List the element laws with their parameters and units."""
    from analysis.laws import LAWS

    for law in LAWS.values():
        params = ", ".join(f"{p.name} [{p.render_unit()}]" for p in law.params)
        print(f"{law.name:20s} {law.summary}: {params}")
    return 0


def cmd_export(args) -> int:
    """Write a session's FRFs as UFF58 or CSV."""
    from app.export import export_csv, export_uff

    if args.uff:
        done = export_uff(args.session, args.uff, overwrite=args.overwrite, per_run=args.per_run,
                          binary=args.binary, frf_only=args.frf_only)
        print(f"wrote {done.records} records to {', '.join(str(p) for p in done.files)}")
        for item in done.left_out:                     # what UFF58 cannot carry: said, never dropped silently
            print(f"note: left out (no UFF58 record carries it): {item}")
        for item in done.left_out_by_choice:           # what a record would carry: the user's choice, said so
            print(f"note: left out (--frf-only: FRF records only, as asked): {item}")
    elif args.csv_long:
        from app.export_csv_long import export_csv_long
        long = export_csv_long(args.session, args.csv_long, overwrite=args.overwrite)
        print(f"wrote {len(long.runs)} stepped-sine runs to {long.path}"
              + (f" (left out, not stepped sine: {', '.join(long.left_out)})" if long.left_out else ""))
        for item in long.not_carried:                  # as --uff and --csv name theirs
            print(f"note: left out (no column of the CSV long format carries it): {item}")
    else:
        left_out: list[str] = []
        paths = export_csv(args.session, args.csv, overwrite=args.overwrite, left_out=left_out)
        print(f"wrote {len(paths)} CSV files to {args.csv}")
        for item in left_out:
            print(f"note: left out: {item}")
    return 0


def cmd_import(args) -> int:
    """Read FRFs or time histories of other systems (UFF58, CSV) into a session."""
    from .importers.runs import SourceOptions, parse_dof_map, parse_records
    from .importers.store import ImportRequest, import_files

    if args.force_amplitude is not None and not (math.isfinite(args.force_amplitude)
                                                 and args.force_amplitude > 0):
        raise InputError(f"--force-amplitude must be a force amplitude > 0 N, got {args.force_amplitude:g}",
                         field="--force-amplitude")
    options = SourceOptions(args.kind, args.force_amplitude, args.direction,
                            [parse_dof_map(t) for t in args.dof or []],
                            args.excitation, parse_records(args.records) if args.records else None,
                            float(args.force_sign))
    result = import_files(ImportRequest([(f, options) for f in args.files], args.output, args.append,
                                        args.overwrite, " ".join(sys.argv), software_version()))
    for note in result.notes:
        print(f"note: {note}")
    for run, source in result.runs:
        print(f"run {run} from {source}")
    print(f"session: {args.output}")
    return 0


def _load_plan_for(rig_name: str | None, plan_arg: str | None):
    from drivers.simulation.rig import builtin_rigs

    from app.models import builtin_plan_path
    from app.campaign.plan import load_plan

    if plan_arg is None:
        if rig_name in builtin_rigs():
            return load_plan(builtin_plan_path(rig_name))
        raise InputError("give a PLAN file (only built-in rigs have a default plan)")
    return load_plan(plan_arg)


def _finish(summary, output) -> int:
    """Print the summary; the exit status says whether the campaign is complete (module docstring)."""
    print(summary.text())
    print(f"session: {summary.session or output}")
    if summary.replaced:
        print(f"contactid: {summary.replaced}", file=sys.stderr)
    if summary.aborted:
        print(f"contactid: campaign aborted: {summary.aborted} (output off; the lines measured so far are kept)",
              file=sys.stderr)
        return EXIT_INSTRUMENT if summary.aborted_by_instrument else EXIT_INCOMPLETE
    if not summary.complete:
        failed = "; ".join(f"{run}: {why}" for run, why in summary.failed.items())
        print(f"contactid: campaign INCOMPLETE: {failed} (the lines are kept, marked in the session)",
              file=sys.stderr)
        return EXIT_INCOMPLETE
    return EXIT_OK


MAX_SEED = 2**32 - 1


def _check_seed(seed: int) -> int:
    """A noise seed the simulator takes: a whole number from 0 to MAX_SEED."""
    if not 0 <= seed <= MAX_SEED:
        raise InputError(f"must be a whole number from 0 to {MAX_SEED}, got {seed}", field="--seed")
    return seed


def _instrument_roles(args) -> dict[str, str]:
    """Instrument names by the URLs given as --shaker/--daq, for messages (an emulated instrument's
    ``sim://rig/shaker`` URL names itself)."""
    urls = ((getattr(args, "shaker", None), "shaker"), (getattr(args, "daq", None), "DAQ"))
    return {url: role for url, role in urls if url}


def cmd_simulate(args) -> int:
    """Run a plan on an emulated rig through the real drivers."""
    from drivers.simulation.rig import builtin_rigs, load_rig

    from app.campaign.instruments import emulated_instruments
    from app.campaign.measure import ProgressBar, run_plan
    from app.session.outputs import check_output

    if args.list:
        for name in builtin_rigs():
            print(name)
        return 0
    if not args.rig or not args.output:
        raise InputError("usage: contactid simulate RIG [PLAN] -o SESSION.h5 (or --list)")
    _check_seed(args.seed)
    check_output(args.output, inputs=[args.rig, args.plan], overwrite=args.overwrite)
    rig = load_rig(args.rig)
    plan = _load_plan_for(args.rig, args.plan)
    print(f"plan: {plan.summary()}")
    with emulated_instruments(rig, seed=args.seed) as inst:
        summary = run_plan(plan, inst, args.output, overwrite=args.overwrite, command=" ".join(sys.argv),
                           software_version=software_version(), listener=ProgressBar(quiet=args.quiet))
    return _finish(summary, args.output)


def cmd_acquire(args) -> int:
    """Run a plan on real instruments."""
    from app.campaign.instruments import real_instruments
    from app.campaign.measure import ProgressBar, run_plan
    from app.session.outputs import check_output
    from app.campaign.plan import load_plan

    check_output(args.output, inputs=[args.plan], overwrite=args.overwrite)
    plan = load_plan(args.plan)
    print(f"plan: {plan.summary()}")
    placement = plan.placement.overridden(args.excitation, args.sensors)
    with real_instruments(args.shaker, args.daq, placement=placement, unguarded=args.unguarded) as inst:
        summary = run_plan(plan, inst, args.output, overwrite=args.overwrite, command=" ".join(sys.argv),
                           software_version=software_version(), listener=ProgressBar(quiet=args.quiet))
    return _finish(summary, args.output)


def cmd_emulate(args) -> int:
    """Serve a rig's emulated instruments over pseudo terminals or TCP until interrupted."""
    from drivers.simulation.rig import load_rig
    from drivers.serve import parse_tcp_address, serve_emulator
    from drivers.simulation.simulator import RigSimulator

    _check_seed(args.seed)
    rig = load_rig(args.rig)
    if args.tcp:
        host, port = parse_tcp_address(args.tcp)
        transport = {"transport": "tcp", "host": host, "port": port}
    else:
        transport = {"transport": "pty"}
    serve_emulator(RigSimulator(rig, seed=args.seed), fast=args.fast, faults=rig.faults, name=rig.name,
                   shaker_model=args.shaker_model, **transport)
    return 0


def cmd_analyze(args) -> int:
    """Identify, fit, predict, compare and rank missing effects. An error the analysis found in what the session
    and the model say together (no element line well conditioned, a level no law can fit) names them both."""
    try:
        return _analyze(args)
    except InputError as exc:
        if exc.source:
            raise
        raise InputError(exc.message, f"{args.session} with {args.model}", exc.field) from None


def _analyze(args) -> int:
    import json
    from dataclasses import replace

    from analysis.loop.cross_check import cross_validate
    from analysis.prediction.held_out import predict_session
    from app.analyze import (admissibility_json, backbones, backbones_json, misfits_json, model_admissibility,
                             read_measurements, reference_only, report_text, run_workbench, run_workbench_auto,
                             session_notes, store_history)
    from app.predict import (cross_validation_json, cross_validation_text, fitted_on, parse_levels, prediction_json,
                             prediction_text)
    from app.progress import Progress
    from app.session.outputs import check_output, require_free_space

    inputs = [args.session, args.model]
    if args.output:                       # refused before any work: never an input, never silently replaced,
        check_output(args.output, inputs=inputs, overwrite=args.overwrite)
        # and never on a disk that cannot take it: a minute of analysis is not spent for nothing
        require_free_space(args.output, FITTED_MODEL_ALLOWANCE, "write the fitted model")
    with Progress("analyze") as progress:
        progress.phase("reading the session")
        session = read_measurements(args.session)
        measurements = session
        if args.fit_levels is not None:     # the fit sees these levels only; the others are predicted after
            measurements = session.at_levels(parse_levels(args.fit_levels, session.level_controls()))
        reference = reference_only(args.session, args.model, args.add or [], measurements)
        if reference is None and not args.auto:
            wb, candidates = run_workbench(args.session, args.model, args.add or [], measurements=measurements,
                                           progress=progress)
    if reference is not None:             # a random run only: its modes and the updated reference
        print(json.dumps(reference.to_json(), indent=1, default=float) if args.json else reference.text())
        if args.output:
            _write_model(args, reference.model.to_toml(), inputs)
        return 0
    # each step of --auto as it is taken, one plain line (stderr under --json: stdout is the JSON object)
    step_out = sys.stderr if args.json else sys.stdout
    auto = None
    if args.auto:
        wb, auto = run_workbench_auto(args.session, args.model, args.add or [],
                                      progress=lambda step: print(f"auto: {step.line()}", file=step_out, flush=True),
                                      note=lambda line: print(f"auto: {line}", file=step_out, flush=True),
                                      measurements=measurements)
        candidates = auto.candidates
    notes = session_notes(args.session)
    if not args.no_history:
        store_history(args.session, wb, args.model, notes)
    modal = backbones(wb)
    provenance = fitted_on(args.session, measurements)
    created = provenance.created
    fitted = replace(wb.model, fitted_on=provenance)
    # the levels the fit did not see, predicted by the fitted model as it is
    held_out = None if args.fit_levels is None else predict_session(fitted, session, created, wb.harmonics)
    folds = None
    if args.cross_validate:
        with Progress("analyze") as progress:
            progress.phase("cross-validating over the levels")
            folds = cross_validate(wb, created)
    if args.json:
        extra = {"auto": auto.to_json()} if auto is not None else {}
        if held_out is not None:
            extra["prediction"] = prediction_json(held_out)
        if folds is not None:
            extra["cross_validation"] = cross_validation_json(folds)
        print(json.dumps({**wb.to_json(candidates), **misfits_json(wb), **backbones_json(modal), **notes.to_json(),
                          **admissibility_json(model_admissibility(wb)), **extra}, indent=1, default=float))
    else:
        if auto is not None:
            print(auto.text() + "\n")
        print(report_text(wb, candidates, comparisons=modal))
        if held_out is not None:
            print("\n" + prediction_text(held_out, Path(args.session).name, "as fitted"))
        if folds is not None:
            print("\n" + cross_validation_text(folds))
        if notes.text():
            print(notes.text())
    if notes.not_stored:
        print(notes.warning(), file=sys.stderr)
    if args.report:
        from app.report import write_report
        for path in write_report(wb, Path(args.report), args.overwrite, modal):
            print(f"plot written: {path}", file=sys.stderr if args.json else sys.stdout)
    if args.output:                       # last: a failure here leaves the report printed and no partial file
        _write_model(args, fitted.to_toml(), inputs)
    return 0


def cmd_predict(args) -> int:
    """A fitted model's prediction of a session, with nothing refitted."""
    import json

    from app.analyze import read_measurements
    from app.predict import KIND_WORDS, prediction_json, prediction_text, run_predict
    from app.progress import Progress

    if args.report:                       # refused before any work, as analyze refuses
        from app.report import PREDICTION_FILES
        from app.session.outputs import check_output
        Path(args.report).mkdir(parents=True, exist_ok=True)
        for name in PREDICTION_FILES:
            check_output(Path(args.report) / name, overwrite=args.overwrite, field=None,
                         overwrite_flag="--overwrite")
    with Progress("predict") as progress:
        progress.phase("predicting every level")
        measurements = read_measurements(args.session)
        _, prediction = run_predict(args.session, args.model, measurements)
    if args.json:
        print(json.dumps(prediction_json(prediction), indent=1, default=float))
    else:
        print(prediction_text(prediction, Path(args.session).name, Path(args.model).name))
    if args.report:
        from app.report import write_prediction_report
        runs = measurements.sine
        kinds = {lv.control.key(): lv.kind for lv in prediction.levels}
        tags = {r.name: KIND_WORDS[kinds[r.control.key()]] for r in runs}
        for path in write_prediction_report(prediction.comparison, runs, prediction.backbones, Path(args.report),
                                            args.overwrite, tags):
            print(f"plot written: {path}", file=sys.stderr if args.json else sys.stdout)
    return 0


def cmd_reference(args) -> int:
    """A modal reference structure from the lowest stepped-sine level, written as a model file."""
    from analysis.linear.level_reference import reference_from_level

    from app.analyze import read_measurements
    from app.session.outputs import check_output

    check_output(args.output, inputs=[args.session], overwrite=args.overwrite)
    if args.band is not None and not (0 < args.band[0] < args.band[1] and all(map(math.isfinite, args.band))):
        raise InputError(f"--band takes F1 F2 in Hz with 0 < F1 < F2, got {args.band[0]:g} {args.band[1]:g}",
                         field="--band")
    measurements = read_measurements(args.session)
    if not measurements.sine:       # said as it is, not as a drive point that no run measures
        has = "only a random run" if measurements.random is not None else "no stepped-sine run with lines"
        raise InputError(f"has {has}: reference fits the modes of the lowest stepped-sine level"
                         + ("; a random run is the reference itself: `contactid analyze SESSION MODEL` fits its "
                            "modes and updates the model's [updating] parameters" if measurements.random is not None
                            else ""), args.session)
    try:
        reference = reference_from_level(measurements, args.run_name, args.band)
    except InputError as exc:       # the level's faults are the session's: named with it
        raise exc if exc.source else InputError(exc.message, args.session, exc.field) from None
    report = reference.text()
    # the file first, then the report (a stdout that went away costs no output either way: main's _Stdout)
    _write_model(args, reference.model().to_toml(), [args.session], "reference model")
    print(report, flush=True)
    for warning in reference_warnings(reference):
        print(f"contactid: warning: {args.output}: {warning}", file=sys.stderr)
    return 0


POOR_REFERENCE = 0.2        # FRF error of a reference on its own level beyond which it is called poor (docs/import.md)


def reference_warnings(reference) -> list[str]:
    """What makes a written reference doubtful, each in one line: an FRF error on its own level beyond
    POOR_REFERENCE (the identified kbar would carry the misfit), and a positive residual inertia at the drive
    point (the modes below the band act as a negative mass: -1/m is what a rigid body gives)."""
    out = []
    if reference.frf_error > POOR_REFERENCE:
        out.append(f"the reference misses its own level {reference.run} by an FRF error of {reference.frf_error:.3g} "
                   f"(above {POOR_REFERENCE:g}): the laws fitted on it would carry that misfit; choose the lines "
                   "(--band F1 F2) or the level (--run NAME)")
    inertia = reference.table.get("residual_inertia")
    if inertia is not None:
        k = reference.table["dofs"].index(reference.drive)
        if inertia[k][k] > 0:
            out.append(f"residual_inertia at the drive point {reference.drive} is {inertia[k][k]:.3g} > 0: modes below "
                       "the band give a negative one (a rigid mass m: -1/m); the band misses a mode or holds a "
                       "second one (--band F1 F2)")
    return out


FITTED_MODEL_ALLOWANCE = 64 * 1024      # bytes: a fitted model file is a few kB of TOML


def _write_model(args, text: str, inputs: list, what: str = "fitted model") -> None:
    """Write the analysed model to ``-o``, never over an input nor silently over a file."""
    from app.session.outputs import atomic_output, require_free_space

    require_free_space(args.output, len(text.encode()) + 4096, "write the fitted model")
    with atomic_output(args.output, inputs=inputs, overwrite=args.overwrite) as temp:
        temp.write_text(text, encoding="utf-8")
    if not getattr(args, "json", False):
        print(f"{what} written to {args.output}")


def cmd_recover(args) -> int:
    """Make a session whose writer process was killed readable by any HDF5 tool."""
    from app.session.writer import damaged_data, needs_recovery, open_session, recover_session

    if not needs_recovery(args.session):
        damaged = damaged_data(args.session)
        if damaged:     # not what a died writer leaves: said, rather than "nothing to recover"
            raise InputError(f"closed normally, but its stored data fail their checksum ({'; '.join(damaged)}): "
                             "changed after it was written, which recover cannot repair; the file is unchanged "
                             "(a copy of it made before the damage is the way back)", args.session)
        print(f"{args.session}: closed normally, nothing to recover")
        return 0
    marked = recover_session(args.session)
    with open_session(args.session) as s:                # the recovery event names what could not be read
        left_out = s.events()[-1]["message"].partition("; unreadable, left out: ")[2]
    print(f"{args.session}: recovered; every HDF5 tool opens it now; run(s) marked aborted and incomplete: "
          f"{', '.join(marked) or 'none'}" + (f"; unreadable, left out: {left_out}" if left_out else ""))
    return 0


def cmd_demo(args) -> int:
    """The main job on the built-in paper-beam rig."""
    from app.demo import main_demo

    return main_demo(args.out, args.quick, software_version(), overwrite=args.overwrite)


def cmd_gui(args) -> int:
    """Open the lab window (default: the first built-in simulated rig)."""
    if bool(args.shaker) != bool(args.daq):
        raise InputError("real instruments need both --shaker URL and --daq URL")
    if args.shaker and args.rig:
        raise InputError("give either --rig or --shaker/--daq, not both")
    from app.gui import run

    return run(session=args.session, rig=args.rig, shaker=args.shaker, daq=args.daq, excitation=args.excitation,
               model=args.model, software_version=software_version())


class _OldSpelling(argparse.Action):
    """An option's former spelling: it still works, as ``replacement`` does, and says so in one line on stderr
    (the command line is a contract: docs/contracts.md §6, "One meaning per flag")."""

    def __init__(self, option_strings, dest, replacement: str, **kwargs):
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)
        self.replacement = replacement

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"contactid: note: {option_string} is the old spelling of {self.replacement} here; use "
              f"{self.replacement}", file=sys.stderr)
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)


def _overwrite_option(p: argparse.ArgumentParser, what: str) -> None:
    """``--overwrite``, the one spelling of "replace an existing output" in every command; ``--force`` is its
    former spelling in analyze, export, simulate and acquire."""
    p.add_argument("--overwrite", action="store_true", help=f"overwrite {what}")
    p.add_argument("--force", dest="overwrite", action=_OldSpelling, replacement="--overwrite", nargs=0,
                   const=True, default=False)


# the keys of drivers.emulator.core.SHAKER_MODELS, spelled here so that --help does not import the emulator
# (and numpy); tests/test_public_api.py checks that they agree
EMULATED_SHAKER_MODELS = ("SC-1", "33500B")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="contactid", description=(
        "Identify how a joint or contact interface behaves: stepped-sine tests, equivalent complex "
        "stiffness per element, nonlinear law fitting."), epilog=EXIT_CODES_HELP)
    parser.add_argument("--version", action="version", version=f"contactid {software_version()}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("modes", help="natural frequencies of a rig or model file: its structure with the "
                                     "elements' small-amplitude stiffness (the contact at rest)")
    p.add_argument("file", help="rig or model TOML file, or a built-in rig name (see simulate --list)")
    p.add_argument("-n", "--count", type=int, default=6, help="how many modes to print (default 6)")
    p.add_argument("--all-dofs", action="store_true", help="list every DOF name")
    p.add_argument("--bare", action="store_true",
                   help="the structure alone (its springs included), without the elements' small-amplitude "
                        "stiffness")
    p.set_defaults(run=cmd_modes)

    p = sub.add_parser("demo", help="the main job on the built-in simulated beam: campaign, identification, "
                                    "missing effects, report")
    p.add_argument("--out", default="contactid-demo", help="output folder (default ./contactid-demo)")
    p.add_argument("--quick", action="store_true", help="a shorter campaign")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier demo's files in the folder (its session only once the new campaign "
                        "is complete)")
    p.set_defaults(run=cmd_demo)

    p = sub.add_parser("simulate", help="run a plan on an emulated rig through the real drivers",
                       epilog=EXIT_CODES_HELP)
    p.add_argument("rig", nargs="?", help="built-in rig name or rig file")
    p.add_argument("plan", nargs="?", help="plan file (default: the built-in rig's plan)")
    p.add_argument("-o", "--output", metavar="SESSION.h5", help="session file to write")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated rig")
    _overwrite_option(p, "an existing session file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--list", action="store_true", help="list the built-in rigs")
    p.set_defaults(run=cmd_simulate)

    p = sub.add_parser("acquire", help="run a plan on real instruments", epilog=EXIT_CODES_HELP)
    p.add_argument("plan", help="plan file")
    p.add_argument("-o", "--output", required=True, metavar="SESSION.h5")
    p.add_argument("--shaker", required=True, metavar="URL", help="shaker controller: port name or pyserial URL")
    p.add_argument("--daq", required=True, metavar="URL", help="DAQ: port name or pyserial URL")
    p.add_argument("--excitation", metavar="DOF",
                   help="DOF of the force gauge, e.g. A.w (overrides the plan's [excitation] dof)")
    p.add_argument("--sensors", nargs="+", metavar="DOF",
                   help="accelerometer DOFs (overrides the plan's [sensors] dofs; default: the DAQ's acc:<dof> "
                        "channels)")
    _overwrite_option(p, "an existing session file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--unguarded", action="store_true",
                   help="let a function generator arm although nothing would switch it off if contactid were "
                        "killed (its guardian process cannot run)")
    p.set_defaults(run=cmd_acquire)

    p = sub.add_parser("emulate", help="serve a rig's emulated shaker controller and DAQ")
    p.add_argument("rig", help="built-in rig name or rig file")
    way = p.add_mutually_exclusive_group()
    way.add_argument("--pty", action="store_true", help="pseudo terminals (default)")
    way.add_argument("--tcp", metavar="HOST:PORT", help="TCP: PORT for the shaker, PORT+1 for the DAQ")
    p.add_argument("--fast", action="store_true", help="as fast as the host reads instead of real time")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shaker-model", choices=EMULATED_SHAKER_MODELS, default="SC-1",
                   help="the shaker controller: SC-1, or 33500B (a bench function generator: no ramp, no watchdog)")
    p.set_defaults(run=cmd_emulate)

    p = sub.add_parser("analyze", help="identify, fit, predict, compare and rank missing effects")
    p.add_argument("session", help="session file (.h5)")
    p.add_argument("model", help="model file (TOML)")
    p.add_argument("--add", action="append", metavar="ELEMENT:LAW", help="add a law before fitting (repeatable)")
    p.add_argument("--auto", action="store_true",
                   help="run the missing-effect loop: linear corrections, then add the top significant candidate, "
                        "refit and rank again until nothing significant is left (each step printed)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-o", "--output", metavar="FITTED.toml", help="write the fitted model (never one of the inputs)")
    _overwrite_option(p, "an existing FITTED.toml or report plots")
    p.add_argument("--no-history", action="store_true", help="do not append the model history to the session")
    p.add_argument("--report", metavar="DIR", help="write the report plots (PNG) into DIR: FRFs, kbar, residuals, "
                                                   "error history, and natural frequency and damping against "
                                                   "response amplitude where the session has response levels")
    p.add_argument("--fit-levels", metavar="N,M-K",
                   help="fit on these stepped-sine levels only (numbered from 1 as the report lists them: force "
                        "levels by force, then response levels); the others are predicted by the fitted model, "
                        "nothing refitted, and their error is reported as held out")
    p.add_argument("--cross-validate", action="store_true",
                   help="refit the final model's laws on alternate levels and predict the others with nothing "
                        "refitted: how well the model predicts levels its fit did not see")
    p.set_defaults(run=cmd_analyze)

    p = sub.add_parser("predict", help="a fitted model's prediction of a session, nothing refitted: the error of "
                                       "each level, held-out levels marked, backbones")
    p.add_argument("session", help="session file (.h5)")
    p.add_argument("model", help="fitted model file (TOML, as analyze -o writes it)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--report", metavar="DIR", help="write the plots (PNG) into DIR: FRFs, residuals, and natural "
                                                   "frequency and damping against response amplitude where the "
                                                   "session has response levels")
    _overwrite_option(p, "existing report plots")
    p.set_defaults(run=cmd_predict)

    p = sub.add_parser("recover", help="repair a session whose writer was killed so that any HDF5 tool opens it")
    p.add_argument("session", help="session file (.h5)")
    p.set_defaults(run=cmd_recover)

    p = sub.add_parser("export", help="export a session's FRFs (UFF58 or CSV)")
    p.add_argument("session", help="session file (.h5)")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--uff", metavar="FILE",
                        help="write UFF dataset 58 records, one file per run named after FILE (see --one-file)")
    target.add_argument("--csv", metavar="DIR", help="write one CSV per run into DIR")
    target.add_argument("--csv-long", metavar="FILE", help="write the stepped-sine runs into FILE in the CSV long "
                                                           "format that import reads (force per line, control)")
    files = p.add_mutually_exclusive_group()
    files.add_argument("--per-run", dest="per_run", action="store_true", default=True,
                       help="UFF: one file per run, FILE's stem + _<run> (the default: modal tools read one "
                            "frequency axis a file)")
    files.add_argument("--one-file", dest="per_run", action="store_false", help="UFF: every run in FILE")
    encoding = p.add_mutually_exclusive_group()
    encoding.add_argument("--binary", dest="binary", action="store_true", default=True,
                          help="UFF: binary records (58b, doubles: every frequency kept exact; the default)")
    encoding.add_argument("--ascii", dest="binary", action="store_false",
                          help="UFF: ASCII records (six significant digits: a frequency they would round is "
                               "refused)")
    p.add_argument("--frf-only", action="store_true",
                   help="UFF: only the FRF records, without contactid's per-line quantities")
    _overwrite_option(p, "existing output files")
    p.set_defaults(run=cmd_export)

    p = sub.add_parser("import", help="import FRFs or time histories of other systems (UFF58, CSV) into a "
                                      "session")
    p.add_argument("files", nargs="+", metavar="FILE", help="UFF58 files (ASCII or binary) or CSV files (.csv)")
    p.add_argument("-o", "--output", required=True, metavar="SESSION.h5", help="session file to write")
    p.add_argument("--append", action="store_true", help="add the runs to an existing session")
    p.add_argument("--overwrite", action="store_true", help="overwrite an existing session file")
    p.add_argument("--kind", choices=["sine", "random"], help="what the FRF records are (default: the file's "
                                                              "contactid tags, else sine)")
    p.add_argument("--force-amplitude", type=float, metavar="N", help="force amplitude of the stepped-sine "
                                                                      "records, N (where the file does not say it)")
    p.add_argument("--force", dest="force_amplitude", type=float, metavar="N", action=_OldSpelling,
                   replacement="--force-amplitude")
    p.add_argument("--direction", choices=["up", "down"], help="sweep direction (default: from the line order)")
    p.add_argument("--dof", action="append", metavar="NODE[+DIR]=NAME",
                   help="map a UFF node (and direction) to a model DOF, e.g. 3+Z=A.w (repeatable)")
    p.add_argument("--excitation", metavar="NAME", help="DOF of the force (reference) where no --dof maps it")
    p.add_argument("--records", metavar="N,M,...",
                   help="UFF: import only these records (numbered from 1 in file order), e.g. the FRFs of one "
                        "reference of a roving-hammer file")
    p.add_argument("--force-sign", type=int, choices=[1, -1], default=1, metavar="{1,-1}",
                   help="-1: the files' force is reversed against exp(+jwt) (a drive-point accelerance with phase "
                        "-pi/2 at resonance); every FRF changes sign. Recorded in the import provenance")
    p.set_defaults(run=cmd_import)

    p = sub.add_parser("reference", help="a modal reference structure fitted to the lowest stepped-sine level, "
                                         "written as a model file (for sessions without a random run)")
    p.add_argument("session", help="session file (.h5)")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.toml", help="model file to write")
    p.add_argument("--run", dest="run_name", metavar="NAME",
                   help="the run to fit (default: the level with the smallest response)")
    p.add_argument("--band", nargs=2, type=float, metavar=("F1", "F2"), help="fit on the lines from F1 to F2 Hz")
    p.add_argument("--overwrite", action="store_true", help="overwrite an existing model file")
    p.set_defaults(run=cmd_reference)

    p = sub.add_parser("gui", help="the lab window: rig, acquisition, identification, model, session")
    p.add_argument("session", nargs="?", help="session file to open")
    p.add_argument("--rig", help="built-in rig name or rig file to emulate (default: the first built-in rig)")
    p.add_argument("--shaker", metavar="URL", help="real shaker controller: port name or pyserial URL")
    p.add_argument("--daq", metavar="URL", help="real DAQ: port name or pyserial URL")
    p.add_argument("--excitation", metavar="DOF", help="DOF of the force gauge on real instruments")
    p.add_argument("--model", metavar="MODEL.toml", help="model file to open")
    p.set_defaults(run=cmd_gui)

    p = sub.add_parser("laws", help="list the element laws and their parameters")
    p.set_defaults(run=cmd_laws)
    return parser


class _NeverRaised(Exception):
    """Stands for an exception class whose module no command has imported: nothing can have raised it."""


def _raised_class(module: str, name: str) -> type[BaseException]:
    """The exception class ``module.name`` if the command imported its module, else :class:`_NeverRaised`:
    ``main`` need not import the campaign and the drivers to recognise their errors (start-up time)."""
    loaded = sys.modules.get(module)
    return getattr(loaded, name) if loaded is not None else _NeverRaised


def _notes(exc: BaseException) -> str:
    """What was added to an error on its way up (where an interrupted session went), for its one line: its own
    notes and those of the errors it was raised in the handling of. A second Ctrl-C during the first one's cleanup
    replaces it after the session was closed and said; what was said still holds."""
    notes, seen = [], set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        notes += [n for n in getattr(exc, "__notes__", []) if n not in notes]
        exc = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
    return f"; {'; '.join(notes)}" if notes else ""


class _Stdout:
    """``sys.stdout`` while a command runs: where the reader went away (a closed pipe, ``| head -1``) or the
    medium is full (``> /dev/full``), what is printed from then on is dropped -- the stream is pointed at the null
    device, so nothing is left to fail at exit -- and the command goes on to finish its work and write its files.
    ``lost`` says why output was lost: None, "closed" (the reader closed the pipe) or the system's words."""

    def __init__(self, stream):
        self.stream = stream
        self.lost: str | None = None

    def __getattr__(self, name):
        return getattr(self.stream, name)

    def write(self, text: str) -> int:
        if self.lost is None:
            try:
                return self.stream.write(text)
            except OSError as exc:
                self._lose(exc)
        return len(text)

    def flush(self) -> None:
        try:
            self.stream.flush()
        except OSError as exc:
            self._lose(exc)
            self._flush_quietly()

    def writelines(self, lines) -> None:
        for line in lines:
            self.write(line)

    def _lose(self, exc: OSError) -> None:
        from app.session.outputs import WRITE_ERRNOS, write_failure

        if not isinstance(exc, BrokenPipeError) and exc.errno not in WRITE_ERRNOS:
            raise exc
        if self.lost is None:
            self.lost = "closed" if isinstance(exc, BrokenPipeError) else write_failure(exc)
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, self.stream.fileno())
            finally:
                os.close(null)
        except (OSError, ValueError, AttributeError):
            pass                                    # a stream without a descriptor (a test's capture)

    def _flush_quietly(self) -> None:
        try:
            self.stream.flush()                     # what was buffered goes to the null device now
        except (OSError, ValueError):
            pass


def _stdout_lost_words(lost: str) -> str:
    """The one line saying that standard output could not be written: what was lost, and what was not."""
    written = sys.modules.get("app.session.outputs")
    names = ", ".join(str(p) for p in written.committed_outputs()) if written is not None else ""
    return (f"contactid: error: standard output: not written: {lost}; the report was not printed in full, but the "
            "command ran to its end" + (f" and wrote {names}" if names else " (any file it writes is written)"))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    committed = sys.modules.get("app.session.outputs")
    if committed is not None:
        committed.committed_outputs().clear()
    stdout = sys.stdout = _Stdout(sys.stdout)
    stderr = sys.stderr = _Stdout(sys.stderr)      # `2>&1 | head -1`: the warnings' and progress's reader is gone too
    try:
        status = _run(args)
        stdout.flush()
        if stdout.lost not in (None, "closed"):
            if not getattr(args, "finished", False):     # its own error said what happened; this adds the report
                print(f"contactid: note: standard output: not written: {stdout.lost}; the report was not printed "
                      "in full", file=sys.stderr)
                return status
            print(_stdout_lost_words(stdout.lost), file=sys.stderr)
            return status or EXIT_BAD_INPUT
        return status
    finally:
        stdout.flush()
        stderr.flush()
        sys.stdout, sys.stderr = stdout.stream, stderr.stream


def _run(args) -> int:
    """Run the command; an error is one line on stderr and an exit status (the module docstring)."""
    try:
        status = args.run(args)
        args.finished = True                # ran to its end (its status may still say a campaign is incomplete)
        return status
    except InputError as exc:
        if args.debug:
            raise
        print(f"contactid: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except _raised_class("app.campaign.engine", "CampaignIncomplete") as exc:
        print(f"contactid: {exc}{_notes(exc)}", file=sys.stderr)
        return EXIT_INCOMPLETE
    except FileNotFoundError as exc:
        if args.debug:
            raise
        print(f"contactid: error: {exc.filename}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        # an output that cannot be written (full disk, read-only medium): nothing was written, as for bad input
        from app.session.outputs import WRITE_ERRNOS, write_failure

        if args.debug or exc.errno not in WRITE_ERRNOS:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"contactid: error: {where}{write_failure(exc)}; nothing was written", file=sys.stderr)
        return EXIT_BAD_INPUT
    except _raised_class("drivers.errors", "InstrumentError") as exc:
        if args.debug:
            raise
        from drivers.errors import describe_instrument_error

        where = describe_instrument_error(exc, _instrument_roles(args))
        print(f"contactid: instrument failure: {where}{_notes(exc)}", file=sys.stderr)
        return EXIT_INSTRUMENT
    except KeyboardInterrupt as exc:
        print(f"contactid: interrupted{_notes(exc)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemExit as exc:       # SIGTERM (drivers.safety): it ends the process as it asked, saying what it left
        if notes := _notes(exc):
            print(f"contactid: stopped{notes}", file=sys.stderr)
        raise
    except Exception as exc:  # a one-line report for anything unexpected; --debug shows the traceback
        if args.debug:
            raise
        print(f"contactid: error: {type(exc).__name__}: {exc} (run with --debug for the traceback)",
              file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
