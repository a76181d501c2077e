"""The campaign: what is measured and how (docs/campaigns.md).

It owns the plan file (:mod:`.plan`), the instruments a plan is run on (:mod:`.instruments`), the campaign
engine that runs random and stepped-sine runs (:mod:`.engine`), the measurement of one stepped-sine line
(:mod:`.stepped_sine`, :mod:`.transient_line`), the record feed from the DAQ (:mod:`.acquisition`) and the
command-level driver of a whole plan (:mod:`.measure`).

It may import :mod:`analysis`, :mod:`drivers` and the session writer's public names from :mod:`app.session`
(never a module inside it); it never imports the commands or the GUI. Other code uses the names below.
"""
from app.campaign.engine import (Campaign, CampaignAborted, CampaignIncomplete, CampaignListener, CampaignSummary,
                                 line_extras, lock_extras)
from app.campaign.instruments import Instruments, emulated_instruments, real_instruments
from app.campaign.measure import ProgressBar, run_plan
from app.campaign.plan import Plan, SineSpec, check_against_instruments, load_plan, parse_plan
from app.campaign.stepped_sine import LineMeasurement

__all__ = ["Campaign", "CampaignAborted", "CampaignIncomplete", "CampaignListener", "CampaignSummary",
           "Instruments", "LineMeasurement", "Plan", "ProgressBar", "SineSpec", "check_against_instruments",
           "emulated_instruments", "line_extras", "lock_extras", "load_plan", "parse_plan", "real_instruments",
           "run_plan"]
