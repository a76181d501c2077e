"""Run a plan against instruments into a new session (``contactid simulate`` / ``contactid acquire``)."""
from __future__ import annotations

import sys
import time

from app.campaign.engine import Campaign, CampaignListener, CampaignSummary, asked_to_stop
from app.campaign.instruments import Instruments
from app.campaign.plan import Plan, check_against_instruments
from app.session import SessionWriteError, SessionWriter


class ProgressBar(CampaignListener):
    """Campaign progress on stderr: lines done of planned plus added (refinement adds lines), run, force
    level, ETA; faults on their own lines.

    On a terminal one line updates in place (at most five times a second). Anywhere else (a log file, a
    pipe) plain lines are written: one when a run starts and ends and one each time another tenth of the
    lines is done -- never carriage-return frames.
    """

    def __init__(self, stream=None, quiet: bool = False):
        self.stream = sys.stderr if stream is None else stream   # the stderr of now, not of import time
        self.quiet = quiet
        self.live = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last = 0.0
        self._tenth = 0
        self._force = {}
        self._planned: int | None = None
        self._added = 0
        self._counted = ""

    def run_started(self, name, spec):
        self._force[name] = spec.force
        if not self.quiet and not self.live:
            self._write(f"{name}: started ({spec.force:g} N)\n")

    def lines_added(self, planned, added):
        self._planned, self._added = planned, added

    def _count(self, done: int, total: int) -> str:
        planned = total if self._planned is None else self._planned
        added = total - planned
        return f"{done}/{planned}" + (f"+{added}" if added else "") + " lines"

    def progress(self, done, total, eta_s, run):
        if self.quiet:
            return
        eta = "" if eta_s is None else f" ETA {eta_s:5.0f} s"
        self._counted = self._count(done, total)
        text = f"{self._counted}  {run} ({self._force.get(run, 0):g} N){eta}"
        if self.live:
            now = time.monotonic()
            if now - self._last < 0.2 and done < total:
                return
            self._last = now
            width = 30
            filled = int(width * min(done / max(total, 1), 1.0))
            self._write(f"\r[{'#' * filled}{'.' * (width - filled)}] {text}   ")
            return
        tenth = int(10 * done / max(total, 1))
        if tenth > self._tenth:
            self._tenth = tenth
            self._write(text + "\n")

    def event(self, kind, message):
        if kind == "fault" or (kind == "safety" and message.startswith("trip")):
            self._write(("\n" if self.live else "") + f"{kind}: {message}\n")

    def run_ended(self, run, status):
        if not self.quiet:
            counted = f" ({self._counted})" if self._counted else ""
            self._write(("\n" if self.live else "") + f"{run}: {status}{counted}\n")

    def _write(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()


def run_plan(plan: Plan, instruments: Instruments, output, *, overwrite: bool = False, command: str = "",
             software_version: str = "", listener: CampaignListener | None = None,
             on_campaign=None) -> CampaignSummary:
    """Check the plan against the instruments, then run it into a new session file at ``output``.

    The plan is refused (InputError) before anything is armed or written if the instruments cannot run it.
    ``on_campaign(campaign)`` is called once the campaign exists (the GUI keeps it to pause or abort).
    """
    check_against_instruments(plan, instruments.daq.sample_rate, instruments.shaker.frequency_range)
    writer = SessionWriter(output, overwrite=overwrite, plan_text=plan.text,
                           rig_text=None if instruments.rig is None else instruments.rig.text,
                           software_version=software_version, command=command,
                           instruments=instruments.identities())
    try:
        campaign = Campaign(plan, instruments.shaker, instruments.daq, writer, instruments.excitation_dof,
                            instruments.sensor_dofs, listener)
        if on_campaign is not None:
            on_campaign(campaign)
        summary = campaign.run()
    except BaseException as exc:       # Ctrl-C, a failure: the file is closed, and where it went is said
        try:
            writer.close(complete=False)
        except BaseException as again:  # a second Ctrl-C, or the file failing as it closes
            if not (isinstance(again, SessionWriteError) and asked_to_stop(exc)):
                _say_where_kept(writer, again)
                raise
            exc.add_note(f"the session could not be closed: {again}")
        _say_where_kept(writer, exc)
        raise
    writer.close(complete=summary.complete)
    summary.session = str(writer.written_to)
    if _kept_beside(writer):
        summary.replaced = _kept_note(writer)
    return summary


def _kept_beside(writer: SessionWriter) -> bool:
    """Whether the new session could not replace the existing file and went beside it."""
    return writer.written_to != writer.path


def _say_where_kept(writer: SessionWriter, exc: BaseException) -> None:
    if _kept_beside(writer):
        exc.add_note(_kept_note(writer))


def _kept_note(writer: SessionWriter) -> str:
    return (f"{writer.path} is left as it was: the new session is incomplete and was kept beside it as "
            f"{writer.written_to}")
