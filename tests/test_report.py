"""Report plots: log axes labelled at the decades only, in engineering notation, and every plot written."""
import numpy as np
import pytest

from analysis.model import load_model
from analysis.workbench import Workbench
from analysis.numbers import engineering
from app.report import _labelled_log_ticks, _log_axis, qt_application, write_report
from test_workbench import PAPER_LAWS, model_doc, synthesise


@pytest.mark.parametrize("value, unit, text", [
    (2e-5, "m", "20 µm"), (1e-3, "m/N", "1 mm/N"), (1e7, "N/m", "10 MN/m"), (100e-6, "rad", "100 µrad"),
    (0.01, "", "0.01"), (1e-6, "", "10⁻⁶"), (3e5, "", "3·10⁵"), (1.0, "N", "1 N"), (-2.5e3, "N/m", "-2.5 kN/m")])
def test_engineering_notation(value, unit, text):
    assert engineering(value, unit) == text


def test_decades_only_when_the_view_holds_two_or_more():
    assert _labelled_log_ticks(-7.3, -4.6) == [-7.0, -6.0, -5.0]
    # within one decade: 1-2-5 steps; within a factor of 2: round values, never fewer than two labels
    assert np.allclose(10 ** np.array(_labelled_log_ticks(np.log10(0.15), np.log10(0.9))), [0.2, 0.5])
    close = 10 ** np.array(_labelled_log_ticks(np.log10(1.2), np.log10(1.23)))
    assert len(close) >= 2 and np.all((close >= 1.2 - 1e-12) & (close <= 1.23 + 1e-12))


def test_log_axis_labels_decades_and_leaves_minor_ticks_blank():
    qt_application()
    axis = _log_axis("bottom", "m")
    (major_spacing, major), (minor_spacing, minor) = axis.tickValues(-7.3, -4.6, 600)  # 50 nm .. 25 µm
    assert axis.tickStrings(major, 1.0, major_spacing) == ["100 nm", "1 µm", "10 µm"]
    assert len(minor) == 4 + 8 + 8 + 1 and set(axis.tickStrings(minor, 1.0, minor_spacing)) == {""}


@pytest.mark.slow
def test_write_report_draws_every_plot(tmp_path):
    wb = Workbench(load_model(model_doc({"left": PAPER_LAWS["left"], "right": [{"law": "cubic"}]})),
                   synthesise(PAPER_LAWS, lines=17))
    wb.start()
    wb.add("right", "coulomb")
    paths = write_report(wb, tmp_path)
    assert [p.name for p in paths] == ["frf.png", "kbar.png", "residuals.png", "error_history.png"]
    from PySide6.QtGui import QImage
    for p in paths:
        image = QImage(str(p))
        assert image.width() == 1400 and image.height() in (600, 900)
