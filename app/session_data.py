"""A documented name kept after the move into packages (docs/contracts.md): a session's runs as the analysis reads them, from
:mod:`app.session.data`."""
from app.session.data import measurements_from_session

__all__ = ["measurements_from_session"]
