"""A documented name kept after the move into packages (docs/contracts.md): the instruments a plan runs on, from
:mod:`app.campaign.instruments`."""
from app.campaign.instruments import emulated_instruments, real_instruments

__all__ = ["emulated_instruments","" "real_instruments"]
