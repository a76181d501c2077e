"""Public API and command-line conformance (docs/contracts.md): the names of analysis/, drivers/ and app/ that
other code and users rely on, every command and option of the command line, the law vocabulary, the
``analyze --json`` object and the session layout. Each check is a superset check: additions pass, a rename or a
drop fails. Two sources are pinned: the lists below (so that code and docs cannot drift away together) and the
docs themselves (every command, option and law they show must exist)."""
import importlib
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis import LAWS
from app.cli import build_parser, main
from test_workbench import PAPER_LAWS, synthesise
from paper_structure import PAPER_STRUCTURE

ROOT = Path(__file__).resolve().parents[1]

# module -> names that must exist in it
PUBLIC_NAMES = {
    "analysis": ["Element", "InputError", "LAWS", "LawTerm", "Structure", "describing_function", "get_law",
                 "load_elements", "load_structure"],
    "analysis.laws": ["LAWS", "describing_function", "get_law"],
    "analysis.model": ["Model", "load_model"],
    "analysis.tables": ["load_toml"],
    "analysis.identify": ["identify_complex_stiffness"],
    "analysis.fit": ["fit_laws"],
    "analysis.harmonic_balance": ["predict_sweep"],
    "analysis.measurements": ["Measurements", "SineRun", "RandomRun"],
    "analysis.workbench": ["Workbench"],
    "analysis.unexplained": ["NonParametricOffer", "Unexplained", "offer_nonparametric", "unexplained"],
    "analysis.nonparametric": ["NonParametric", "fit_nonparametric"],
    "analysis.auto": ["AutoRules", "AutoStep", "AutoResult", "run_auto", "kbar_unexplained"],
    "drivers": ["AbortLimits", "Block", "Daq", "InstrumentError", "LinkLost", "OutputGuard", "SerialDaq",
                "SerialShaker", "ShakerController", "open_daq", "open_shaker"],
    "drivers.emulator": ["EmulatedRig", "register", "set_backend_factory"],
    "drivers.serve": ["serve_emulator"],
    "drivers.simulation.rig": ["Rig", "builtin_rigs", "load_rig", "parse_rig"],
    "drivers.simulation.simulator": ["RigSimulator", "SimulationError"],
    "app.cli": ["build_parser", "main"],
    "app.campaign": ["Campaign", "CampaignListener", "CampaignSummary", "CampaignIncomplete", "Plan", "load_plan",
                     "parse_plan", "run_plan", "emulated_instruments", "real_instruments"],
    "app.plan": ["load_plan", "parse_plan"],
    "app.session": ["SessionWriter", "RunSpec", "open_session", "recover_session", "append_model_history"],
    "app.session_data": ["measurements_from_session"],
    "app.session.writer": ["SessionWriter", "RunSpec", "Session", "RunData", "open_session", "recover_session"],
    "app.outputs": ["check_output", "atomic_output", "require_free_space"],
    "app.instruments": ["emulated_instruments", "real_instruments"],
    "app.measure": ["run_plan"],
    "app.analyze": ["run_workbench", "run_workbench_auto", "report_text"],
    "app.export": ["export_csv", "export_uff"],
    "app.report": ["write_report"],
    "app.demo": ["run_demo"],
}

# class -> members that must exist on it
PUBLIC_MEMBERS = {
    ("analysis", "Structure"): ["dofs", "n", "frf", "natural_frequencies", "modes", "index"],
    ("analysis.loop.workbench", "Workbench"): ["start", "update_reference", "identify", "fit", "compare", "candidates",
                                          "add", "add_laws", "pair_candidates", "to_json", "undo", "back_to",
                                          "take_back", "error_without", "discover", "harmonics_blind", "read_as",
                                          "replace_laws"],
    ("drivers.simulation.simulator", "RigSimulator"): ["advance", "set_sine", "set_noise", "set_output", "time",
                                                        "output_on", "frequency"],
    ("drivers", "ShakerController"): [], ("drivers", "Daq"): [],
}

# subcommand -> options (and positional names) that must parse; None: the global options
COMMANDS = {
    None: ["--version", "--debug"],
    "demo": ["--out", "--quick"],
    "gui": ["session", "--rig", "--shaker", "--daq", "--excitation", "--model"],
    "simulate": ["rig", "plan", "-o", "--output", "--seed", "--force", "--overwrite", "--quiet", "--list"],
    "acquire": ["plan", "-o", "--output", "--shaker", "--daq", "--excitation", "--sensors", "--force", "--overwrite",
                "--quiet"],
    "emulate": ["rig", "--pty", "--tcp", "--fast", "--seed"],
    "analyze": ["session", "model", "--add", "--auto", "--json", "-o", "--output", "--no-history", "--force",
                "--overwrite", "--fit-levels", "--cross-validate"],
    "predict": ["session", "model", "--json", "--report", "--overwrite"],
    "export": ["session", "--uff", "--csv", "--csv-long", "--force", "--overwrite", "--per-run", "--one-file",
               "--binary", "--ascii", "--frf-only"],
    "import": ["files", "-o", "--output", "--append", "--overwrite", "--kind", "--force", "--force-amplitude",
               "--direction", "--dof", "--excitation", "--records", "--force-sign"],
    "reference": ["session", "-o", "--output", "--run", "--band", "--overwrite"],
    "modes": ["file", "-n", "--count", "--all-dofs", "--bare"],
    "laws": [],
}


# the flat module paths of before analysis/ had rooms: each is the room's module itself (analysis/__init__.py)
FLAT_PATHS = {"analysis.model": "analysis.mechanics.model", "analysis.tables": "analysis.common.tables",
              "analysis.identify": "analysis.identification.identify", "analysis.fit": "analysis.fitting.fit",
              "analysis.harmonic_balance": "analysis.prediction.harmonic_balance",
              "analysis.measurements": "analysis.common.measurements", "analysis.workbench": "analysis.loop.workbench",
              "analysis.unexplained": "analysis.missing.unexplained",
              "analysis.nonparametric": "analysis.mechanics.nonparametric", "analysis.auto": "analysis.loop.auto"}
PUBLIC_NAMES.update({new: PUBLIC_NAMES[old] for old, new in FLAT_PATHS.items()})


@pytest.mark.parametrize("old, new", sorted(FLAT_PATHS.items()))
def test_flat_paths_are_the_rooms_modules_themselves(old, new, monkeypatch):
    """An old path gives the same module object, so a patch through it reaches the code that runs."""
    flat, room = importlib.import_module(old), importlib.import_module(new)
    assert flat is room and room.__spec__.name == new
    name = PUBLIC_NAMES[old][0]
    monkeypatch.setattr(f"{old}.{name}", "patched")
    assert getattr(room, name) == "patched"


def test_every_flat_name_of_analysis_still_imports():
    import analysis

    for flat, target in analysis.MOVED.items():
        assert importlib.import_module(f"analysis.{flat}") is importlib.import_module(f"analysis.{target}")
        assert getattr(analysis, flat) is importlib.import_module(f"analysis.{target}")


@pytest.mark.parametrize("module", sorted(PUBLIC_NAMES))
def test_public_names_exist(module):
    mod = importlib.import_module(module)
    assert [n for n in PUBLIC_NAMES[module] if not hasattr(mod, n)] == []


def test_package_exports_keep_their_names():
    for package in ("analysis", "drivers"):
        exported = set(importlib.import_module(package).__all__)
        assert set(PUBLIC_NAMES[package]) <= exported, package


@pytest.mark.parametrize("module, cls", sorted(PUBLIC_MEMBERS))
def test_public_members_exist(module, cls):
    klass = getattr(importlib.import_module(module), cls)
    fields = getattr(klass, "__dataclass_fields__", {})       # dataclass fields without a class default
    assert [m for m in PUBLIC_MEMBERS[(module, cls)] if not hasattr(klass, m) and m not in fields] == []


def _parser_options() -> dict:
    """subcommand (None: global) -> its option strings and positional names, read from the parser."""
    parser = build_parser()

    def names(p):
        return {s for a in p._actions for s in (a.option_strings or [a.dest])}

    subparsers = next(a for a in parser._actions if a.choices and a.dest == "command")
    out = {None: names(parser)}
    out.update({name: names(sub) for name, sub in subparsers.choices.items()})
    return out


def test_every_pinned_command_and_option_parses():
    options = _parser_options()
    missing = {cmd: sorted(set(want) - options.get(cmd, set())) for cmd, want in COMMANDS.items()
               if cmd not in options or not set(want) <= options[cmd]}
    assert missing == {}


def _parsed(argv: list[str]):
    return build_parser().parse_args(argv)


@pytest.mark.parametrize("argv", [["simulate", "paper-beam", "-o", "s.h5"], ["acquire", "p.toml", "-o", "s.h5",
                                  "--shaker", "a", "--daq", "b"], ["analyze", "s.h5", "m.toml", "-o", "f.toml"],
                                  ["export", "s.h5", "--csv", "d"], ["import", "a.uff", "-o", "s.h5"]])
def test_overwrite_has_one_spelling_and_force_is_its_old_one(argv, capsys):
    assert _parsed(argv).overwrite is False and _parsed(argv + ["--overwrite"]).overwrite is True
    assert capsys.readouterr().err == ""
    if argv[0] != "import":                  # --force was "overwrite" here: it still is, with a note
        assert _parsed(argv + ["--force"]).overwrite is True
        assert capsys.readouterr().err.strip() == ("contactid: note: --force is the old spelling of --overwrite "
                                                   "here; use --overwrite")


def test_import_names_its_force_as_a_force(capsys):
    argv = ["import", "a.uff", "-o", "s.h5"]
    assert _parsed(argv + ["--force-amplitude", "0.5"]).force_amplitude == 0.5
    assert capsys.readouterr().err == ""
    old = _parsed(argv + ["--force", "0.5"])
    assert old.force_amplitude == 0.5 and old.overwrite is False
    assert "use --force-amplitude" in capsys.readouterr().err


def test_a_refused_output_names_the_flag_that_overwrites(tmp_path, capsys):
    existing = tmp_path / "fitted.toml"
    existing.write_text("")
    assert main(["analyze", str(tmp_path / "s.h5"), str(tmp_path / "m.toml"), "-o", str(existing)]) == 2
    assert "pass --overwrite to overwrite it" in capsys.readouterr().err


DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SPAN = re.compile(r"`contactid ([^`]*)`")
FENCED = re.compile(r"\bcontactid ([a-z][a-z-]*(?![\w=])[^#&|`\n]*)")  # a subcommand, not an id line (`contactid run=...`)
OPTION = re.compile(r"(?<![\w-])(--?[a-z][\w-]*)")


def _documented_command_lines(path: Path) -> list[str]:
    """The command lines a doc shows: inline code spans and lines of fenced code blocks."""
    text = path.read_text(encoding="utf-8")
    found = [s.replace("\\|", "|") for s in SPAN.findall(text)]
    for i, block in enumerate(text.split("```")):
        if i % 2:
            found += FENCED.findall(block)
    return found


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_documented_command_and_option_exists(path):
    options = _parser_options()
    wrong = []
    for line in _documented_command_lines(path):
        words = line.split()
        cmd = words[0] if words and not words[0].startswith("-") else None
        if cmd is not None and cmd not in options:
            wrong.append(f"unknown command: contactid {line}")
            continue
        known = options[cmd] | options[None]
        wrong += [f"unknown option {o}: contactid {line}" for o in OPTION.findall(line) if o not in known]
    assert wrong == []


def test_the_docs_show_every_pinned_command():
    shown = {line.split()[0] for path in DOCS for line in _documented_command_lines(path) if line.split()}
    assert set(COMMANDS) - {None} <= shown


def test_law_vocabulary_matches_the_contract_table():
    text = (ROOT / "docs/contracts.md").read_text(encoding="utf-8")
    section = text.split("## 2.")[1].split("## 3.")[0]
    rows = re.findall(r"^\| ([a-z_]+) \| ([a-z_0-9, ]+) \|", section, flags=re.M)[1:]   # after the header
    assert len(rows) == 15
    for name, params in rows:
        assert name in LAWS, name
        assert set(p.strip() for p in params.split(",")) <= set(LAWS[name].param_names), name


# --- analyze --json and the session layout, through the command line ---------------------------------------
MODEL = PAPER_STRUCTURE + """rayleigh = [0.0, 0.002]

[[element]]
name = "left"
dof = "x1"
laws = ["cubic", "quadratic_damping"]

[[element]]
name = "right"
dof = "x2"
laws = ["cubic"]
"""


def _write_session(path: Path) -> None:
    """A session as a campaign writes it, from FRFs synthesised by harmonic balance (no campaign needed)."""
    from app.session import RunSpec, SessionWriter

    writer = SessionWriter(path, plan_text="", software_version="test")
    for run in synthesise(PAPER_LAWS, lines=13).sine:
        dofs = run.sensor_dofs
        writer.begin_run(RunSpec(run.name, "stepped_sine", run.force, run.direction, run.excitation_dof, dofs,
                                 256.0, ["force"] + [f"acc:{d}" for d in dofs], ["N"] + ["m/s^2"] * len(dofs),
                                 extras={f"frf_std/{d}": ("m/N", (), "f8") for d in dofs}))
        for k, f in enumerate(run.frequency_hz):
            writer.append_line(f, {d: run.receptance[k, p] for p, d in enumerate(dofs)},
                               {f"frf_std/{d}": run.receptance_std[k, p] for p, d in enumerate(dofs)})
        writer.end_run("complete")
    writer.close()


def _keys_missing(example, actual, where="") -> list[str]:
    """Keys of the documented example that the actual JSON lacks, at the same nesting (lists: first item)."""
    if isinstance(example, dict):
        if not isinstance(actual, dict):
            return [where or "<root>"]
        return [m for k, v in example.items()
                for m in ([f"{where}.{k}"] if k not in actual else _keys_missing(v, actual[k], f"{where}.{k}"))]
    if isinstance(example, list) and example:
        if not isinstance(actual, list) or not actual:
            return [f"{where}[]"]
        return _keys_missing(example[0], actual[0], f"{where}[]")
    return []


@pytest.fixture(scope="module")
def analyzed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("api")
    session, model, fitted = folder / "s.h5", folder / "model.toml", folder / "fitted.toml"
    _write_session(session)
    model.write_text(MODEL, encoding="utf-8")
    return session, model, fitted


@pytest.mark.slow
def test_analyze_json_has_every_documented_key(analyzed, capsys):
    session, model, fitted = analyzed
    assert main(["analyze", str(session), str(model), "--add", "right:coulomb", "--json", "-o", str(fitted),
                 "--no-history"]) == 0
    out = json.loads(capsys.readouterr().out)
    text = (ROOT / "docs/contracts.md").read_text(encoding="utf-8")
    example = json.loads(text.split("## 6.")[1].split("```json")[1].split("```")[0])
    assert _keys_missing(example, out) == []
    assert out["elements"][0]["verdict"] in ("linear", "nonlinear", None)
    assert isinstance(out["misfits"], list)
    right = next(e for e in out["elements"] if e["name"] == "right")
    assert [law["law"] for law in right["laws"]] == ["cubic", "coulomb"]
    # the fitted model is a model file again (docs/contracts.md §4)
    from analysis.model import load_model
    from analysis.tables import load_toml
    assert [t.law.name for t in load_model(load_toml(fitted)).elements[1].laws] == ["cubic", "coulomb"]


def test_session_layout_has_the_contract_parts(analyzed):
    session, _, _ = analyzed
    with h5py.File(session, "r") as f:
        assert f.attrs["format"] == "contactid-session"
        assert isinstance(f.attrs["format_version"], (int, np.integer))
        assert {"created", "software_version"} <= set(f.attrs)
        run = f["runs"][next(iter(f["runs"]))]
        assert {"kind", "force", "direction", "status", "excitation_dof", "sensor_dofs"} <= set(run.attrs)
        assert run["frequency"].attrs["units"] == "Hz"
        assert all(run["frf"][d].attrs["units"] == "m/N" and run["frf"][d].dtype.kind == "c"
                   for d in json.loads(run.attrs["sensor_dofs"]))
        assert "data" in run["raw"]
