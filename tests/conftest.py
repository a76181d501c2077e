import gc
import os
import signal

import pytest

# GUI tests run without a display.
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# The tests' matrices are small and the suite runs beside emulator and writer processes on two cores:
# threaded BLAS there spends more time waiting than computing (a 1000 x 201 SVD, 5.5 s against 0.4 s).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The suite's own workers take the cores: an analysis step computes its pieces in one process
# (tests/test_parallel.py forks workers where that is what it tests).
os.environ.setdefault("CONTACTID_WORKERS", "1")

# Each worker holds its own interpreter, numba kernels and Qt (about 300 MB): past four the memory grows
# faster than the suite shrinks (module fixtures are built once per worker that runs their tests).
_MAX_WORKERS = 4


def pytest_xdist_auto_num_workers(config):
    return max(1, min(_MAX_WORKERS, os.cpu_count() or 1))


def pytest_configure(config):
    """Compile the rig simulator's kernels once, in the controller before its workers start: each worker then
    loads them from numba's cache. Otherwise every worker compiles the same kernels at once on a fresh clone
    (about 40 s of CPU alone, 70-75 s each when two compile side by side on two cores)."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    from drivers.simulation.simulator import RigSimulator

    RigSimulator("paper-2dof", seed=0).advance(64)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """An acceptance case is slow too, so that the fast set (``-m "not slow"``), whose ``-m`` replaces the
    configuration's, leaves it out as README's test command does."""
    for item in items:
        if item.get_closest_marker("acceptance"):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def _qt_garbage_in_the_main_thread(request):
    """After a test that made Qt objects, collect its cyclic garbage here, in the GUI thread.

    Closing the last window turns automatic collection back on (app/gui/gc_guard.py); the window's Python
    wrappers become garbage only afterwards. Left to chance, a later allocation in an emulator or worker thread
    would run their Qt destructors there, which can crash or deadlock the worker."""
    yield
    if "qtbot" in request.fixturenames:
        gc.collect()


@pytest.fixture
def ctrl_c():
    """SIGINT as a user's shell delivers it (KeyboardInterrupt): a test run started in the background has it
    ignored."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)
