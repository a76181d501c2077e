"""The model workbench on data synthesised by harmonic balance from a known truth (the hidden-effect tests
against the time-domain rig are in tests/test_hidden_effects.py)."""
import tomllib

import numpy as np
import pytest

from analysis import InputError
from analysis.prediction.harmonic_balance import predict_sweep
from analysis.common.measurements import Measurements, RandomRun, SineRun
from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench

STRUCTURE = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
             "stiffness": [[200.0, -100.0], [-100.0, 200.0]], "rayleigh": [0.0, 0.002]}
PAPER_LAWS = {"left": [{"law": "cubic", "k3": -500.0}, {"law": "quadratic_damping", "c2": 1.0}],
              "right": [{"law": "cubic", "k3": -750.0}, {"law": "coulomb", "fs": 0.1}]}


def model_doc(laws, structure=STRUCTURE):
    return {"structure": structure, "element": [{"name": "left", "dof": "x1", "laws": laws["left"]},
                                                {"name": "right", "dof": "x2", "laws": laws["right"]}]}


def workbench(model, measurements):
    """Data synthesised by the single-harmonic balance hold no harmonics to model: compared single-harmonically."""
    return Workbench(model, measurements, harmonics=None)


def synthesise(truth_laws, forces=(0.4, 0.8), seed=0, lines=49, structure=STRUCTURE):
    truth = load_model(model_doc(truth_laws, structure))
    f = np.linspace(0.8, 3.2, lines)
    rng = np.random.default_rng(seed)
    runs = []
    for F in forces:
        H = predict_sweep(truth.structure, truth.elements, "x2", 2 * np.pi * f, F, "up").receptance[:, 0, :]
        std = 1e-4 * np.abs(H)
        noisy = H + std / np.sqrt(2) * (rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape))
        runs.append(SineRun(f"sine_{F}N_up", F, "up", "x2", ["x1", "x2"], f, noisy, std))
    return Measurements(runs)


@pytest.mark.acceptance
def test_missing_effect_loop_recovers_the_paper_laws_and_the_error_falls():
    # the two dissipative effects missing, one at each element
    wb = workbench(load_model(model_doc({"left": [{"law": "cubic"}], "right": [{"law": "cubic"}]})),
                   synthesise(PAPER_LAWS))
    wb.start()
    assert all(not r.verdict.linear for r in wb.reports.values())
    for _ in range(6):
        ranked = wb.candidates()
        if not ranked[0].significant:
            break
        wb.add(ranked[0].element, ranked[0].law)
    errors = [h.error for h in wb.history]
    assert all(b < a for a, b in zip(errors, errors[1:]))          # the error falls at every step
    assert errors[-1] < 1e-3 * errors[0]
    laws = {el.name: {t.law.name: t.values for t in el.laws} for el in wb.model.elements}
    assert set(laws["left"]) == {"cubic", "quadratic_damping"} and set(laws["right"]) == {"cubic", "coulomb"}
    assert laws["left"]["cubic"]["k3"] == pytest.approx(-500, rel=1e-2)
    assert laws["right"]["coulomb"]["fs"] == pytest.approx(0.1, rel=1e-2)
    assert laws["left"]["quadratic_damping"]["c2"] == pytest.approx(1.0, rel=1e-2)
    assert laws["right"]["cubic"]["k3"] == pytest.approx(-750, rel=1e-2)


@pytest.mark.acceptance
def test_first_candidate_explains_dry_friction_with_the_measured_slope():
    wb = workbench(load_model(model_doc({"left": PAPER_LAWS["left"], "right": [{"law": "cubic"}]})),
                   synthesise(PAPER_LAWS))
    wb.start()
    top = wb.candidates()[0]
    assert (top.element, top.law) == ("right", "coulomb") and top.significant
    assert "Im kbar falls" in top.explanation and "log-slope -1.0" in top.explanation
    assert "dry friction" in top.explanation and top.gain > 5
    # a law kbar cannot reveal is never proposed, even when asked for
    assert {c.law for c in wb.candidates(["bilinear", "coulomb"])} == {"coulomb"}


@pytest.mark.slow
def test_nothing_missing_means_no_significant_candidate():
    wb = workbench(load_model(model_doc(PAPER_LAWS)), synthesise(PAPER_LAWS, seed=1))
    wb.start()
    assert wb.history[0].error < 1e-3
    ranked = wb.candidates()
    assert ranked and not any(c.significant for c in ranked)


@pytest.mark.slow
def test_wrong_reference_stiffness_is_named_a_linear_correction():
    truth = {"left": [{"law": "linear", "k": -40.0, "c": 0.0}, {"law": "cubic", "k3": -500.0}], "right": []}
    wb = workbench(load_model(model_doc({"left": [{"law": "cubic"}], "right": []})), synthesise(truth))
    wb.start()
    top = wb.candidates()[0]
    assert (top.element, top.law) == ("left", "linear") and top.gain > 5
    assert "constant offset" in top.explanation
    step = wb.add("left", "linear")
    assert step.error < wb.history[0].error / 5
    assert wb.model.element("left").laws[1].values["k"] == pytest.approx(-40.0, rel=1e-2)


def test_reference_is_updated_from_the_random_run():
    true_structure = dict(STRUCTURE, stiffness=[[230.0, -100.0], [-100.0, 200.0]])
    meas = synthesise({"left": [], "right": []}, structure=true_structure)
    truth = load_model(model_doc({"left": [], "right": []}, true_structure))
    f = np.linspace(0.5, 4.0, 800)
    H = truth.structure.frf(2 * np.pi * f, columns=["x2"])[:, :, 0]
    meas.random = RandomRun("x2", ["x1", "x2"], f, H)
    doc = model_doc({"left": [], "right": []})
    doc["structure"] = dict(STRUCTURE, springs=[{"dof": "x1", "k": 1.0}])
    doc["updating"] = {"parameters": ["springs[0].k"], "modes": [1, 2]}
    wb = Workbench(load_model(doc), meas)
    report = wb.update_reference()
    assert report.update.after[0] == pytest.approx(30.0, rel=2e-3)     # K[0,0] = 200 + spring = 230
    np.testing.assert_allclose(report.modal.frequency, truth.structure.natural_frequencies(), rtol=1e-4)
    assert "springs[0].k" in report.text()


def test_model_file_round_trip():
    wb = workbench(load_model(model_doc(PAPER_LAWS)), synthesise(PAPER_LAWS))
    wb.start()
    again = load_model(tomllib.loads(wb.model.to_toml()))
    assert again.describe() == wb.model.describe()
    np.testing.assert_array_equal(again.structure.K, wb.model.structure.K)


def test_undo_twice_leaves_the_state_it_returns_to_as_recorded():
    wb = workbench(load_model(model_doc({"left": [{"law": "cubic"}], "right": [{"law": "cubic"}]})),
                   synthesise(PAPER_LAWS, lines=25))
    wb.start()
    for _ in range(2):
        wb.add("right", "coulomb")
        wb.undo()
        # the law added after a return to the first step did not enter that step's state
        assert [t.law.name for t in wb.model.element("right").laws] == ["cubic"]
        assert wb.compare().error == pytest.approx(wb.history[0].error, rel=1e-12)


def test_bad_workbench_input():
    meas = synthesise({"left": [], "right": []})
    doc = {"structure": STRUCTURE, "element": [{"name": "a", "dof": "x1"}, {"name": "b", "dof": "x2"},
                                               {"name": "c", "between": ["x1", "x2"]}]}
    with pytest.raises(InputError, match="at least as many sensors as elements"):
        Workbench(load_model(doc), meas).identify()
    other = {"structure": dict(STRUCTURE, dofs=["a", "b"]), "element": []}
    with pytest.raises(InputError, match="x1, x2 are not in the model"):
        Workbench(load_model(other), meas)


def test_add_errors_name_the_law_and_the_model_not_the_command_line():
    wb = Workbench(load_model(model_doc({"left": [], "right": [{"law": "cubic"}]}), "model.toml"),
                   synthesise({"left": [], "right": []}, lines=5))
    with pytest.raises(InputError, match="unknown law 'cubicc'") as err:
        wb.add("right", "cubicc")
    assert err.value.field is None
    with pytest.raises(InputError, match="element 'right' already has law 'cubic'") as err:
        wb.add("right", "cubic")
    assert (err.value.source, err.value.field) == ("model.toml", None)
    with pytest.raises(InputError, match="no element named 'middle'"):
        wb.add("middle", "cubic")
    assert not wb.history and not wb.model.element("left").laws
