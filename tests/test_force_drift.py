"""A stepped sine whose force drifts +-25 % around its target, as a real controller's does (``force_drift``):
on the emulated Jenkins rig the law fitted with the force measured per line is the rig's; with the nominal force
it is not (docs/campaigns.md, docs/import.md)."""
import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from analysis import InputError
from analysis.mechanics.model import load_model
from analysis.common.tables import load_toml
from analysis.loop.workbench import Workbench
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from app.session import open_session
from app.session.data import measurements_from_session
from drivers.simulation.rig import load_rig

RIG = Path(__file__).parent / "rigs" / "jenkins-sdof.toml"
LEVEL = """
[[stepped_sine]]
force = {force}
start = 20.0
stop = 25.0
step = 0.25
refine = false
force_drift = {drift}
"""
LIMITS = "[limits]\nmax_force = 1.0\nmax_acceleration = 150.0\n"


def plan(levels, drift=0.25, limits=LIMITS):
    text = "".join(LEVEL.format(force=f, drift=drift) for f in levels) + limits
    return parse_plan(tomllib.loads(text), text, "plan.toml")


def test_force_drift_is_checked():
    with pytest.raises(InputError, match=r"\[\[stepped_sine\]\]\[0\]\.force_drift: must be a fraction below 1"):
        plan([0.1], drift=1.0)
    with pytest.raises(InputError, match=r"force 0.9 N \(drifting to 1.125 N\) is not below the abort limit"):
        plan([0.9])
    spec = plan([0.1]).sine[0]
    targets = np.array([spec.line_target(i) for i in range(40)])
    assert targets.max() == pytest.approx(0.125, rel=0.01) and targets.min() == pytest.approx(0.075, rel=0.01)


def _fitted_jenkins(measurements, per_line: bool):
    doc = {k: v for k, v in load_toml(RIG).items() if k in ("structure", "element")}
    doc["element"][0]["laws"] = [{"law": "jenkins"}]
    runs = [dataclasses.replace(r, force_achieved=r.force_achieved if per_line else None) for r in measurements.sine]
    wb = Workbench(load_model(doc), dataclasses.replace(measurements, sine=runs))
    wb.identify()
    wb.fit()
    return wb.model.elements[0].laws[0].values, wb.compare().error


@pytest.mark.slow
def test_a_drifting_campaign_on_the_emulated_jenkins_rig_gives_the_rigs_law(tmp_path):
    rig = load_rig(RIG)
    path = tmp_path / "drift.h5"
    with emulated_instruments(rig, seed=2) as inst:
        run_plan(plan([0.01, 0.03, 0.06]), inst, path)
    with open_session(path) as s:
        run = s.run("sine_0.03N_up")
        force, target = run.arrays["force_amplitude"], run.arrays["force_target"]
        assert run.attrs["status"] == "complete"
        measurements = measurements_from_session(s)
    np.testing.assert_allclose(force, target, rtol=0.011)                # held on each line's drifted target
    assert force.max() > 1.2 * 0.03 and force.min() < 0.8 * 0.03
    truth = {law["law"]: law for law in load_toml(RIG)["element"][0]["laws"]}["jenkins"]
    values, error = _fitted_jenkins(measurements, per_line=True)
    assert values["kt"] == pytest.approx(truth["kt"], rel=0.05) and values["fs"] == pytest.approx(truth["fs"], rel=0.05)
    nominal, nominal_error = _fitted_jenkins(measurements, per_line=False)
    assert abs(nominal["fs"] / truth["fs"] - 1) > 0.1 and nominal_error > 10 * error
