"""Reference structures against analytic results."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from analysis import InputError, load_structure
from analysis.common.tables import load_toml

E, RHO, B, H, L = 211e9, 7860.0, 0.04, 0.005, 0.6
EI, RHO_A = E * B * H**3 / 12, RHO * B * H


def beam(**extra):
    table = {"type": "beam", "length": L, "youngs_modulus": E, "density": RHO, "width": B, "thickness": H,
             "elements": 20, "left": "clamped", "right": "free"}
    table.update(extra)
    return load_structure(table, "beam.toml")


def euler_bernoulli_hz(beta_l):
    return np.asarray(beta_l) ** 2 * np.sqrt(EI / (RHO_A * L**4)) / (2 * np.pi)


PAPER_2DOF = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
              "stiffness": [[200.0, -100.0], [-100.0, 200.0]]}


def test_sdof_receptance_is_analytic():
    s = load_structure({"type": "lumped", "dofs": ["x"], "mass": [[2.0]], "stiffness": [[800.0]],
                        "damping": [[3.0]]})
    w = np.linspace(0.1, 60, 500)
    expected = 1.0 / (800.0 - 2.0 * w**2 + 3j * w)
    np.testing.assert_allclose(s.frf(w)[:, 0, 0], expected, rtol=1e-13)


def test_two_dof_receptance_is_analytic_and_reciprocal():
    s = load_structure(PAPER_2DOF)
    w = np.linspace(0.1, 25, 301)
    det = (200 - w**2) * (200 - 2 * w**2) - 100.0**2
    H = s.frf(w)
    np.testing.assert_allclose(H[:, 0, 0], (200 - 2 * w**2) / det, rtol=1e-11)
    np.testing.assert_allclose(H[:, 0, 1], 100.0 / det, rtol=1e-11)
    np.testing.assert_allclose(H[:, 1, 1], (200 - w**2) / det, rtol=1e-11)
    np.testing.assert_allclose(s.frf(w, columns=["x2"])[:, :, 0], H[:, :, 1], rtol=1e-14)
    # eigenvalues of K - w^2 M: w^2 = 150 -+ 50 sqrt(5)... i.e. (300 -+ sqrt(300^2 - 4*2*30000)) / 4
    lam = (600 + np.array([-1, 1]) * np.sqrt(600**2 - 4 * 2 * 30000)) / 4
    np.testing.assert_allclose(s.natural_frequencies(), np.sqrt(lam) / (2 * np.pi), rtol=1e-12)


@pytest.mark.parametrize("left,right,beta_l", [
    ("clamped", "free", [1.875104, 4.694091, 7.854757]),
    ("clamped", "pinned", [3.926602, 7.068583, 10.210176]),
    ("pinned", "pinned", [np.pi, 2 * np.pi, 3 * np.pi]),
    ("clamped", "clamped", [4.730041, 7.853205, 10.995608]),
])
def test_beam_natural_frequencies_match_euler_bernoulli(left, right, beta_l):
    f = beam(left=left, right=right).natural_frequencies()[:3]
    # consistent-mass cubic elements converge from above as h^4: 20 elements -> < 1e-4 on mode 3
    np.testing.assert_allclose(f, euler_bernoulli_hz(beta_l), rtol=1e-4)
    assert np.all(f >= euler_bernoulli_hz(beta_l) * (1 - 1e-6))


def test_cantilever_static_tip_flexibility_is_exact():
    s = beam(points={"O": L})
    h0 = s.frf([0.0], columns=["O.w"])[0, s.index("O.w"), 0]
    assert h0.real == pytest.approx(L**3 / (3 * EI), rel=1e-10)
    t0 = s.frf([0.0], columns=["O.w"])[0, s.index("O.theta"), 0]
    assert t0.real == pytest.approx(L**2 / (2 * EI), rel=1e-10)


def test_stiff_tip_spring_tends_to_clamped_pinned():
    f = beam(points={"O": L}, springs=[{"dof": "O.w", "k": 1e12}]).natural_frequencies()[:2]
    np.testing.assert_allclose(f, euler_bernoulli_hz([3.926602, 7.068583]), rtol=2e-4)


def test_stations_are_nodes_and_named():
    s = beam(points={"A": 0.15, "B": 0.31, "O": 0.6})
    for name in ("A.w", "A.theta", "B.w", "B.theta", "O.w", "O.theta"):
        assert name in s.dofs
    assert s.is_rotational("A.theta") and not s.is_rotational("A.w")
    assert len(s.dofs) == 2 * 20  # 21 nodes, clamped root removed; B off the uniform grid adds no element
    h = s.frf([0.0], columns=["B.w"])[0, s.index("B.w"), 0].real
    a = 0.31  # static flexibility of a cantilever at a: a^3 / (3 EI)
    assert h == pytest.approx(a**3 / (3 * EI), rel=1e-10)


def test_stiffness_proportional_damping_and_modal_superposition():
    s = beam(points={"A": 0.15, "O": 0.6}, springs=[{"dof": "O.w", "k": 1e7}, {"dof": "O.theta", "k": 152.0}],
             damping={"stiffness_proportional": 1e-5})
    np.testing.assert_allclose(s.C, 1e-5 * s.K)
    w = 2 * np.pi * np.linspace(5, 400, 400)
    full = s.frf(w, columns=["A.w"])
    # all modes: equal up to the round-off of the eigensolution (w and theta DOFs differ in scale by ~1e3)
    np.testing.assert_allclose(s.frf(w, columns=["A.w"], method="modal"), full, rtol=0, atol=1e-7 * abs(full).max())
    errors = [s.modal_truncation_error(w, m, columns=["A.w"]) for m in (3, 8, 20)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-3


def test_modal_needs_classical_damping():
    s = load_structure({**PAPER_2DOF, "damping": [[1.0, 0.0], [0.0, 0.0]]})
    with pytest.raises(ValueError, match="classical damping"):
        s.frf([1.0], method="modal")


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 6), seed=st.integers(0, 2**31 - 1))
def test_random_lumped_frf_solves_dynamic_stiffness(n, seed):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    Mv = rng.uniform(0.5, 2.0, n)
    s = load_structure({"type": "lumped", "dofs": [f"d{i}" for i in range(n)], "mass": np.diag(Mv).tolist(),
                        "stiffness": K.tolist(), "rayleigh": [0.01, 0.001]})
    w = rng.uniform(0.1, 5.0, 7)
    H = s.frf(w)
    Z = s.dynamic_stiffness(w)
    np.testing.assert_allclose(Z @ H, np.broadcast_to(np.eye(n), H.shape), atol=1e-9)
    np.testing.assert_allclose(H, np.swapaxes(H, 1, 2), rtol=1e-9, atol=1e-14)  # reciprocity


@pytest.mark.parametrize("table,match", [
    ({"type": "spring"}, r"\[structure\]\.type: must be one of lumped, beam"),
    ({**PAPER_2DOF, "mass": [[1.0, 0.0]]}, r"\[structure\]\.mass: must be a 2x2 matrix"),
    ({**PAPER_2DOF, "stiffness": [[200.0, -100.0], [-90.0, 200.0]]}, r"stiffness: matrix must be symmetric"),
    ({**PAPER_2DOF, "stiffness": [[100.0, -100.0], [-100.0, 100.0]]}, r"stiffness: .*rigid body"),
    ({**PAPER_2DOF, "mass": [[1.0, 0.0], [0.0, -2.0]]}, r"mass: mass matrix is not positive definite"),
    ({**PAPER_2DOF, "stifness": 1}, r"\[structure\]\.stifness: unknown key"),
    ({**PAPER_2DOF, "dofs": ["x1", "x1"]}, r"dofs: DOF names must be unique"),
    ({**PAPER_2DOF, "springs": [{"dof": "x3", "k": 1.0}]}, r"springs\[0\]\.dof: DOF 'x3' is not in the structure"),
    ({**PAPER_2DOF, "mass": [[1.0, 0.0], [0.0, "heavy"]]}, r"mass: every entry must be a finite number"),
])
def test_bad_lumped_tables_name_file_and_field(table, match):
    with pytest.raises(InputError, match=match) as err:
        load_structure(table, "model.toml")
    assert str(err.value).startswith("model.toml: ")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("extra,match", [
    ({"points": {"A": 0.9}}, r"points\.A: station at 0.9 m lies outside"),
    ({"left": "welded"}, r"left: must be one of clamped, pinned, free"),
    ({"elements": 0}, r"elements: must be a whole number >= 1"),
    ({"length": -1.0}, r"length: must be > 0"),
    ({"points": {"R": 0.0}, "springs": [{"dof": "R.w", "k": 1.0}]}, r"springs\[0\]\.dof: DOF 'R.w' is fixed"),
    ({"left": "free", "right": "free"}, r"rigid body"),
])
def test_bad_beam_tables(extra, match):
    with pytest.raises(InputError, match=match):
        beam(**extra)


def test_malformed_toml_names_the_file(tmp_path):
    p = tmp_path / "rig.toml"
    p.write_text("[structure\ntype = 'lumped'\n")
    with pytest.raises(InputError, match=r"rig.toml: not valid TOML: .*line 1"):
        load_toml(p)
    with pytest.raises(InputError, match="file not found"):
        load_toml(tmp_path / "missing.toml")


# --- definiteness: a property of the structure, not of its units or mesh ------------------------------------
@pytest.mark.slow
def test_fine_clamped_beam_is_accepted_and_still_a_cantilever():
    # its stiffness eigenvalues span 4e-14 of each other: a fixed ratio of 1e-12 of them called it singular;
    # it is not (its diagonally scaled reciprocal condition number is 2.5e-13, a rigid-body mode's 1e-17)
    s = beam(elements=800, points={"O": L})
    # still a cantilever: the static tip flexibility L^3 / 3EI is exact for Hermite elements at any mesh
    h0 = s.frf([0.0], columns=["O.w"])[0, s.index("O.w"), 0]
    assert h0.real == pytest.approx(L**3 / (3 * EI), rel=1e-4)     # round-off grows with the mesh: 3e-5 here


@pytest.mark.parametrize("left, right", [("free", "free"), ("pinned", "free")])
def test_fine_beam_that_can_move_as_a_rigid_body_is_still_refused(left, right):
    with pytest.raises(InputError, match=r"stiffness: stiffness matrix is not positive definite.*rigid body"):
        beam(elements=800, left=left, right=right)


def test_beam_beyond_the_element_limit_is_refused_naming_the_field_before_allocating():
    from analysis.mechanics.structures import MAX_BEAM_ELEMENTS
    for n in (2000, 100_000):
        with pytest.raises(InputError) as err:
            beam(elements=n)
        assert err.value.source == "beam.toml" and err.value.field == "[structure].elements"
        assert f"{n} elements is more than the {MAX_BEAM_ELEMENTS} a beam may have" in err.value.message
    beam(elements=3, left="clamped", right="clamped")
    with pytest.raises(InputError, match=r"elements: the clamped-clamped boundaries leave no DOF free"):
        beam(elements=1, left="clamped", right="clamped")


def test_definiteness_does_not_depend_on_units():
    # the same 2-DOF system with x2 in micrometres: mass and stiffness entries 1e-12 apart
    u = np.diag([1.0, 1e-6])
    s = load_structure({**PAPER_2DOF, "mass": (u @ np.array(PAPER_2DOF["mass"]) @ u).tolist(),
                        "stiffness": (u @ np.array(PAPER_2DOF["stiffness"]) @ u).tolist()}, "um.toml")
    np.testing.assert_allclose(s.natural_frequencies(), load_structure(PAPER_2DOF).natural_frequencies(),
                               rtol=1e-9)


def test_damping_may_leave_a_dof_undamped_but_not_add_energy():
    load_structure({**PAPER_2DOF, "damping": [[0.5, 0.0], [0.0, 0.0]]})
    with pytest.raises(InputError, match=r"damping: damping matrix must not be negative .*add energy"):
        load_structure({**PAPER_2DOF, "damping": [[1.0, 2.0], [2.0, 1.0]]}, "model.toml")
    with pytest.raises(InputError, match=r"DOF 'x2'"):
        load_structure({**PAPER_2DOF, "damping": [[1.0, 0.0], [0.0, -0.1]]}, "model.toml")


def test_a_dof_typo_names_the_closest_dofs_first():
    # the demo's beam has 14 DOFs: the plain list of twelve stopped before O.theta, the one a user mistypes
    from pathlib import Path

    from analysis.mechanics.model import load_model
    structure = load_model(load_toml(Path(__file__).parents[1] / "app/models/paper-beam.model.toml")).structure
    assert structure.n > 12 and structure.dofs.index("O.theta") >= 12
    with pytest.raises(InputError) as err:
        structure.index("O.tehta", field="element[1].dof")
    assert "did you mean 'O.theta'? its DOFs, closest first: O.theta," in str(err.value)
    listed = str(err.value).split("closest first: ")[1].removesuffix(", ...)").split(", ")
    assert len(listed) == 12 and len(set(listed)) == 12
