"""Fuzz corpus: command lines. Each is refused with exit 2 -- one line naming the option or file, or the argument
parser's usage error -- without a traceback and without writing anything."""
import pytest

from conftest import MODEL, PLAN
from fuzz_runner import Case, check, params, run_case

SESSION = lambda inputs: inputs["session"]   # noqa: E731 -- the simulated session
FILES = {"s.h5": SESSION, "model.toml": MODEL.encode(), "plan.toml": PLAN.encode(), "out.csv": b"earlier",
         "fitted.toml": b"earlier"}

REFUSED = [
    ("seed negative", ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}/o.h5", "--seed", "-5"), "--seed"),
    ("seed too large", ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}/o.h5", "--seed", "99999999999"),
     "--seed"),
    ("emulate seed negative", ("emulate", "paper-2dof", "--seed", "-1"), "--seed"),
    ("session over its plan", ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}/plan.toml", "--overwrite"),
     "plan.toml"),
    ("session over the model", ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}/model.toml"), "model.toml"),
    ("session into a missing folder", ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}/no/o.h5"), "o.h5"),
    ("session onto a folder", ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}"), "-o"),
    ("unknown rig", ("simulate", "paper-3dof", "{d}/plan.toml", "-o", "{d}/o.h5"), "paper-3dof"),
    ("no output", ("simulate", "paper-2dof", "{d}/plan.toml"), "usage"),
    ("acquire over its plan", ("acquire", "{d}/plan.toml", "-o", "{d}/plan.toml", "--shaker", "x", "--daq", "y"),
     "plan.toml"),
    ("analyze missing session", ("analyze", "{d}/none.h5", "{d}/model.toml"), "none.h5"),
    ("analyze fitted over the model", ("analyze", "{d}/s.h5", "{d}/model.toml", "-o", "{d}/model.toml", "--overwrite"),
     "model.toml"),
    ("analyze fitted over the session", ("analyze", "{d}/s.h5", "{d}/model.toml", "-o", "{d}/s.h5", "--overwrite"),
     "s.h5"),
    ("analyze fitted exists", ("analyze", "{d}/s.h5", "{d}/model.toml", "-o", "{d}/fitted.toml"), "fitted.toml"),
    ("add with two colons", ("analyze", "{d}/s.h5", "{d}/model.toml", "--add", "ri:ght:cubic"), "--add"),
    ("add without element", ("analyze", "{d}/s.h5", "{d}/model.toml", "--add", ":cubic"), "--add"),
    ("add unknown law", ("analyze", "{d}/s.h5", "{d}/model.toml", "--add", "right:cubist"), "cubist"),
    ("add unknown element", ("analyze", "{d}/s.h5", "{d}/model.toml", "--add", "middle:cubic"), "middle"),
    ("export csv onto a file", ("export", "{d}/s.h5", "--csv", "{d}/out.csv"), "out.csv"),
    ("export uff over the session", ("export", "{d}/s.h5", "--uff", "{d}/s.h5", "--overwrite"), "s.h5"),
    ("export both targets", ("export", "{d}/s.h5", "--uff", "{d}/a.uff", "--csv", "{d}/c"), "usage"),
    ("export of a plan", ("export", "{d}/plan.toml", "--csv", "{d}/c"), "plan.toml"),
    ("recover a plan", ("recover", "{d}/plan.toml"), "plan.toml"),
    ("modes of a session", ("modes", "{d}/s.h5"), "s.h5"),
    ("modes count text", ("modes", "paper-2dof", "-n", "many"), "usage"),
    ("demo into a file", ("demo", "--out", "{d}/plan.toml"), "plan.toml"),
    ("emulate bad tcp", ("emulate", "paper-2dof", "--tcp", "nowhere"), "--tcp"),
    ("import of a CSV without a header", ("import", "{d}/out.csv", "-o", "{d}/new.h5"), "out.csv"),
    ("gui half instruments", ("gui", "--shaker", "x"), "--daq"),
    ("unknown command", ("identify", "{d}/s.h5"), "usage"),
]


def cases():
    for name, argv, named in REFUSED:
        yield Case("command-line", name, argv, FILES, names=() if named == "usage" else (named,),
                   usage=named == "usage")


CASES = list(cases())


@pytest.mark.parametrize("case", params(CASES))
def test_a_hostile_command_line_is_refused_in_one_line(case, tmp_path, small_session):
    check(case, run_case(case, tmp_path, {"session": small_session}))
