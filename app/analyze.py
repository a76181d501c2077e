"""``contactid analyze``: identify, fit, predict, compare and rank missing effects for a session and a model."""
from __future__ import annotations

import math

from analysis.errors import InputError
from analysis.frf_noise import METHOD as NOISE_METHOD
from analysis.model import load_model
from analysis.tables import load_toml
from analysis.workbench import Workbench

from .session import append_model_history, open_session
from .session_data import measurements_from_session


def parse_add(text: str) -> tuple[str, str]:
    """``ELEMENT:LAW`` -> (element, law)."""
    element, sep, law = text.partition(":")
    if not sep or not element or not law:
        raise InputError(f"--add takes ELEMENT:LAW (e.g. contact:coulomb), got {text!r}")
    return element, law


def run_workbench(session_path, model_path, adds: list[str] = (), rank: bool = True, store_history: bool = True):
    """The workbench taken through start, the requested additions and (optionally) the candidate ranking.

    Returns (workbench, candidates)."""
    model = load_model(load_toml(model_path), str(model_path))
    with open_session(session_path) as s:
        measurements = measurements_from_session(s)
    wb = Workbench(model, measurements)
    wb.start()
    for add in adds:
        wb.add(*parse_add(add))
    candidates = wb.candidates() if rank else []
    if store_history:
        append_model_history(session_path, [h.to_json() for h in wb.history], str(model_path))
    return wb, candidates


def _data_notes(wb: Workbench) -> list[str]:
    """What the analysis had to do without (imported FRFs carry no noise and no harmonics)."""
    out = []
    estimated = [r.name for r in wb.measurements.sine if r.noise_estimated]
    if estimated:
        out.append(f"noise: not measured for {', '.join(estimated)}; estimated {NOISE_METHOD}")
    blind = [r.name for r in wb.measurements.sine if r.distortion is None]
    if blind:
        out.append(f"distortion: no harmonics for {', '.join(blind)}, so no line is left out as far from "
                   "harmonic; lines that do not follow the fitted laws show in the misfit and the missing effects")
    return out + ([""] if out else [])


def report_text(wb: Workbench, candidates, top: int = 5) -> str:
    """The analysis as a test engineer reads it."""
    out = []
    if wb.reference is not None and wb.reference.text():
        out += [wb.reference.text(), ""]
    out += _data_notes(wb)
    out.append("elements:")
    for el in wb.model.elements:
        r = wb.reports[el.name]
        verdict = "no verdict (too few lines)" if r.verdict is None else \
            ("LINEAR" if r.verdict.linear else "NONLINEAR")
        out.append(f"  {el.name} ({', '.join(el.dofs)}): {verdict}; {r.lines_used} lines used, "
                   f"{r.lines_flagged} left out (ill-conditioned or distorted)")
        if r.verdict is not None:
            out.append(f"    evidence: {r.verdict.evidence}")
        for j, term in enumerate(el.laws):
            params = []
            for k, v in term.values.items():
                err = r.fit.terms[j].stderr.get(k) if r.fit is not None else None
                params.append(f"{k} = {v:.5g}" + ("" if err is None or not math.isfinite(err) else f" ± {err:.2g}"))
            out.append(f"    law {term.law.name}: {', '.join(params)}")
    comp = wb.compare()
    out.append("")
    out.append(f"FRF error of the model: {comp.error:.4g}  (" +
               ", ".join(f"{f:g} N: {e:.3g}" for f, e in comp.error_by_level) + ")")
    worst = max(comp.residual_map, key=lambda n: comp.residual_map[n].max())
    i = int(comp.residual_map[worst].argmax())
    run = next(r for r in wb.measurements.sine if r.name == worst)
    out.append(f"largest misfit: run {worst} at {run.frequency_hz[i]:.4g} Hz (relative error "
               f"{comp.residual_map[worst][i]:.3g})")
    if len(wb.history) > 1:
        out.append("history: " + " -> ".join(f"{h.action} {h.error:.3g}" for h in wb.history))
    if candidates:
        out += ["", "what is missing (best first):"]
        for c in candidates[:top]:
            mark = "significant" if c.significant else "not significant"
            out.append(f"  {c.element}:{c.law}  error {c.error:.4g} (x{c.gain:.2f} better, {mark})")
            out.append(f"    {c.explanation}")
    return "\n".join(out)
