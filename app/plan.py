"""A documented name kept after the move into packages (docs/contracts.md): the plan file's reader, from
:mod:`app.campaign.plan`."""
from app.campaign.plan import load_plan, parse_plan

__all__ = ["load_plan","" "parse_plan"]
