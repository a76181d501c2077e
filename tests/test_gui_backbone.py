"""A session without a random run, imported as a response controller writes it: the reference made from the Model
tab as ``contactid reference`` makes it (the same model file, its fit and its NONLINEAR warning shown), and the
Backbone tab's natural frequency and damping against amplitude -- measured as soon as the session opens, the
model's prediction beside them once analysed, the numbers ``contactid analyze`` prints."""
import csv

import numpy as np
import pytest

from analysis.linear.level_reference import reference_from_level
from app.analyze import backbone_text, backbones, read_measurements, run_workbench
from app.cli import main
from app.gui.main_window import MainWindow

LINES = np.linspace(19.0, 25.0, 41)
# displacement held at x1 (m) -> the natural frequency (Hz) and damping ratio of the level: a joint that softens
# and dissipates more as it slips
LEVELS = {1e-5: (22.0, 0.010), 3e-5: (21.9, 0.012), 1e-4: (21.6, 0.015)}
MASS = 2.0


def receptance(fn: float, zeta: float) -> np.ndarray:
    w, wn = 2 * np.pi * LINES, 2 * np.pi * fn
    return 1.0 / (MASS * (wn ** 2 - w ** 2 + 2j * zeta * wn * w))


@pytest.fixture(scope="module")
def held_session(tmp_path_factory):
    """Three displacement levels at x1, each the FRF of one mode at its own frequency and damping, the force per
    line the controller needed to hold the displacement; imported from the CSV long format."""
    folder = tmp_path_factory.mktemp("held")
    path = folder / "held.csv"
    with open(path, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["frequency_hz", "force_n", "dof", "re", "im", "force_amplitude_n", "control_dof",
                      "control_quantity", "control_target"])
        for target, (fn, zeta) in LEVELS.items():
            for f, h in zip(LINES, receptance(fn, zeta)):
                out.writerow([repr(float(f)), "", "x1", repr(float(h.real)), repr(float(h.imag)),
                              repr(float(target / abs(h))), "x1", "displacement", repr(target)])
    session = folder / "held.h5"
    assert main(["import", str(path), "-o", str(session), "--excitation", "x1"]) == 0
    return session


@pytest.fixture
def window(qtbot):
    w = MainWindow("test")
    qtbot.addWidget(w)
    return w


def measured_dots(plot) -> tuple[np.ndarray, np.ndarray]:
    [dots] = [c for c in plot.listDataItems() if c.opts["symbol"] is not None]
    x, y = dots.getOriginalDataset()
    return np.asarray(x), np.asarray(y)


def test_the_backbone_tab_shows_a_sessions_measured_levels_as_it_opens(window, qtbot, held_session):
    assert window.backbone.status.text().startswith("No session open")
    with qtbot.waitSignal(window.lab.backboneUpdated, timeout=30000):
        window.lab.open_session(str(held_session))
    tab = window.backbone
    x, f = measured_dots(tab.frequency)
    np.testing.assert_allclose(x, sorted(LEVELS), rtol=0.02)              # the held displacements
    np.testing.assert_allclose(f, [LEVELS[k][0] for k in sorted(LEVELS)], rtol=1e-3)
    _, zeta = measured_dots(tab.damping)
    np.testing.assert_allclose(zeta, [LEVELS[k][1] for k in sorted(LEVELS)], rtol=0.05)
    assert "3 response level(s), displacement at x1" in tab.status.text() and "once the model is analysed" in \
        tab.status.text()
    assert tab.legend_names() == ["displacement at x1: measured"]
    assert tab.frequency.getAxis("bottom").labelUnits == "m"
    assert "f meas [Hz]" in tab.table.toPlainText()


@pytest.mark.slow
def test_a_reference_made_in_the_window_is_the_commands_and_its_prediction_is_drawn(window, qtbot, held_session,
                                                                                   tmp_path, capsys):
    with qtbot.waitSignal(window.lab.backboneUpdated, timeout=30000):      # the measured curves first
        window.lab.open_session(str(held_session))
    panel = window.model
    qtbot.waitUntil(panel.reference_button.isEnabled, timeout=30000)
    with qtbot.waitSignal(window.lab.modelChanged, timeout=30000):
        panel.reference_button.click()
    # the model file `contactid reference` writes, and its report in the tab
    written = tmp_path / "reference.toml"
    assert main(["reference", str(held_session), "-o", str(written)]) == 0
    printed = capsys.readouterr().out
    assert window.lab.model.to_toml() == written.read_text(encoding="utf-8")
    reference = reference_from_level(read_measurements(held_session))
    top = panel.laws.topLevelItem(0)
    assert top.text(0) == f"structure: modal reference from run {reference.run}"
    lines = [top.child(i).text(0) for i in range(top.childCount())]
    assert lines == [line.strip() for line in reference.text().splitlines()[1:]]
    assert all(line in printed for line in lines)
    assert "NONLINEAR already between the two lowest levels" in panel.model_label.text()
    assert "as loaded: joint: no laws" in panel.model_label.text()

    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=300000):
        panel.analyze_button.click()
    tab = window.backbone
    assert tab.view.predicted and tab.legend_names() == ["displacement at x1: model", "displacement at x1: measured"]
    lines = [c for c in tab.frequency.listDataItems() if c.opts["symbol"] is None]
    assert len(lines) == 1 and len(lines[0].getOriginalDataset()[0]) > 3
    # the numbers the command line prints for the same session and model
    wb, _ = run_workbench(held_session, written, rank=False)
    assert tab.table.toPlainText() == "\n".join(backbone_text(backbones(wb))).strip()
    assert "RMS relative error of the model: natural frequency" in tab.status.text()
    # the laws are fitted on the tab: the model line no longer says there are none
    assert "as fitted here: joint: no laws" in panel.model_label.text()
