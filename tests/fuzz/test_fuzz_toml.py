"""Fuzz corpus: rig, plan and model files (TOML) mutated so that each must be refused, run against every
command that reads them; each refusal is one line naming the file, exit status 2, and nothing is written."""
import pytest

from conftest import MODEL, PLAN
from drivers.simulation.rig import builtin_rig_path
from fuzz_runner import Case, check, params, run_case

RIG = builtin_rig_path("paper-2dof").read_text(encoding="utf-8")
SESSION = lambda inputs: inputs["session"]   # noqa: E731 -- the simulated session, where a command needs one
DEEP = "x = " + "[" * 5000 + "]" * 5000 + "\n"


def edit(text: str, old: str, new: str) -> bytes:
    assert old in text, old
    return text.replace(old, new, 1).encode()


def structural(text: str) -> list[tuple[str, bytes]]:
    """Mutations of any TOML file that no reader may accept."""
    data = text.encode()
    return [
        ("empty", b""),
        ("deeply nested", DEEP.encode() + data),
        ("deeply nested tables", ("[" + ".".join(["t"] * 3000) + "]\n").encode() + data),
        ("non-UTF-8 byte", data[:40] + b"\xff\xfe" + data[40:]),
        ("binary junk", bytes(range(256)) * 4),
        ("cut mid-line", data[: len(data) // 3 + 7]),
        ("duplicate key", data + b"\n" + data.splitlines()[-1] + b"\n"),
        ("unknown table", data + b"\n[nonsense]\nx = 1\n"),
        ("BOM then garbage", b"\xef\xbb\xbf" + b"= = =\n" + data),
        ("NUL bytes", data.replace(b"\n", b"\n\x00", 3)),
    ]


RIG_ONLY = {"no name", "law parameter missing", "excitation unknown dof", "sensors empty", "sample rate zero",
            "sample rate huge", "resolution text", "noise negative", "noise seed negative", "oversample zero"}
"""Edits that make a rig file wrong but leave a structure that ``modes`` (which reads models too) may show."""

RIG_EDITS = [
    ("no name", RIG.replace('name = "paper-2dof"', "").encode()),
    ("mass negative", edit(RIG, "mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[-1.0, 0.0], [0.0, 2.0]]")),
    ("mass wrong shape", edit(RIG, "mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[1.0, 0.0]]")),
    ("stiffness text", edit(RIG, "stiffness = [[200.0, -100.0], [-100.0, 200.0]]", 'stiffness = "stiff"')),
    ("stiffness NaN", edit(RIG, "[[200.0, -100.0]", "[[nan, -100.0]")),
    ("element name empty", edit(RIG, 'name = "left"', 'name = ""')),
    ("element name with colon", edit(RIG, 'name = "left"', 'name = "le:ft"')),
    ("element twice", edit(RIG, 'name = "left"', 'name = "right"')),
    ("unknown law", edit(RIG, 'law = "cubic", k3 = -500.0', 'law = "cubical", k3 = -500.0')),
    ("law parameter missing", edit(RIG, "{ law = \"cubic\", k3 = -500.0 }", '{ law = "cubic" }')),
    ("law parameter inf", edit(RIG, "k3 = -500.0", "k3 = -inf")),
    ("element on unknown dof", edit(RIG, 'dof = "x1"', 'dof = "x9"')),
    ("excitation unknown dof", edit(RIG, 'dof = "x2"                 # ideal', 'dof = "x7"  # ideal')),
    ("sensors empty", edit(RIG, 'dofs = ["x1", "x2"]        # accel', "dofs = []  # accel")),
    ("sample rate zero", edit(RIG, "sample_rate = 256.0", "sample_rate = 0.0")),
    ("sample rate huge", edit(RIG, "sample_rate = 256.0", "sample_rate = 1e300")),
    ("resolution text", edit(RIG, "resolution = 24", 'resolution = "high"')),
    ("noise negative", edit(RIG, "force = 0.0", "force = -1.0")),
    ("noise seed negative", edit(RIG, "seed = 0", "seed = -5")),
    ("oversample zero", edit(RIG, "oversample = 4", "oversample = 0")),
]

PLAN_EDITS = [
    ("force negative", edit(PLAN, "force = 0.8", "force = -0.8")),
    ("force NaN", edit(PLAN, "force = 0.8", "force = nan")),
    ("force at the limit", edit(PLAN, "force = 0.8", "force = 5.0")),
    ("start zero", edit(PLAN, "start = 1.0", "start = 0.0")),
    ("stop below start", edit(PLAN, "stop = 1.2", "stop = 0.9")),
    ("step zero", edit(PLAN, "step = 0.05", "step = 0.0")),
    ("step tiny: billions of lines", edit(PLAN, "step = 0.05", "step = 1e-12")),
    ("step beyond span", edit(PLAN, "step = 0.05", "step = 5.0")),
    ("direction sideways", edit(PLAN, 'direction = "up"', 'direction = "sideways"')),
    ("refine text", edit(PLAN, 'direction = "up"', 'direction = "up"\nrefine = "yes"')),
    ("min_step above step", edit(PLAN, 'direction = "up"', 'direction = "up"\nmin_step = 1.0')),
    ("same run twice", edit(PLAN, "force = 0.4", "force = 0.8")),
    ("max_force zero", edit(PLAN, "max_force = 5.0", "max_force = 0.0")),
    ("max_acceleration missing", PLAN.replace("max_acceleration = 50.0", "").encode()),
    ("max_lines zero", (PLAN + "max_lines = 0\n").encode()),
    ("random duration 1e12 s", (PLAN + "[random]\nforce_rms = 0.05\nband = [0.5, 5.0]\nduration = 1e12\n").encode()),
    ("random duration 1e6 s", (PLAN + "[random]\nforce_rms = 0.05\nband = [0.5, 5.0]\nduration = 1e6\n").encode()),
    ("random band reversed", (PLAN + "[random]\nforce_rms = 0.05\nband = [5.0, 0.5]\nduration = 8\n").encode()),
    ("random band one value", (PLAN + "[random]\nforce_rms = 0.05\nband = [5.0]\nduration = 8\n").encode()),
    ("random rms at the limit", (PLAN + "[random]\nforce_rms = 2.0\nband = [0.5, 5.0]\nduration = 8\n").encode()),
    ("random resolution too fine", (PLAN + "[random]\nforce_rms = 0.05\nband = [0.5, 5.0]\nduration = 8\n"
                                           "resolution = 0.001\n").encode()),
    ("settle block_periods 1e9", (PLAN + "[settle]\nblock_periods = 1e9\n").encode()),
    ("settle block_periods 2.5", (PLAN + "[settle]\nblock_periods = 2.5\n").encode()),
    ("settle max_periods 1e12", (PLAN + "[settle]\nmax_periods = 1e12\n").encode()),
    ("settle fixed_periods negative", (PLAN + "[settle]\nfixed_periods = -1\n").encode()),
    ("settle min_blocks 1e9", (PLAN + "[settle]\nmin_blocks = 1e9\n").encode()),
    ("settle method unknown", (PLAN + '[settle]\nmethod = "guess"\n').encode()),
    ("settle transient and fixed", (PLAN + '[settle]\nmethod = "transient"\nfixed_periods = 50\n').encode()),
    ("control tolerance zero", (PLAN + "[control]\ntolerance = 0\n").encode()),
    ("excitation dof empty", (PLAN + '[excitation]\ndof = ""\n').encode()),
    ("excitation dof with colon", (PLAN + '[excitation]\ndof = "a:b"\n').encode()),
    ("sensors repeated", (PLAN + '[sensors]\ndofs = ["x1", "x1"]\n').encode()),
    ("thousands of tables", ("".join(f"[[stepped_sine]]\nforce = {0.001 * (i + 1):g}\nstart = 1.0\nstop = 1.1\n"
                                     "step = 0.1\n" for i in range(4000))
                             + "[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n").encode()),
    ("plans nothing", b"[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n"),
]

MODEL_EDITS = [
    ("element name empty", edit(MODEL, 'name = "right"', 'name = ""')),
    ("element name with colon", edit(MODEL, 'name = "right"', 'name = "ri:ght"')),
    ("element name with spaces", edit(MODEL, 'name = "right"', 'name = " right"')),
    ("element twice", edit(MODEL, 'name = "right"', 'name = "left"')),
    ("unknown law", edit(MODEL, 'laws = ["cubic"]', 'laws = ["cubist"]')),
    ("law as number", edit(MODEL, 'laws = ["cubic"]', "laws = [3]")),
    ("unknown dof", edit(MODEL, 'dof = "x2"', 'dof = "x3"')),
    ("both dof and between", edit(MODEL, 'dof = "x2"', 'dof = "x2"\nbetween = ["x1", "x2"]')),
    ("structure type unknown", edit(MODEL, 'type = "lumped"', 'type = "lumpy"')),
    ("mass not symmetric", edit(MODEL, "mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[1.0, 0.5], [0.0, 2.0]]")),
    ("stiffness infinite", edit(MODEL, "[[200.0, -100.0]", "[[inf, -100.0]")),
    ("no structure", MODEL.split("[[element]]", 1)[1].join(["[[element]]", ""]).encode()),
]


def cases():
    rig_cmds = [("modes", "{d}/rig.toml"), ("simulate", "{d}/rig.toml", "{d}/plan.toml", "-o", "{d}/out.h5")]
    plan_cmd = ("simulate", "paper-2dof", "{d}/plan.toml", "-o", "{d}/out.h5")
    model_cmds = [("modes", "{d}/model.toml"), ("analyze", "{d}/s.h5", "{d}/model.toml", "--no-history"),
                  ("analyze", "{d}/s.h5", "{d}/model.toml", "-o", "{d}/fitted.toml")]
    for name, data in structural(RIG) + RIG_EDITS:
        for argv in rig_cmds[1:] if name in RIG_ONLY else rig_cmds:
            yield Case("rig", name, argv, {"rig.toml": data, "plan.toml": PLAN.encode()}, names=("rig.toml",))
    acquire = ("acquire", "{d}/plan.toml", "-o", "{d}/out.h5", "--shaker", "sim://none/shaker", "--daq",
               "sim://none/daq")
    for name, data in structural(PLAN) + PLAN_EDITS:
        for argv in (plan_cmd, acquire):
            yield Case("plan", name, argv, {"plan.toml": data}, names=("plan.toml",))
    for name, data in structural(MODEL) + MODEL_EDITS:
        for argv in model_cmds:
            yield Case("model", name, argv, {"model.toml": data, "s.h5": SESSION}, names=("model.toml",))
    # the wrong kind of file where a TOML file is expected
    for argv, field in [(rig_cmds[0], "rig.toml"), (rig_cmds[1], "rig.toml"), (plan_cmd, "plan.toml"),
                        (model_cmds[0], "model.toml"), (model_cmds[1], "model.toml")]:
        for what, data in (("session", SESSION), ("folder", None)):
            files = {"plan.toml": PLAN.encode(), "s.h5": SESSION, field: data}
            yield Case("wrong-file", f"{what} as {field}", argv, files, names=(field,))


CASES = list(cases())


@pytest.mark.parametrize("case", params(CASES))
def test_a_hostile_toml_file_is_refused_in_one_line(case, tmp_path, small_session):
    check(case, run_case(case, tmp_path, {"session": small_session}))
