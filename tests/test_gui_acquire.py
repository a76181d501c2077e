"""The lab window driven through its widgets against the emulated paper-2dof rig (offscreen Qt): a whole
campaign with live plots, abort mid-run and closing the window mid-run (output off, lines kept), and plan
validation before arming."""
import numpy as np
import pytest

from app.gui.main_window import MainWindow
from app.session.writer import open_session
from app.session.data import measurements_from_session

LEVEL = {"force": 0.8, "start": 0.9, "stop": 2.9, "step": 0.125, "direction": "up", "refine": False}
LONG_LEVEL = {**LEVEL, "start": 0.8, "stop": 3.2, "step": 0.025}          # 97 lines: time to abort mid-run
RUN = "sine_0.8N_up"
RANDOM_SECONDS = 16.0                   # two Welch segments of 8 s


@pytest.fixture
def window(qtbot):
    w = MainWindow("test")
    qtbot.addWidget(w)                 # closed (output off, threads joined) at teardown
    w.show()
    w.lab.identify_timer.setInterval(100)
    return w


def connect_and_arm(window, qtbot, level, output):
    rig = window.rig
    rig.use_builtin.setChecked(True)
    rig.builtin_rig.setCurrentText("paper-2dof")
    rig.connect_button.click()
    qtbot.waitUntil(lambda: window.lab.connected, timeout=30000)
    editor = window.acquire.editor
    editor.random.setChecked(True)              # a short random run: reference FRFs and the drive gain
    editor.random_duration.setValue(RANDOM_SECONDS)
    editor.set_levels([level])
    assert window.lab.plan is not None, window.lab.plan_message
    assert not window.acquire.start_button.isEnabled()          # nothing starts before the explicit arm
    rig.arm_button.click()
    assert window.lab.armed_plan is not None and window.acquire.start_button.isEnabled()
    window.acquire.output.setText(str(output))


@pytest.mark.slow
def test_campaign_through_the_widgets_grows_the_live_plots_and_writes_the_session(window, qtbot, tmp_path):
    output = tmp_path / "gui.h5"
    connect_and_arm(window, qtbot, LEVEL, output)
    live = window.acquire.live
    seen = []                                                   # what the plots held at each frame while running

    def sample():
        if window.lab.campaign_running:
            seen.append((len(live.shown(live.magnitude, RUN, "x1")[0]), live.shown_samples()))
    window.clock.tick.connect(sample)
    live_identifications = []
    window.lab.identificationUpdated.connect(lambda view: live_identifications.append(view.live))

    with qtbot.waitSignal(window.lab.campaignFinished, timeout=120000) as done:
        window.acquire.start_button.click()
    text, aborted = done.args
    assert not aborted, text
    assert window.lab.armed_plan is None                        # the arm is used up by one campaign

    with open_session(output) as s:
        run = s.run(RUN)
        assert run.status == "complete" and len(run.frequency) == 17
        order = np.argsort(run.frequency)
        stored = np.abs(run.frf["x1"][order])
    # the live FRF grew line by line while the campaign ran, and ends as exactly what the session holds
    lines_seen = [n for n, _ in seen]
    assert any(0 < n < 17 for n in lines_seen) and lines_seen == sorted(lines_seen)
    assert any(t > 0 for _, t in seen)
    live.lines_redraw.now()
    np.testing.assert_allclose(live.shown(live.magnitude, RUN, "x1")[1], stored, rtol=1e-12)
    np.testing.assert_allclose(live.shown(live.force_level, RUN, "target")[1], 0.8)
    assert window.acquire.progress.value() == window.acquire.progress.maximum() == 17 + 1   # + the random run
    assert any(live_identifications)                            # kbar identified while the lines arrived
    # the live identification read the lines exactly as the session file has them
    with open_session(output) as s:
        from_file = measurements_from_session(s)
    from_live = measurements_from_session(window.lab.live)
    assert [r.name for r in from_live.sine] == [r.name for r in from_file.sine] == [RUN]
    for name in ("frequency_hz", "receptance", "receptance_std", "force_achieved", "distortion"):
        np.testing.assert_array_equal(getattr(from_live.sine[0], name), getattr(from_file.sine[0], name))
    np.testing.assert_array_equal(from_live.random.receptance, from_file.random.receptance)
    # afterwards the session is open in the Session tab and identified from the file
    assert window.lab.session_path == str(output)
    qtbot.waitUntil(lambda: window.lab.identification is not None and not window.lab.identification.live
                    and window.lab.identification.lines == 17, timeout=30000)
    table = window.session.runs
    rows = {table.item(r, 0).text(): (table.item(r, 4).text(), table.item(r, 5).text()) for r in range(table.rowCount())}
    assert rows[RUN] == ("complete", "17") and rows["random"][0] == "complete"


@pytest.mark.slow
def test_abort_mid_run_switches_the_output_off_and_keeps_the_lines(window, qtbot, tmp_path):
    output = tmp_path / "aborted.h5"
    connect_and_arm(window, qtbot, LONG_LEVEL, output)
    emulator, shaker = window.lab.instruments.emulator, window.lab.instruments.shaker
    window.acquire.start_button.click()
    qtbot.waitUntil(lambda: window.lab.live is not None and window.lab.live.lines >= 3, timeout=60000)
    assert emulator.shaker.output_on
    with qtbot.waitSignal(window.lab.campaignFinished, timeout=60000) as done:
        window.acquire.abort_button.click()
    assert done.args[1]                                         # reported as aborted
    assert not emulator.shaker.output_on and not shaker.output_enabled()
    assert emulator.output_events()[-1].detail.startswith("off")
    with open_session(output) as s:
        run = s.run(RUN)
        assert run.status == "aborted"
        assert 3 <= len(run.frequency) < 97
        assert len(run.frequency) == window.lab.live.lines          # every line shown is in the file
        assert any("operator abort" in e["message"] for e in s.events())
    assert "ABORTED" in window.acquire.run_label.text()


@pytest.mark.slow
def test_closing_the_window_mid_run_switches_the_output_off_first(window, qtbot, tmp_path):
    output = tmp_path / "closed.h5"
    connect_and_arm(window, qtbot, LONG_LEVEL, output)
    emulator = window.lab.instruments.emulator
    window.acquire.start_button.click()
    qtbot.waitUntil(lambda: window.lab.live is not None and window.lab.live.lines >= 2, timeout=60000)
    window.close()
    assert window.lab.campaign is None and window.lab.instruments is None
    assert not emulator.shaker.output_on
    assert emulator.output_events()[-1].detail.startswith("off")
    with open_session(output) as s:
        run = s.run(RUN)
        assert run.status == "aborted" and len(run.frequency) >= 2
        assert any("window closed" in e["message"] for e in s.events())


def test_an_invalid_plan_is_refused_before_arming(window, qtbot):
    window.rig.connect_button.click()
    qtbot.waitUntil(lambda: window.lab.connected, timeout=30000)
    window.acquire.editor.random.setChecked(False)
    window.acquire.editor.set_levels([{**LEVEL, "start": 3.0, "stop": 2.0}])
    assert window.lab.plan is None
    assert "stop (2.0 Hz) must be above start (3.0 Hz)" in window.acquire.editor.validation.text()
    window.rig.arm_button.click()
    assert window.lab.armed_plan is None and not window.acquire.start_button.isEnabled()
    assert window.error_bar.isVisible() and "cannot arm" in window.error_bar.label.text()
    # beyond the DAQ's Nyquist frequency (paper-2dof samples at 256 Hz): refused against the instruments
    window.acquire.editor.set_levels([{**LEVEL, "stop": 200.0, "step": 50.0}])
    assert window.lab.plan is None and "Nyquist" in window.acquire.editor.validation.text()
    # a force level at the abort limit is refused too
    window.acquire.editor.set_levels([LEVEL])
    window.rig.max_force.setValue(0.5)
    assert window.lab.plan is None and "max_force" in window.acquire.editor.validation.text()


def test_last_line_says_which_path_it_took():
    from types import SimpleNamespace

    from app.gui.acquire_panel import _line_path
    line = dict(frequency=7.25, settle_periods=10.0, steady=True, transient=True, transient_std=2e-6)
    assert _line_path(SimpleNamespace(**line)) == \
        "last line 7.25 Hz: from its transient after 10 periods (3 std 6.0e-06)"
    assert _line_path(SimpleNamespace(**{**line, "transient": False})) == "last line 7.25 Hz: steady after 10 periods"
    assert _line_path(SimpleNamespace(**{**line, "transient": False, "steady": False})) == \
        "last line 7.25 Hz: measured at the settling limit (10 periods)"


def test_a_response_level_is_edited_and_kept_as_the_plan_spells_it(window):
    editor = window.acquire.editor
    level = {"response": 5.0, "quantity": "acceleration", "dof": "x2", "force_limit": 2.0, "start": 1.0,
             "stop": 1.5, "step": 0.1, "direction": "up", "refine": False}
    editor.set_levels([LEVEL, level])
    kept = editor.levels()
    assert kept[0] == LEVEL
    assert {k: kept[1][k] for k in level} == level
    editor.table.cellWidget(1, 6).setCurrentText("velocity")
    assert editor.levels()[1]["quantity"] == "velocity"
    editor.table.cellWidget(1, 6).setCurrentText("force")        # back to a force level: the amplitude is N
    assert editor.levels()[1]["force"] == 5.0 and "response" not in editor.levels()[1]


PHASE_PLAN = """
[limits]
max_force = 4.0
max_acceleration = 40.0

[[stepped_sine]]
force = 0.2
start = 1.1
stop = 1.4
step = 0.03
refine = false

[[stepped_sine]]
response = 2.0
dof = "x2"
start = 1.1
stop = 1.4
step = 0.03
refine = false

[[phase_resonance]]
dof = "x2"
forces = [0.3, 0.6, 0.9]
start = 1.25
"""


@pytest.mark.slow
def test_frequency_and_damping_against_amplitude_grow_point_by_point(window, qtbot, tmp_path):
    rig = window.rig
    rig.use_builtin.setChecked(True)
    rig.builtin_rig.setCurrentText("paper-2dof")
    rig.connect_button.click()
    qtbot.waitUntil(lambda: window.lab.connected, timeout=30000)
    (tmp_path / "plan.toml").write_text(PHASE_PLAN, encoding="utf-8")
    window.acquire.editor.load(tmp_path / "plan.toml")
    assert window.lab.plan is not None and window.lab.plan.phase, window.lab.plan_message
    rig.arm_button.click()
    window.acquire.output.setText(str(tmp_path / "gui.h5"))
    live = window.acquire.live
    locked, errors = [], []
    window.lab.error.connect(errors.append)           # the live identification reads the locked points too

    def sample():
        if window.lab.campaign_running:
            locked.append(len(live.shown(live.natural, "phase_x2_90deg", "locked")[0]))
    window.clock.tick.connect(sample)
    with qtbot.waitSignal(window.lab.campaignFinished, timeout=300000) as done:
        window.acquire.start_button.click()
    assert not done.args[1], done.args[0]
    qtbot.waitUntil(lambda: len(live.shown(live.natural, "phase_x2_90deg", "locked")[0]) == 3, timeout=10000)
    assert {1, 2} <= set(locked)                                    # grew point by point while it ran
    qtbot.waitUntil(lambda: window.lab.identification is not None and not window.lab.identification.live,
                    timeout=60000)
    assert not errors, errors
    f, zeta = (live.shown(plot, "response levels", "acceleration at x2")[1] for plot in (live.natural, live.damping))
    assert len(f) == 1 and 1.1 < f[0] < 1.3 and 0 < zeta[0] < 0.2   # the response level's modal fit
    # the locked points' damping by the power balance, the modal constant from the 0.1 N level measured first
    zeta = live.shown(live.damping, "phase_x2_90deg", "locked")[1]
    assert len(zeta) == 3 and np.all((0 < zeta) & (zeta < 0.2))


def test_live_legends_stand_beside_the_plots_never_over_their_data(window, qtbot):
    """|H|, acceleration and natural frequency name their curves in legends of their own right of the plots (as the
    Model tab does), each marker level with its words: none lies over a plot's data area."""
    live = window.acquire.live
    window.resize(1366, 768)
    window.tabs.setCurrentWidget(window.acquire)
    f = np.linspace(0.8, 3.2, 50)
    for k, dof in enumerate(("x1", "x2")):
        live._curve(live.acc_time, ("time", dof), pen="b", name=f"acc:{dof}").setData(-f, np.sin(f))
        live._curve(live.magnitude, ("random", dof), pen="k", name=f"random · {dof}").setData(f, 1e-3 / f)
        for level in ("0.4 N", "0.8 N", "2 m/s^2 at x2"):
            live._curve(live.magnitude, (level, dof), pen=None, symbol="o", name=f"{level} up · {dof}").setData(
                f, 1e-2 / f)
    live._curve(live.natural, ("phase", "locked"), symbol="o", name="phase resonance at x2").setData(
        [0.06, 0.1, 0.2], [1.26, 1.23, 1.2])
    live._curve(live.natural, ("response levels", "x2"), symbol="d", pen=None,
                name="response levels at x2").setData([0.02], [1.26])
    qtbot.wait(200)
    plots = live.plots()
    for name, plot in plots.items():                   # every plot whole in view, the legends' column too
        assert live.viewport().rect().contains(live.mapFromScene(plot.sceneBoundingRect()).boundingRect()), name
    beside = {"acceleration_time": ("force_time", "acceleration_time"), "frf_magnitude": ("frf_magnitude", "frf_phase"),
              "natural_frequency": ("natural_frequency", "damping")}
    for name, count in (("acceleration_time", 2), ("frf_magnitude", 8), ("natural_frequency", 2)):
        plot, legend = plots[name], live.legends[name]
        assert plot.legend is legend and len(legend.items) == count, name
        area = legend.sceneBoundingRect()
        assert area.left() >= max(plots[p].vb.sceneBoundingRect().right() for p in beside[name]) - 1, name
        assert not any(area.intersects(p.vb.sceneBoundingRect()) for p in plots.values()), name
        shown = live.mapFromScene(area).boundingRect()
        assert live.viewport().rect().contains(shown), (name, shown)
        for sample, label in legend.items:             # each marker level with its words
            assert abs(sample.sceneBoundingRect().center().y() - label.item.sceneBoundingRect().center().y()) <= 2
    # a new campaign empties them
    live.plots()["frf_magnitude"].legend.clear()
    assert not live.legends["frf_magnitude"].items


def test_the_plan_check_and_the_progress_bar_count_the_same_lines(window, tmp_path):
    """The plan check counted the stepped-sine lines alone (97) where the progress bar counted the random run and
    each phase-resonance level as well (0 / 100): one count now, the campaign's (Plan.planned_lines)."""
    import re

    (tmp_path / "plan.toml").write_text("[random]\nforce_rms = 0.3\nband = [0.5, 5.0]\nduration = 16.0\n" + PHASE_PLAN,
                                        encoding="utf-8")
    window.acquire.editor.load(tmp_path / "plan.toml")
    plan = window.lab.plan
    assert plan is not None and plan.random is not None and plan.phase, window.lab.plan_message
    stepped = sum(len(spec.lines(d)) for spec, d in plan.runs)
    assert plan.planned_lines() == stepped + 1 + 3
    (said,) = re.findall(r"(\d+) planned lines", window.lab.plan_message)
    progress = window.acquire.progress
    assert int(said) == plan.planned_lines() == progress.maximum() and progress.value() == 0
    assert progress.text() == f"0 / {said} planned lines"
    assert f"({stepped} stepped-sine + the random run + 3 phase-resonance level(s))" in window.lab.plan_message
    # refinement adds lines as the campaign runs: said apart from the planned ones
    window.acquire._planned = plan.planned_lines()
    window.acquire._on_progress(10, plan.planned_lines() + 6, 30.0, "sine_0.2N_up")
    assert progress.maximum() == plan.planned_lines() + 6
    assert f"({said} planned + 6 added by refinement)" in progress.format()


def test_every_plan_cell_shows_its_whole_content_on_a_small_screen(window, qtbot):
    window.resize(1366, 768)
    window.tabs.setCurrentWidget(window.acquire)
    editor = window.acquire.editor
    editor.set_levels([{**LONG_LEVEL, "force": 0.4, "step": 0.05},
                       {"response": 2.0, "quantity": "acceleration", "dof": "x2", "start": 1.05, "stop": 1.45,
                        "step": 0.025, "direction": "both", "refine": False}])
    qtbot.wait(50)
    table = editor.table
    for row in range(table.rowCount()):
        for col in range(table.columnCount()):
            cell = table.cellWidget(row, col)
            text = cell.currentText() if hasattr(cell, "currentText") else cell.text()
            assert cell.width() >= cell.sizeHint().width() and table.columnWidth(col) >= cell.sizeHint().width()
            assert cell.fontMetrics().horizontalAdvance(text) <= cell.width() - 6, (row, col, text)
    assert [table.cellWidget(1, c).text() for c in range(4)] == ["2", "1.05", "1.45", "0.025"]
    # the table as wide as its columns at the window's default split: no column hidden to the right
    assert table.horizontalScrollBar().maximum() == 0
    assert editor.levels()[1]["step"] == 0.025 and editor.levels()[0]["force"] == 0.4
