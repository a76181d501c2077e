"""paper-2dof served over TCP from a thread of this process, and one fixed-count acquisition on it checked for what
a repeated acquisition must keep: every line complete and within the control tolerance, the force never above its
target. Shared by tests/test_campaign_integrity.py and benchmarks/fixed_count_settling.py (which counts how often
an acquisition fails over many)."""
from __future__ import annotations

import threading
import tomllib
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from app.campaign.engine import CampaignListener
from app.campaign.instruments import real_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from app.session.writer import open_session
from drivers.serve import serve_emulator
from drivers.simulation.rig import load_rig
from drivers.simulation.simulator import RigSimulator

FIVE_LINES = "[[stepped_sine]]\nforce = 0.8\nstart = 1.0\nstop = 3.0\nstep = 0.5\nrefine = false\n" \
             "[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n"
FIXED_COUNT = FIVE_LINES.replace("[limits]", "[settle]\nfixed_periods = 10\n[limits]")


@contextmanager
def served_paper_2dof():
    """paper-2dof served over TCP (fast) from a thread of this process: {"shaker": url, "daq": url}."""
    urls, stop = {}, threading.Event()
    announced = threading.Event()

    def announce(line):
        role, url = line.split(": ")
        urls[role] = url
        announced.set() if len(urls) == 2 else None

    thread = threading.Thread(target=serve_emulator, args=(RigSimulator(load_rig("paper-2dof")),),
                              kwargs={"transport": "tcp", "port": 0, "fast": True, "announce": announce,
                                      "stop": stop}, daemon=True)
    thread.start()
    try:
        if not announced.wait(60):
            raise RuntimeError("the served emulator did not announce its URLs within 60 s")
        yield urls
    finally:
        stop.set()
        thread.join(10)


class ForcePeaks(CampaignListener):
    """The largest force each run's blocks held, N."""

    def __init__(self):
        self.peak = {}
        self.run = None

    def run_started(self, name, spec):
        self.run = name

    def block(self, block):
        self.peak[self.run] = max(self.peak.get(self.run, 0.0), float(np.abs(block.data[:, 0]).max()))


def fixed_count_acquisition(urls, path: Path) -> list[str]:
    """One acquisition of FIXED_COUNT (`[settle] fixed_periods = 10`, five lines at 0.8 N, driven at x2) on the
    served rig at ``urls``, written to ``path``; what it got wrong (empty: nothing)."""
    peaks = ForcePeaks()
    with real_instruments(urls["shaker"], urls["daq"], "x2") as inst:
        summary = run_plan(parse_plan(tomllib.loads(FIXED_COUNT), FIXED_COUNT, "plan.toml"), inst, path,
                           listener=peaks)
    problems = []
    if not summary.complete:
        problems.append(f"incomplete: {summary.text()}")
    if peaks.peak.get("sine_0.8N_up", 0.0) > 0.8 * 1.01:
        problems.append(f"force peak {peaks.peak} above the 0.8 N target")
    if summary.complete:
        with open_session(path) as s:
            force = s.run("sine_0.8N_up").arrays["force_amplitude"]
        if len(force) != 5 or not np.allclose(force, 0.8, rtol=0.01):
            problems.append(f"lines held {force} N, not 5 lines at 0.8 N within 1 %")
    return problems
