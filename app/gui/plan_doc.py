"""Plan documents for the editor: the TOML tables of docs/contracts.md §5 as a dict, to and from files.

The editor builds the document, :func:`app.campaign.plan.parse_plan` validates it (the same checks as a plan file),
and :func:`plan_toml` writes the text stored in the session's provenance and in a saved plan file.
"""
from __future__ import annotations

import json
from dataclasses import asdict

from app.campaign import Plan, SineSpec

TABLE_ORDER = ("random", "settle", "control", "limits")


def plan_document(plan: Plan) -> dict:
    """The document of a validated plan (every table explicit, defaults included)."""
    doc: dict = {"stepped_sine": [_level(s) for s in plan.sine],
                 "settle": asdict(plan.settle), "control": {"tolerance": plan.control_tolerance},
                 "limits": {"max_force": plan.limits.max_force,
                            "max_acceleration": plan.limits.max_acceleration}}
    if plan.random is not None:
        doc["random"] = {"force_rms": plan.random.force_rms, "band": list(plan.random.band),
                         "duration": plan.random.duration}
    if plan.phase:
        doc["phase_resonance"] = [asdict(p) for p in plan.phase]
    return doc


def _level(s: SineSpec) -> dict:
    """One ``[[stepped_sine]]`` table: a force level, or a response level with its force limit."""
    held = {"force": s.force} if s.response is None else \
        {"response": s.response.target, "quantity": s.response.quantity, "dof": s.response.dof,
         "force_limit": s.response.force_limit}
    return {**held, "start": s.start, "stop": s.stop, "step": s.step, "direction": s.direction, "refine": s.refine,
            "min_step": s.min_step}


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)               # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def plan_toml(doc: dict) -> str:
    """TOML text of a plan document (tables in a fixed order, stepped-sine levels last)."""
    out = ["# plan written by contactid gui"]
    for name in TABLE_ORDER:
        if name in doc:
            out += ["", f"[{name}]"] + [f"{k} = {_value(v)}" for k, v in doc[name].items()]
    for table in ("stepped_sine", "phase_resonance"):
        for level in doc.get(table, []):
            out += ["", f"[[{table}]]"] + [f"{k} = {_value(v)}" for k, v in level.items()]
    return "\n".join(out) + "\n"
