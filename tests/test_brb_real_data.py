"""The Brake-Reuss beam's measured stepped sine (real data that cannot ship: tests/realdata.py): read from MATLAB
into the CSV long format by the documented script, imported (the reversed force sign refused until named), the
reference from the lowest level, a law fitted and cross-validated over the levels, and an Iwan element added by
hand (docs/import.md shows the numbers). The automatic loop on all twelve levels takes too long for the suite:
benchmarks/brb_auto.py runs it and checks its targets."""
import importlib.util
import json
import re
import tomllib
from pathlib import Path

import pytest

from analysis.loop.workbench import Workbench
from analysis.mechanics.model import load_model
from app.analyze import report_text
from app.cli import main
from app.session import open_session
from app.session.data import measurements_from_session
from realdata import BRB_MAT, BRB_MISSING

ROOT = Path(__file__).resolve().parents[1]
MAT = BRB_MAT
pytestmark = pytest.mark.skipif(not MAT.exists(), reason=BRB_MISSING)


def _script():
    spec = importlib.util.spec_from_file_location("brb_to_csv", ROOT / "docs" / "examples" / "brb_to_csv.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def brb(tmp_path_factory):
    folder = tmp_path_factory.mktemp("brb")
    _script().write_csv(str(MAT), str(folder / "brb.csv"))
    return folder


def test_the_reversed_force_sign_is_refused_then_imported_with_the_flag(brb, capsys):
    session = brb / "refused.h5"
    assert main(["import", str(brb / "brb.csv"), "-o", str(session), "--excitation", "x1"]) == 2
    err = capsys.readouterr().err
    assert "run sine_0.2N_up, frf x1 (drive point)" in err and "give --force-sign -1" in err
    assert not session.exists()


@pytest.mark.slow
def test_import_reference_a_law_and_an_iwan_element_on_the_measured_beam(brb, capsys):
    session, model = brb / "brb.h5", brb / "reference.toml"
    assert main(["import", str(brb / "brb.csv"), "-o", str(session), "--excitation", "x1", "--force-sign", "-1"]) == 0
    out = capsys.readouterr().out
    for name in ("sine_0.2N_up", "sine_1.5N_up", "sine_x1_5mps2_up", "sine_x1_80mps2_up"):
        assert f"run {name} from" in out
    assert main(["reference", str(session), "-o", str(model)]) == 0
    out = capsys.readouterr().out
    assert "reference from run sine_x1_5mps2_up" in out and "NONLINEAR already" in out
    structure = tomllib.loads(model.read_text())["structure"]
    assert 80.0 < structure["frequencies"][0] < 80.6 and 0.001 < structure["damping"][0] < 0.003
    assert main(["analyze", str(session), str(model), "--add", "joint:cubic_damping", "--json", "--no-history",
                 "--cross-validate"]) == 0
    result = json.loads(capsys.readouterr().out)
    labels = [e["label"] for e in result["error_by_level"]]
    assert labels[:4] == ["0.2 N", "0.5 N", "1 N", "1.5 N"] and labels[4] == "5 m/s^2 at x1"
    level = result["error_by_level"][4]
    assert (level["control"], level["control_dof"], level["control_target"]) == ("response", "x1", 5.0)
    assert result["error"] < 0.7                                 # the reference alone misses by about 1
    # the test repeats far less well than a line is measured (the mode moves 0.1-0.4 Hz between levels): the
    # scatter between runs, about 430 N/m against a line noise of 13 N/m, is the yardstick (docs/fitting.md)
    yardstick = result["elements"][0]["yardstick"]
    assert yardstick["ruled_by"] == "between_runs" and yardstick["groups"] >= 40
    assert 200 < yardstick["between_runs_std"] < 900 and yardstick["line_noise_std"] < 30
    # carried to the FRFs, that scatter alone gives a model right in every law an FRF error of about 0.18 (the
    # line noise 0.005): the error the test allows, which no law of the joint can be judged below
    floor = result["error_floor"]
    assert floor["ruled_by"] == ["joint"] and 0.1 < floor["between_runs"] < 0.3 and floor["line_noise"] < 0.02
    # a joint's law dissipates and keeps the beam standing at every line measured
    assert result["admissibility"]["passive"] and result["admissibility"]["statically_stiff"]
    # how far it carries: refitted on half of the levels, each half predicting the others
    folds = result["cross_validation"]
    assert len(folds) == 4 and all(0 < f["fitted_error"] and 0 < f["held_out_error"] for f in folds)
    # an Iwan element added by hand, measured from the reference that holds the joint's stuck stiffness
    # (docs/laws.md, "Measured from the reference"): finite values, every line kept, and the error less than half
    # the reference's (0.399 against 0.983 on 2026-12-03; added on top of the reference it ran to kt = 1.7e32 at
    # 0.968, and measured from it, while its departure from the stuck stiffness was lost to round-off, to kt =
    # 4e16, 44 % of the lines left out, at 0.462)
    # (the workbench as `analyze --add joint:iwan` drives it, less the ranking of what is still missing, which
    # would triple the test's time)
    with open_session(session) as s:
        measurements = measurements_from_session(s)
    wb = Workbench(load_model(tomllib.loads(model.read_text()), str(model)), measurements)
    wb.start()
    wb.add("joint", "iwan")
    out = report_text(wb, [])
    assert "measured from the reference" in out and "yardstick: the scatter between runs" in out
    assert "FRF error the test itself allows" in out
    assert "NOT A FIT OF THE DATA" not in out
    law = next(line for line in out.splitlines() if line.strip().startswith("law iwan"))
    assert not re.search(r"e\+[1-9][0-9]", law), law
    assert wb.history[-1].error < 0.5 * wb.history[0].error, [h.error for h in wb.history]
    # and in JSON: every value shown is finite and of a joint's size
    joint = next(el for el in wb.model.elements if el.name == "joint")
    reported = wb.reports["joint"].to_json(joint)
    (iwan,) = reported["laws"]
    assert all(v is None or abs(v) < 1e12 for v in iwan["params"].values()), iwan["params"]
    assert reported["lines_excluded_share"] <= 0.10 and reported["fit_describes_data"]
