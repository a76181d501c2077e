"""Long work off the GUI thread: a one-at-a-time task runner and the campaign thread.

Results and errors come back to the GUI thread through queued Qt signals; nothing here touches a widget.
"""
from __future__ import annotations

import logging
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

from PySide6.QtCore import QObject, Qt, QThread, Signal

from analysis.common.errors import InputError
from drivers import InstrumentError

from app.campaign import Campaign, CampaignListener, Instruments, Plan, run_plan
from app.session import SessionWriteError

log = logging.getLogger("contactid.gui")


def describe_error(exc: BaseException) -> str:
    """One line for the operator: input and instrument errors speak for themselves, anything else is named
    by its type (the traceback goes to the log)."""
    if isinstance(exc, (InputError, InstrumentError, SessionWriteError)):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


class TaskRunner(QObject):
    """Run callables one after another on a worker thread.

    ``on_done(result)`` or ``on_error(message)`` is called in the GUI thread; without ``on_error`` the
    message is emitted as ``failed``. Tasks on one runner never overlap, so objects only they touch (e.g. the
    model workbench) need no lock.
    """

    busyChanged = Signal(bool)
    failed = Signal(str)
    _completed = Signal(object, object, object)     # future, on_done, on_error

    def __init__(self, name: str, parent: QObject | None = None):
        super().__init__(parent)
        self.name = name
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"contactid-{name}")
        self._pending = 0
        self._completed.connect(self._deliver, Qt.ConnectionType.QueuedConnection)

    @property
    def busy(self) -> bool:
        return self._pending > 0

    def submit(self, task: Callable[[], object], on_done: Callable[[object], None] | None = None,
               on_error: Callable[[str], None] | None = None) -> Future:
        future = self._executor.submit(task)
        self._pending += 1
        if self._pending == 1:
            self.busyChanged.emit(True)
        future.add_done_callback(lambda f: self._completed.emit(f, on_done, on_error))
        return future

    def _deliver(self, future: Future, on_done, on_error) -> None:
        self._pending -= 1
        if self._pending == 0:
            self.busyChanged.emit(False)
        if future.cancelled():
            return
        exc = future.exception()
        if exc is None:
            if on_done is not None:
                on_done(future.result())
            return
        if not isinstance(exc, (InputError, InstrumentError)):
            log.error("%s task failed", self.name, exc_info=exc)
        message = describe_error(exc)
        if on_error is not None:
            on_error(message)
        else:
            self.failed.emit(message)

    def shutdown(self) -> None:
        """Drop queued tasks and wait for the running one (window closing)."""
        self._executor.shutdown(wait=True, cancel_futures=True)


class CampaignThread(QThread):
    """Runs :func:`app.campaign.measure.run_plan` and lets the GUI pause, resume and abort it.

    An abort asked for before the campaign object exists is applied the moment it does, so the output is
    never switched on after the operator pressed Abort.
    """

    finishedWith = Signal(object)     # CampaignSummary
    failedWith = Signal(str)

    def __init__(self, plan: Plan, instruments: Instruments, output: str, listener: CampaignListener,
                 software_version: str, parent: QObject | None = None):
        super().__init__(parent)
        self.plan = plan
        self.instruments = instruments
        self.output = output
        self.listener = listener
        self.software_version = software_version
        self._lock = threading.Lock()
        self._campaign: Campaign | None = None
        self._abort_reason: str | None = None

    def run(self) -> None:
        try:
            summary = run_plan(self.plan, self.instruments, self.output, command="contactid gui",
                               software_version=self.software_version, listener=self.listener,
                               on_campaign=self._attach)
        except Exception as exc:          # reported in the window; the guard has switched the output off
            if not isinstance(exc, (InputError, InstrumentError, SessionWriteError)):
                log.error("campaign failed", exc_info=exc)
            self.failedWith.emit(describe_error(exc))
            return
        self.finishedWith.emit(summary)

    def _attach(self, campaign: Campaign) -> None:
        with self._lock:
            self._campaign = campaign
            if self._abort_reason is not None:
                campaign.abort(self._abort_reason)

    def abort(self, reason: str) -> None:
        """Output off now; the run in progress ends as aborted (its lines are kept)."""
        with self._lock:
            self._abort_reason = reason
            campaign = self._campaign
        if campaign is not None:
            campaign.abort(reason)

    def pause(self) -> None:
        with self._lock:
            if self._campaign is not None:
                self._campaign.pause()

    def resume(self) -> None:
        with self._lock:
            if self._campaign is not None:
                self._campaign.resume()

    @property
    def paused(self) -> bool:
        with self._lock:
            return self._campaign is not None and self._campaign.paused
