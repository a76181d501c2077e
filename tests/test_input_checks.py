"""Bad input refused early with one line naming the file and field: rig, model and plan files, the modes
command, plan size, and where the force gauge and accelerometers sit on real instruments."""
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from analysis import InputError
from analysis.mechanics.model import load_model
from analysis.common.tables import load_toml
from app.cli import main
from app.campaign.instruments import check_placement
from app.campaign.plan import LARGEST_MAX_LINES, load_plan, parse_plan
from drivers.simulation.rig import builtin_rig_path, load_rig
from paper_structure import PAPER_STRUCTURE

ROOT = Path(__file__).resolve().parents[1]
RIG = builtin_rig_path("paper-2dof").read_text()
PLAN = """
[[stepped_sine]]
force = 0.5
start = 2.0
stop = 2.2
step = 0.1
refine = false

[limits]
max_force = 5.0
max_acceleration = 50.0
"""
PLACED = PLAN + '\n[excitation]\ndof = "x2"\n\n[sensors]\ndofs = ["x1", "x2"]\n'
CHANNELS = ["force", "acc:x1", "acc:x2"]


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


# --- rig, model and plan files alike: unknown top-level keys and numbers written as strings -------------------
def load_as_rig(path):
    load_rig(path)


def load_as_model(path):
    load_model(load_toml(path), str(path))


@pytest.mark.parametrize("load", [load_as_rig, load_as_model])
@pytest.mark.parametrize("edit, field, message", [
    (lambda t: "bogus = 3\n" + t, "bogus", "unknown key"),
    (lambda t: t.replace("k3 = -750.0", 'k3 = "-750"'), "[[element]][1].laws[0].k3", "must be a number, got '-750'"),
    (lambda t: t.replace("fs = 0.1", "fs = true"), "[[element]][1].laws[1].fs", "must be a number, got True"),
])
def test_rig_and_model_files_refuse_unknown_keys_and_string_numbers(tmp_path, load, edit, field, message):
    path = write(tmp_path, "rig.toml", edit(RIG))
    with pytest.raises(InputError) as err:
        load(path)
    assert (err.value.source, err.value.field) == (str(path), field) and message in err.value.message


def test_a_rig_file_is_still_a_model_file_and_a_model_may_update(tmp_path):
    load_as_model(write(tmp_path, "rig.toml", RIG))
    model = load_model({**load_toml(write(tmp_path, "m.toml", RIG)), "updating": {"parameters": []}})
    assert [e.name for e in model.elements] == ["left", "right"]


@pytest.mark.parametrize("edit, field, message", [
    (lambda t: "bogus = 3\n" + t, "bogus", "unknown key"),
    (lambda t: t.replace("force = 0.5", 'force = "0.5"'), "[[stepped_sine]][0].force", "must be a number"),
    (lambda t: t.replace("max_force = 5.0", 'max_force = "5"'), "[limits].max_force", "must be a number"),
])
def test_plan_files_refuse_unknown_keys_and_string_numbers(tmp_path, edit, field, message):
    path = write(tmp_path, "plan.toml", edit(PLAN))
    with pytest.raises(InputError) as err:
        load_plan(path)
    assert (err.value.source, err.value.field) == (str(path), field) and message in err.value.message


# --- plan size ----------------------------------------------------------------------------------------------
def test_a_plan_of_absurdly_many_lines_is_refused_unless_asked_for(tmp_path):
    path = write(tmp_path, "plan.toml", PLAN.replace("step = 0.1", "step = 1e-9"))
    with pytest.raises(InputError) as err:
        load_plan(path)
    assert err.value.field == "[[stepped_sine]][0].step"
    assert "200,000,001 stepped-sine lines" in err.value.message and "max_lines = 10,000" in err.value.message
    # asked for explicitly: 2 sweeps of 3001 lines need max_lines >= 6002
    both = PLAN.replace("step = 0.1", "step = 0.0001\ndirection = \"both\"").replace("start = 2.0", "start = 1.9")
    assert sum(len(s.lines(d)) for s, d in parse_plan(_toml(both)).runs) == 6002
    with pytest.raises(InputError, match="the plan has 6,002 stepped-sine lines"):
        parse_plan(_toml(both.replace("max_acceleration", "max_lines = 6001\nmax_acceleration")))
    parse_plan(_toml(both.replace("max_acceleration", "max_lines = 6002\nmax_acceleration")))
    with pytest.raises(InputError, match=f"max_lines: must be a whole number from 1 to {LARGEST_MAX_LINES}"):
        parse_plan(_toml(PLAN.replace("max_acceleration", "max_lines = 1e12\nmax_acceleration")))


def _toml(text):
    import tomllib
    return tomllib.loads(text)


# --- modes ----------------------------------------------------------------------------------------------------
def test_modes_accepts_built_in_rig_names_as_simulate_does(capsys):
    assert main(["modes", "paper-2dof"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("builtin:paper-2dof: lumped, 2 DOFs") and "mode  1:       1.2672 Hz" in out
    assert main(["modes", "paper-2dof.toml"]) == 2
    assert "no such file, and no built-in rig of that name" in capsys.readouterr().err


TWO_DOF_WITH_CONTACT = PAPER_STRUCTURE + """
[[element]]
name = "contact"
dof = "x1"
laws = [ { law = "linear", k = 50.0, c = 0.0 } ]

[[element]]
name = "unknown"
dof = "x2"
laws = ["cubic"]
"""


def _printed_hz(out: str) -> list[float]:
    return [float(line.split()[-2]) for line in out.splitlines() if line.strip().startswith("mode")]


def test_modes_includes_the_elements_stiffness_at_rest_and_says_so(tmp_path, capsys):
    model = tmp_path / "m.toml"
    model.write_text(TWO_DOF_WITH_CONTACT)
    assert main(["modes", str(model)]) == 0
    out = capsys.readouterr().out
    # det(K + k e1 e1' - lam M) = 0: 2 lam^2 - 700 lam + 40000 = 0
    lam = (700 + np.array([-1, 1]) * np.sqrt(700**2 - 8 * 40000)) / 4
    assert np.allclose(_printed_hz(out), np.sqrt(lam) / (2 * np.pi), rtol=1e-4)
    assert "with the elements' small-amplitude stiffness (contact on x1: 50 N/m)" in out
    assert "left out, their laws have no values: unknown" in out
    assert main(["modes", str(model), "--bare"]) == 0
    out = capsys.readouterr().out
    lam = (600 + np.array([-1, 1]) * np.sqrt(600**2 - 8 * 30000)) / 4      # 2 lam^2 - 600 lam + 30000 = 0
    assert np.allclose(_printed_hz(out), np.sqrt(lam) / (2 * np.pi), rtol=1e-4)
    assert "the structure alone" in out


def test_modes_of_the_demo_rig_are_what_the_demo_measures(capsys):
    # the bare clamped-free beam is at 11.6 / 72.9 Hz; with its contact the rig rings at 53.05 / 157.9 Hz
    assert main(["modes", "paper-beam", "-n", "2"]) == 0
    assert np.allclose(_printed_hz(capsys.readouterr().out), [53.05, 157.9], rtol=2e-3)


# --- where the force gauge and accelerometers sit ------------------------------------------------------------
def test_plan_says_where_excitation_and_sensors_are():
    place = parse_plan(_toml(PLACED), source="p.toml").placement
    assert (place.excitation_dof, place.sensor_dofs, place.driving_point) == ("x2", ["x1", "x2"], True)
    assert check_placement(CHANNELS, "daq", place) == ("x2", ["x1", "x2"])
    # flags override the plan; without [sensors] or --sensors the DAQ's accelerometers are the sensors
    assert check_placement(CHANNELS, "daq", place.overridden("x1", ["x1"])) == ("x1", ["x1"])
    bare = parse_plan(_toml(PLAN), source="p.toml").placement
    assert check_placement(CHANNELS, "daq", bare.overridden("x2", None)) == ("x2", ["x1", "x2"])
    unmeasured = parse_plan(_toml(PLACED.replace('dof = "x2"', 'dof = "x3"\ndriving_point = false'))).placement
    assert check_placement(CHANNELS, "daq", unmeasured) == ("x3", ["x1", "x2"])


@pytest.mark.parametrize("plan, flags, source, field, message", [
    (PLAN, {}, "p.toml", None, "no excitation DOF: say where the force gauge sits"),
    (PLACED, {"excitation": "x9"}, None, "--excitation", "excitation DOF 'x9' carries no accelerometer"),
    (PLACED.replace('dof = "x2"', 'dof = "x9"'), {}, "p.toml", "[excitation].dof", "'x9' carries no accelerometer"),
    (PLACED, {"sensors": ["q"]}, None, "--sensors", "sensor DOF 'q' has no accelerometer channel acc:q"),
    (PLACED.replace('["x1", "x2"]', '["x1", "x4"]'), {}, "p.toml", "[sensors].dofs", "sensor DOF 'x4'"),
])
def test_misplaced_dofs_are_refused_naming_plan_field_or_flag(plan, flags, source, field, message):
    place = parse_plan(_toml(plan), source="p.toml").placement.overridden(flags.get("excitation"),
                                                                            flags.get("sensors"))
    with pytest.raises(InputError) as err:
        check_placement(CHANNELS, "socket://daq", place)
    assert (err.value.source, err.value.field) == (source, field) and message in err.value.message


@pytest.mark.parametrize("table, field", [('[excitation]\ndof = "acc:x2"', "[excitation].dof"),
                                          ('[sensors]\ndofs = []', "[sensors].dofs"),
                                          ('[sensors]\ndofs = ["x1", "x1"]', "[sensors].dofs"),
                                          ('[excitation]\ndof = "x2"\nat = 1', "[excitation].at")])
def test_bad_placement_tables(table, field):
    with pytest.raises(InputError) as err:
        parse_plan(_toml(PLAN + table), source="p.toml")
    assert err.value.field == field


@pytest.fixture(scope="module")
def served():
    """URLs of paper-2dof's instruments served by ``contactid emulate`` in another process."""
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "emulate", "paper-2dof", "--tcp", "127.0.0.1:0",
                             "--fast"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        yield dict(proc.stdout.readline().strip().split(": ", 1) for _ in range(2))
    finally:
        proc.terminate()
        proc.wait(10)


def acquire(capsys, served, plan, output, *flags):
    rc = main(["acquire", str(plan), "-o", str(output), "--shaker", served["shaker"], "--daq", served["daq"],
               "--quiet", *flags])
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("plan, flags, message", [
    (PLACED, ["--excitation", "x9"], "--excitation: excitation DOF 'x9' carries no accelerometer"),
    (PLACED, ["--sensors", "q"], "--sensors: sensor DOF 'q' has no accelerometer channel acc:q"),
    (PLAN, [], "p.toml: no excitation DOF"),
])
@pytest.mark.slow
def test_acquire_checks_dofs_before_measuring_or_writing(capsys, tmp_path, served, plan, flags, message):
    path, output = write(tmp_path, "p.toml", plan), tmp_path / "s.h5"
    rc, err = acquire(capsys, served, path, output, *flags)
    assert rc == 2 and message in err and err.count("\n") == 1
    assert not output.exists()


@pytest.mark.slow
def test_acquire_runs_the_documented_command_with_dofs_from_the_plan(capsys, tmp_path, served):
    output = tmp_path / "s.h5"
    rc, err = acquire(capsys, served, write(tmp_path, "p.toml", PLACED), output)
    assert rc == 0, err
    with h5py.File(output, "r") as f:
        run = f["runs"]["sine_0.5N_up"]
        assert run.attrs["excitation_dof"] == "x2" and run.attrs["sensor_dofs"] == '["x1", "x2"]'
        assert run.attrs["status"] == "complete" and run["frequency"].shape == (3,)
