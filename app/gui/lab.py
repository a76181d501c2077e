"""The window's state and actions: instruments, plan and arming, the campaign, the session, the model and the
analysis. The tabs are views of one :class:`Lab`; it calls the application layer (app/, drivers/ through
app.campaign.instruments) and never computes anything itself.

Threads: everything here runs in the GUI thread except the campaign thread and the tasks handed to three
runners -- instruments (connecting, probing ports, polling the output state), analysis (live identification,
analyze / add / undo, the level reference; the workbench lives on that thread only) and files (exports,
imports, the session's measured backbones: work that only reads or writes files). A result computed for a
session or model that has since been replaced is dropped, not shown.
"""
from __future__ import annotations

import logging
import threading
import tomllib
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtCore import QObject, QTimer, Signal

from analysis.loop.auto import run_auto
from analysis.common.errors import InputError
from analysis.linear.level_reference import LevelReference, reference_from_level
from analysis.mechanics.model import FittedOn, Model, load_model
from analysis.prediction.held_out import predict_session
from analysis.common.tables import load_toml
from analysis.loop.workbench import Workbench
from drivers import InstrumentError
from drivers.discovery import find_instruments
from drivers.simulation.rig import Rig, load_rig

from app.analyze import read_measurements
from app.campaign import (CampaignSummary, Instruments, Plan, check_against_instruments, emulated_instruments,
                          parse_plan, real_instruments)
from app.export import export_csv, export_uff
from app.predict import fitted_on, prediction_text, session_created
from app.session import Session, atomic_output, measurements_from_session, open_session
from ..importers.store import ImportRequest, ImportResult, import_files
from .live import CampaignFeed, LinkCounters, LiveSession, SignalRing
from .plan_doc import plan_toml
from .results import (AnalysisView, BackboneView, IdentificationView, PredictionView, analysis_view,
                      identification_of, identification_view, measured_backbones)
from .workers import CampaignThread, TaskRunner

log = logging.getLogger("contactid.gui")


def save_text(path, text: str) -> None:
    """Write a text file the operator chose in a save dialog (which asked before replacing one), all at once:
    an error leaves the old file as it was."""
    with atomic_output(path, overwrite=True, field=None) as temp:
        temp.write_text(text, encoding="utf-8")

IDENTIFY_INTERVAL_MS = 1500
"""Least time between two live identifications (they run while lines arrive)."""
STATUS_INTERVAL_MS = 1000
"""Polling period of the output state and instrument faults."""


@dataclass(frozen=True)
class InstrumentStatus:
    """The shaker's output as the instrument reports it, and any fault its supervision found."""

    output_on: bool
    level: float | None           # V peak (sine) or V rms (noise); None when not asked (campaign running)
    armed_by_host: bool
    fault: str


def starter_model(rig: Rig) -> Model:
    """A first hypothesis for a rig: its structure as designed, an unknown element (no laws) at each of its
    joints. Only the places come from the rig, never its laws."""
    doc = tomllib.loads(rig.text)
    elements = [{"name": el.name, "laws": [], **({"dof": el.dofs[0]} if el.grounded else {"between": list(el.dofs)})}
                for el in rig.elements]
    return load_model({"structure": doc["structure"], "element": elements}, f"starter model for {rig.name}")


class Lab(QObject):
    """State and actions of the lab window (see module docstring)."""

    instrumentsChanged = Signal()
    statusPolled = Signal(object)              # InstrumentStatus
    planChecked = Signal(bool, str)            # valid, message
    limitsChanged = Signal(float, float)       # max force N, max acceleration m/s^2
    armedChanged = Signal(bool, str)
    campaignStarted = Signal(object)           # CampaignFeed
    campaignFinished = Signal(str, bool)       # summary text, aborted
    sessionChanged = Signal()
    modelChanged = Signal()
    identificationUpdated = Signal(object)     # IdentificationView
    analysisUpdated = Signal(object)           # AnalysisView
    analysisBusy = Signal(bool)
    predictionUpdated = Signal(object)         # PredictionView
    backboneUpdated = Signal(object)           # BackboneView
    autoProgress = Signal(str)                 # a line of the automatic loop as it is taken
    instrumentsBusy = Signal(bool)
    error = Signal(str)

    def __init__(self, software_version: str = "", parent: QObject | None = None):
        super().__init__(parent)
        self.software_version = software_version
        self.instrument_tasks = TaskRunner("instruments", self)
        self.analysis_tasks = TaskRunner("analysis", self)
        self.file_tasks = TaskRunner("files", self)
        for runner in (self.instrument_tasks, self.analysis_tasks, self.file_tasks):
            runner.failed.connect(self.error)
        self.instrument_tasks.busyChanged.connect(self.instrumentsBusy)
        self.analysis_tasks.busyChanged.connect(self.analysisBusy)
        self._auto_stop = threading.Event()      # set by stop_auto, read by the loop in the analysis worker
        # instruments
        self.instruments: Instruments | None = None
        self.rig: Rig | None = None
        self.connection_label = ""
        self._stack: ExitStack | None = None
        # plan and arming
        self.limits = (5.0, 50.0)
        self.plan_document: dict | None = None
        self.plan: Plan | None = None
        self.plan_message = "no plan yet"
        self.armed_plan: Plan | None = None
        # campaign
        self.campaign: CampaignThread | None = None
        self.feed: CampaignFeed | None = None
        self.live: LiveSession | None = None
        self.campaign_output: str | None = None
        # session, model, analysis
        self.session: Session | None = None
        self.session_path: str | None = None
        self._session_contents: list[tuple[str, str, int]] = []   # runs, statuses and lines last shown
        self.model: Model | None = None
        self.model_label = ""
        self.analysis: AnalysisView | None = None
        self.identification: IdentificationView | None = None
        self.backbone: BackboneView | None = None
        self.reference: LevelReference | None = None              # the level reference the model was made from
        self._workbench: tuple[int, Workbench] | None = None     # touched by analysis tasks only
        self._fitted_on: FittedOn | None = None                   # the analysed session and levels, for the saved model
        self._generation = 0                                      # bumped when the session or model changes
        self._sessions = 0                                        # bumped when the session changes
        self._closed = False
        # coalesces identification requests; its interval is the least time between two live identifications
        self.identify_timer = QTimer(self, singleShot=True, interval=IDENTIFY_INTERVAL_MS)
        self.identify_timer.timeout.connect(self._identify_now)
        self._status_timer = QTimer(self, interval=STATUS_INTERVAL_MS)
        self._status_timer.timeout.connect(self.poll_status)
        self._status_timer.start()

    def act(self, action, *args) -> bool:
        """Run an operator's action; a refusal (bad input, instrument error) becomes a message, not an
        exception. Returns whether it went through."""
        try:
            action(*args)
        except (InputError, InstrumentError) as exc:
            self.error.emit(str(exc))
            return False
        return True

    # ================================================================== instruments
    @property
    def connected(self) -> bool:
        return self.instruments is not None

    @property
    def campaign_running(self) -> bool:
        return self.campaign is not None

    def connect_simulated(self, rig_name_or_path: str, paced: bool = False, seed: int = 0) -> None:
        """Open a rig's emulated shaker controller and DAQ (in-process ``sim://`` links) in the background."""
        def task():
            rig = load_rig(rig_name_or_path)
            stack = ExitStack()
            instruments = stack.enter_context(emulated_instruments(rig, seed=seed, paced=paced))
            return stack, instruments, rig, f"simulated rig {rig.name} ({'real time' if paced else 'fast'})"
        self._connect(task)

    def connect_real(self, shaker_url: str, daq_url: str, excitation_dof: str,
                     sensor_dofs: list[str] | None = None) -> None:
        """Open real instruments at two port names or pyserial URLs in the background."""
        if not shaker_url or not daq_url:
            raise InputError("give the shaker controller's and the DAQ's port or URL")
        if not excitation_dof:
            raise InputError("give the DOF of the force gauge (the excitation DOF), e.g. A.w")

        def task():
            stack = ExitStack()
            instruments = stack.enter_context(real_instruments(shaker_url, daq_url, excitation_dof, sensor_dofs))
            return stack, instruments, None, f"instruments at {shaker_url} and {daq_url}"
        self._connect(task)

    def _connect(self, task) -> None:
        if self.campaign_running:
            raise InputError("a campaign is running: abort it before changing instruments")
        self.disconnect()

        def connected(result):
            if self._closed:                  # the window closed while connecting: release at once
                result[0].close()
                return
            self._stack, self.instruments, self.rig, self.connection_label = result
            self.disarm("instruments changed")
            self._check_plan()
            if self.model is None and self.rig is not None:
                self.use_starter_model()
            self.instrumentsChanged.emit()
        self.instrument_tasks.submit(task, connected)

    def disconnect(self) -> None:
        """Close the instruments (their drivers switch the output off on the way)."""
        if self.campaign_running:
            raise InputError("a campaign is running: abort it before disconnecting")
        stack, self._stack = self._stack, None
        if stack is None:
            return
        self.instruments = self.rig = None
        self.connection_label = ""
        self.disarm("instruments closed")
        self.instrument_tasks.submit(stack.close)
        self.instrumentsChanged.emit()

    def probe_ports(self, on_done) -> None:
        """Ask every listed serial port ``*IDN?`` (background); ``on_done((found, probes))``."""
        self.instrument_tasks.submit(find_instruments, on_done)

    def poll_status(self) -> None:
        """Show the output state and faults.

        Idle, the instrument is asked (in the background). While a campaign runs the instrument is left to
        the campaign -- an extra query competing with its commands could only delay them -- and the state
        shown is the driver's own (armed by the host, faults its supervision found), which costs no I/O.
        """
        instruments = self.instruments
        if instruments is None:
            return
        shaker = instruments.shaker
        if self.campaign_running:
            self.statusPolled.emit(InstrumentStatus(shaker.armed, None, shaker.armed, self._driver_fault(shaker)))
            return
        if self.instrument_tasks.busy:
            return

        def task():
            return InstrumentStatus(shaker.output_enabled(), shaker.output_level(), shaker.armed,
                                    self._driver_fault(shaker))
        self.instrument_tasks.submit(task, self.statusPolled.emit, self._status_failed)

    @staticmethod
    def _driver_fault(shaker) -> str:
        try:
            shaker.check()
        except InstrumentError as exc:
            return str(exc)
        return ""

    def _status_failed(self, message: str) -> None:
        self.statusPolled.emit(InstrumentStatus(False, None, False, message))

    def link_health(self) -> LinkCounters | None:
        """Blocks, samples and losses of the current (or last) campaign's stream."""
        return None if self.feed is None else self.feed.ring.health()

    # ================================================================== plan, limits, arming
    def set_limits(self, max_force: float, max_acceleration: float) -> None:
        if (max_force, max_acceleration) == self.limits:
            return
        self.limits = (float(max_force), float(max_acceleration))
        self.limitsChanged.emit(*self.limits)
        self.disarm("limits changed")
        self._check_plan()

    def set_plan_document(self, doc: dict) -> None:
        """The editor's plan without limits (they come from :attr:`limits`); validated at once."""
        self.plan_document = doc
        self.disarm("plan changed")
        self._check_plan()

    def full_plan_document(self) -> dict | None:
        if self.plan_document is None:
            return None
        return {**self.plan_document, "limits": {"max_force": self.limits[0], "max_acceleration": self.limits[1]}}

    def _check_plan(self) -> None:
        doc = self.full_plan_document()
        self.plan = None
        if doc is None:
            self.plan_message = "no plan yet"
            self.planChecked.emit(False, self.plan_message)
            return
        try:
            plan = parse_plan(doc, plan_toml(doc), "plan")
            if self.instruments is not None:
                check_against_instruments(plan, self.instruments.daq.sample_rate,
                                          self.instruments.shaker.frequency_range)
        except InputError as exc:
            self.plan_message = str(exc)
            self.planChecked.emit(False, self.plan_message)
            return
        self.plan = plan
        self.plan_message = "plan valid: " + plan.summary() + \
            ("" if self.instruments is not None else " (not yet checked against instruments)")
        self.planChecked.emit(True, self.plan_message)

    def arm(self) -> None:
        """The explicit arm step: a valid plan on connected instruments may now switch the output on."""
        if self.instruments is None:
            raise InputError("connect the instruments first")
        if self.campaign_running:
            raise InputError("a campaign is running")
        self._check_plan()
        if self.plan is None:
            raise InputError(f"cannot arm: {self.plan_message}")
        self.armed_plan = self.plan
        self.armedChanged.emit(True, f"ARMED: Start switches the output on (max force {self.limits[0]:g} N, "
                                     f"max acceleration {self.limits[1]:g} m/s²)")

    def disarm(self, reason: str = "disarmed") -> None:
        if self.armed_plan is None:
            return
        self.armed_plan = None
        self.armedChanged.emit(False, f"not armed ({reason})")

    # ================================================================== campaign
    def start_campaign(self, output: str) -> None:
        """Run the armed plan into a new session file ``output`` (the arm is used up)."""
        if self.armed_plan is None or self.instruments is None:
            raise InputError("arm first (Rig tab): the output is switched on only after an explicit arm")
        if not output:
            raise InputError("choose the session file to write")
        if Path(output).exists():
            raise InputError("exists already; choose another session file name", output)
        if self.session_path is not None and Path(self.session_path).resolve() == Path(output).resolve():
            self.close_session()
        daq = self.instruments.daq
        ring = SignalRing(daq.channels, daq.units, daq.sample_rate)
        self.feed = CampaignFeed(ring)
        self.live = LiveSession(daq.channels)
        signals = self.feed.signals
        signals.runStarted.connect(self.live.begin)
        signals.lineMeasured.connect(self._on_line)
        signals.randomMeasured.connect(self.live.add_random)
        signals.pointLocked.connect(self.live.add_point)
        signals.runEnded.connect(self.live.end)
        plan, self.armed_plan = self.armed_plan, None
        self.armedChanged.emit(False, "not armed (the arm was used by the campaign)")
        self.campaign_output = output
        self.campaign = CampaignThread(plan, self.instruments, output, self.feed, self.software_version, self)
        self.campaign.finishedWith.connect(self._campaign_finished)
        self.campaign.failedWith.connect(self._campaign_failed)
        self._bump_generation()
        self.campaignStarted.emit(self.feed)
        self.campaign.start()

    def _on_line(self, run: str, index: int, m, target: float) -> None:
        self.live.add_line(run, m, target)
        self.request_identification()

    def pause(self) -> None:
        if self.campaign is not None:
            self.campaign.pause()

    def resume(self) -> None:
        if self.campaign is not None:
            self.campaign.resume()

    def abort(self, reason: str = "operator abort") -> None:
        """Output off at once; the lines measured so far stay in the session."""
        if self.campaign is not None:
            self.campaign.abort(reason)

    def _campaign_finished(self, summary: CampaignSummary) -> None:
        self._end_campaign(summary.text(), bool(summary.aborted))

    def _campaign_failed(self, message: str) -> None:
        self.error.emit(f"campaign stopped: {message}")
        self._end_campaign(f"campaign stopped: {message}", True)

    def _end_campaign(self, text: str, aborted: bool) -> None:
        if self._closed:                      # the window closed meanwhile: shutdown() has joined the thread
            return
        thread, self.campaign = self.campaign, None
        if thread is not None:
            thread.wait()
            thread.deleteLater()
        self.campaignFinished.emit(text, aborted)
        if self.campaign_output and Path(self.campaign_output).exists():
            self.open_session(self.campaign_output)

    # ================================================================== session
    def open_session(self, path: str) -> None:
        """Read a session file (also one another process is still writing)."""
        if self.campaign_running and Path(path).resolve() == Path(self.campaign_output).resolve():
            raise InputError("is being written by this window's campaign; it opens here when the campaign ends",
                             path)
        session = open_session(path)
        self.close_session()
        self.session, self.session_path = session, str(path)
        self._session_contents = self._contents()
        self._session_replaced()
        self.sessionChanged.emit()
        self.request_identification()
        self._measure_backbones()

    def close_session(self) -> None:
        if self.session is not None:
            self.session.close()
        self.session = self.session_path = None
        self._session_replaced()
        self.sessionChanged.emit()

    def _forget_results(self) -> None:
        """Another session or model: the results of the one before are dropped here, and results still being
        computed for it are dropped when they arrive (the generation moves on), so no tab shows them."""
        self.analysis = self.identification = self.backbone = None
        self._bump_generation()

    def _session_replaced(self) -> None:
        self._sessions += 1
        self._forget_results()

    def refresh_session(self) -> bool:
        """Re-read a session another process is writing; True when a run, a line or a status changed."""
        if self.session is None:
            return False
        self.session.refresh()
        contents = self._contents()
        if contents == self._session_contents:
            return False
        self._session_contents = contents
        self.request_identification()
        self._measure_backbones()            # a response level that ended is a point more
        return True

    def export(self, kind: str, target: str, on_done) -> None:
        """Write the open session's FRFs as UFF58 (``kind="uff"``: one file per run named after the save
        dialog's file) or CSV (one file per run into a folder), in the background; ``on_done(message)``.
        Existing files are refused."""
        if self.session_path is None:
            raise InputError("open a session first")
        path = self.session_path
        if kind == "uff":
            def task():
                done = export_uff(path, target)
                return f"wrote {done.records} records to {', '.join(p.name for p in done.files)}"
        else:
            def task():
                return f"wrote {len(export_csv(path, target))} CSV files to {target}"
        self.file_tasks.submit(task, on_done)

    def import_measurements(self, request: ImportRequest, on_done, on_refused=None) -> None:
        """Import other systems' files into a session in the background, then open it; ``on_done(message)``, or
        on a refusal ``on_refused(message)`` besides the error bar."""
        def task():
            return import_files(request)

        def done(result: ImportResult):
            if self.act(self.open_session, request.output):
                on_done(f"imported {len(result.runs)} run(s) into {Path(request.output).name}" +
                        "".join(f"\nnote: {n}" for n in result.notes))

        def refused(message: str):
            self.error.emit(message)
            if on_refused is not None:
                on_refused(message)
        self.file_tasks.submit(task, done, refused)

    def _contents(self) -> list[tuple[str, str, int]]:
        return [(n, run.status, len(run.frequency))
                for n in self.session.run_names() for run in (self.session.run(n),)]

    # ================================================================== model
    def load_model_file(self, path: str) -> None:
        self.set_model(load_model(load_toml(path), str(path)), str(path))

    def set_model(self, model: Model, label: str, reference: LevelReference | None = None) -> None:
        """Use ``model`` (``label`` names it); ``reference``: the level reference it was made from, shown with it."""
        measured = None if self.backbone is None else self.backbone.measured
        self.model, self.model_label, self.reference = model, label, reference
        self._forget_results()
        self.modelChanged.emit()
        self.request_identification()
        if measured is not None:                  # the session's curves stay; the old model's prediction goes
            self._show_backbone(BackboneView(measured))

    def make_reference(self) -> None:
        """A modal reference fitted to the open session's lowest level, as ``contactid reference`` fits it
        (:func:`reference_from_level`: its fit, its FRF error, the NONLINEAR warning when the next level moves),
        then the model on it -- the joint element at the drive point without laws -- for Analyze and Auto: the
        way in for a session without a random run."""
        if self.session_path is None or self.campaign_running:
            raise InputError("open a session first: a reference is fitted to a finished test's lowest level")
        path, generation = self.session_path, self._generation

        def task():
            return reference_from_level(read_measurements(path))

        def done(reference: LevelReference):
            if generation == self._generation:
                label = (f"reference from {Path(path).name}, run {reference.run} (modal, drive point "
                         f"{reference.drive}), an element at the drive point")
                self.set_model(reference.model(), label, reference)
        self.analysis_tasks.submit(task, done)

    def use_starter_model(self) -> None:
        if self.rig is None:
            raise InputError("a starter model needs a simulated rig or rig file (Rig tab)")
        self.set_model(starter_model(self.rig),
                       f"starter model for {self.rig.name} (the rig's structure, an element at each joint)")

    def _bump_generation(self) -> None:
        self._generation += 1

    # ================================================================== backbones
    def _measure_backbones(self) -> None:
        """The open session's measured natural frequency and damping against amplitude, without a model (in the
        background); an analysis or a prediction adds the model's curves."""
        path, sessions = self.session_path, self._sessions

        def task():
            return BackboneView(measured_backbones(read_measurements(path)))

        def done(view: BackboneView):
            # a model changed meanwhile leaves the session's curves valid; a model's prediction already shown
            # holds them too
            if sessions == self._sessions and (self.backbone is None or not self.backbone.predicted):
                self._show_backbone(view)
        # on the files runner, as the exports that also only read the session: an analysis task would hold Analyze
        # and the model's buttons disabled the moment a session opens. A session the analysis refuses says so
        # when analysed; here it only has no curves.
        self.file_tasks.submit(task, done, lambda message: log.info("no backbone: %s", message))

    def _show_backbone(self, view: BackboneView | None) -> None:
        self.backbone = view
        self.backboneUpdated.emit(view)

    # ================================================================== analysis
    def _measurement_reader(self):
        """A callable the worker runs to get the measurements: the live lines of a running campaign (frozen
        now), else the open session file (read in the worker); None when there is nothing to analyse."""
        if self.campaign_running and self.live is not None:
            snapshot = self.live.snapshot()
            return lambda: measurements_from_session(snapshot)
        if self.session_path is not None:
            path = self.session_path

            def read():
                with open_session(path) as s:
                    return measurements_from_session(s)
            return read
        return None

    def request_identification(self) -> None:
        """Identify again soon (coalesced: at most one live identification per IDENTIFY_INTERVAL_MS)."""
        if self.model is not None and not self._closed and not self.identify_timer.isActive():
            self.identify_timer.start()

    def _identify_now(self) -> None:
        reader, model = self._measurement_reader(), self.model
        if reader is None or model is None:
            return
        if self.analysis_tasks.busy:
            self.identify_timer.start()          # try again after the running task
            return
        live, generation = self.campaign_running, self._generation

        def task():
            measurements = reader()
            if not measurements.sine or not model.elements:
                return None              # a structure without joints (a linear rig): its FRFs are the result
            wb = Workbench(model, measurements)
            wb.identify()
            return identification_view(wb, live)

        def done(view):
            if view is not None and generation == self._generation:
                self._show_identification(view)
        self.analysis_tasks.submit(task, done)

    def _show_identification(self, view: IdentificationView) -> None:
        self.identification = view
        self.identificationUpdated.emit(view)

    def analyze(self) -> None:
        """Reference, identification, fit, comparison and candidate ranking of the current model."""
        reader, model, generation = self._measurement_reader(), self.model, self._generation
        if model is None:
            raise InputError("open a model first (Model tab)")
        if reader is None:
            raise InputError("open a session or run a campaign first")

        path = None if self.campaign_running else self.session_path

        def task():
            measurements = reader()
            wb = Workbench(model, measurements)
            wb.start()
            self._workbench = (generation, wb)
            self._fitted_on = None if path is None else fitted_on(path, measurements)
            return self._view(wb)
        self.analysis_tasks.submit(task, lambda view: self._analysis_done(view, generation))

    def predict(self) -> None:
        """The open session predicted by the current model as it is, nothing refitted (as ``contactid
        predict``): each level's error, the levels the model's ``[fitted]`` table says the fit did not see marked
        held out. Sent as ``predictionUpdated``."""
        reader, model, generation = self._measurement_reader(), self.model, self._generation
        if model is None:
            raise InputError("open a fitted model first (Model tab)")
        if reader is None or self.session_path is None or self.campaign_running:
            raise InputError("open a session first: a prediction compares a fitted model with a finished test")
        path = self.session_path

        def task():
            measurements = reader()
            prediction = predict_session(model, measurements, session_created(path))
            return PredictionView(prediction_text(prediction, Path(path).name, self.model_label), prediction,
                                  list(measurements.sine))

        def done(view):
            if generation == self._generation:
                self.predictionUpdated.emit(view)
                backbones = view.prediction.backbones
                self._show_backbone(BackboneView([c.measured for c in backbones], backbones,
                                                 f"{self.model_label}, nothing refitted"))
        self.analysis_tasks.submit(task, done)

    def add_law(self, element: str, law: str) -> None:
        """Add a law to an element, refit it and rank again."""
        self._on_workbench(lambda wb: wb.add(element, law))

    def undo(self) -> None:
        """Take back the last added law."""
        self._on_workbench(lambda wb: wb.undo())

    def auto(self) -> None:
        """The missing-effect loop (:func:`analysis.loop.auto.run_auto`, as ``contactid analyze --auto``) on the
        analysed model: discovery of the elements without laws, linear corrections, then the top significant
        candidate added until none is left. Each step is sent as ``autoProgress`` as it is taken;
        :meth:`stop_auto` ends the loop within its step under way, which is undone."""
        self._auto_stop.clear()

        def loop(wb):
            return run_auto(wb, progress=lambda step: self.autoProgress.emit(step.text()),
                            note=self.autoProgress.emit, stop=self._auto_stop.is_set)
        self._on_workbench(loop, lambda wb, result: analysis_view(wb, result.candidates, result, self._fitted_on))

    def stop_auto(self) -> None:
        """End the automatic loop within its step under way, which is undone (the steps taken stay)."""
        self._auto_stop.set()

    def _on_workbench(self, change, view=None) -> None:
        """Run ``change(wb)`` on the analysed workbench in the analysis worker, then show
        ``view(wb, what change returned)`` (default: the view with the candidates ranked again)."""
        generation = self._generation

        def task():
            if self._workbench is None or self._workbench[0] != generation:
                raise InputError("the model or the session changed: press Analyze first")
            wb = self._workbench[1]
            done = change(wb)
            return self._view(wb) if view is None else view(wb, done)
        self.analysis_tasks.submit(task, lambda v: self._analysis_done(v, generation))

    def _view(self, wb: Workbench) -> AnalysisView:
        return analysis_view(wb, wb.candidates(), fitted_on=self._fitted_on)

    def _analysis_done(self, view: AnalysisView, generation: int) -> None:
        if generation != self._generation:
            return
        self.analysis = view
        # an identification asked for before this analysis finished would replace its fitted one with an older
        # state of the same data
        self.identify_timer.stop()
        self.analysisUpdated.emit(view)
        self._show_identification(identification_of(view))
        self._show_backbone(BackboneView([c.measured for c in view.backbones], view.backbones,
                                         f"{self.model_label}, as fitted here"))

    # ================================================================== closing
    def shutdown(self, timeout_s: float = 30.0) -> None:
        """Output off and everything released: abort the campaign and wait for it, stop the workers, close
        the session and the instruments."""
        self._closed = True
        self._status_timer.stop()
        self.identify_timer.stop()
        if self.campaign is not None:
            self.campaign.abort("window closed")
            self.campaign.wait(int(timeout_s * 1000))
            self.campaign = None
        for runner in (self.analysis_tasks, self.file_tasks, self.instrument_tasks):
            runner.shutdown()
        if self.session is not None:
            self.session.close()
            self.session = None
        if self._stack is not None:
            stack, self._stack = self._stack, None
            self.instruments = None
            try:
                stack.close()
            except InstrumentError as exc:
                # an instrument that does not confirm the output off: its watchdog switches it off once the
                # heartbeats stop; the window closes all the same
                log.warning("closing the instruments: %s", exc)
