"""Model updating by eigenvalue sensitivity."""
import numpy as np
import pytest

from analysis import InputError, load_structure
from analysis.linear.updating import frequency_sensitivity, set_parameter, update_parameters
from analysis.mechanics.structures import structure_parameter

BEAM = {"type": "beam", "length": 0.6, "youngs_modulus": 211e9, "density": 7860.0, "width": 0.04,
        "thickness": 0.005, "elements": 20, "left": "clamped", "right": "free",
        "points": {"A": 0.15, "O": 0.6},
        "springs": [{"dof": "O.w", "k": 1e7}, {"dof": "O.theta", "k": 152.0}]}


def test_recovers_spring_and_modulus_from_three_frequencies():
    measured = load_structure(BEAM).natural_frequencies()[:3]
    start = set_parameter(set_parameter(BEAM, "springs[1].k", 80.0), "youngs_modulus", 190e9)
    result = update_parameters(start, ["springs[1].k", "youngs_modulus"], measured)
    np.testing.assert_allclose(result.after, [152.0, 211e9], rtol=1e-6)
    np.testing.assert_allclose(result.after_hz, measured, rtol=1e-9)
    assert np.abs(result.before_hz / measured - 1).max() > 0.01
    assert "springs[1].k: 80 -> 152" in result.table_text()
    assert structure_parameter(result.table, "springs[1].k") == pytest.approx(152.0, rel=1e-6)


def test_sensitivities_match_finite_differences_of_frequencies():
    params = ["springs[0].k", "springs[1].k", "youngs_modulus"]
    values = np.array([structure_parameter(BEAM, p) for p in params])

    def structure_of(v):
        t = BEAM
        for p, x in zip(params, v):
            t = set_parameter(t, p, x)
        return load_structure(t)

    f, sens = frequency_sensitivity(structure_of, values, [1, 2, 3])
    h = 1e-3   # central differences; smaller steps drown in the eigensolver's round-off
    for j in range(3):
        up, dn = values.copy(), values.copy()
        up[j] *= 1 + h
        dn[j] *= 1 - h
        fd = (np.log(structure_of(up).natural_frequencies()[:3] / structure_of(dn).natural_frequencies()[:3])
              / np.log((1 + h) / (1 - h)))
        np.testing.assert_allclose(sens[:, j], fd, rtol=1e-3, atol=1e-9)
    # the paper's observation: mode 1 is far more sensitive to the rotational spring than to the normal one
    assert sens[0, 1] / sens[0, 0] > 10


@pytest.mark.parametrize("params,match", [
    (["springs[5].k"], r"no structure parameter at 'springs\[5\]\.k'"),
    (["width", "thickness", "length", "density"], r"4 parameters cannot be found from 3 frequencies"),
    ([], "name at least one parameter"),
    (["left"], "must be a positive number"),
])
def test_bad_updating_requests(params, match):
    with pytest.raises(InputError, match=match):
        update_parameters(BEAM, params, [50.0, 160.0, 300.0], source="model.toml")


def test_an_update_that_moves_a_matched_mode_away_says_so():
    # one spring cannot match two modes: the demo's case, mode 1 matched before and moved away by the update
    f = load_structure(BEAM).natural_frequencies()[:2]
    measured = np.array([f[0], f[1] * 0.95])          # mode 1 matched, mode 2 five percent lower than the model
    result = update_parameters(BEAM, ["springs[1].k"], measured)
    before, after = (np.abs(hz / measured - 1) for hz in (result.before_hz, result.after_hz))
    assert after[0] > before[0] and after[1] < before[1]           # the least-squares trade
    notes = [line for line in result.table_text().splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and notes[0].startswith("note: the update moved mode 1 away from its measured frequency")
    assert "mode 2:" in notes[0]


def test_an_update_that_improves_every_mode_adds_no_note():
    measured = load_structure(BEAM).natural_frequencies()[:3]
    start = set_parameter(BEAM, "springs[1].k", 80.0)
    assert "note:" not in update_parameters(start, ["springs[1].k"], measured).table_text()
