"""Law metadata: each law's whole description (and the docs generated from it), parameter validation, fit
parametrisation, shapes, passivity."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from analysis import InputError
from analysis.laws import LAWS, Law, Param, describing_function, get_law
from analysis.laws import docs_table
from analysis.laws.base import SignatureWords

DISSIPATIVE = ["linear", "quadratic_damping", "cubic_damping", "coulomb", "anderson_ferri", "jenkins", "iwan"]
CONSERVATIVE = [n for n in LAWS if n not in DISSIPATIVE]


# --------------------------------------------------------------------------- a law carries everything about itself
WORDS = SignatureWords(re="<re>", im="<im>", re_slope="<slope>", mean_re="<mean re>", mean_im="<mean im>",
                       spring="<spring>")


@pytest.mark.parametrize("name", list(LAWS))
def test_every_law_carries_its_whole_description(name):
    law = LAWS[name]
    assert law.name == name and law.summary
    assert law.params and all(isinstance(p, Param) and p.description for p in law.params)
    assert set(law.linear) <= set(law.param_names) | {p.name for p in law.shape}
    assert law.kernel is not None and law.force_text and law.kbar_text
    assert isinstance(law.visible_in_kbar, bool)
    sentence = law.explain(WORDS)
    assert sentence and "{" not in sentence and "}" not in sentence
    row = law.docs_row()
    assert row.startswith(f"| {name} | {law.kind} | ") and row.count(" | ") == 6   # seven cells, escaped pipes excepted
    assert all(p.name in row for p in law.params)


@pytest.mark.parametrize("name", list(LAWS))
def test_visible_in_kbar_means_kbar_is_not_one_constant(name):
    """A law kbar cannot reveal has the same kbar at every amplitude and frequency (the linear law reproduces
    it); every other law's kbar changes over its example amplitudes or over frequency."""
    law = LAWS[name]
    X = np.geomspace(*law.example_amplitude, 9)[:, None]
    kbar = law.describing_function(X, np.array([[10.0, 300.0, 2000.0]]), **law.example)
    assert law.visible_in_kbar == (np.ptp(kbar.real) > 0 or np.ptp(kbar.imag) > 0)


def test_a_law_lacking_part_of_its_description_fails_when_defined():
    linear = LAWS["linear"]
    body = {"name": "spring2", "kind": "linear", "summary": "s", "params": linear.params, "linear": linear.linear,
            "example": linear.example, "kernel": linear.kernel, "force_text": "k x", "kbar_text": "k",
            "basis": type(linear).basis}
    with pytest.raises(TypeError, match="lacks explanation"):
        type("Spring2", (Law,), dict(body))
    with pytest.raises(TypeError, match="lacks kind"):
        type("Spring2", (Law,), {k: v for k, v in body.items() if k != "kind"} | {"explanation": "{re}"})
    with pytest.raises(TypeError, match="kind 'spring' is not one of"):
        type("Spring2", (Law,), dict(body, kind="spring", explanation="{re}"))
    with pytest.raises(TypeError, match=r"unknown field\(s\) slope"):
        type("Spring2", (Law,), dict(body, explanation="{re} with {slope}"))
    law = type("Spring2", (Law,), dict(body, explanation="{re}: a spring"))()
    assert law.explain(WORDS) == "<re>: a spring"


def test_docs_law_tables_are_what_the_classes_say():
    """docs/laws.md's generated tables (law vocabulary, parameters, formulas, examples, explanations) are up to
    date: after a change to a law class, ``python -m analysis.laws.docs_table`` rewrites them."""
    text = docs_table.DOCS.read_text(encoding="utf-8")
    assert docs_table.updated(text) == text
    table = text[text.index("<!-- table 'laws'"):text.index("<!-- end of table 'laws'")]
    assert [line.split(" | ")[0][2:] for line in table.splitlines()[3:]] == list(LAWS)
    assert docs_table.main(["--check"]) == 0


def test_docs_table_generator_finds_an_out_of_date_page(tmp_path, monkeypatch, capsys):
    page = tmp_path / "stale-page.txt"
    current = docs_table.DOCS.read_text(encoding="utf-8")
    page.write_text(current.replace("| cubic | k3 ", "| cubic | k4 "), encoding="utf-8")
    monkeypatch.setattr(docs_table, "DOCS", page)
    assert docs_table.main(["--check"]) == 1 and "out of date" in capsys.readouterr().out
    assert docs_table.main([]) == 0
    assert page.read_text(encoding="utf-8") == current
    with pytest.raises(ValueError, match="markers of table 'laws'"):
        docs_table.updated("no tables here")


@pytest.mark.parametrize("name", list(LAWS))
def test_example_is_valid_and_complete(name):
    law = LAWS[name]
    assert law.check_params(law.example, complete=True) == law.example
    lo, hi = law.example_amplitude
    assert 0 < lo < hi


@pytest.mark.parametrize("name", list(LAWS))
def test_fit_parametrisation_round_trips(name):
    law = LAWS[name]
    linear, shape = law.to_fit(law.example)
    assert tuple(linear) == law.linear and tuple(shape) == tuple(p.name for p in law.shape)
    back = law.from_fit(linear, shape)
    assert back == pytest.approx(law.example, rel=1e-15)
    # the fitted form reproduces the describing function
    X = np.geomspace(*law.example_amplitude, 7)
    basis = law.basis(X, 300.0, **shape)
    assert np.allclose(np.tensordot([linear[n] for n in law.linear], basis, axes=1),
                       law.describing_function(X, 300.0, **law.example), rtol=1e-14, atol=0)


@pytest.mark.parametrize("name", list(LAWS))
def test_basis_and_describing_function_broadcast(name):
    law = LAWS[name]
    shape = law.to_fit(law.example)[1]
    X = np.geomspace(*law.example_amplitude, 4)[:, None]
    w = np.array([[10.0, 300.0, 2000.0]])
    assert law.basis(X, w, **shape).shape == (len(law.linear), 4, 3)
    kbar = describing_function(name, X, w, **law.example)
    assert kbar.shape == (4, 3) and kbar.dtype == complex
    one_by_one = np.array([[law.describing_function(x, f, **law.example) for f in w[0]] for x in X[:, 0]])
    # equal up to rounding (tanh's quadrature rule is chosen for the largest amplitude of a call)
    assert np.allclose(kbar, one_by_one, rtol=1e-14, atol=0)
    assert law.describing_function(X[0, 0], 300.0, **law.example).shape == ()


def test_jenkins_and_iwan_fit_the_slip_displacement():
    jenkins, iwan = LAWS["jenkins"], LAWS["iwan"]
    assert jenkins.to_fit({"kt": 2.0e5, "fs": 4.0}) == ({"kt": 2.0e5}, {"xs": 2.0e-5})
    assert iwan.from_fit({"kt": 2.0e5}, {"xs": 2.0e-5, "chi": -0.5, "beta": 0.1}) == \
        {"kt": 2.0e5, "fs": 4.0, "chi": -0.5, "beta": 0.1}
    J = jenkins.fit_jacobian({"kt": 2.0e5}, {"xs": 2.0e-5})
    assert np.allclose(J, [[1.0, 0.0], [2.0e-5, 2.0e5]], rtol=1e-6)
    assert iwan.unit("xs") == "m" and iwan.unit("xs", rotational=True) == "rad"


def test_units_render_for_translational_and_rotational_dofs():
    assert LAWS["quintic"].unit("k5") == "N/m^5"
    assert LAWS["quintic"].unit("k5", rotational=True) == "N·m/rad^5"
    assert LAWS["quadratic_damping"].unit("c2") == "N·s^2/m^2"
    assert LAWS["tanh_softening"].unit("beta", rotational=True) == "1/rad"
    assert LAWS["anderson_ferri"].unit("b", rotational=True) == "N·m/rad"
    assert LAWS["iwan"].unit("chi") == "1"


# --------------------------------------------------------------------------- validation
def test_misspelt_parameter_names_the_field():
    with pytest.raises(InputError) as err:
        LAWS["jenkins"].check_params({"kt": 1e5, "fss": 1.0}, source="rig.toml", field="element[0].laws[1]")
    assert err.value.field == "element[0].laws[1].fss" and err.value.source == "rig.toml"
    assert "kt, fs" in err.value.message


def test_missing_parameter_is_named():
    with pytest.raises(InputError) as err:
        LAWS["iwan"].check_params({"kt": 1e5, "fs": 1.0}, complete=True, field="laws[0]")
    assert err.value.field == "laws[0]" and "chi, beta" in err.value.message
    with pytest.raises(InputError, match="needs parameter"):
        describing_function("tanh_softening", 1e-3, 1.0, alpha=1.0)


@pytest.mark.parametrize("name, field, value, open_bound", [
    ("coulomb", "fs", -1.0, False),
    ("jenkins", "kt", 0.0, True),           # strictly positive
    ("jenkins", "fs", -0.1, False),
    ("iwan", "chi", -1.0, True),            # -1 < chi
    ("iwan", "chi", 1.5, True),             # chi <= 1
    ("iwan", "beta", -0.1, False),
    ("tanh_softening", "beta", 0.0, True),  # strictly positive
    ("arctan_softening", "beta", -1.0, True),
    ("gap", "gap", -1e-4, False),
    ("cubic", "k3", math.nan, False),
    ("linear", "k", math.inf, False),
])
def test_out_of_bounds_value_names_the_field(name, field, value, open_bound):
    law = LAWS[name]
    values = dict(law.example, **{field: value})
    with pytest.raises(InputError) as err:
        law.check_params(values, complete=True, field="laws[2]")
    assert err.value.field == f"laws[2].{field}"
    assert err.value.message.endswith("]")
    assert ("range (" in err.value.message) == open_bound  # an open bound is shown as such


@pytest.mark.parametrize("name, values", [
    ("iwan", {"kt": 1e5, "fs": 10.0, "chi": 1.0, "beta": 0.0}),   # the closed end of chi
    ("unilateral", {"k": 1e5, "gap": -1e-4}),                    # preload
    ("cubic", {"k3": -500.0}),                                   # softening
    ("velocity_stiffness", {"gamma": -4.4}),                     # paper Table 3
    ("anderson_ferri", {"a": -3.14e6, "b": -1253.5, "c": 3.9}),  # paper Table 3, load case d
])
def test_physically_allowed_values_are_accepted(name, values):
    assert LAWS[name].check_params(values, complete=True) == values


def test_non_numeric_value_is_rejected():
    with pytest.raises(InputError, match="must be a number") as err:
        LAWS["gap"].check_params({"k": "stiff"}, field="laws[0]")
    assert err.value.field == "laws[0].k"


def test_unknown_law_is_named():
    with pytest.raises(InputError, match="unknown law 'iwann'"):
        get_law("iwann", "model.toml", "element[0].laws[0].law")


# --------------------------------------------------------------------------- stick limits
def test_friction_laws_provide_a_stick_limit():
    coulomb, af = LAWS["coulomb"], LAWS["anderson_ferri"]
    assert coulomb.stick_limit(0.3, coulomb.parameter_vector(fs=2.5)) == 2.5
    p = af.parameter_vector(a=1.0, b=500.0, c=2.0)
    assert af.stick_limit(-1e-3, p) == pytest.approx(math.pi / 4 + math.pi / 2 * 0.5)
    assert af.stick_limit(1e-3, af.parameter_vector(a=-1.0, b=0.0, c=0.0)) == 0.0
    # the sliding force is the stick limit in the direction of motion
    assert af.kernel(-1e-3, -0.2, p, af.initial_state(p)) == pytest.approx(-(af.stick_limit(-1e-3, p) + 0.4))
    assert all(LAWS[n].stick_limit is None for n in LAWS if n not in ("coulomb", "anderson_ferri"))


def test_state_sizes():
    for name, law in LAWS.items():
        state = law.initial_state(law.parameter_vector(**law.example))
        assert state.shape == (max(law.n_state, 1),) and not state.any()
        assert law.hysteretic == (name in ("jenkins", "iwan"))


# --------------------------------------------------------------------------- passivity
def _amplitudes_and_values(name):
    law = LAWS[name]
    lo, hi = law.example_amplitude

    def admissible(p, typical):  # inside the bounds, and non-negative where the sign is free
        lower = p.lower if math.isfinite(p.lower) else 0.0
        top = p.upper if math.isfinite(p.upper) else 10.0 * abs(typical) + 1.0
        return st.floats(min_value=lower, max_value=top, exclude_min=p.lower_open,
                         allow_nan=False, allow_infinity=False)

    values = st.fixed_dictionaries({p.name: admissible(p, law.example[p.name]) for p in law.params})
    X = st.floats(min_value=lo / 100, max_value=hi * 100)
    w = st.floats(min_value=0.0, max_value=1e4)
    return st.tuples(values, X, w)


@pytest.mark.parametrize("name", DISSIPATIVE)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_dissipative_laws_are_passive_for_non_negative_parameters(name, data):
    values, X, w = data.draw(_amplitudes_and_values(name))
    kbar = LAWS[name].describing_function(X, w, **values)
    assert np.isfinite(kbar) and kbar.imag >= 0.0


@pytest.mark.parametrize("name", CONSERVATIVE)
@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_conservative_laws_dissipate_nothing(name, data):
    values, X, w = data.draw(_amplitudes_and_values(name))
    kbar = LAWS[name].describing_function(X, w, **values)
    assert np.isfinite(kbar) and kbar.imag == 0.0


def test_bilinear_sees_only_the_mean_stiffness():
    law = LAWS["bilinear"]
    X = np.geomspace(1e-6, 1.0, 5)
    a = law.describing_function(X, 50.0, k_pos=3.0e4, k_neg=1.0e4)
    b = law.describing_function(X, 50.0, k_pos=1.0e4, k_neg=3.0e4)
    assert np.array_equal(a, b) and np.all(a == 2.0e4)


def test_gap_onset_is_smooth():
    """kbar ~ k (32 / (3 pi)) ((X - g) / (2 X))^(3/2) just past the clearance."""
    k, g = 1.0e5, 1.0e-4
    eps = np.array([1e-8, 1e-6, 1e-4])
    X = g * (1 + eps)
    kbar = LAWS["gap"].describing_function(X, 1.0, k=k, gap=g).real
    s = (X - g) / (2 * X)
    assert np.allclose(kbar, k * 32 / (3 * math.pi) * s**1.5, rtol=1e-3)
    assert LAWS["gap"].describing_function(g, 1.0, k=k, gap=g) == 0.0


def test_unilateral_limits():
    law = LAWS["unilateral"]
    assert law.describing_function(0.5e-4, 1.0, k=1e5, gap=1e-4) == 0.0          # never closes
    assert law.describing_function(0.5e-4, 1.0, k=1e5, gap=-1e-4) == 1e5         # never opens
    assert law.describing_function(1e-4, 1.0, k=1e5, gap=0.0) == pytest.approx(0.5e5, rel=1e-15)
