"""The ``contactid`` command line (CONTRACTS.md §6).

Every command reports bad input as one line on stderr and exits non-zero; the
traceback is shown only with ``--debug``.
"""
from __future__ import annotations

import argparse
import sys
from importlib.metadata import PackageNotFoundError, version

from analysis import LAWS, InputError, load_structure
from analysis.tables import load_toml


def software_version() -> str:
    try:
        return version("contactid")
    except PackageNotFoundError:
        return "0+unknown"


def cmd_modes(args) -> int:
    """Print the DOFs and natural frequencies of the [structure] of a rig or model file."""
    doc = load_toml(args.file)
    if "structure" not in doc:
        raise InputError("has no [structure] table", args.file)
    s = load_structure(doc["structure"], args.file)
    print(f"{args.file}: {s.description}, {s.n} DOFs")
    shown = s.dofs if args.all_dofs or s.n <= 12 else s.dofs[:12] + ["..."]
    print("DOFs: " + ", ".join(shown))
    freqs = s.natural_frequencies()
    for i, f in enumerate(freqs[: args.count], 1):
        print(f"  mode {i:2d}: {f:12.4f} Hz")
    return 0


def cmd_laws(args) -> int:
    """List the element laws with their parameters and units."""
    for law in LAWS.values():
        params = ", ".join(f"{p.name} [{p.render_unit()}]" for p in law.params)
        print(f"{law.name:20s} {law.summary}: {params}")
    return 0


def cmd_export(args) -> int:
    """Write a session's FRFs as UFF58 or CSV."""
    from .export import export_csv, export_uff

    if args.uff:
        n = export_uff(args.session, args.uff, overwrite=args.force)
        print(f"wrote {n} FRF records to {args.uff}")
    else:
        paths = export_csv(args.session, args.csv, overwrite=args.force)
        print(f"wrote {len(paths)} CSV files to {args.csv}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="contactid", description=(
        "Identify how a joint or contact interface behaves: stepped-sine tests, equivalent complex "
        "stiffness per element, nonlinear law fitting."))
    parser.add_argument("--version", action="version", version=f"contactid {software_version()}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("modes", help="natural frequencies of a rig or model file's structure")
    p.add_argument("file", help="rig or model TOML file")
    p.add_argument("-n", "--count", type=int, default=6, help="how many modes to print (default 6)")
    p.add_argument("--all-dofs", action="store_true", help="list every DOF name")
    p.set_defaults(run=cmd_modes)

    p = sub.add_parser("export", help="export a session's FRFs (UFF58 or CSV)")
    p.add_argument("session", help="session file (.h5)")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--uff", metavar="FILE", help="write UFF dataset 58 records to FILE")
    target.add_argument("--csv", metavar="DIR", help="write one CSV per run into DIR")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(run=cmd_export)

    p = sub.add_parser("laws", help="list the element laws and their parameters")
    p.set_defaults(run=cmd_laws)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except InputError as exc:
        if args.debug:
            raise
        print(f"contactid: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("contactid: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a one-line report for anything unexpected; --debug shows the traceback
        if args.debug:
            raise
        print(f"contactid: error: {type(exc).__name__}: {exc} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
