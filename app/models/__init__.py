"""Files shipped with the app: the built-in rigs' default plans (``RIG.plan.toml``), the demo's quick plan and
its reference model."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

from analysis.common.errors import InputError
from drivers.simulation.rig import builtin_rigs


def asset(name: str) -> Path:
    """Path of the shipped file ``name``."""
    return Path(str(resources.files(__name__).joinpath(name)))


def builtin_plan_path(rig_name: str) -> Path:
    """The default plan of built-in rig ``rig_name``."""
    if rig_name not in builtin_rigs():
        raise InputError(f"no built-in rig {rig_name!r} (built-in rigs: {', '.join(builtin_rigs())})")
    return asset(f"{rig_name}.plan.toml")
