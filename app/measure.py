"""Run a plan against instruments into a new session (``contactid simulate`` / ``contactid acquire``)."""
from __future__ import annotations

import sys
import time

from .campaign import Campaign, CampaignListener, CampaignSummary
from .instruments import Instruments
from .plan import Plan, check_against_instruments
from .session import SessionWriter


class ProgressBar(CampaignListener):
    """One updating line on a terminal (stderr): run, line, force level, ETA; faults on their own lines."""

    def __init__(self, stream=sys.stderr, quiet: bool = False):
        self.stream = stream
        self.quiet = quiet
        self._last = 0.0
        self._force = {}

    def run_started(self, name, spec):
        self._force[name] = spec.force

    def progress(self, done, total, eta_s, run):
        now = time.monotonic()
        if self.quiet or (now - self._last < 0.2 and done < total):
            return
        self._last = now
        width = 30
        filled = int(width * done / max(total, 1))
        eta = "" if eta_s is None else f" ETA {eta_s:5.0f} s"
        self.stream.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{total} lines  {run} "
                          f"({self._force.get(run, 0):g} N){eta}   ")
        self.stream.flush()

    def event(self, kind, message):
        if kind == "fault" or (kind == "safety" and message.startswith("trip")):
            self.stream.write(f"\n{kind}: {message}\n")

    def run_ended(self, run, status):
        if not self.quiet:
            self.stream.write(f"\n{run}: {status}\n")


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
        return campaign.run()
    finally:
        writer.close()
