"""Stop inside a long computation (analysis.common.interrupt): heard at a fit's next evaluation and a prediction's
next line, only in the thread that asked, and the automatic loop undoes the step under way and keeps the rest."""
import threading

import numpy as np
import pytest

from analysis.common.interrupt import Interrupted, check_stop, stoppable
from analysis.fitting.fit import fit_laws
from analysis.laws import get_law
from analysis.loop.auto import STOPPED_BY_USER, run_auto
from test_auto import laws_of, rk4_joint, started  # noqa: F401  (rk4_joint: the fixture)
from test_hidden_effects import element


class Countdown:
    """A stop that answers True from its ``after``-th question on, counting every question."""

    def __init__(self, after: int):
        self.after, self.asked = after, 0

    def __call__(self) -> bool:
        self.asked += 1
        return self.asked >= self.after


def test_no_question_no_stop_and_a_yes_raises():
    check_stop()                                    # outside stoppable: nothing to ask
    with stoppable(lambda: False):
        check_stop()
    with stoppable(lambda: True), pytest.raises(Interrupted):
        check_stop()
    check_stop()                                    # the question is gone with its block


def test_a_stop_is_heard_only_in_the_thread_that_asked():
    heard = []

    def other():
        check_stop()                                # another thread's computation runs on
        heard.append("ran")
    with stoppable(lambda: True):
        t = threading.Thread(target=other)
        t.start()
        t.join()
    assert heard == ["ran"]


def cubic_samples():
    X = np.geomspace(1e-4, 1e-2, 40)
    w = np.full(X.shape, 60.0)
    kbar = get_law("cubic").describing_function(X, w, k3=2e6) + 1j * 5.0
    return X, w, kbar, np.full(X.shape, 1.0)


def test_a_fit_stops_at_its_next_evaluation():
    X, w, kbar, std = cubic_samples()
    fit_laws(["cubic"], X, w, kbar, std)            # runs to its end without a question
    stop = Countdown(after=3)
    with stoppable(stop), pytest.raises(Interrupted):
        fit_laws(["cubic", "tanh_softening"], X, w, kbar, std)
    assert stop.asked == 3                          # no evaluation after the stop was heard


@pytest.mark.slow
def test_stop_inside_discovery_leaves_the_model_as_started(rk4_joint):  # noqa: F811
    wb = started(rk4_joint, element("a", "x1", ""))
    asked = Countdown(after=10 ** 9)
    discover = wb.discover

    def discover_then_stop(*args, **kwargs):        # Stop pressed as discovery starts
        asked.after = asked.asked + 1
        return discover(*args, **kwargs)
    wb.discover = discover_then_stop
    result = run_auto(wb, stop=asked)
    assert asked.asked == asked.after               # heard at its first question: discovery's first fit
    assert result.stopped == STOPPED_BY_USER and result.undone == "discovery" and result.steps == []
    assert len(wb.history) == 1 and laws_of(wb) == {"a": []}
    assert "stopped: stopped by the user during discovery, which was undone" in result.text()
    assert result.to_json()["undone"] == "discovery"


@pytest.mark.slow
def test_stop_inside_a_fit_undoes_that_step_and_keeps_the_model_as_it_was(rk4_joint):  # noqa: F811
    wb = started(rk4_joint, element("a", "x1", ""))
    asked = Countdown(after=10 ** 9)
    add_laws = wb.add_laws

    def add_laws_then_stop(*args, **kwargs):        # Stop pressed as the first law found is being fitted
        asked.after = asked.asked + 1
        return add_laws(*args, **kwargs)
    wb.add_laws = add_laws_then_stop
    start = wb.history[-1].model_toml
    result = run_auto(wb, stop=asked)
    assert result.stopped == STOPPED_BY_USER and result.steps == []
    assert result.undone.startswith("the fit of a:") and result.undone.endswith("found by discovery")
    assert result.discovery is not None and result.discovery.elements[0].laws
    # the laws the fit had added are gone, the values are the start's, nothing was recorded
    assert laws_of(wb) == {"a": []} and len(wb.history) == 1 and wb.model.to_toml() == start
