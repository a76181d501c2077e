"""How well a model's laws predict levels their fit did not see: two-fold cross-validation over the levels
(docs/workbench.md §6).

The levels, in :meth:`analysis.common.measurements.Control.order`, are split in halves two ways: alternate
(1, 3, 5, ... and 2, 4, 6, ...), so that the check asks for interpolation between levels, and lower against upper,
so that it asks for extrapolation both ways, beyond the levels seen, which is what a law is for and where a law
that fits its own lines fails first. For each half the model's laws -- the same laws, their current values as starting values -- are refitted on
that half alone by a fresh workbench (reference, identification, fit), and the fitted model predicts every level
of the session with nothing refitted (:func:`analysis.prediction.held_out.predict_session`). A fold's held-out
error against its fitted error says what the in-sample error alone cannot: whether the model describes its own
lines or the joint.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..common.measurements import Measurements
from ..common.parallel import map_tasks
from ..identification.between_runs import BetweenRuns
from ..laws.base import LimitForm
from ..mechanics.model import FittedOn, Model
from ..missing.diagnosis import RankingRules
from ..missing.modal_judge import ModalChange, ModalRules, measures_modes
from ..prediction.backbone import ModalError, ModalResiduals
from ..prediction.comparison import pooled_error
from ..prediction.held_out import FITTED, HELD_OUT, SessionPrediction, predict_session
from .workbench import Workbench


@dataclass(frozen=True)
class Fold:
    """One half: ``levels`` the labels it was fitted on, ``prediction`` of every level by the refitted model;
    ``others_fitted_error`` the fitted error of the levels this half held out, where another half was fitted on
    exactly them (NaN where none was)."""

    levels: tuple[str, ...]
    prediction: SessionPrediction
    others_fitted_error: float = float("nan")

    @property
    def fitted_error(self) -> float:
        return self.prediction.error_of(FITTED)

    @property
    def held_out_error(self) -> float:
        return self.prediction.error_of(HELD_OUT)

    @property
    def ratio(self) -> float:
        """The held-out error over this half's own fitted error: the two are of different levels."""
        return self.held_out_error / self.fitted_error if self.fitted_error > 0 else float("inf")

    @property
    def cost(self) -> float:
        """The held-out error over the error of the same levels fitted on themselves: what not seeing them costs.
        Levels differ in how well the test repeats them (a force-controlled level drifts through its resonance,
        a response-controlled one is held at it), so :attr:`ratio` also measures which half is the harder one to
        fit; the same levels against themselves measure the prediction alone. NaN where no half was fitted on
        exactly the held-out levels."""
        e = self.others_fitted_error
        return self.held_out_error / e if e > 0 else float("nan")


def cross_validate(wb: Workbench, created: str) -> list[Fold]:
    """The folds (up to four) of ``wb``'s model on ``wb``'s measurements (a session created at ``created``); none for a
    session with fewer than two stepped-sine levels (nothing to hold out)."""
    controls = wb.measurements.level_controls()
    folds = [_fold(wb, half, created) for half in _halves(controls)] if len(controls) >= 2 else []
    fitted = {frozenset(f.levels): f.fitted_error for f in folds}
    every = frozenset(c.label() for c in controls)
    return [replace(f, others_fitted_error=fitted.get(every - frozenset(f.levels), float("nan"))) for f in folds]


def _fold(wb: Workbench, half: list, created: str) -> Fold:
    """``wb``'s laws refitted on the levels ``half`` alone (:func:`_refitted`), and every level of the session
    predicted by them."""
    labels = tuple(c.label() for c in half)
    fitted = replace(_refitted(wb, half, as_fitted(wb)).model, fitted_on=FittedOn("", created, labels))
    return Fold(labels, predict_session(fitted, wb.measurements, created, wb.harmonics, folds=False))


@dataclass(frozen=True)
class AsFitted:
    """A model as a fit of the whole test left it, the scatter between runs (element -> yardstick) its samples
    were judged by, and the limits its laws were taken in (:meth:`Workbench.limits`): what a fit on part of the
    levels starts from and keeps (:func:`as_fitted`)."""

    model: Model
    yardsticks: dict[str, BetweenRuns]
    limits: dict[str, dict[int, LimitForm]]


def as_fitted(wb: Workbench) -> AsFitted:
    """``wb``'s model, yardsticks and limits as they stand, kept apart from what ``wb`` does next."""
    return AsFitted(wb.model.copy(), wb.yardsticks(), wb.limits())


def _refitted(wb: Workbench, levels: list, start: AsFitted) -> Workbench:
    """A fresh workbench on ``wb``'s measurements at ``levels`` alone with the laws of ``start`` refitted from their
    current values (reference, identification, fit; its own error is not computed; started at the whole test's
    fit), its samples judged by the whole test's scatter between runs (:meth:`Workbench._yardstick`) and its laws
    kept in the limits the whole test's fit took them in (:meth:`Workbench.limits`)."""
    fold = Workbench(start.model, _at(wb, levels), wb.distortion_limit, wb.harmonics, start.yardsticks,
                     started_at_fit=True, limits=start.limits)
    fold.prepare()
    return fold


def _sees_its_laws(fold: Workbench) -> bool:
    """Whether a fold's fit sees every law of its model: each law's size beyond its 95 % interval of zero
    (:attr:`analysis.fitting.results.TermFit.size_unseen`)."""
    return all(not t.size_unseen for r in fold.reports.values() if r.fit is not None for t in r.fit.terms)


def _at(wb: Workbench, levels: list) -> Measurements:
    return wb.measurements.at_levels({c.key() for c in levels})


#: Folds of :func:`held_out`: the levels are dealt into at most this many, interleaved
HELD_OUT_FOLDS = 3


#: The fewest levels a fold's fit must see for its held-out error to judge a law whatever that fit sees: a fit
#: on one level may not determine a law that level does not show (a clearance that closes, a quintic, at the
#: other level only), and what it then predicts there measures that, not the law
LEVELS_TO_JUDGE = 2


@dataclass(frozen=True)
class HeldOut:
    """A model's FRF error on levels its fit did not see: ``error`` over all of them pooled, ``folds`` per fold
    (the levels one refit predicted), in fold order; ``seen`` the fewest levels any fold's fit saw;
    ``sees_its_laws`` whether every fold's fit saw every law of the model (:func:`_sees_its_laws`); ``modes`` the
    natural frequency and damping errors of the held-out response levels, each predicted by the fit that did not
    see it, pooled over the folds (None where the session measures no mode)."""

    error: float
    folds: tuple[float, ...]
    seen: int = 0
    sees_its_laws: bool = False
    modes: ModalError | None = None

    @property
    def judges(self) -> bool:
        """Whether these folds can judge the model's laws: every fold's fit saw :data:`LEVELS_TO_JUDGE` levels,
        or fewer and still saw the size of every law. A fit that sees a law on one level and predicts another
        tests the law where it is meant to hold, beyond the amplitudes it was fitted on; a fit that does not see
        it tests nothing of it."""
        return bool(self.folds) and (self.seen >= LEVELS_TO_JUDGE or self.sees_its_laws)

    def better_than(self, other: "HeldOut") -> bool:
        """Whether this model predicts the folds better than ``other`` did on the same folds. Where every fold's
        fit saw :data:`LEVELS_TO_JUDGE` levels or more: better on every fold -- each is data both fits left out,
        so a model that describes the joint rather than its own lines does better on each, and no margin needs a
        number. Where each saw fewer (two levels, each predicting the other): better on at least one. Each such
        fold is an extrapolation one way, and a law fitted on one level carries its parameters' uncertainty to
        the other, amplified by its power of the amplitude going up, while the model without it absorbs part of
        the effect into the laws it keeps; a law of the joint predicts better at least one way, and one that
        predicts worse both ways describes only the level it was fitted on. A fold this model does not predict
        (NaN) is not better; one only the other did not predict is."""
        if not len(self.folds) == len(other.folds) > 0:
            return False
        better = [bool(np.isfinite(a) and not a >= b) for a, b in zip(self.folds, other.folds)]
        return all(better) if self.every_fold_with(other) else any(better)

    def every_fold_with(self, other: "HeldOut") -> bool:
        """Whether :meth:`better_than` against ``other`` asks for every fold (each fold's fit saw
        :data:`LEVELS_TO_JUDGE` levels or more), not for one of two."""
        return min(self.seen, other.seen) >= LEVELS_TO_JUDGE


NOT_CHECKED = HeldOut(float("nan"), ())


def predicts_no_better(before: HeldOut, after: HeldOut, min_gain: float = RankingRules().min_gain,
                       modal: ModalRules | None = ModalRules()) -> str:
    """Why a law is refused for what its model predicts, "" where it stays. Two witnesses speak of the levels the
    fits did not see: their FRFs, and -- where the session measures the modes -- their natural frequency and damping
    against amplitude (:attr:`HeldOut.modes`). A law stays where the model with it predicts better in one of them
    and worse by the margin a law must bring (``min_gain``) in neither:

    - better in the FRFs: every held-out fold better (:meth:`HeldOut.better_than`; of two levels, each predicting
      the other, at least one). A law that fits its own lines better and predicts the levels its fit did not see
      no better describes those lines, not the joint;
    - better in the modes: either curve better by ``min_gain`` and neither worse by it (:class:`ModalChange`,
      the points of every fold pooled: a fold holds a few response levels, one point of each curve each). On
      measured data the FRF error of a level is mostly the test's own drift between runs, the mode moving by
      about its half-power bandwidth, which no law predicts. The mode's frequency and damping at each amplitude
      are what a joint's law is for: the drift shifts the frequency by a fraction of a per cent and leaves the
      damping, where near resonance it changes the lines by tens of per cent;
    - worse by the margin: the held-out FRF error pooled, or either curve, ``min_gain`` times the model's without
      the law. The same margin in every witness, as in the ranking's veto (:mod:`analysis.missing.modal_judge`).

    Nothing is judged where a fold's fit saw too little to determine a law (:attr:`HeldOut.judges`: one level that
    does not show the size of every law of either model). ``modal`` None: the FRFs alone judge, as the loop's
    ranking does without the modes (``AutoRules.modes``)."""
    if not (before.judges and after.judges):
        return ""
    change = _modal_change(before, after, modal)
    frf_worse = after.error > min_gain * before.error
    modes_worse = change is not None and change.worse(min_gain)
    better = after.better_than(before) or (change is not None and change.better(min_gain))
    if better and not (frf_worse or modes_worse):
        return ""
    folds = ", ".join(f"{a:.3g} against {b:.3g}" for a, b in zip(after.folds, before.folds))
    rule = ("every held-out fold better" if after.every_fold_with(before) else
            "at least one of the two levels better from the other")
    modes = "" if change is None else f"; the held-out response levels' {change.words()}"
    head = (f"it predicts the levels its fits did not see worse, its {'FRFs' if frf_worse else 'modes'} by more than "
            f"the x{min_gain:g} a law must bring" if frf_worse or modes_worse else
            "it does not predict the levels its fits did not see better")
    if change is not None:
        rule += f", or the held-out natural frequency or damping better by x{min_gain:g}, neither worse by it"
    return (f"{head}: held-out {after.error:.3g} against {before.error:.3g} without it (per fold {folds}){modes}; "
            f"a law is kept only where it predicts {rule}")


def _modal_change(before: HeldOut, after: HeldOut, modal: ModalRules | None) -> ModalChange | None:
    """What the law does to the held-out levels' modes, None where either model's were not measured (or the modes
    do not judge: ``modal`` None)."""
    if modal is None or not all(m is not None and m.measured for m in (before.modes, after.modes)):
        return None
    return ModalChange.of(before.modes, after.modes, modal)


def held_out(wb: Workbench, folds: int = HELD_OUT_FOLDS) -> HeldOut:
    """The FRF error of ``wb``'s model on levels its fit did not see: the levels, in order, dealt into ``folds``
    interleaved folds (level i into fold i mod K, K at most the number of levels), the laws refitted on all the
    levels but one fold's, which they then predict; every level's lines pooled as predicted by the fit that did not
    see it, and each fold's alone. Beside the in-sample error it says whether a step of the loop describes the
    joint or its own lines. Each fit sees all but a K-th of the levels (with three levels, two of them; with
    twelve, eight): a fit on a half or on a single level leaves laws with more parameters than it determines, and
    its held-out error would measure that, not the model. K folds cost K refits. :data:`NOT_CHECKED` for a
    session of fewer than two stepped-sine levels."""
    return held_out_of_each(wb, [as_fitted(wb)], folds)[0]


def held_out_of_each(wb: Workbench, starts: list[AsFitted], folds: int = HELD_OUT_FOLDS) -> list[HeldOut]:
    """:func:`held_out` of each of the models ``starts`` (``wb`` as it stood once otherwise fitted: a law taken off
    and its element refitted, :meth:`Workbench.without`, or read otherwise, :meth:`Workbench.read_as`), on ``wb``'s
    measurements: the folds of them all are the tasks of one map, as they need nothing of each other. Three folds
    of one model on two cores take two rounds of refits, two models' six folds three rounds instead of four. Each
    fold is the refit :func:`held_out` makes of that model alone."""
    splits = interleaved(wb.measurements.level_controls(), folds)
    if not splits:
        return [NOT_CHECKED] * len(starts)
    measured = [_at(wb, held) for _, held in splits]     # only the levels a fit did not see are predicted

    modes = measures_modes(wb.measurements)

    def one(j: int) -> tuple:
        v, k = divmod(j, len(splits))
        fold = _refitted(wb, splits[k][0], starts[v])
        predicted = predict_session(fold.model, measured[k], "", wb.harmonics, folds=False)
        # the held-out levels' modes, as the prediction's backbones compared them
        residuals = ModalResiduals.of([(c.measured, c.predicted) for c in predicted.backbones])
        return predicted.comparison, _sees_its_laws(fold), residuals

    done = map_tasks(one, len(starts) * len(splits))
    out = []
    for v in range(len(starts)):
        mine = done[v * len(splits):(v + 1) * len(splits)]
        parts = [(comparison, m.sine) for (comparison, _, _), m in zip(mine, measured)]
        held_modes = ModalResiduals.joined([r for _, _, r in mine]).error() if modes else None
        out.append(HeldOut(pooled_error(parts), tuple(pooled_error([part]) for part in parts),
                           min(len(seen) for seen, _ in splits), all(sees for _, sees, _ in mine), held_modes))
    return out


def interleaved(levels: list, folds: int) -> list[tuple[list, list]]:
    """``levels`` dealt into ``folds`` interleaved folds (level i into fold i mod K, K = min(folds, len(levels))):
    per fold, (the levels a fit sees, the levels it predicts). Every level is predicted once; none for fewer
    than two levels."""
    k = min(folds, len(levels))
    if k < 2:
        return []
    return [([c for j, c in enumerate(levels) if j % k != i], levels[i::k]) for i in range(k)]


def _halves(controls: list) -> list[list]:
    """Alternate halves, then the lower and upper halves (the lower taking the middle level of an odd count);
    a split that repeats an earlier one is left out."""
    middle = (len(controls) + 1) // 2
    out = []
    for half in (controls[0::2], controls[1::2], controls[:middle], controls[middle:]):
        if half and all({c.key() for c in half} != {c.key() for c in h} for h in out):
            out.append(half)
    return out
