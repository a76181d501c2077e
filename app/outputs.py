"""A documented name kept after the move into packages (docs/contracts.md): the atomic outputs every command writes, from
:mod:`app.session.outputs`."""
from app.session.outputs import atomic_output, check_output, require_free_space

__all__ = ["atomic_output","" "check_output","" "require_free_space"]
