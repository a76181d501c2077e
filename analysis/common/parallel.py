"""Independent pieces of one analysis step computed on the machine's other cores.

A step of the loop does many things that need nothing of each other: discovery fits an element's sets of laws of
one size, each started from the smaller sets, and scores the FRFs of many choices of laws; the ranking fits and
predicts every candidate law; a held-out check refits the model once per fold. :func:`map_tasks` computes such
pieces in forked worker processes, one piece a task, and returns their results in order.

The rules, and why:

- **The same answer with any number of workers.** A task is a function of its index and of what the process held
  when the workers were forked; the results come back in order. What a solver keeps from one call to the next to
  start from is kept per task (:func:`task_scope`), so a task starts from nothing the tasks before it in its
  process left, whichever worker runs it after which tasks, or none. A task must not need what another computes:
  what it leaves in a cache goes with its worker, so a cache may save time, never change a result.
- **Nothing lost to a worker's failure.** A task that raises in a worker, whose result cannot come back, or whose
  worker is gone, is computed again here, where it raises as it would have without workers.
- **A stop is heard, and a dead parent ends its workers.** The caller's stop question (:mod:`.interrupt`) is asked
  here while the workers run, and stops them. A worker dies with the process that forked it (on Linux the kernel
  kills it; elsewhere its numerics ask whether its parent is alive, and a send to a parent that has gone ends it):
  a worker left running would hold the pipes and ports it inherited open, and a session writer waits for the end
  of its input.
- **Results cross a pipe from this process's own children** (Python's serialisation, as ``multiprocessing``
  does); nothing serialised is written to or read from a file.

The number of workers (:func:`worker_count`) is ``CONTACTID_WORKERS`` where the user set it, else the cores this
process may run on, at most :data:`MAX_WORKERS`; 1 (a loop here) where the system cannot fork, inside a worker,
and for a single task. Benchmarks that measure CPU seconds and the test suite's own workers set it to 1.
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import signal
import sys
from contextvars import ContextVar
from multiprocessing.connection import wait
from typing import Callable, TypeVar

from numba.core.compiler_lock import global_compiler_lock

from .errors import InputError
from .interrupt import Interrupted, check_stop, stop_when

T = TypeVar("T")

#: Workers at most: each holds a copy of the process's pages it writes to, and the tasks of one step are few
MAX_WORKERS = 4
#: Seconds between two askings of the caller's stop question while workers run
POLL_S = 0.1
#: Seconds a worker that sent all it had may take to end before it is made to
EXIT_S = 5.0
_PR_SET_PDEATHSIG = 1

_TASK: Callable[[int], object] | None = None   # the task the workers run; set before they are forked
_IN_WORKER = False


class TaskScope:
    """The task of a map that code runs in (:func:`task_scope`); one object per task, dropped when it ends."""

    __slots__ = ("__weakref__",)


#: The scope of code that runs in no task
OUTSIDE = TaskScope()
# the thread's own, as a stop question is (analysis.common.interrupt): another thread's map is not this one's
_SCOPE: ContextVar[TaskScope] = ContextVar("contactid_task", default=OUTSIDE)


def task_scope() -> TaskScope:
    """The task of :func:`map_tasks` the calling thread runs in (:data:`OUTSIDE` in none). What a solver keeps
    from one call to the next to start from (a placed contact's last balance) is kept per task: a task then starts
    from nothing the tasks before it in its process left, so its answer is the same whichever worker runs it after
    which tasks, or none."""
    return _SCOPE.get()


def _in_scope(task: Callable[[int], T], i: int) -> T:
    """``task(i)`` in a task scope of its own."""
    token = _SCOPE.set(TaskScope())
    try:
        return task(i)
    finally:
        _SCOPE.reset(token)


#: What a worker sends back for a task it could not compute or send: the task is computed here instead
_FAILED = None


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the system says, else the machine's)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def worker_count() -> int:
    """Workers :func:`map_tasks` uses (module docstring); a ``CONTACTID_WORKERS`` that is not a whole number is
    an :class:`InputError` naming it."""
    if _IN_WORKER or not hasattr(os, "fork") or sys.platform == "win32":
        return 1
    given = os.environ.get("CONTACTID_WORKERS", "").strip()
    if given:
        try:
            n = int(given)
        except ValueError:
            raise InputError(f"{given!r} is not a whole number of workers", "environment",
                             "CONTACTID_WORKERS") from None
        return max(1, n)
    return max(1, min(MAX_WORKERS, usable_cores()))


def map_tasks(task: Callable[[int], T], n: int, workers: int | None = None) -> list[T]:
    """``[task(0), ..., task(n - 1)]``, computed by up to ``workers`` (default :func:`worker_count`) forked
    workers, in that order, each in a task scope of its own (:func:`task_scope`); a loop here where one worker
    would do. A worker that ends a task takes the next one not yet taken (a counter the workers share): tasks
    differ in cost by x10 and more (a set with a hysteretic law against a spring), and a fixed share of every
    W-th task left one worker idle while the other still had several to do."""
    count = min(worker_count() if workers is None else workers, n)
    if count <= 1 or _IN_WORKER:
        return [_in_scope(task, i) for i in range(n)]
    context = multiprocessing.get_context("fork")
    global _TASK
    links = []
    sent: list = [_FAILED] * n
    done = False
    try:
        # forked while no other thread of this process compiles (a worker that compiled would wait for ever on
        # the compiler's lock, copied held) and none forks its own workers with another task
        with global_compiler_lock:
            _TASK = task
            taken = _Counter(context)
            try:
                for k in range(count):
                    receive, send = context.Pipe(duplex=False)
                    worker = context.Process(target=_work, args=(taken, n, receive, send, os.getpid()),
                                             daemon=True)
                    try:
                        worker.start()
                    except OSError:           # no fork now (memory, processes): its tasks are computed here
                        receive.close()
                        send.close()
                        break
                    send.close()
                    links.append((worker, receive))
            finally:
                _TASK = None
        running = [receive for _, receive in links]
        while running:
            check_stop()                      # raises; the workers are ended below
            for receive in wait(running, POLL_S):
                try:
                    i, out = receive.recv()
                except EOFError:              # the worker is done, or gone: what it did not send is computed here
                    running.remove(receive)
                    continue
                sent[i] = out
        done = True
    finally:
        for worker, receive in links:
            receive.close()
            if done:
                worker.join(EXIT_S)           # it closed its pipe: it is ending by itself
            if worker.is_alive():
                worker.terminate()
            worker.join()
    return [_received(task, i, out) for i, out in enumerate(sent)]


def _received(task: Callable[[int], T], i: int, out) -> T:
    """Task ``i``'s result as its worker sent it, or computed here where none came or it cannot be read."""
    if out is not _FAILED:
        try:
            return pickle.loads(out)
        except Exception:
            pass
    return _in_scope(task, i)


def _work(taken: _Counter, n: int, receive, send, parent: int) -> None:
    """A worker: the next task of ``n`` not yet ``taken`` (a shared counter), computed and sent back, until none
    is left.

    It dies with the process that forked it: on Linux the kernel kills it when its parent goes, else its numerics
    ask whether its parent has changed (:func:`stop_when`), and a send to a parent that has gone ends it; a worker
    blocked in a send, or left running, would keep the pipes and ports it inherited open (a session writer waits
    for the end of its input). The caller's own stop question is not inherited, as it may read objects only the
    caller's threads may touch; an interrupt from the terminal is the caller's to answer, and a request to
    terminate ends the worker at once, whatever handler its parent installed."""
    global _IN_WORKER
    _IN_WORKER = True
    receive.close()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _die_with_parent()
    if os.getppid() != parent:                # gone before the kernel was asked
        return
    stop_when(lambda: os.getppid() != parent)
    while True:
        i = _next_task(taken)
        if i is None or i >= n:
            break
        try:
            out = pickle.dumps(_in_scope(_TASK, i), protocol=pickle.HIGHEST_PROTOCOL)
        except Interrupted:
            return
        except Exception:                     # computed again by the caller, where it raises as it would have
            out = _FAILED
        try:
            send.send((i, out))
        except OSError:                       # the caller has gone
            return
    send.close()


class _Counter:
    """The index of the next task no worker has taken, shared by the workers forked after it was made."""

    def __init__(self, context):
        self.lock = context.Lock()
        self.value = context.RawValue("q", 0)


def _next_task(taken: _Counter) -> int | None:
    """The next task's index from the shared counter, or None where its lock is not had in :data:`EXIT_S`: a
    worker killed while holding it (microseconds) would leave the others waiting for ever, and the parent with
    them; so they end instead, and the caller computes what no worker sent."""
    if not taken.lock.acquire(timeout=EXIT_S):
        return None
    try:
        i = taken.value.value
        taken.value.value = i + 1
        return i
    finally:
        taken.lock.release()


def _die_with_parent() -> None:
    """Ask the kernel to kill this process when its parent ends (Linux ``PR_SET_PDEATHSIG``); nothing elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
