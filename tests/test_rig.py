"""Rig files: built-in rigs, optional tables, and refusal of rigs that cannot be simulated."""
import tomllib

import numpy as np
import pytest

from analysis.common.errors import InputError
from app.models import builtin_plan_path
from drivers.simulation.rig import builtin_rigs, load_rig, parse_rig
from paper_structure import PAPER_STRUCTURE

SMALL = """
name = "small"
""" + PAPER_STRUCTURE + """
[[element]]
name = "joint"
dof = "x1"
laws = [ { law = "cubic", k3 = 1000.0 } ]

[excitation]
dof = "x2"

[sensors]
dofs = ["x1", "x2"]

[daq]
sample_rate = 128.0
"""


def test_builtin_rigs_and_plans():
    assert {"paper-2dof", "paper-beam"} <= set(builtin_rigs())
    for name in builtin_rigs():
        rig = load_rig(name)
        assert rig.name == name and rig.source == f"builtin:{name}"
        plan = tomllib.loads(builtin_plan_path(name).read_text())
        assert plan["stepped_sine"] and "limits" in plan
    with pytest.raises(InputError, match="built-in rigs"):
        builtin_plan_path("no-such-rig")


def test_paper_2dof_is_the_contract_example():
    rig = load_rig("paper-2dof")
    np.testing.assert_array_equal(rig.structure.M, np.diag([1.0, 2.0]))
    np.testing.assert_array_equal(rig.structure.K, [[200.0, -100.0], [-100.0, 200.0]])
    np.testing.assert_array_equal(rig.structure.C, 0.0)
    laws = {el.name: (el.dofs, [(t.law.name, t.values) for t in el.laws]) for el in rig.elements}
    assert laws == {"left": (("x1",), [("cubic", {"k3": -500.0}), ("quadratic_damping", {"c2": 1.0})]),
                    "right": (("x2",), [("cubic", {"k3": -750.0}), ("coulomb", {"fs": 0.1})])}
    assert rig.excitation_dof == "x2" and rig.sensor_dofs == ["x1", "x2"]
    assert rig.shaker is None and rig.source_gain == 1.0
    assert rig.channels == ["force", "acc:x1", "acc:x2"]
    np.testing.assert_allclose(rig.structure.natural_frequencies(), [1.2672, 2.4481], atol=1e-4)
    plan = tomllib.loads(builtin_plan_path("paper-2dof").read_text())
    assert plan["stepped_sine"][0]["force"] == 0.8


def test_paper_beam_tables():
    rig = load_rig("paper-beam")
    assert rig.shaker is not None and rig.excitation_dof == "A.w"
    assert rig.sensor_dofs == ["A.w", "B.w", "C.w"]
    assert [t.law.name for el in rig.elements for t in el.laws] == ["linear", "iwan"]
    assert rig.linear.natural_frequencies[0] == pytest.approx(53.0, abs=0.5)


def test_rig_file_round_trip_and_optional_tables(tmp_path):
    text = SMALL + """
[noise]
force = 0.01
acceleration = 0.02
seed = 7
[generator]
ramp_cycles = 5.0
[faults]
drop_link_after = 10.0
"""
    path = tmp_path / "small.toml"
    path.write_text(text)
    rig = load_rig(path)
    assert rig.text == text and rig.source == str(path)
    assert (rig.noise.force, rig.noise.acceleration, rig.noise.seed) == (0.01, 0.02, 7)
    assert rig.generator.ramp_cycles == 5.0 and rig.faults == {"drop_link_after": 10.0}
    assert rig.daq.oversample == 4 and rig.daq.resolution == 24
    assert rig.simulation.reduction == "none"


@pytest.mark.parametrize("edit, field, message", [
    (("mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[1.0, 0.0], [0.0, -2.0]]"), "[structure].mass", "positive definite"),
    (("stiffness = [[200.0, -100.0], [-100.0, 200.0]]", "stiffness = [[200.0, -100.0], [-90.0, 200.0]]"),
     "[structure].stiffness", "symmetric"),
    (('law = "cubic", k3 = 1000.0', 'law = "cubical", k3 = 1000.0'), "[[element]][0].laws[0].law", "unknown law"),
    (('law = "cubic", k3 = 1000.0', 'law = "cubic", k5 = 1000.0'), "[[element]][0].laws[0].k5", "no parameter"),
    (('law = "cubic", k3 = 1000.0', 'law = "jenkins", kt = 1000.0'), "[[element]][0].laws[0]", "needs parameter"),
    (('law = "cubic", k3 = 1000.0', 'law = "linear", k = -250.0, c = 0.0'), "[[element]][0].laws",
     "unstable at rest"),
    (('law = "cubic", k3 = 1000.0', 'law = "linear", k = 0.0, c = -1.0'), "[[element]][0].laws",
     "the rig would add energy: its damping, with the elements' small-amplitude damping, is negative: negative "
     "small-amplitude damping of element 'joint' (c0 = -1)"),
    (('dofs = ["x1", "x2"]\n\n[daq]', 'dofs = ["x1", "x3"]\n\n[daq]'), "[sensors].dofs", "not in the structure"),
    (('[excitation]\ndof = "x2"', '[excitation]\ndof = "x2"\ngain = -1.0'), "[excitation].gain", "> 0"),
    (("sample_rate = 128.0", "sample_rate = 128.0\npassband = 0.6"), "[daq].passband", "below 0.5"),
    (("sample_rate = 128.0", "sample_rate = 128.0\noversample = 0"), "[daq].oversample", "whole number"),
    (("[daq]", "[shaker]\nresistance = -4.0\ninductance = 1e-3\nforce_factor = 2.0\narmature_mass = 0.01\n[daq]"),
     "[shaker].resistance", "> 0"),
    (("[daq]", "[sensor]\ndofs = []\n[daq]"), "sensor", "unknown key"),
])
def test_bad_rig_files_are_refused_naming_file_and_field(tmp_path, edit, field, message):
    old, new = edit
    assert old in SMALL
    path = tmp_path / "bad.toml"
    path.write_text(SMALL.replace(old, new, 1))
    with pytest.raises(InputError) as info:
        load_rig(path)
    assert info.value.source == str(path)
    assert info.value.field == field
    assert message in info.value.message


def test_unstable_rig_blames_the_element_with_negative_stiffness_not_a_cubic_at_rest():
    # a softening cubic on x1 has a tangent of k3 dx^2 ~ -1e-15 at rest (round-off); the culprit is 'right'
    text = SMALL.replace('laws = [ { law = "cubic", k3 = 1000.0 } ]', 'laws = [ { law = "cubic", k3 = -500.0 } ]') \
        + '[[element]]\nname = "right"\ndof = "x2"\nlaws = [ { law = "linear", k = -500.0, c = 0.0 } ]\n'
    with pytest.raises(InputError) as info:
        parse_rig(text, "neg.toml")
    assert info.value.field == "[[element]][1].laws"
    assert info.value.message == ("the rig is unstable at rest: its stiffness, with the elements' small-amplitude "
                                  "stiffness, is not positive definite: negative small-amplitude stiffness of "
                                  "element 'right' (k0 = -500)")


def test_sample_rate_too_low_for_the_highest_mode_names_mode_and_rate():
    stiff = SMALL.replace("stiffness = [[200.0, -100.0], [-100.0, 200.0]]",
                          "stiffness = [[2.0e6, -1.0e6], [-1.0e6, 2.0e6]]")
    with pytest.raises(InputError) as info:
        parse_rig(stiff, "stiff.toml")
    error = info.value
    assert error.field == "[daq].sample_rate"
    # highest mode: sqrt(3e6 / 1) / (2 pi) ~ 276 Hz for these masses (computed independently below)
    lam = np.linalg.eigvals(np.linalg.solve(np.diag([1.0, 2.0]), [[2e6, -1e6], [-1e6, 2e6]]))
    f_max = np.sqrt(lam.max()) / (2 * np.pi)
    assert f"mode 2 of the model (the highest kept) at {f_max:.6g} Hz" in error.message
    assert f"at least {2.5 * f_max:.6g} Hz" in error.message
    parse_rig(stiff.replace("sample_rate = 128.0", f"sample_rate = {2.5 * f_max / 4 + 1:.1f}"), "ok.toml")


def test_beam_reduction_resolution_hint_mentions_the_cutoff():
    text = builtin_text("paper-beam").replace("mode_cutoff = 400.0", "mode_cutoff = 1000.0")
    with pytest.raises(InputError, match=r"reduced model .* lower \[simulation\].mode_cutoff"):
        parse_rig(text, "beam.toml")


def test_excitation_and_sensors_must_be_translations():
    text = builtin_text("paper-beam")
    with pytest.raises(InputError, match="is a rotation"):
        parse_rig(text.replace('dof = "A.w"                    # shaker', 'dof = "A.theta"  # shaker'), "b.toml")
    with pytest.raises(InputError, match="accelerometers measure displacement"):
        parse_rig(text.replace('dofs = ["A.w", "B.w", "C.w"]', 'dofs = ["A.w", "O.theta"]'), "b.toml")


def test_missing_file_and_unknown_builtin():
    with pytest.raises(InputError, match="no such rig file"):
        load_rig("no-such-file.toml")
    with pytest.raises(InputError, match="not valid TOML"):
        parse_rig("name = ", "broken.toml")


def builtin_text(name):
    return load_rig(name).text
