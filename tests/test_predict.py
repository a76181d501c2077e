"""A fitted model's prediction with nothing refitted: ``contactid predict`` and ``analyze --fit-levels``.

Truth: a Duffing oscillator held at displacement amplitude a responds, in single-harmonic balance, as the linear
oscillator of stiffness k + 3/4 k3 a^2 -- h(w) = 1 / (k + 3/4 k3 a^2 - m w^2 + j c w), the force F = a / |h| --
so the sessions here are written from that formula (no simulator, no harmonic balance of the product's), with
a measured noise added. A cubic law fitted on the low levels must predict the high ones as well as its own; a
linear law, which cannot follow the amplitude, must predict them worse, and the report must say so.
"""
import json
import tomllib

import numpy as np
import pytest

from analysis.common.errors import InputError
from analysis.common.measurements import Control
from analysis.mechanics.model import FittedOn, load_model
from app.cli import main
from app.predict import parse_levels

K, M, C, K3 = 3947.8, 1.0, 1.5, 4.0e7
# m held at x, one level each; below the amplitude where the force-controlled response folds (a held response
# there can sit on the branch force control cannot hold, which a prediction at the measured force does not give)
AMPLITUDES = (0.4e-3, 0.8e-3, 1.2e-3, 1.6e-3)
NOISE = 2e-3                                            # relative standard deviation of each FRF value
FREQUENCY = np.arange(9.4, 10.8, 0.04)                  # Hz: every level's resonance (10.0-10.1 Hz) and skirts

STRUCTURE = f"""
[structure]
type = "lumped"
dofs = ["x"]
mass = [[{M}]]
stiffness = [[{K}]]
damping = [[{C}]]
"""


def model_text(laws: str) -> str:
    return STRUCTURE + f'\n[[element]]\nname = "spring"\ndof = "x"\nlaws = [{laws}]\n'


def duffing_receptance(a: float, f_hz: np.ndarray) -> np.ndarray:
    w = 2 * np.pi * f_hz
    return 1.0 / (K + 0.75 * K3 * a ** 2 - M * w ** 2 + 1j * C * w)


def write_session(path, seed: int) -> None:
    """Response-controlled up sweeps at AMPLITUDES, as a campaign writes them: the force measured at each line,
    the FRF's standard deviation beside it."""
    from app.session import RunSpec, SessionWriter

    rng = np.random.default_rng(seed)
    writer = SessionWriter(path, plan_text="", software_version="test")
    for a in AMPLITUDES:
        h = duffing_receptance(a, FREQUENCY)
        std = NOISE * np.abs(h)
        measured = h + std / np.sqrt(2) * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape))
        force = a / np.abs(h)
        name = f"sine_x_{a:g}m_up"
        writer.begin_run(RunSpec(name, "stepped_sine", float(np.median(force)), "up", "x", ["x"], 256.0,
                                 ["force", "acc:x"], ["N", "m/s^2"],
                                 extras={"frf_std/x": ("m/N", (), "f8"), "force_amplitude": ("N", (), "f8")},
                                 attrs={"control": "response", "control_dof": "x",
                                        "control_quantity": "displacement", "control_target": a,
                                        "control_units": "m"}))
        for k, f in enumerate(FREQUENCY):
            writer.append_line(f, {"x": measured[k]}, {"frf_std/x": std[k], "force_amplitude": force[k]})
        writer.end_run("complete")
    writer.close()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    folder = tmp_path_factory.mktemp("predict")
    first, second = folder / "duffing.h5", folder / "duffing_again.h5"
    write_session(first, seed=1)
    write_session(second, seed=2)
    (folder / "cubic.toml").write_text(model_text('"cubic"'), encoding="utf-8")
    (folder / "linear.toml").write_text(model_text('"linear"'), encoding="utf-8")
    return folder


def _fit(folder, law: str, output: str, *extra) -> None:
    assert main(["analyze", str(folder / "duffing.h5"), str(folder / f"{law}.toml"), "--no-history",
                 "-o", str(folder / output), *extra]) == 0


def _predict_json(capsys, session, model) -> dict:
    capsys.readouterr()
    assert main(["predict", str(session), str(model), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.fixture(scope="module")
def fitted_low(sessions):
    """The cubic and the linear law fitted on the two lowest levels."""
    _fit(sessions, "cubic", "cubic_low.toml", "--fit-levels", "1,2")
    _fit(sessions, "linear", "linear_low.toml", "--fit-levels", "1-2")
    return sessions


def test_the_fitted_model_names_the_session_and_levels_it_was_fitted_to(fitted_low):
    doc = tomllib.loads((fitted_low / "cubic_low.toml").read_text(encoding="utf-8"))
    assert doc["fitted"]["session"] == "duffing.h5"
    assert doc["fitted"]["levels"] == ["0.0004 m at x", "0.0008 m at x"]
    from app.predict import session_created
    assert doc["fitted"]["session_created"] == session_created(fitted_low / "duffing.h5")


def test_a_cubic_law_fitted_on_low_levels_predicts_the_held_out_ones_as_well_as_its_own(fitted_low, capsys):
    out = _predict_json(capsys, fitted_low / "duffing.h5", fitted_low / "cubic_low.toml")
    assert [lv["kind"] for lv in out["levels"]] == ["fitted", "fitted", "held_out", "held_out"]
    fitted, held = out["errors"]["fitted"], out["errors"]["held_out"]
    # the noise alone leaves a relative error of about NOISE; the right law adds little to it anywhere
    assert fitted < 3 * NOISE and held < 3 * NOISE
    # the natural frequency of each level against the formula's, sqrt((k + 3/4 k3 a^2) / m)
    (backbone,) = out["backbones"]
    for point in backbone["predicted"]["points"]:
        truth = np.sqrt((K + 0.75 * K3 * point["amplitude"] ** 2) / M) / (2 * np.pi)
        assert point["frequency_hz"] == pytest.approx(truth, rel=2e-4)
    assert all(abs(lv["damping_error"]) < 0.05 for lv in out["levels"])


def test_a_linear_law_fitted_on_low_levels_is_seen_to_fail_on_the_held_out_ones(fitted_low, capsys):
    out = _predict_json(capsys, fitted_low / "duffing.h5", fitted_low / "linear_low.toml")
    assert out["errors"]["held_out"] > 4 * out["errors"]["fitted"]
    levels = out["levels"]
    assert abs(levels[-1]["frequency_error"]) > 5 * abs(levels[0]["frequency_error"])
    assert main(["predict", str(fitted_low / "duffing.h5"), str(fitted_low / "linear_low.toml")]) == 0
    text = capsys.readouterr().out
    assert "held out" in text and "better than it predicts others" in text


@pytest.mark.slow
def test_analyze_with_fit_levels_prints_the_same_prediction_predict_gives(fitted_low, capsys):
    capsys.readouterr()
    assert main(["analyze", str(fitted_low / "duffing.h5"), str(fitted_low / "cubic.toml"), "--no-history",
                 "--fit-levels", "1,2", "--json"]) == 0
    analysed = json.loads(capsys.readouterr().out)["prediction"]
    predicted = _predict_json(capsys, fitted_low / "duffing.h5", fitted_low / "cubic_low.toml")
    assert [lv["error"] for lv in analysed["levels"]] == pytest.approx([lv["error"] for lv in predicted["levels"]],
                                                                     rel=1e-9)
    # the fit saw only its levels: its own error is over them alone
    assert len(json.loads(json.dumps(analysed))["levels"]) == len(AMPLITUDES)


@pytest.mark.slow
def test_predict_on_the_fitted_session_gives_the_error_analyze_gave_nothing_refitted(sessions, capsys):
    capsys.readouterr()
    assert main(["analyze", str(sessions / "duffing.h5"), str(sessions / "cubic.toml"), "--no-history", "--json",
                 "-o", str(sessions / "cubic_all.toml")]) == 0
    analysed = json.loads(capsys.readouterr().out)
    predicted = _predict_json(capsys, sessions / "duffing.h5", sessions / "cubic_all.toml")
    assert predicted["error"] == pytest.approx(analysed["error"], rel=1e-6)
    assert {lv["kind"] for lv in predicted["levels"]} == {"fitted"}


def test_another_session_is_unseen_and_a_model_that_does_not_say_is_unknown(fitted_low, capsys):
    out = _predict_json(capsys, fitted_low / "duffing_again.h5", fitted_low / "cubic_low.toml")
    assert {lv["kind"] for lv in out["levels"]} == {"unseen"}
    assert out["errors"]["unseen"] < 3 * NOISE
    stripped = fitted_low / "cubic_low_stripped.toml"
    text = (fitted_low / "cubic_low.toml").read_text(encoding="utf-8")
    stripped.write_text(text.split("[fitted]")[0], encoding="utf-8")
    out = _predict_json(capsys, fitted_low / "duffing.h5", stripped)
    assert {lv["kind"] for lv in out["levels"]} == {"unknown"} and out["fitted_on"] is None


@pytest.mark.slow
def test_predict_writes_its_plots_and_refuses_to_overwrite_them(fitted_low, tmp_path, capsys):
    folder = tmp_path / "new" / "report"
    args = ["predict", str(fitted_low / "duffing.h5"), str(fitted_low / "cubic_low.toml"), "--report", str(folder)]
    assert main(args) == 0
    for name in ("frf.png", "residuals.png", "backbone.png"):
        assert (folder / name).stat().st_size > 10_000
    before = (folder / "frf.png").stat().st_mtime_ns
    assert main(args) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (folder / "frf.png").stat().st_mtime_ns == before
    assert main(args + ["--overwrite"]) == 0


@pytest.mark.parametrize("levels, says", [("5", "no level '5'"), ("0", "no level '0'"), ("a", "level numbers"),
                                          ("2-1", "no level '2-1'")])
def test_fit_levels_out_of_range_is_refused_listing_the_levels(sessions, capsys, levels, says):
    assert main(["analyze", str(sessions / "duffing.h5"), str(sessions / "cubic.toml"), "--no-history",
                 "--fit-levels", levels]) == 2
    err = capsys.readouterr().err
    assert says in err and "1 = 0.0004 m at x" in err and err.count("\n") == 1


def test_a_model_without_values_is_refused_by_predict(sessions, capsys):
    assert main(["predict", str(sessions / "duffing.h5"), str(sessions / "cubic.toml")]) == 2
    err = capsys.readouterr().err
    assert "cubic.toml" in err and "has no values" in err


def test_parse_levels_numbers_levels_in_the_reports_order():
    controls = [Control("force", "x", "force", 0.2), Control("force", "x", "force", 0.8),
                Control("response", "x", "displacement", 1e-3)]
    assert parse_levels("1,3", controls) == {controls[0].key(), controls[2].key()}
    assert parse_levels(" 2-3 ", controls) == {controls[1].key(), controls[2].key()}
    with pytest.raises(InputError, match="the session has 3"):
        parse_levels("4", controls)


def test_the_fitted_table_round_trips_and_is_checked():
    doc = tomllib.loads(model_text('{ law = "cubic", k3 = 1.0 }'))
    doc["fitted"] = {"session": "s.h5", "session_created": "2026-12-01T10:00:00.000001+00:00",
                     "levels": ["0.2 N", "1 m/s^2 at x"]}
    model = load_model(doc, "m.toml")
    assert model.fitted_on == FittedOn("s.h5", "2026-12-01T10:00:00.000001+00:00", ("0.2 N", "1 m/s^2 at x"))
    assert load_model(tomllib.loads(model.to_toml()), "again.toml").fitted_on == model.fitted_on
    assert model.fitted_on.saw("2026-12-01T10:00:00.000001+00:00", "0.2 N") is True
    assert model.fitted_on.saw("2026-12-01T10:00:00.000001+00:00", "0.8 N") is False
    assert model.fitted_on.saw("another", "0.2 N") is None
    doc["fitted"]["extra"] = 1
    with pytest.raises(InputError, match=r"\[fitted\]"):
        load_model(doc, "m.toml")
    doc["fitted"] = {"session": "s.h5", "session_created": "x", "levels": "0.2 N"}
    with pytest.raises(InputError, match="list of strings"):
        load_model(doc, "m.toml")


@pytest.mark.slow
def test_cross_validation_tells_a_law_that_follows_the_amplitude_from_one_that_fits_its_lines(sessions, capsys):
    folds = {}
    for law in ("cubic", "linear"):
        capsys.readouterr()
        assert main(["analyze", str(sessions / "duffing.h5"), str(sessions / f"{law}.toml"), "--no-history",
                     "--cross-validate", "--json"]) == 0
        folds[law] = json.loads(capsys.readouterr().out)["cross_validation"]
    assert [f["levels"] for f in folds["cubic"]] == [["0.0004 m at x", "0.0012 m at x"],
                                                     ["0.0008 m at x", "0.0016 m at x"],
                                                     ["0.0004 m at x", "0.0008 m at x"],
                                                     ["0.0012 m at x", "0.0016 m at x"]]
    assert all(f["ratio"] < 2 and f["held_out_error"] < 3 * NOISE for f in folds["cubic"])
    # each half's held-out levels are another half's fitted ones: the cost of not seeing them, on the same levels
    cubic = folds["cubic"]
    assert [cubic[k]["others_fitted_error"] for k in range(4)] == [cubic[k]["fitted_error"] for k in (1, 0, 3, 2)]
    assert all(f["cost"] == pytest.approx(f["held_out_error"] / f["others_fitted_error"]) and f["cost"] < 2
               for f in cubic)
    # beyond the levels it saw, a constant stiffness misses the amplitude's stiffening
    assert max(f["ratio"] for f in folds["linear"]) > 4
    assert main(["analyze", str(sessions / "duffing.h5"), str(sessions / "linear.toml"), "--no-history",
                 "--cross-validate"]) == 0
    out = capsys.readouterr().out
    assert "describes its own levels better than it predicts others" in out
    assert "against the same levels fitted on themselves: predicting a half costs" in out


@pytest.mark.slow
def test_the_model_tab_predicts_with_nothing_refitted_and_saves_what_it_was_fitted_to(fitted_low, qtbot, tmp_path):
    from app.gui.main_window import MainWindow

    window = MainWindow("test")
    qtbot.addWidget(window)
    window.lab.load_model_file(str(fitted_low / "linear_low.toml"))
    window.lab.open_session(str(fitted_low / "duffing.h5"))
    panel = window.model
    assert panel.predict_button.isEnabled()
    with qtbot.waitSignal(window.lab.predictionUpdated, timeout=60000) as shown:
        panel.predict_button.click()
    prediction = shown.args[0].prediction
    assert panel.error_label.text() == (f"Prediction, nothing refitted: fitted levels "
                                        f"{prediction.errors['fitted']:.3g}; held out levels "
                                        f"{prediction.errors['held_out']:.3g}")
    assert "better than it predicts others" in panel.explanation.toPlainText()
    names = [item.text for _, item in panel.frf.legend.items]
    assert "0.0016 m at x up · x (held out)" in names and "0.0004 m at x up · x (fitted)" in names
    # analysed in the window, the model it saves names the session and levels it was fitted to
    window.lab.load_model_file(str(fitted_low / "cubic.toml"))
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=60000):
        panel.analyze_button.click()
    saved = tomllib.loads(window.lab.analysis.model_toml)
    assert saved["fitted"]["session"] == "duffing.h5" and len(saved["fitted"]["levels"]) == len(AMPLITUDES)


@pytest.mark.slow
def test_the_held_out_check_predicts_each_held_out_level_s_mode_by_the_fit_that_did_not_see_it(sessions):
    """The loop's held-out check (analysis/loop/cross_check.py ``held_out``) on response levels written from the
    single-harmonic formula: its modes are those of each held-out level as predicted by the fold's refit that did
    not see it, pooled over the folds; the cubic, which bends the backbone as the formula does, predicts them, the
    linear spring does not, and the modes alone keep the cubic (the second witness)."""
    from analysis.loop.cross_check import _at, _refitted, as_fitted, held_out, interleaved, predicts_no_better
    from analysis.loop.workbench import Workbench
    from analysis.prediction.held_out import predict_session
    from app.analyze import read_measurements

    measurements = read_measurements(sessions / "duffing.h5")
    held, folds = {}, {}
    for law in ("linear", "cubic"):
        wb = Workbench(load_model(tomllib.loads((sessions / f"{law}.toml").read_text()), law), measurements)
        wb.start()
        held[law] = held_out(wb)
        errors = []
        for seen, out in interleaved(wb.measurements.level_controls(), 3):
            fold = _refitted(wb, seen, as_fitted(wb))
            errors += [lv.frequency_error for lv in predict_session(fold.model, _at(wb, out), "").levels]
        folds[law] = float(np.sqrt(np.mean(np.square(errors))))
    for law in ("linear", "cubic"):
        assert held[law].modes.frequency == pytest.approx(folds[law], rel=1e-9)
    # a constant stiffness misses how the natural frequency moves with the amplitude (0.0039 on 2026-12-07), ten
    # times the floor of 2e-4 below which two frequency errors are the same; the cubic follows it (2.4e-5)
    assert held["cubic"].modes.frequency < 1e-4 and held["linear"].modes.frequency > 10 * 2e-4
    assert predicts_no_better(held["linear"], held["cubic"]) == ""
    # the modes alone: the same FRF errors for both, the cubic still kept, the linear spring refused
    frf = {law: type(held[law])(held["cubic"].error, held["cubic"].folds, held["cubic"].seen, True,
                                held[law].modes) for law in held}
    assert predicts_no_better(frf["linear"], frf["cubic"]) == ""
    assert "worse, its modes by more than the x1.3" in predicts_no_better(frf["cubic"], frf["linear"])
