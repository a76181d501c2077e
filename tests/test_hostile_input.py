"""What the fuzz corpus (tests/fuzz/) found, one test each where a refusal alone does not show the fix: a byte
order mark accepted, the planned shaker time stated and bounded, exports that never replace a file silently."""
import tomllib

import numpy as np
import pytest

from analysis.common.errors import InputError
from analysis.common.tables import load_toml
from app.cli import main
from app.campaign.plan import MAX_SHAKER_SECONDS, load_plan, parse_plan
from drivers.simulation.rig import builtin_rig_path, load_rig

PLAN = """[random]
force_rms = 0.05
band = [0.5, 5.0]
duration = 100.0

[[stepped_sine]]
force = 0.8
start = 1.0
stop = 2.0
step = 0.5
direction = "both"

[settle]
block_periods = 4
min_blocks = 3
max_periods = 200

[limits]
max_force = 5.0
max_acceleration = 50.0
"""


def test_toml_files_with_a_utf8_byte_order_mark_are_read(tmp_path, capsys):
    bom = b"\xef\xbb\xbf"
    (tmp_path / "plan.toml").write_bytes(bom + PLAN.encode())
    (tmp_path / "rig.toml").write_bytes(bom + builtin_rig_path("paper-2dof").read_bytes())
    assert load_plan(tmp_path / "plan.toml").random.duration == 100.0
    assert load_rig(tmp_path / "rig.toml").name == "paper-2dof"
    assert load_toml(tmp_path / "rig.toml")["name"] == "paper-2dof"
    assert main(["modes", str(tmp_path / "rig.toml")]) == 0
    assert "1.2672 Hz" in capsys.readouterr().out


def test_the_planned_shaker_time_counts_the_random_run_and_every_line_both_ways():
    plan = parse_plan(tomllib.loads(PLAN), PLAN)
    periods = 2 * (1 / 1.0 + 1 / 1.5 + 1 / 2.0)           # lines at 1, 1.5, 2 Hz, swept up and down
    planned = plan.planned_time()
    assert planned.least == pytest.approx(100 + 3 * 4 * periods)
    assert planned.most == pytest.approx(100 + (200 + 4) * periods)
    assert "planned shaker time 3 min to 16 min" in plan.summary()


def test_a_plan_whose_least_shaker_time_exceeds_a_day_is_refused_naming_it():
    text = PLAN.replace("max_periods = 200", "fixed_periods = 90000").replace("[random]\nforce_rms = 0.05\n"
                                                                               "band = [0.5, 5.0]\n"
                                                                               "duration = 100.0\n", "")
    text = text.replace("start = 1.0", "start = 0.1").replace("step = 0.5", "step = 0.02")
    with pytest.raises(InputError, match=r"plan.toml: planned shaker time .* more than 24 h"):
        parse_plan(tomllib.loads(text), text, "plan.toml")
    assert MAX_SHAKER_SECONDS == 24 * 3600


def test_simulate_states_the_plan_before_measuring(tmp_path, capsys):
    (tmp_path / "p.toml").write_text(PLAN.replace("duration = 100.0", "duration = 1e6"), encoding="utf-8")
    assert main(["simulate", "paper-2dof", str(tmp_path / "p.toml"), "-o", str(tmp_path / "s.h5")]) == 2
    assert "[random].duration: 1e+06 s is more than 3600 s" in capsys.readouterr().err
    assert not (tmp_path / "s.h5").exists()


def test_the_gui_plot_export_refuses_a_folder_holding_those_plots(tmp_path):
    pytest.importorskip("PySide6")
    import pyqtgraph as pg

    from app.gui.plots import export_png
    from app.report import qt_application

    qt_application()
    plot = pg.PlotWidget()
    plot.plot(np.arange(5.0), np.arange(5.0))
    target = tmp_path / "frf.png"
    target.write_bytes(b"an earlier export")
    with pytest.raises(InputError, match="frf.png: exists already"):
        export_png(plot.getPlotItem(), target)
    assert target.read_bytes() == b"an earlier export"
    export_png(plot.getPlotItem(), tmp_path / "new.png")
    assert (tmp_path / "new.png").read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frf.png", "new.png"]
