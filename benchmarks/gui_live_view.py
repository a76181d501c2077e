"""Frame rate and CPU cost of the lab window's live view while the emulated DAQ streams 4 channels at 25.6 kS/s
in real time.

The rig (written to a temporary folder): a 3-DOF lumped chain (modes 22.4, 62.8 and 90.7 Hz) with a hardening
cubic joint, driven at x3 by an ideal force source, a force gauge and three accelerometers sampled at 25 600 Hz
(the emulator integrates at 4 x 25 600 Hz and runs paced, i.e. in real time). A stepped-sine campaign sweeps the
first mode through the window's widgets with the Acquire tab shown (offscreen): time signals of the four
channels, FRF magnitude and phase, force, THD and settling plots all live.

Measured over ``--seconds`` of streaming:

- frames per second: paints of the live view that showed new samples (the target is 30, the frame clock's
  cap), next to the clock's ticks and the ticks that found new samples (the campaign hands the window the
  blocks it reads; while it sets up a line it reads none);
- acquisition: samples received per second (25 600 when nothing is lost) and samples lost in gaps (the DAQ
  numbers its frames, so every lost frame is counted);
- CPU: the process's share of one core, the GUI thread's alone, and the same campaign without a window (the
  campaign thread and the emulator), whose difference is what the live view costs.

Usage: ``python benchmarks/gui_live_view.py [--seconds S]`` (default 20).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from PySide6.QtCore import QEvent, QObject, QTimer  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

from app.campaign.engine import CampaignListener  # noqa: E402
from app.gui.main_window import MainWindow  # noqa: E402
from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import parse_plan  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402

RIG = """
name = "chain-25k"
[structure]
type = "lumped"
dofs = ["x1", "x2", "x3"]
mass = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
stiffness = [[2.0e5, -1.0e5, 0.0], [-1.0e5, 2.0e5, -1.0e5], [0.0, -1.0e5, 1.0e5]]
rayleigh = [20.0, 1.0e-4]

[[element]]
name = "joint"
dof = "x1"
laws = [ { law = "cubic", k3 = 1.0e9 } ]

[excitation]
dof = "x3"

[sensors]
dofs = ["x1", "x2", "x3"]

[daq]
sample_rate = 25600.0
force_range = 50.0
acceleration_range = 500.0
"""
LEVEL = {"force": 1.0, "start": 18.0, "stop": 28.0, "step": 0.1, "direction": "up", "refine": False}
SAMPLE_RATE = 25600.0


class PaintCounter(QObject):
    """Counts the paints of a widget that put new data on screen (one per frame, however many repaints)."""

    def __init__(self, widget):
        super().__init__()
        self.frames = 0
        self._fresh = False
        widget.installEventFilter(self)

    def mark(self) -> None:
        self._fresh = True

    def eventFilter(self, watched, event) -> bool:  # noqa: N802 (Qt API)
        if event.type() == QEvent.Type.Paint and self._fresh:
            self._fresh = False
            self.frames += 1
        return False


def run_loop(app: QApplication, seconds: float) -> None:
    QTimer.singleShot(int(seconds * 1000), app.quit)
    app.exec()


def wait_for(app: QApplication, predicate, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("the window did not get there in time")
        app.processEvents()
        time.sleep(0.005)


def with_window(rig_path: Path, output: Path, seconds: float) -> dict:
    app = QApplication.instance() or QApplication([])
    window = MainWindow("benchmark")
    window.resize(1500, 950)
    window.show()
    window.tabs.setCurrentWidget(window.acquire)
    lab, live = window.lab, window.acquire.live
    lab.connect_simulated(str(rig_path), paced=True)
    wait_for(app, lambda: lab.connected, 60)
    window.acquire.editor.random.setChecked(False)
    window.acquire.editor.set_levels([LEVEL])
    lab.arm()
    lab.start_campaign(str(output))
    wait_for(app, lambda: lab.feed is not None and lab.feed.ring.end > 0, 30)

    counter = PaintCounter(live.viewport())
    ring = lab.feed.ring
    last_end = [ring.end]
    ticks = [0, 0]                    # clock ticks, ticks that found new samples

    def new_samples_drawn():          # connected after the live plots' own redraws: runs after them
        ticks[0] += 1
        if ring.end != last_end[0]:
            last_end[0] = ring.end
            ticks[1] += 1
            counter.mark()
    window.clock.tick.connect(new_samples_drawn)

    health0 = ring.health()
    wall0, cpu0, gui0 = time.perf_counter(), time.process_time(), time.thread_time()
    run_loop(app, seconds)
    wall = time.perf_counter() - wall0
    cpu, gui = time.process_time() - cpu0, time.thread_time() - gui0
    health = ring.health()
    lines = lab.live.lines
    lab.abort("benchmark over")
    wait_for(app, lambda: not lab.campaign_running, 60)
    window.close()
    return {"fps": counter.frames / wall, "ticks": ticks[0] / wall, "fresh": ticks[1] / wall,
            "rate": (health.samples - health0.samples) / wall,
            "lost": health.lost_samples, "gaps": health.gaps, "cpu": cpu / wall, "gui": gui / wall,
            "lines": lines, "wall": wall}


class BlockCounter(CampaignListener):
    def __init__(self):
        self.samples = 0
        self.lost = 0

    def block(self, block):
        self.samples += len(block)
        self.lost += block.lost_samples


def without_window(rig_path: Path, output: Path, seconds: float) -> dict:
    """The same campaign with no window: the acquisition's own CPU share."""
    counter = BlockCounter()
    campaign = []
    with emulated_instruments(load_rig(rig_path), paced=True) as instruments:
        plan = parse_plan({"stepped_sine": [LEVEL], "limits": {"max_force": 10.0, "max_acceleration": 400.0}})
        thread = threading.Thread(target=run_plan, args=(plan, instruments, output),
                                  kwargs={"listener": counter, "on_campaign": campaign.append})
        thread.start()
        while not counter.samples:
            time.sleep(0.01)
        samples0 = counter.samples
        wall0, cpu0 = time.perf_counter(), time.process_time()
        time.sleep(seconds)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        rate = (counter.samples - samples0) / wall
        campaign[0].abort("benchmark over")
        thread.join()
    return {"cpu": cpu / wall, "rate": rate, "lost": counter.lost}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="streaming time measured (default 20 s)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        rig_path = Path(tmp) / "chain-25k.toml"
        rig_path.write_text(RIG, encoding="utf-8")
        base = without_window(rig_path, Path(tmp) / "base.h5", args.seconds)
        gui = with_window(rig_path, Path(tmp) / "gui.h5", args.seconds)
    print(f"streaming 4 channels at {SAMPLE_RATE:g} Hz for {gui['wall']:.1f} s, {gui['lines']} lines measured, "
          f"{os.cpu_count()} cores")
    print(f"live view: {gui['fps']:.1f} frames/s painted (target 30: ratio {gui['fps'] / 30:.2f}); frame clock "
          f"{gui['ticks']:.1f} ticks/s, {gui['fresh']:.1f} of them with new samples")
    print(f"acquisition with the window: {gui['rate']:.0f} samples/s per channel, {gui['lost']} lost "
          f"in {gui['gaps']} gaps")
    print(f"acquisition without a window: {base['rate']:.0f} samples/s per channel, {base['lost']} lost")
    print(f"CPU (share of one core): process {100 * gui['cpu']:.0f} % with the window "
          f"(GUI thread {100 * gui['gui']:.0f} %), {100 * base['cpu']:.0f} % without; "
          f"the live view costs {100 * (gui['cpu'] - base['cpu']):.0f} %")


if __name__ == "__main__":
    main()
