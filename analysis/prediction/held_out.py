"""A fitted model's prediction of a session, level by level, with nothing refitted (docs/workbench.md §6).

A model is judged by what it predicts of data it did not see. Every stepped-sine run of the session is predicted
with the model's laws and values as they are -- no identification, no fit, no reference update -- and each level
is marked by what the model's ``[fitted]`` table says of it (:class:`analysis.mechanics.model.FittedOn`):

- *fitted*: the fit used this level of this session (an in-sample error);
- *held out*: a level of the session the model was fitted to, which the fit did not use;
- *unseen*: a level of another session (the next test, another specimen);
- *unknown*: the model file does not say what it was fitted to.

The pooled errors are :func:`analysis.prediction.comparison.error_over` over the levels of each kind, and each
level's natural frequency and damping are those of the backbone comparison (a single-mode fit per response
level, :mod:`analysis.prediction.backbone`): their relative errors, the largest in size over the level's runs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..common.errors import InputError
from ..common.measurements import Control, Measurements
from ..mechanics.model import FittedOn, Model
from .backbone import BackboneComparison, compare_backbones
from .comparison import Comparison, HarmonicCriterion, Predictor, error_over

FITTED, HELD_OUT, UNSEEN, UNKNOWN = "fitted", "held_out", "unseen", "unknown"


@dataclass(frozen=True)
class LevelPrediction:
    """One level: ``force`` its force (N; the median measured on a response-controlled level), ``error`` the
    relative FRF error of its runs (both directions), ``kind`` one of FITTED,
    HELD_OUT, UNSEEN, UNKNOWN (module docstring), ``frequency_error`` and ``damping_error`` the relative errors
    of the predicted natural frequency and damping ratio (the largest in size over the level's runs; NaN where
    the level has no single-mode fit: a force-controlled level, or a damping the model cannot place)."""

    control: Control
    force: float
    error: float
    kind: str
    frequency_error: float = float("nan")
    damping_error: float = float("nan")


@dataclass
class SessionPrediction:
    """A model's prediction of every stepped-sine level of a session.

    Attributes
    ----------
    comparison : Comparison
        Every run, predicted and compared (:meth:`Predictor.compare`, folds located).
    levels : list of LevelPrediction
        In :meth:`Control.order` (as ``comparison.error_by_level``).
    backbones : list of BackboneComparison
        Natural frequency and damping against amplitude, measured and predicted.
    fitted_on : FittedOn or None
        What the model's file says it was fitted to.
    """

    comparison: Comparison
    levels: list[LevelPrediction]
    backbones: list[BackboneComparison]
    fitted_on: FittedOn | None
    errors: dict[str, float]          # kind -> pooled relative FRF error over its levels (kinds present only)

    def error_of(self, kind: str) -> float:
        return self.errors.get(kind, float("nan"))

    def worst(self, kind: str, quantity: str) -> float:
        """The largest relative ``quantity`` ("frequency" or "damping") error in size over the levels of
        ``kind``, signed; NaN where none is measured."""
        return _largest([getattr(lv, f"{quantity}_error") for lv in self.levels if lv.kind == kind])


def level_kind(fitted_on: FittedOn | None, created: str, label: str) -> str:
    """FITTED, HELD_OUT, UNSEEN or UNKNOWN for level ``label`` of the session created at ``created``."""
    if fitted_on is None:
        return UNKNOWN
    saw = fitted_on.saw(created, label)
    return UNSEEN if saw is None else FITTED if saw else HELD_OUT


def predict_session(model: Model, measurements: Measurements, created: str,
                    harmonics: HarmonicCriterion | None = HarmonicCriterion(), folds: bool = True
                    ) -> SessionPrediction:
    """Predict every stepped-sine run of ``measurements`` (a session created at ``created``) with ``model`` as it
    is. ``harmonics`` selects the lines predicted multi-harmonically, as the workbench does (None where an element
    has a non-parametric part: it has no time-domain force). ``folds``: each jump's fold located, which a report
    shows and a judgement by the errors does without (:meth:`~analysis.prediction.comparison.Predictor.locate_folds`).

    Raises InputError where the session has no stepped-sine run, a measured DOF is not in the model, or a law has
    no values (a model to be fitted, not a fitted one)."""
    if not measurements.sine:
        raise InputError("the session has no stepped-sine run to predict")
    missing = sorted(d for d in measurements.dofs() if d not in model.structure.dofs)
    if missing:
        raise InputError(f"measured DOF(s) {', '.join(missing)} are not in the model's structure", model.source)
    for el in model.elements:
        for t in el.laws:
            if not t.complete:
                raise InputError(f"element {el.name!r}: law {t.law.name} has no values; a model to predict with is "
                                 "a fitted one (contactid analyze ... -o FITTED.toml)", model.source)
    if not all(el.time_domain for el in model.elements):
        harmonics = None
    comp = Predictor(model, measurements).compare(locate_folds=folds, harmonics=harmonics)
    backbones = compare_backbones(model.structure, model.elements, measurements.sine, measurements.phase)
    modal = _modal_errors_by_run(backbones)
    levels, by_kind = [], {}
    for level in comp.error_by_level:
        control = level.control
        runs = [r for r in measurements.sine if r.control.key() == control.key()]
        kind = level_kind(model.fitted_on, created, control.label())
        by_kind.setdefault(kind, []).extend(runs)
        errors = [modal[r.name] for r in runs if r.name in modal]
        levels.append(LevelPrediction(control, level.force, level.error, kind,
                                      _largest([e[0] for e in errors]), _largest([e[1] for e in errors])))
    return SessionPrediction(comp, levels, backbones, model.fitted_on,
                             {kind: error_over(comp, runs) for kind, runs in by_kind.items()})


def _modal_errors_by_run(backbones: list[BackboneComparison]) -> dict[str, tuple[float, float]]:
    """Run name -> (frequency error, damping error) of its point on a response levels' backbone. A backbone's
    errors are in ascending amplitude (:meth:`Backbone.arrays`), its ``runs`` in the order of its points."""
    out = {}
    for c in backbones:
        m = c.measured
        if not m.method.startswith("single-mode") or len(m.runs) != len(m.points):
            continue
        order = sorted(range(len(m.points)), key=lambda i: m.points[i].amplitude)
        for rank, i in enumerate(order):
            out[m.runs[i]] = (float(c.frequency_error[rank]), float(c.damping_error[rank]))
    return out


def _largest(values: list[float]) -> float:
    values = [v for v in values if np.isfinite(v)]
    return max(values, key=abs) if values else float("nan")
