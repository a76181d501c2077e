"""File > Import…: two controller files at their own force levels, one DOF map, into a session the Identify tab
then shows."""
import numpy as np
import pytest
import pyuff

from app.gui.main_window import MainWindow
from app.session.writer import open_session

M, K = np.diag([1.0, 2.0]), np.array([[200.0, -100.0], [-100.0, 200.0]])
FREQS = np.linspace(0.9, 3.0, 30)


def controller_file(path):
    """Accelerance of a linear 2-DOF system, nodes 1 and 2 in +Z, force at node 2."""
    w = 2 * np.pi * FREQS
    H = np.array([np.linalg.solve(K - wi ** 2 * M + 1j * wi * 0.02 * K, [0.0, 1.0]) for wi in w])
    sets = [pyuff.prepare_58(binary=0, func_type=4, rsp_node=p + 1, rsp_dir=3, ref_node=2, ref_dir=3,
                             ordinate_spec_data_type=12, ordinate_axis_units_lab="m/s^2",
                             orddenom_spec_data_type=13, orddenom_axis_units_lab="N", abscissa_spec_data_type=18,
                             x=FREQS, data=-(w ** 2) * H[:, p], id1=f"Point{p + 1}", id2="", id3="", id4="",
                             id5="") for p in range(2)]
    pyuff.UFF(str(path)).write_sets(sets, mode="add")
    return str(path)


@pytest.fixture
def window(qtbot):
    w = MainWindow("test")
    qtbot.addWidget(w)
    return w


@pytest.mark.slow
def test_import_dialog_with_a_level_per_file_opens_the_session_on_the_identify_tab(window, qtbot, tmp_path):
    files = [controller_file(tmp_path / "low.uff"), controller_file(tmp_path / "high.uff")]
    dialog = window.import_dialog()
    dialog.add_files(files)
    dialog.dof_map.setPlainText("1+Z=x1\n2+Z=x2")
    with qtbot.waitSignal(window.lab.error, timeout=30000) as blocker:      # no level given: refused
        dialog._accept()
    assert "low.uff: record 1: force: the file does not say the force level" in blocker.args[0]
    assert not (tmp_path / "low.h5").exists()
    dialog = window.import_dialog()                     # as it was left, to correct
    assert dialog.files.rowCount() == 2 and dialog.output.text() == str(tmp_path / "low.h5")
    dialog.files.item(0, 1).setText("fast")
    dialog._accept()
    assert dialog.isVisible() and "force 'fast' is not a number" in dialog.message.text()
    dialog.files.item(0, 1).setText("0.2")
    dialog.files.item(1, 1).setText("0.8")
    dialog.dof_map.setPlainText("1+Z=x1\n2+Z=x2")
    dialog.grab().save(str(tmp_path / "import_dialog.png"))
    with qtbot.waitSignal(window.lab.sessionChanged, timeout=30000):
        dialog._accept()
    qtbot.waitUntil(lambda: window.lab.session_path == str(tmp_path / "low.h5"), timeout=30000)
    assert window.tabs.currentWidget() is window.identify
    with open_session(tmp_path / "low.h5") as s:
        assert {s.run(n).force for n in s.run_names()} == {0.2, 0.8}
        assert all(s.run(n).attrs["imported"] for n in s.run_names())


def test_a_bad_file_is_a_message_and_writes_nothing(window, qtbot, tmp_path):
    (tmp_path / "bad.uff").write_text("not a universal file\n")
    dialog = window.import_dialog()
    dialog.add_files([str(tmp_path / "bad.uff")])
    dialog.files.item(0, 1).setText("0.5")
    with qtbot.waitSignal(window.lab.error, timeout=30000) as blocker:
        dialog._accept()
    assert "bad.uff: holds no universal-file dataset" in blocker.args[0]
    assert not (tmp_path / "bad.h5").exists()


def test_the_records_of_one_reference_are_picked_per_file(window, tmp_path):
    """A roving-hammer file: the Records cell is ``--records`` of the command line."""
    dialog = window.import_dialog()
    dialog.add_files([controller_file(tmp_path / "hammer.uff")])
    dialog.files.item(0, 4).setText("1, 2")
    [(_, options)] = dialog.request().sources
    assert options.records == [1, 2]
    dialog.files.item(0, 4).setText("first")
    dialog._accept()
    assert dialog.isVisible() and "--records takes record numbers" in dialog.message.text()


@pytest.mark.slow
def test_a_reversed_force_is_refused_until_the_dialog_says_so(window, qtbot, tmp_path):
    reversed_path = tmp_path / "rev.uff"                # the controller's force sign reversed: every FRF negated
    sets = pyuff.UFF(controller_file(tmp_path / "low.uff")).read_sets()
    for s in sets:
        s["data"] = -s["data"]
    pyuff.UFF(str(reversed_path)).write_sets(sets, mode="add")
    dialog = window.import_dialog()
    dialog.add_files([str(reversed_path)])
    dialog.files.item(0, 1).setText("0.2")
    dialog.dof_map.setPlainText("1+Z=x1\n2+Z=x2")
    with qtbot.waitSignal(window.lab.error, timeout=30000) as blocker:
        dialog._accept()
    assert "give --force-sign -1" in blocker.args[0]
    dialog = window.import_dialog()                     # as it was left: only the flag to add
    dialog.reversed_force.setChecked(True)
    with qtbot.waitSignal(window.lab.sessionChanged, timeout=30000):
        dialog._accept()
    assert (tmp_path / "rev.h5").exists()
