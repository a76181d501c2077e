"""Garbage collection in the GUI thread only.

Python's cyclic garbage collector runs in whichever thread happens to allocate when a generation fills up. If
that is a worker thread (an analysis, a campaign) and the garbage holds Qt objects of the GUI thread, their C++
destructors run in the worker while the GUI thread may hold a Qt lock the destructor needs: the process
deadlocks. While a lab window is open, automatic collection is off and the GUI thread collects on a timer
(pyqtgraph's ``GarbageCollector``); closing the last window turns automatic collection back on.
"""
from __future__ import annotations

import gc

from pyqtgraph.util.garbage_collector import GarbageCollector

INTERVAL = 0.5
"""s between the GUI thread's collections."""

_collector: GarbageCollector | None = None
_windows = 0


def acquire() -> None:
    """A window opened: from now on only the GUI thread collects."""
    global _collector, _windows
    if _windows == 0:
        _collector = GarbageCollector(interval=INTERVAL)
    _windows += 1


def release() -> None:
    """A window closed: after the last one, automatic collection again."""
    global _collector, _windows
    if _windows == 0:
        return
    _windows -= 1
    if _windows == 0 and _collector is not None:
        _collector.timer.stop()
        _collector = None
        gc.collect()              # what the windows left, collected here before any other thread may
        gc.enable()
