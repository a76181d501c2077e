"""Physical admissibility of fitted laws (analysis/mechanics/admissibility.py).

Truth: the energy a motion x(t) = Re(x e^{jwt}) dissipates over one cycle, integrated in time by quadrature
(the structure's damping force and each element's force Re(kbar y e^{jwt}), y = v^T x, against the velocity) --
not the eigenvalue formula the module uses."""
import numpy as np
import pytest

from analysis.mechanics.admissibility import admissibility
from analysis.mechanics.structures import Structure


def two_dof(c: float = 2.0) -> Structure:
    M = np.diag([1.0, 1.5])
    K = np.array([[3000.0, -1000.0], [-1000.0, 1000.0]])
    C = c / 1000.0 * K
    return Structure(["a", "b"], M, K, C)


def dissipated_per_cycle(structure: Structure, vectors, kbar: np.ndarray, x: np.ndarray, w: float) -> float:
    """The energy dissipated over one period by the motion x (complex amplitudes), by the trapezoidal rule on
    4096 points of the force times the velocity."""
    t = np.linspace(0.0, 2 * np.pi / w, 4097)
    phase = np.exp(1j * w * t)
    velocity = np.real(1j * w * x[:, None] * phase)
    force = structure.C @ velocity
    for v, k in zip(vectors, kbar):
        y = v @ x
        force = force + v[:, None] * np.real(k * y * phase)[None]
    return float(np.trapezoid(np.sum(force * velocity, axis=0), t))


def test_an_element_that_gives_energy_back_beyond_the_structure_s_damping_is_not_passive():
    s = two_dof()
    v = np.array([1.0, -1.0])
    w = 2 * np.pi * 5.0
    # the structure's damping (0.002 K) gives w C about 63 N/m across the coupling spring: an element taking back
    # less than that leaves the whole passive, one taking back 200 N/m does not
    for im, passive in ((-0.5, True), (-60.0, True), (-200.0, False)):
        check = admissibility(s, [v], [lambda X, w_, im=im: np.full(np.shape(X), 100.0 + 1j * im)],
                              np.array([[1e-3]]), np.array([w]))
        assert check.passive is passive, im
        # the quadrature's verdict over the motions that matter most: the eigenvectors of the dissipation matrix
        D = w * s.C + im * np.outer(v, v)
        _, vecs = np.linalg.eigh(D)
        energy = dissipated_per_cycle(s, [v], [100.0 + 1j * im], vecs[:, 0].astype(complex), w)
        assert (energy >= -1e-9) is passive
        assert energy == pytest.approx(np.pi * vecs[:, 0] @ D @ vecs[:, 0], rel=1e-6, abs=1e-12)


def test_a_negative_element_damping_that_the_reference_covers_is_passive_and_one_alone_is_not():
    # a reference that holds the joint's damping at low amplitude: the element's kbar is negative there
    s = Structure(["x"], np.eye(1), np.array([[4000.0]]), np.array([[1.5]]))
    w = np.array([2 * np.pi * 10.0])
    covered = admissibility(s, [np.ones(1)], [lambda X, w_: -1j * 0.5 * 1.5 * w_], np.array([[1e-4]]), w)
    assert covered.passive
    bare = Structure(["x"], np.eye(1), np.array([[4000.0]]), np.zeros((1, 1)))
    alone = admissibility(bare, [np.ones(1)], [lambda X, w_: -1j * 0.5 * 1.5 * w_], np.array([[1e-4]]), w)
    assert not alone.passive and alone.active.tolist() == [True]


def test_a_softening_law_that_turns_the_static_stiffness_negative_is_flagged_where_it_does():
    s = Structure(["x"], np.eye(1), np.array([[4000.0]]), np.array([[1.5]]))
    X = np.array([[1e-3], [5e-3], [1e-2]])
    w = np.full(3, 2 * np.pi * 10.0)
    cubic = admissibility(s, [np.ones(1)], [lambda X_, w_: 0.75 * -1e8 * X_ ** 2 + 0j], X, w)
    # 4000 - 75e6 X^2 < 0 beyond X = 7.3 mm
    assert cubic.buckled.tolist() == [False, False, True] and cubic.passive and not cubic.admissible


def test_states_where_every_element_adds_damping_and_stiffness_are_admissible_without_solving():
    s = two_dof()
    vectors = [np.array([1.0, 0.0]), np.array([1.0, -1.0])]
    laws = [lambda X, w: 200.0 + 1j * 3.0 * X, lambda X, w: 50.0 + 0.1j * w]
    check = admissibility(s, vectors, laws, np.full((5, 2), 1e-3), np.linspace(10.0, 60.0, 5))
    assert check.admissible
    assert check.dissipation.tolist() == [0.0] * 5 and check.stiffness.tolist() == [0.0] * 5


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_one_element_s_margin_agrees_with_the_eigenvalues_of_the_whole(seed):
    """The rank-one margin (one element) gives the verdict of the full eigenproblem (the same element twice at
    half its kbar), on random structures and states."""
    rng = np.random.default_rng(seed)
    n = 6
    A = rng.standard_normal((n, n))
    K = A @ A.T + n * np.eye(n)
    C = 0.01 * K + 0.02 * np.diag(rng.uniform(0, 1, n))
    s = Structure([f"d{i}" for i in range(n)], np.eye(n), K, C)
    v = rng.standard_normal(n)
    X = np.full((200, 1), 1e-3)
    w = rng.uniform(5.0, 200.0, 200)
    re, im = rng.uniform(-40.0, 5.0, 200), rng.uniform(-4.0, 1.0, 200)
    law = lambda X_, w_: re + 1j * im * w_ / 50.0                    # noqa: E731
    half = lambda X_, w_: 0.5 * law(X_, w_)                          # noqa: E731
    one = admissibility(s, [v], [law], X, w)
    two = admissibility(s, [v, v], [half, half], np.hstack([X, X]), w)
    assert one.active.tolist() == two.active.tolist() and one.buckled.tolist() == two.buckled.tolist()
    assert 0 < one.active.sum() < 200


def test_discovery_offers_no_set_that_gives_energy_back_nor_one_that_leaves_most_lines_out():
    from analysis.mechanics.surroundings import surroundings_of
    from analysis.missing.diagnosis import ElementSamples
    from analysis.search.discovery import search_element

    rng = np.random.default_rng(3)
    X = np.geomspace(1e-5, 1e-3, 40)
    w = 2 * np.pi * np.linspace(9.0, 11.0, 40)
    # a spring whose damping is negative: a reference that over-damps by more than the structure has
    truth = 500.0 - 1j * 0.8 * w
    std = np.full(40, 1.0)
    kbar = truth + (rng.standard_normal(40) + 1j * rng.standard_normal(40)) * std / np.sqrt(2)
    samples = ElementSamples("e", X, w, kbar, std, np.ones(40))
    lightly_damped = Structure(["x"], np.eye(1), np.array([[3947.8]]), np.array([[0.1]]))
    search = search_element(0, samples, True, around=surroundings_of(lightly_damped, np.ones(1)))
    assert "linear" in {s.name for s in search.refused}
    assert "linear" not in {s.name for s in search.sets}
    # a reference damped enough to hold it: the same set is a joint's
    damped = Structure(["x"], np.eye(1), np.array([[3947.8]]), np.array([[2.0]]))
    search = search_element(0, samples, True, around=surroundings_of(damped, np.ones(1)))
    assert search.best.name == "linear" and not search.refused


def test_a_fit_that_leaves_out_more_than_a_tenth_of_the_lines_is_no_description_of_the_data():
    from analysis.common.statistics import OUTLIER_SHARE_LIMIT
    from analysis.fitting.fit import fit_laws

    rng = np.random.default_rng(5)
    X = np.geomspace(1e-5, 1e-3, 60)
    w = np.full(60, 2 * np.pi * 10.0)
    std = np.full(60, 1.0)
    noise = (rng.standard_normal(60) + 1j * rng.standard_normal(60)) * std / np.sqrt(2)
    for departing, describes in ((3, True), (20, False)):
        kbar = 500.0 + 20j + noise
        kbar[-departing:] += 300.0            # lines far beyond the noise, which the linear law cannot follow
        fit = fit_laws(["linear"], X, w, kbar, std, exclude_outliers=True)
        assert fit.outlier_share == pytest.approx(departing / 60)
        assert fit.describes_the_data is describes and (departing / 60 <= OUTLIER_SHARE_LIMIT) is describes
