"""A documented name kept after the move into packages (docs/contracts.md): the command-level run of a plan, from
:mod:`app.campaign.measure`."""
from app.campaign.measure import run_plan

__all__ = ["run_plan"]
