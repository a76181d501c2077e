"""analysis.common.parallel: the same answer with any number of workers, nothing lost to a worker's failure, a
stop heard, and no worker outliving the process that forked it."""
import os
import subprocess
import sys
import multiprocessing
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from analysis.common import parallel
from analysis.common.errors import InputError
from analysis.common.interrupt import Interrupted, stoppable
from analysis.common.parallel import map_tasks, worker_count

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="forked workers need fork")


def test_the_results_come_in_order_and_equal_to_a_loop_here():
    data = np.random.default_rng(3).normal(size=(9, 40, 40))    # read by the workers from what they were forked with

    def task(i):
        return np.linalg.svd(data[i])[1], os.getpid()

    serial = map_tasks(task, len(data), workers=1)
    forked = map_tasks(task, len(data), workers=2)
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(serial, forked))
    assert {pid for _, pid in serial} == {os.getpid()}
    assert os.getpid() not in {pid for _, pid in forked}      # the work was done elsewhere


def test_a_worker_that_ends_its_task_takes_the_next_one_not_taken(tmp_path):
    # task 0 lasts until the last task is done: every other task is then the other worker's, where a fixed share
    # of every second task would have left tasks 2, 4, ... waiting behind task 0
    done = tmp_path / "last done"

    def task(i):
        if i == 0:
            deadline = time.monotonic() + 60
            while not done.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
        elif i == 9:
            done.touch()
        return os.getpid()

    pids = map_tasks(task, 10, workers=2)
    assert pids[0] not in pids[1:] and len(set(pids[1:])) == 1


def test_a_worker_that_cannot_have_the_counter_ends_and_its_tasks_are_computed_here(monkeypatch):
    monkeypatch.setattr(parallel, "EXIT_S", 0.2)
    held = parallel._Counter(multiprocessing.get_context("fork"))
    held.lock.acquire()                    # as a worker killed while taking a task leaves it
    assert parallel._next_task(held) is None
    held.lock.release()
    assert parallel._next_task(held) == 0 and parallel._next_task(held) == 1


def test_a_task_that_raises_in_a_worker_raises_here_as_it_would_have():
    def task(i):
        if i == 2:
            raise InputError("no such law", "model.toml", "element[1].laws[0]")
        return i

    with pytest.raises(InputError, match=r"model.toml: element\[1\].laws\[0\]: no such law"):
        map_tasks(task, 4, workers=2)


def test_a_result_that_cannot_come_back_is_computed_here():
    pids = []

    def task(i):
        pids.append(os.getpid())
        return (lambda: i) if i % 2 else i                # a closure cannot cross the pipe

    out = map_tasks(task, 4, workers=2)
    assert [out[0], out[1](), out[2], out[3]()] == [0, 1, 2, 3]
    assert pids == [os.getpid(), os.getpid()]              # only the two that could not come back, here


def test_a_stop_asked_while_workers_run_stops_them():
    asked = time.monotonic() + 0.5

    def task(i):
        time.sleep(30)
        return i

    start = time.monotonic()
    with stoppable(lambda: time.monotonic() > asked), pytest.raises(Interrupted):
        map_tasks(task, 2, workers=2)
    assert time.monotonic() - start < 20                    # not the tasks' 30 s
    assert multiprocessing.active_children() == []


def test_inside_a_worker_a_map_is_a_loop():
    def task(i):
        return worker_count(), map_tasks(lambda j: os.getpid(), 3)

    for count, pids in map_tasks(task, 2, workers=2):
        assert count == 1 and len(set(pids)) == 1


def test_the_number_of_workers_is_read_from_the_environment(monkeypatch):
    monkeypatch.setenv("CONTACTID_WORKERS", "3")
    assert worker_count() == 3
    monkeypatch.setenv("CONTACTID_WORKERS", "0")
    assert worker_count() == 1
    monkeypatch.delenv("CONTACTID_WORKERS")
    assert 1 <= worker_count() <= parallel.MAX_WORKERS
    monkeypatch.setenv("CONTACTID_WORKERS", "two")
    with pytest.raises(InputError, match="CONTACTID_WORKERS: 'two' is not a whole number of workers"):
        worker_count()


def test_workers_end_when_the_process_that_forked_them_is_killed(tmp_path):
    """A worker's numerics ask whether its parent is alive: killed, it leaves no worker computing on."""
    _assert_workers_end_with_their_parent(tmp_path, """
        from analysis.common.interrupt import check_stop

        def task(i):
            mark_worker()
            while True:                # a long fit: its residual asks between evaluations
                time.sleep(0.01)
                check_stop()
    """)


def test_workers_blocked_sending_to_a_killed_parent_end_with_it(tmp_path):
    """A worker whose result fills the pipe waits in its send for a parent that reads no more: killed, the parent
    takes its workers with it, which would otherwise hold every pipe and port they inherited open."""
    _assert_workers_end_with_their_parent(tmp_path, """
        parallel.wait = lambda *args, **kwargs: time.sleep(3600)      # the parent never reads

        def task(i):
            mark_worker()
            return bytes(4 << 20)                                      # more than a pipe holds
    """)


def _assert_workers_end_with_their_parent(tmp_path: Path, tasks: str) -> None:
    """Run ``map_tasks(task, 2, workers=2)`` in a process of its own, ``task`` defined by ``tasks`` (which call
    ``mark_worker()`` first); once both workers have begun (and half a second more), kill that process: both
    workers must be gone within 10 s."""
    script = textwrap.dedent(f"""
        import os, sys, time
        sys.path.insert(0, {str(ROOT)!r})
        from analysis.common import parallel

        def mark_worker():
            with open(os.path.join({str(tmp_path)!r}, f"worker{{os.getpid()}}"), "w") as f:
                f.write(str(os.getpid()))
    """) + textwrap.dedent(tasks) + "\nparallel.map_tasks(task, 2, workers=2)\n"
    parent = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 60
        while len(list(tmp_path.glob("worker*"))) < 2:
            assert time.monotonic() < deadline and parent.poll() is None
            time.sleep(0.05)
        time.sleep(0.5)
        pids = [int(p.read_text()) for p in tmp_path.glob("worker*")]
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 10
    while any(_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(pid) for pid in pids)


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, ended and not yet reaped by init, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.slow
def test_discovery_the_ranking_and_the_held_out_check_answer_alike_with_two_workers(monkeypatch):
    """The loop's steps whose pieces are forked: every number the same as computed in one process."""
    from dataclasses import replace

    from test_nonparametric import library_force, measured, started

    from analysis.loop.cross_check import held_out
    from analysis.search.discovery import DiscoveryRules

    data = measured(library_force)

    def answers():
        empty = started([], data)
        empty.start()
        found = empty.discover(replace(DiscoveryRules(), max_laws=1))
        wb = started(["cubic"], data)
        wb.fit()
        ranked = wb.candidates()
        return ([(e.element, e.laws, [(s.laws, s.error, s.taken) for s in e.walk]) for e in found.elements],
                [(c.element, c.law, c.error, c.evidence, c.significant) for c in ranked], held_out(wb))

    monkeypatch.setenv("CONTACTID_WORKERS", "1")
    alone = answers()
    monkeypatch.setenv("CONTACTID_WORKERS", "2")
    assert answers() == alone
    assert alone[0][0][1] == ("quadratic_damping",) and len(alone[1]) > 5


def test_the_tasks_of_a_worker_that_is_gone_are_computed_here():
    parent = os.getpid()

    def task(i):
        if i == 1 and os.getpid() != parent:
            os.kill(os.getpid(), 9)                          # the worker dies with its task unsent
        return i * i

    assert map_tasks(task, 5, workers=2) == [0, 1, 4, 9, 16]


def test_a_law_of_the_library_comes_back_from_a_worker_as_itself():
    from analysis.laws import LAWS
    from analysis.laws.iwan import MicroSlip

    laws = [law for name, law in LAWS.items()] + [law.relative() for law in LAWS.values()]
    back = map_tasks(lambda i: laws[i] if i < len(laws) else MicroSlip(0.01, True), len(laws) + 1, workers=2)
    assert all(a is b for a, b in zip(laws, back))
    assert isinstance(back[-1], MicroSlip) and back[-1].__dict__ == MicroSlip(0.01, True).__dict__


def test_a_placed_balance_starts_from_what_its_own_task_solved_so_any_number_of_workers_gives_the_same_bits():
    """A placed contact's balance starts from the last one solved at the same samples (a fit's evaluations differ
    by a step): kept per task, a task's answer does not depend on the tasks its process ran before it."""
    from analysis.laws import LAWS
    from analysis.mechanics.structures import Structure
    from analysis.mechanics.surroundings import placed_kbar, surroundings_of

    around = surroundings_of(Structure(["x"], np.eye(1), np.eye(1) * 1e4, np.eye(1) * 2.0), np.ones(1))
    X, w = np.geomspace(1e-4, 3e-3, 12), np.full(12, 95.0)
    contact = LAWS["unilateral"]
    values = [{"k": 2e3 * (1 + 0.3 * i), "gap": 5e-4} for i in range(4)]

    def task(i):
        return placed_kbar([(contact, values[i])], X, w, around)

    alone = map_tasks(task, 4, workers=1)
    assert all(np.array_equal(a, b) for a, b in zip(alone, map_tasks(task, 4, workers=2)))
    assert all(np.array_equal(a, b) for a, b in zip(alone[::-1], map_tasks(lambda i: task(3 - i), 4, workers=1)))


def test_a_task_scope_is_its_own_threads():
    """Another thread's code runs in no task while a map's task runs here (a GUI thread predicting beside the
    analysis): what it solves starts from what it solved itself."""
    import threading

    from analysis.common.parallel import OUTSIDE, task_scope

    def task(i):
        seen = []
        other = threading.Thread(target=lambda: seen.append(task_scope()))
        other.start()
        other.join()
        return task_scope() is not OUTSIDE, seen[0] is OUTSIDE

    assert map_tasks(task, 2, workers=1) == [(True, True), (True, True)]
    assert task_scope() is OUTSIDE
