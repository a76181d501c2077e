"""``contactid predict``: a fitted model's prediction of a session, with nothing refitted; and the words of a
prediction, which ``analyze --fit-levels`` prints too (docs/workbench.md §6)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.common.errors import InputError
from analysis.common.measurements import Control, Measurements
from analysis.mechanics.model import FittedOn, Model, load_model
from analysis.common.tables import load_toml
from analysis.loop.cross_check import Fold
from analysis.prediction.comparison import HarmonicCriterion
from analysis.prediction.held_out import FITTED, HELD_OUT, UNKNOWN, UNSEEN, SessionPrediction, predict_session

from app.analyze import backbone_text, backbones_json, read_measurements
from app.session import open_session

KIND_WORDS = {FITTED: "fitted", HELD_OUT: "held out", UNSEEN: "unseen", UNKNOWN: "not known"}


def session_created(session_path) -> str:
    """The session's ``created`` attribute: what tells it from another session of the same name."""
    with open_session(session_path) as s:
        return str(s.attrs.get("created", ""))


def fitted_on(session_path, measurements: Measurements) -> FittedOn:
    """What a model fitted to ``measurements`` of the session at ``session_path`` says it was fitted to (the
    ``[fitted]`` table, docs/contracts.md §4): the session's file name and ``created``, the levels' labels."""
    return FittedOn(Path(session_path).name, session_created(session_path),
                    tuple(c.label() for c in measurements.level_controls()))


def run_predict(session_path, model_path, measurements: Measurements | None = None) -> tuple[Model, SessionPrediction]:
    """The model file's prediction of the session."""
    model = load_model(load_toml(model_path), str(model_path))
    if measurements is None:
        measurements = read_measurements(session_path)
    try:
        return model, predict_session(model, measurements, session_created(session_path), HarmonicCriterion())
    except InputError as err:
        raise err if err.source else err.located(source=str(session_path)) from None


def parse_levels(text: str, controls: list[Control]) -> set[tuple]:
    """``--fit-levels 1,3,5-7`` -> the keys of those levels (numbered from 1 in :meth:`Control.order`, as the
    report lists them)."""
    listing = "; ".join(f"{i} = {c.label()}" for i, c in enumerate(controls, 1))
    chosen: set[int] = set()
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        try:
            lo = int(first)
            hi = int(last) if dash else lo
        except ValueError:
            raise InputError(f"--fit-levels takes level numbers and ranges (1,3,5-7), got {text!r}; the levels: "
                             f"{listing}", field="--fit-levels") from None
        if not 1 <= lo <= hi <= len(controls):
            raise InputError(f"--fit-levels: no level {part.strip()!r}; the session has {len(controls)}: {listing}",
                             field="--fit-levels")
        chosen.update(range(lo, hi + 1))
    return {controls[i - 1].key() for i in sorted(chosen)}


def prediction_text(prediction: SessionPrediction, session_name: str, model_name: str) -> str:
    """The prediction as a test engineer reads it: each level's FRF error and modal errors, marked fitted or held
    out, the pooled errors of each kind, the backbones and the jumps."""
    fitted_on = prediction.fitted_on
    if fitted_on is None:
        out = [f"model {model_name}: its file does not say what it was fitted to (no [fitted] table), so no level "
               "is known to be held out"]
    else:
        out = [f"model {model_name}: fitted to session {fitted_on.session} on {len(fitted_on.levels)} level(s): "
               + ", ".join(fitted_on.levels)]
    out.append(f"prediction of session {session_name}, nothing refitted (FRF error relative; natural frequency "
               "and damping from a single-mode fit per response level):")
    out.append(f"  {'#':>3} {'level':<26} {'fit':<9} {'FRF error':>9} {'f error':>9} {'zeta error':>10}")
    for i, lv in enumerate(prediction.levels, 1):
        out.append(f"  {i:>3} {lv.control.label():<26} {KIND_WORDS[lv.kind]:<9} {lv.error:9.3g} "
                   f"{_percent(lv.frequency_error, 3):>9} {_percent(lv.damping_error, 2):>10}")
    out.append("FRF error: " + "; ".join(_summary(prediction, kind) for kind in (FITTED, HELD_OUT, UNSEEN, UNKNOWN)
                                         if kind in prediction.errors))
    fitted, held = prediction.error_of(FITTED), prediction.error_of(HELD_OUT)
    if np.isfinite(fitted) and np.isfinite(held) and fitted > 0:
        out.append(f"the held-out levels' error is {held / fitted:.3g} times the fitted levels' ({held:.3g} against "
                   f"{fitted:.3g}): {_verdict(held / fitted)}")
    out += backbone_text(prediction.backbones)
    if prediction.comparison.jumps:
        out.append("jumps (predicted fold against measured):")
        out += [f"  {j.text()}" for j in prediction.comparison.jumps]
    return "\n".join(out)


HELD_OUT_TOLERANCE = 2.0     # a held-out error up to twice the fitted one: the model predicts as it fits


def _verdict(ratio: float) -> str:
    return ("the model predicts what it did not see about as well as what it was fitted to"
            if ratio <= HELD_OUT_TOLERANCE else "the model describes its own levels better than it predicts others")


def cross_validation_text(folds: list[Fold]) -> str:
    """The two folds of ``analyze --cross-validate`` (analysis/loop/cross_check.py) and what they say."""
    if not folds:
        return "cross-validation: the session has one level; nothing to hold out"
    out = ["cross-validation over the levels (the laws refitted on half of them -- alternate, lower, upper -- each "
           "half predicting the others with nothing refitted):"]
    for fold in folds:
        same = (f", the others fitted on themselves {fold.others_fitted_error:.3g} (x{fold.cost:.3g} for not seeing "
                "them)" if np.isfinite(fold.cost) else "")
        out.append(f"  fitted on {', '.join(fold.levels)}: {fold.fitted_error:.3g} on its levels, "
                   f"{fold.held_out_error:.3g} on the others (x{fold.ratio:.3g}){same}; damping of the others within "
                   + _percent_size(fold.prediction.worst(HELD_OUT, "damping")))
    out.append(f"  {_verdict(max(f.ratio for f in folds))}")
    costs = [f.cost for f in folds if np.isfinite(f.cost)]
    if costs:
        out.append(f"  against the same levels fitted on themselves: {_cost_verdict(max(costs))}")
    return "\n".join(out)


def _cost_verdict(cost: float) -> str:
    return (f"predicting a half costs at most x{cost:.3g}: the model predicts levels it did not see about as well as "
            "a fit of them" if cost <= HELD_OUT_TOLERANCE else
            f"predicting a half costs up to x{cost:.3g}: the laws fitted on one half do not carry to the other")


def cross_validation_json(folds: list[Fold]) -> list[dict]:
    return [{"levels": list(f.levels), "fitted_error": f.fitted_error, "held_out_error": f.held_out_error,
             "ratio": f.ratio, "held_out_damping_error": _number(f.prediction.worst(HELD_OUT, "damping")),
             "others_fitted_error": _number(f.others_fitted_error), "cost": _number(f.cost)}
            for f in folds]


def _percent_size(value: float) -> str:
    return f"{abs(value) * 100:.3g} %" if np.isfinite(value) else "- (no response level held out)"


def _summary(prediction: SessionPrediction, kind: str) -> str:
    n = sum(lv.kind == kind for lv in prediction.levels)
    text = f"{KIND_WORDS[kind]} levels ({n}) {prediction.error_of(kind):.3g}"
    damping = prediction.worst(kind, "damping")
    return text + (f", damping within {_percent_size(damping)}" if np.isfinite(damping) else "")


def _percent(value: float, decimals: int) -> str:
    return f"{100 * value:+.{decimals}f} %" if np.isfinite(value) else "-"


def prediction_json(prediction: SessionPrediction) -> dict:
    """The JSON of ``predict --json`` (docs/contracts.md §6)."""
    comp = prediction.comparison
    fitted_on = prediction.fitted_on
    return {"fitted_on": None if fitted_on is None else
            {"session": fitted_on.session, "session_created": fitted_on.created, "levels": list(fitted_on.levels)},
            "error": comp.error,
            "errors": dict(prediction.errors),
            "levels": [{**lv.control.to_json(), "force": lv.force, "error": lv.error, "kind": lv.kind,
                        "frequency_error": _number(lv.frequency_error), "damping_error": _number(lv.damping_error)}
                       for lv in prediction.levels],
            "jumps": [j.to_json() for j in comp.jumps],
            **backbones_json(prediction.backbones)}


def _number(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None
