"""The valid inputs the fuzz corpus mutates: a rig, a plan, a model, and a small simulated session."""
import tomllib

import pytest

from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from drivers.simulation.rig import builtin_rig_path, load_rig
from session_helpers import MODEL  # noqa: F401  (the valid model the corpus mutates)

PLAN = """[[stepped_sine]]
force = 0.8
start = 1.0
stop = 1.2
step = 0.05
direction = "up"

[[stepped_sine]]
force = 0.4
start = 1.0
stop = 1.2
step = 0.05
direction = "up"

[limits]
max_force = 5.0
max_acceleration = 50.0
"""



@pytest.fixture(scope="session")
def rig_text() -> str:
    return builtin_rig_path("paper-2dof").read_text(encoding="utf-8")


@pytest.fixture(scope="session")
def small_session(tmp_path_factory) -> bytes:
    """A session simulated on paper-2dof: two stepped-sine runs of five lines."""
    path = tmp_path_factory.mktemp("fuzz-base") / "s.h5"
    with emulated_instruments(load_rig("paper-2dof"), seed=0) as inst:
        summary = run_plan(parse_plan(tomllib.loads(PLAN), PLAN), inst, path)
    assert summary.complete
    return path.read_bytes()
