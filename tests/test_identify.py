"""Closed-form complex-stiffness identification against synthesised truth.

The "measured" receptance is built independently of the method under test:
``Hbar = (Z + Delta)^-1`` by a direct solve, with ``Delta = sum_i kbar_i e_i e_i^T``.
"""
import numpy as np
import pytest
import scipy.linalg
from hypothesis import assume, given, settings, strategies as st

from analysis import InputError, load_elements, load_structure
from analysis.identification.identify import DEFAULT_COND_LIMIT, identify_complex_stiffness
from analysis.identification.sherman_morrison import receptance_with_elements, solve_per_line

PAPER_2DOF = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
              "stiffness": [[200.0, -100.0], [-100.0, 200.0]]}
FORCE = 0.8  # N, paper eq. 22


def element_vector(n, dofs):
    e = np.zeros(n)
    e[dofs[0]] = 1.0
    if len(dofs) == 2:
        e[dofs[1]] = -1.0
    return e


def synthesise(Z, elements, kbar):
    """Receptance of Z plus the elements, by a direct solve (independent of the methods)."""
    n = Z.shape[-1]
    E = np.stack([element_vector(n, el) for el in elements], axis=1)
    Delta = np.einsum("ai,li,bi->lab", E, kbar, E)
    return np.linalg.solve(Z + Delta, np.broadcast_to(np.eye(n, dtype=complex), Z.shape))


def random_spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.5 * np.eye(n))


@st.composite
def identification_cases(draw, overdetermined=False):
    n = draw(st.integers(2, 6))
    r = draw(st.integers(1, min(3, n - 1 if overdetermined else n)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    M = random_spd(rng, n, 1.0)
    K = random_spd(rng, n, 1.0e3)
    C = random_spd(rng, n, 0.5) if draw(st.booleans()) else np.zeros((n, n))
    # Distinct DOFs a_i; partners b_i outside {a} keep the element vectors independent.
    a_dofs = [int(x) for x in rng.permutation(n)[:r]]
    others = [d for d in range(n) if d not in a_dofs]
    elements = []
    for a in a_dofs:
        between = bool(others) and draw(st.booleans())
        elements.append((a, int(rng.choice(others))) if between else (a,))
    element_dofs = {d for el in elements for d in el}
    free_rows = [d for d in range(n) if d not in element_dofs]
    P = draw(st.integers(r + 1 if overdetermined else r, n))
    if len(free_rows) >= P and draw(st.booleans()):
        rows = [int(x) for x in rng.permutation(free_rows)[:P]]     # element DOFs not measured
    else:
        rows = [int(x) for x in rng.permutation(n)[:P]]
    q = draw(st.integers(0, n - 1))
    wn = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True))
    w = np.linspace(0.2 * wn.min(), 1.5 * wn.max(), 12)
    k_scale = np.diag(K).mean()
    kbar = k_scale * (rng.uniform(-0.5, 1.0, (w.size, r)) + 1j * rng.uniform(0.0, 0.5, (w.size, r)))
    Z = K[None] - w[:, None, None] ** 2 * M[None] + 1j * w[:, None, None] * C[None]
    return dict(Z=Z, w=w, elements=elements, rows=rows, q=q, kbar=kbar)


def column_scaled_cond(G):
    return np.linalg.cond(G / np.linalg.norm(G, axis=1, keepdims=True))


def check_recovery(case):
    Z, elements, rows, q, kbar = (case[k] for k in ("Z", "elements", "rows", "q", "kbar"))
    H = np.linalg.inv(Z)
    Hbar = synthesise(Z, elements, kbar)
    result = identify_complex_stiffness(H, Hbar[:, rows, q], rows, q, elements, force=FORCE)

    n = Z.shape[-1]
    E = np.stack([element_vector(n, el) for el in elements], axis=1)
    genuinely_bad = column_scaled_cond(H[:, rows, :] @ E) > DEFAULT_COND_LIMIT
    assert result.ill_conditioned[genuinely_bad].all()
    good = ~result.ill_conditioned
    assume(good.any())
    rel = np.abs(result.kbar - kbar) / np.abs(kbar)
    assert rel[good].max() < 1e-9
    true_element_response = Hbar[:, :, q] @ E
    np.testing.assert_allclose(result.element_receptance[good], true_element_response[good], rtol=1e-9)
    np.testing.assert_allclose(result.amplitude[good], FORCE * np.abs(true_element_response[good]), rtol=1e-9)
    scale = np.abs(Hbar[:, rows, q]).max(axis=1)
    assert (result.residual[good] < 1e-9 * scale[good]).all()
    return result


@settings(max_examples=60, deadline=None)
@given(identification_cases())
def test_recovers_random_elements(case):
    check_recovery(case)


@settings(max_examples=40, deadline=None)
@given(identification_cases(overdetermined=True))
def test_recovers_random_elements_overdetermined(case):
    result = check_recovery(case)
    assert result.residual_dof == 2 * (len(case["rows"]) - len(case["elements"]))


@settings(max_examples=30, deadline=None)
@given(identification_cases())
def test_sherman_morrison_updates_equal_direct_inverse(case):
    Z, elements, kbar = case["Z"], case["elements"], case["kbar"]
    n = Z.shape[-1]
    vectors = np.stack([element_vector(n, el) for el in elements])
    H = np.linalg.inv(Z)
    updated = receptance_with_elements(H, vectors, kbar)
    direct = synthesise(Z, elements, kbar)
    scale = np.abs(direct).max(axis=(1, 2), keepdims=True)
    cond = np.linalg.cond(Z + np.einsum("ia,li,ib->lab", vectors, kbar, vectors))
    well_posed = cond < 1e6
    assert (np.abs(updated - direct) / scale)[well_posed].max(initial=0.0) < 1e-9


# --- the paper's 2DOF example (section 3) --------------------------------------------

def paper_case(n_lines):
    """Paper 2DOF, force on x2, elements at x1 and x2 with kbar from eqs. 30-31.

    The element amplitudes are prescribed (0.8 N times the receptance of the reference
    with C = 0.02 K) rather than solved by harmonic balance: identification needs
    only some kbar per line, and these have the paper's size and form.
    """
    s = load_structure(PAPER_2DOF)
    w = 2 * np.pi * np.linspace(0.8, 3.2, n_lines)
    damped = s.with_matrices(C=0.02 * s.K).frf(w, columns=[1])[:, :, 0]
    X1, X2 = FORCE * np.abs(damped[:, 0]), FORCE * np.abs(damped[:, 1])
    kbar = np.stack([-0.75 * 500.0 * X1**2 + 1j * 8.0 / (3.0 * np.pi) * 1.0 * X1 * w**2,
                     -0.75 * 750.0 * X2**2 + 1j * 4.0 * 0.1 / (np.pi * X2)], axis=1)
    Hbar = synthesise(s.dynamic_stiffness(w), [(0,), (1,)], kbar)
    return s, w, kbar, Hbar[:, :, 1]


def test_paper_example_by_names_and_elements():
    s, w, kbar, measured = paper_case(201)
    elements = load_elements({"element": [{"name": "left", "dof": "x1"}, {"name": "right", "dof": "x2"}]}, s)
    result = identify_complex_stiffness(s, measured, ["x1", "x2"], "x2", elements, w=w, force=FORCE)
    assert result.element_names == ["left", "right"]
    np.testing.assert_allclose(result.kbar, kbar, rtol=1e-9)
    by_index = identify_complex_stiffness(s.frf(w), measured, [0, 1], 1, [0, 1])
    np.testing.assert_allclose(by_index.kbar, result.kbar, rtol=1e-12)
    with pytest.raises(InputError, match="2 elements need at least 2 measured FRF rows; got 1"):
        identify_complex_stiffness(s, measured[:, :1], ["x1"], "x2", elements, w=w)


def test_root_solve_agrees_with_closed_form_on_paper_example():
    s, w, kbar, measured = paper_case(201)
    H = s.frf(w)
    closed = identify_complex_stiffness(H, measured, [0, 1], 1, [0, 1])
    plain = solve_per_line(H, measured, [0, 1], 1, [(0,), (1,)])
    assert plain.converged.mean() > 0.5
    c = plain.converged
    assert (np.abs(plain.kbar[c] - closed.kbar[c]) / np.abs(closed.kbar[c])).max() < 1e-9
    warm = solve_per_line(H, measured, [0, 1], 1, [(0,), (1,)], guess=closed.kbar * (1 + 1e-3))
    assert warm.converged.all()
    np.testing.assert_allclose(warm.kbar, closed.kbar, rtol=1e-9)


def test_overdetermined_noisy_data_has_the_same_minimiser_as_the_root_solve():
    """With more rows than elements and noisy data both routes minimise the same output error."""
    rng = np.random.default_rng(3)
    n, w = 4, np.linspace(5.0, 40.0, 15)
    M, K, C = random_spd(rng, n, 1.0), random_spd(rng, n, 1.0e3), random_spd(rng, n, 0.5)
    Z = K[None] - w[:, None, None] ** 2 * M[None] + 1j * w[:, None, None] * C[None]
    elements, rows, q = [(0,), (1, 3)], [0, 1, 2, 3], 2
    kbar = 300.0 * (1.0 + rng.uniform(0.0, 1.0, (w.size, 2)) + 0.3j)
    measured = synthesise(Z, elements, kbar)[:, rows, q]
    measured = measured * (1 + 1e-3 * (rng.normal(size=measured.shape) + 1j * rng.normal(size=measured.shape)))
    H = np.linalg.inv(Z)
    closed = identify_complex_stiffness(H, measured, rows, q, elements)
    assert (closed.residual > 0).all()
    lm = solve_per_line(H, measured, rows, q, elements, guess=kbar)
    assert lm.converged.all()
    np.testing.assert_allclose(lm.kbar, closed.kbar, rtol=1e-7)


# --- conditioning flags ---------------------------------------------------------------

def linear_elements_case(w):
    s = load_structure(PAPER_2DOF)
    kbar = np.broadcast_to(np.array([50.0 + 0.05j, 30.0 + 0.02j]), (w.size, 2))
    Hbar = synthesise(s.dynamic_stiffness(w), [(0,), (1,)], kbar)
    return s, kbar, Hbar[:, :, 1]


def test_antiresonance_of_element_response_is_flagged_and_noisy():
    # hbar_22 of the structure with its elements vanishes near w^2 = (200 + 50) / 1.
    w = np.linspace(14.0, 17.5, 351)
    s, kbar, measured = linear_elements_case(w)
    result = identify_complex_stiffness(s, measured, [0, 1], 1, [0, 1], w=w,
                                        noise_std=1e-4 * np.abs(measured).max())
    dip = np.argmin(np.abs(w - np.sqrt(250.0)))
    assert result.antiresonance[dip, 1] and result.ill_conditioned[dip]
    assert not result.antiresonance[dip, 0]
    assert result.ill_conditioned.mean() < 0.1
    far = np.abs(w - np.sqrt(250.0)) > 1.0
    assert result.kbar_std[dip, 1] > 30 * np.median(result.kbar_std[far, 1])


def test_inseparable_elements_give_infinite_condition_number():
    # Three decoupled DOFs: an element on DOF 2 moves neither measured row 0 nor 1,
    # so H_{P,A} has a zero column and its kbar is not observable.
    rng = np.random.default_rng(0)
    w = np.linspace(1.0, 3.0, 5)
    Z = (np.diag([100.0, 300.0, 500.0])[None] + 0.1j) * np.eye(3)[None] - w[:, None, None] ** 2 * np.eye(3)[None]
    H = np.linalg.inv(Z)
    measured = rng.normal(size=(5, 2)) * 1e-3 + 0j
    result = identify_complex_stiffness(H, measured, [0, 1], 1, [1, 2])
    assert np.isinf(result.cond).all() and result.ill_conditioned.all()


# --- noise propagation ----------------------------------------------------------------

@pytest.mark.parametrize("rows", [[0, 1], [0, 1, 2]])
def test_propagated_std_matches_monte_carlo(rows):
    rng = np.random.default_rng(11)
    n, samples = 3, 4000
    M, K, C = random_spd(rng, n, 1.0), random_spd(rng, n, 1.0e3), random_spd(rng, n, 0.3)
    w = np.array([10.0, 25.0, 47.0])
    Z = K[None] - w[:, None, None] ** 2 * M[None] + 1j * w[:, None, None] * C[None]
    elements, q = [(0,), (1, 2)], 1
    kbar = np.array([[400.0 + 80j, 250.0 + 30j]] * w.size)
    H = np.linalg.inv(Z)
    clean = synthesise(Z, elements, kbar)[:, rows, q]
    std = 2e-4 * np.abs(clean) * np.array([1.0, 2.0, 0.5])[: len(rows)]
    predicted = identify_complex_stiffness(H, clean, rows, q, elements, noise_std=std)

    # Every Monte Carlo draw is one more "line" with the same reference.
    noise = std * (rng.normal(size=(samples, *clean.shape)) + 1j * rng.normal(size=(samples, *clean.shape)))
    noisy = (clean + noise / np.sqrt(2)).reshape(-1, len(rows))
    stacked = np.broadcast_to(H, (samples, *H.shape)).reshape(-1, n, n)
    std_rows = np.broadcast_to(std, (samples, *std.shape)).reshape(-1, len(rows))
    mc = identify_complex_stiffness(stacked, noisy, rows, q, elements, noise_std=std_rows,
                                    antiresonance_window=1)
    deviation = mc.kbar.reshape(samples, w.size, 2) - kbar
    empirical = np.sqrt(np.mean(np.abs(deviation) ** 2, axis=0))
    np.testing.assert_allclose(empirical, predicted.kbar_std, rtol=0.1)
    covariance = np.einsum("sli,slj->lij", deviation, deviation.conj()) / samples
    np.testing.assert_allclose(covariance, predicted.kbar_cov, atol=0.1 * predicted.kbar_std.max() ** 2)
    dof = 2 * (len(rows) - 2)
    assert mc.residual_dof == dof
    assert abs(mc.residual_chi2.mean() - dof) <= 0.1 * max(dof, 1)


# --- bad input --------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, message", [
    (dict(rows=[0], measured=np.ones((5, 1))), "2 elements need at least 2 measured FRF rows; got 1"),
    (dict(measured=np.zeros((7, 2))), r"measured receptance must have shape \(lines, rows\) = \(5, 2\)"),
    (dict(rows=[0, 2]), r"DOF index 2 is outside 0..1"),
    (dict(rows=[1, 1]), "listed twice"),
    (dict(column=5), r"DOF index 5 is outside 0..1"),
    (dict(elements=[0, (0, 0)]), "between a DOF and itself"),
    (dict(elements=[0, ()]), "one DOF \\(grounded\\) or two \\(between\\), got 0"),
    (dict(elements=[(0, 1), (1, 0)]), "same DOFs as elements\\[0\\]"),
    (dict(elements=[]), "at least one element"),
    (dict(elements=[0, 1.5]), "an element is an Element, a DOF or a tuple"),
    (dict(rows=["x1", "x2"]), "needs the DOF names"),
    (dict(noise_std=-1.0), "noise std must be finite and > 0"),
    (dict(noise_std=np.ones(3)), "noise std must be a scalar or have shape"),
    (dict(force=np.ones(4)), r"force must be a scalar or have shape \(5,\)"),
    (dict(reference=np.zeros((5, 2, 3))), r"shape \(lines, n, n\)"),
])
def test_bad_input_is_one_line_error(kwargs, message):
    w = np.linspace(5.0, 20.0, 5)
    s, _, measured = linear_elements_case(w)
    args = dict(reference=s.frf(w), measured=measured, rows=[0, 1], column=1, elements=[0, 1])
    args.update(kwargs)
    with pytest.raises(InputError, match=message) as info:
        identify_complex_stiffness(args.pop("reference"), args.pop("measured"), args.pop("rows"),
                                   args.pop("column"), args.pop("elements"), **args)
    assert "\n" not in str(info.value)


def test_dependent_elements_and_structure_inputs_are_rejected():
    s = load_structure({"type": "lumped", "dofs": ["a", "b", "c"], "mass": np.eye(3).tolist(),
                        "stiffness": (np.eye(3) * 400 - 100).tolist()})
    w = np.linspace(1.0, 2.0, 3)
    measured = np.ones((3, 3), complex)
    with pytest.raises(InputError, match="linearly dependent"):
        identify_complex_stiffness(s, measured, ["a", "b", "c"], "a", ["a", "b", ("a", "b")], w=w)
    with pytest.raises(InputError, match="needs the angular frequencies"):
        identify_complex_stiffness(s, measured, ["a", "b", "c"], "a", ["a"])
    with pytest.raises(InputError, match="DOF 'z' is not in the structure"):
        identify_complex_stiffness(s, measured, ["a", "b", "z"], "a", ["a"], w=w)
    with pytest.raises(InputError, match="not finite at 1 lines"):
        identify_complex_stiffness(s, np.where(np.arange(3)[:, None] == 1, np.nan, measured),
                                   ["a", "b", "c"], "a", ["a"], w=w)


def test_the_frfs_move_with_each_elements_kbar_as_the_exact_receptance_does():
    """``frf_per_kbar`` against central differences of the receptance of the structure with its elements,
    inverted in full here: a grounded element and one between two DOFs of a damped 3-DOF chain, three sensors."""
    M = np.diag([1.0, 2.0, 1.5])
    K = np.array([[3000.0, -1000.0, 0.0], [-1000.0, 2500.0, -1500.0], [0.0, -1500.0, 1500.0]])
    C = 0.002 * K
    w = np.linspace(10.0, 80.0, 40)
    E = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    kbar = np.array([400 + 80j, 250 + 30j])

    def receptance(k):
        Z = K[None] - w[:, None, None] ** 2 * M[None] + 1j * w[:, None, None] * C[None] + (E * k) @ E.T
        return np.linalg.inv(Z)

    H = receptance(np.zeros(2))
    rows, q = [0, 1, 2], 1
    ident = identify_complex_stiffness(H, receptance(kbar)[:, rows, q], rows, q, [(0,), (1, 2)])
    for j in range(2):
        step = np.zeros(2, complex)
        step[j] = 1e-3
        expected = (receptance(kbar + step)[:, rows, q] - receptance(kbar - step)[:, rows, q]) / 2e-3
        np.testing.assert_allclose(ident.frf_per_kbar[:, :, j], expected, rtol=0, atol=1e-6 * np.abs(expected).max())
