"""Only the GUI thread collects garbage while a lab window is open (a collection in a worker thread that
destroys Qt objects deadlocks against the GUI thread)."""
import gc
import threading

import pytest

from app.gui.main_window import MainWindow


@pytest.mark.slow
def test_collection_is_left_to_the_gui_thread_while_a_window_is_open(qtbot):
    assert gc.isenabled()
    window = MainWindow()
    qtbot.addWidget(window)
    assert not gc.isenabled()

    class Cycle:
        pass

    def make_garbage():
        for _ in range(2000):          # cyclic garbage made in a worker: it must not be collected there
            a, b = Cycle(), Cycle()
            a.other, b.other = b, a

    worker = threading.Thread(target=make_garbage)
    worker.start()
    worker.join()
    assert gc.get_count()[0] > 0
    qtbot.waitUntil(lambda: gc.get_count()[0] < 700, timeout=5000)   # the GUI thread's timer collected
    window.close()
    assert gc.isenabled()
