"""Model against measurement: predicted stepped-sine FRFs and the error metric (docs/workbench.md §3).

The error of a model is the relative FRF error over every measured stepped-sine line and sensor:

    error = sqrt( sum |h_pred - h_meas|^2 / sum |h_meas|^2 )

summed over runs r, lines l and sensors p (0 = perfect). ``error_by_level`` restricts both sums to the runs at
one level (both sweep directions): a force level, or a response-controlled level named by its target response
(:class:`analysis.common.measurements.Control`), and the residual map gives the same ratio per run and line (sum over
sensors only), so where the model fails is visible, not only how much. When the measured receptances carry a
standard deviation, the chi-square ``sum |h_pred - h_meas|^2 / std^2`` is returned too; it decides whether an
improvement is larger than the noise explains. Where some run carries no harmonics (imported FRFs) the
chi-square with each complex value's share capped at the outlier limit (:func:`analysis.fitting.fit.outlier_limit`) of the
values compared is returned as well, as the kbar's chi-square is capped there (:func:`analysis.fitting.fit.capped_chi_square`),
and a fall of either is a fall above the noise (:func:`chi_square_falls`): lines where friction sticks or a contact
closes follow no single-harmonic prediction and carry the least noise where the joint barely moves, so the plain
chi-square is decided by how badly each model misses them, and the capped one by the other lines: a right
friction law can cut the error severalfold while the plain chi-square falls within the noise, and the capped one
falls above it. The capped one alone is no test: where both models are far from every line (no law found yet)
every share is at the cap and it cannot fall, however much the error does.

Every line is predicted at the force measured there (``SineRun.force_per_line``), not the level's nominal
force: a controller holding "0.2 N" measures 0.14-0.23 N across a resonance, and a response-controlled level
lets the force vary tenfold.

Jumps do not dominate it: every run is predicted by a sweep in its own direction and one the other way over the
same lines. Where both give stable solutions that differ, the response is multivalued there, and
``h_pred`` is the one of the two nearer the measured point (summed over sensors): a measurement that jumped a
line or two early is compared with the branch it sits on. Where the swept prediction failed at a line (it did
not converge, or its solution is unstable) and the other sweep found a stable one, that one is compared: a
failed solution predicts nothing, and the rig would have left that branch. Those lines are marked in
``other_branch``, and the jumps are reported separately (:class:`Jump`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from ..common.measurements import Control, Measurements, SineRun
from ..common.statistics import chi_square_noise_bound, outlier_limit
from ..mechanics.model import Model
from .harmonic_balance import CondensedSystem, KbarFunction, NearStart, condense, continue_response, predict_sweeps
from .multiharmonic import HARMONIC_TRUNCATION, predict_multiharmonic_converged, single_harmonic_distortion


@dataclass(frozen=True)
class LevelError:
    """The error of the runs at one level: ``force`` the level's force (N; for a response-controlled level the
    median measured force), ``control`` how it was held (its label names the level)."""

    force: float
    error: float
    control: Control

    def label(self) -> str:
        return self.control.label()

    def to_json(self) -> dict:
        out = {"force": self.force, "error": self.error}
        if self.control.mode != "force":
            out.update(self.control.to_json())
        else:
            out["label"] = self.label()
        return out


@dataclass(frozen=True)
class HarmonicCriterion:
    """Which lines the single-harmonic balance cannot represent well enough (docs/workbench.md §3): those whose
    displacement THD -- measured at the sensors, or implied by the single-harmonic solution itself
    (:func:`analysis.prediction.multiharmonic.single_harmonic_distortion`) -- exceeds ``limit``, and the multivalued
    lines (near a fold the fundamental is so sensitive that harmonics of 0.2 % move it by 2 %). They are
    predicted with ``n_harmonics`` harmonics and the mean, and more, up to ``most_harmonics``, where those left
    out would still move a line's fundamental by more than ``truncation`` of it
    (:func:`analysis.prediction.multiharmonic.predict_multiharmonic_converged`), forces sampled at ``n_time``
    points per period (a friction force's sign change is placed to 1/n_time of the period)."""

    limit: float = 0.01
    n_harmonics: int = 7
    n_time: int = 512
    most_harmonics: int = 28
    truncation: float = HARMONIC_TRUNCATION

    def resolving(self, error: float | None) -> "HarmonicCriterion":
        """This criterion with harmonics enough to resolve an FRF error ``error`` (relative: the FRF error the test
        itself allows, :class:`analysis.identification.between_runs.ErrorFloor`; None where not known): a line's
        truncation a tenth of it (:data:`TRUNCATION_OF_FLOOR`), where that is coarser than
        :data:`~analysis.prediction.multiharmonic.HARMONIC_TRUNCATION`. A change in the fundamental ten times
        below what the test repeats to cannot change which model predicts the test better, and balancing it away
        costs a balance of twice the harmonics a line."""
        coarsest = HARMONIC_TRUNCATION if error is None else max(HARMONIC_TRUNCATION, TRUNCATION_OF_FLOOR * error)
        return replace(self, truncation=coarsest)

    def selects(self, measured: np.ndarray | None, implied: np.ndarray, multivalued: np.ndarray) -> np.ndarray:
        thd = implied if measured is None else np.maximum(np.nan_to_num(np.asarray(measured, float)), implied)
        return (thd > self.limit) | multivalued


#: A line's harmonics resolve its fundamental to this share of the FRF error the test itself allows
#: (:meth:`HarmonicCriterion.resolving`)
TRUNCATION_OF_FLOOR = 0.1


@dataclass
class RunPrediction:
    """The predictions of one run: the sweep in the run's direction and the sweep the other way.

    Attributes
    ----------
    swept, opposite : ndarray (L, P) complex
        Predicted receptance at the sensors, m/N.
    swept_ok, opposite_ok : ndarray (L,) bool
        Converged and stable (:class:`analysis.prediction.harmonic_balance.SweepPrediction`).
    y, opposite_y : ndarray (L, r) complex
        Element phasors of the two sweeps (to continue from, for the fold of a jump; to start the
        multi-harmonic balance on the compared branch).
    """

    swept: np.ndarray
    opposite: np.ndarray
    swept_ok: np.ndarray
    opposite_ok: np.ndarray
    y: np.ndarray
    opposite_y: np.ndarray

    def multivalued(self) -> np.ndarray:
        """Lines where both sweeps found stable solutions that differ (relative 1e-6): coexisting branches."""
        gap = np.linalg.norm(self.swept - self.opposite, axis=1)
        return self.swept_ok & self.opposite_ok & (gap > 1e-6 * np.linalg.norm(self.swept, axis=1))


@dataclass(frozen=True)
class FoldStart:
    """The swept solution at the line before a jump, from which a continuation finds the fold: the element phasors
    ``y`` (r,) complex, m, and the force measured at that line, N."""

    y: np.ndarray
    force: float


@dataclass
class Jump:
    """A jump of one run: where the swept prediction leaves its branch and where the measurement did.

    Attributes
    ----------
    run, direction : str
    predicted_between : (Hz, Hz)
        The two lines (in sweep order) between which the swept prediction jumps.
    fold_hz : float or None
        The predicted jump frequency: the fold where the swept branch ends (continuation); None until located
        (:meth:`Predictor.locate_folds`), and where the continuation found none.
    measured_between : (Hz, Hz)
        The last line measured on the swept branch and the first on the other one.
    lines_early : int
        How many measured lines sit on the other branch before the prediction jumps (0: the measurement
        jumped between the same two lines as the prediction).
    start : FoldStart
        Where the continuation to the fold starts: the swept solution at the line before the jump.
    located : bool
        Whether the fold has been looked for.
    """

    run: str
    direction: str
    predicted_between: tuple[float, float]
    fold_hz: float | None
    measured_between: tuple[float, float]
    lines_early: int
    start: FoldStart = field(repr=False, compare=False)
    located: bool = False

    @property
    def measured_hz(self) -> float:
        """The measured jump frequency: the middle of the two lines it happened between."""
        return 0.5 * (self.measured_between[0] + self.measured_between[1])

    @property
    def predicted_hz(self) -> float:
        """The fold when located, else the middle of the two lines the prediction jumps between."""
        return self.fold_hz if self.fold_hz is not None else 0.5 * sum(self.predicted_between)

    def text(self) -> str:
        early = ("at the same lines" if self.lines_early == 0 else
                 f"{self.lines_early} line{'s' if self.lines_early > 1 else ''} early")
        return (f"run {self.run} ({self.direction}): predicted jump at {self.predicted_hz:.5g} Hz, measured "
                f"between {self.measured_between[0]:.5g} and {self.measured_between[1]:.5g} Hz ({early})")

    def to_json(self) -> dict:
        return {"run": self.run, "direction": self.direction, "predicted_hz": self.predicted_hz,
                "fold_hz": self.fold_hz, "predicted_between_hz": list(self.predicted_between),
                "measured_hz": self.measured_hz, "measured_between_hz": list(self.measured_between),
                "lines_early": self.lines_early}


@dataclass
class Comparison:
    """How well a model predicts the measured stepped-sine FRFs.

    Attributes
    ----------
    error : float
        Relative FRF error over all runs (module docstring).
    error_by_level : list of LevelError
    residual_map : dict run name -> ndarray (L,)
        Relative error per line.
    predicted : dict run name -> ndarray (L, P) complex
        Swept prediction (the run's direction) at the sensors, m/N.
    converged : dict run name -> ndarray (L,) bool
        Whether the harmonic balance converged at each line.
    chi_square : float or None
        ``sum |residual|^2 / std^2`` when the measurement has standard deviations.
    capped_chi_square : float or None
        The same with each complex value's share capped at the outlier limit, where some run carries no
        harmonics (None otherwise).
    n_observations : int
        Real numbers compared (2 per complex FRF value).
    compared : dict run name -> ndarray (L, P) complex
        The prediction each measured line was compared with (the swept one, or the nearer coexisting branch).
    other_branch : dict run name -> ndarray (L,) bool
        Lines where the measurement sits on another branch than the swept prediction.
    jumps : list of Jump
    multiharmonic : dict run name -> ndarray (L,) bool
        Lines predicted by multi-harmonic balance (:class:`HarmonicCriterion`).
    """

    error: float
    error_by_level: list[LevelError]
    residual_map: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]
    converged: dict[str, np.ndarray]
    chi_square: float | None
    n_observations: int
    compared: dict[str, np.ndarray] = field(default_factory=dict)
    other_branch: dict[str, np.ndarray] = field(default_factory=dict)
    jumps: list[Jump] = field(default_factory=list)
    multiharmonic: dict[str, np.ndarray] = field(default_factory=dict)
    capped_chi_square: float | None = None

    @property
    def times_the_noise(self) -> float | None:
        """The FRF residual in units of the measured noise: sqrt of the chi-square over its expectation from the
        noise alone, one per complex value (1 where the model is within the noise); None without standard
        deviations."""
        if self.chi_square is None or self.n_observations == 0:
            return None
        return float(np.sqrt(self.chi_square / (self.n_observations / 2)))

    def other_branch_hz(self, runs: Sequence[SineRun]) -> dict[str, list[float]]:
        """Frequencies of the lines measured on another branch, per run that has any."""
        return {r.name: [float(f) for f in np.asarray(r.frequency_hz)[self.other_branch[r.name]]]
                for r in runs if r.name in self.other_branch and self.other_branch[r.name].any()}

    def to_json(self) -> dict:
        return {"error": self.error,
                "error_by_level": [e.to_json() for e in self.error_by_level],
                "jumps": [j.to_json() for j in self.jumps],
                "multiharmonic_lines": int(sum(m.sum() for m in self.multiharmonic.values()))}


@dataclass
class FundamentalBias:
    """:meth:`Predictor.fundamental_bias`: per run, (lines, elements) the kbar departure; and the comparison,
    with harmonics, of the model it was computed from."""
    bias: dict[str, np.ndarray]
    comparison: Comparison


class Predictor:
    """Predicts every stepped-sine run of a measurement set for a structure with elements at fixed places.

    The condensation (the expensive part for a beam) depends only on the structure and where the elements sit,
    so it is done once and reused for every set of laws tried -- the candidate ranking tries many.
    Runs sharing lines, excitation and direction are predicted together (force levels and both sweep
    directions batched).
    """

    def __init__(self, model: Model, measurements: Measurements):
        self.model = model
        self.runs = list(measurements.sine)
        self._groups: dict[tuple, list[SineRun]] = {}
        for run in self.runs:
            key = (run.excitation_dof, run.direction, tuple(np.round(run.frequency_hz, 9)))
            self._groups.setdefault(key, []).append(run)
        self._systems: dict[tuple, CondensedSystem] = {}
        self._rows = {run.name: [model.structure.index(d) for d in run.sensor_dofs] for run in self.runs}

    def with_laws(self, laws: dict[int, list]) -> "Predictor":
        """A predictor for the same structure, measurements and element places whose elements carry other laws
        (element index -> list of LawTerm); it shares the condensation, which depends on neither."""
        model = self.model.copy()
        for i, terms in laws.items():
            model.elements[i].laws = list(terms)
        out = Predictor.__new__(Predictor)
        out.model, out.runs, out._groups, out._systems, out._rows = model, self.runs, self._groups, self._systems, \
            self._rows
        return out

    def _system(self, key) -> CondensedSystem:
        if key not in self._systems:
            exc, _, freqs = key
            self._systems[key] = condense(self.model.structure, self.model.elements, exc, 2 * np.pi * np.array(freqs))
        return self._systems[key]

    def _functions(self, kbar_fns):
        return list(kbar_fns) if kbar_fns is not None else [e.describing_function for e in self.model.elements]

    def predict(self, kbar_fns: Sequence[KbarFunction] | None = None,
                near: dict[str, RunPrediction] | None = None) -> dict[str, RunPrediction]:
        """Both sweeps of every run at the sensors, for the given element describing functions (default: the
        model elements' laws). ``near``: the predictions for describing functions a hair away, each sweep started
        from them at every line (a finite difference's step; :func:`predict_sweeps`)."""
        fns = self._functions(kbar_fns)
        out = {}
        for key, runs in self._groups.items():
            exc, direction, freqs = key
            system = self._system(key)
            other = "down" if direction == "up" else "up"
            start = None if near is None else NearStart(
                np.stack([near[r.name].y for r in runs] + [near[r.name].opposite_y for r in runs], axis=1),
                np.stack([near[r.name].swept_ok for r in runs] + [near[r.name].opposite_ok for r in runs], axis=1))
            swept, opposite = predict_sweeps(self.model.structure, self.model.elements, exc, system.w,
                                             np.stack([r.force_per_line for r in runs], axis=1), (direction, other),
                                             fns, system, start)
            for b, run in enumerate(runs):
                rows = self._rows[run.name]
                out[run.name] = RunPrediction(swept.receptance[:, b, rows], opposite.receptance[:, b, rows],
                                              swept.converged[:, b] & swept.stable[:, b],
                                              opposite.converged[:, b] & opposite.stable[:, b], swept.y[:, b],
                                              opposite.y[:, b])
        return out

    def compare(self, kbar_fns: Sequence[KbarFunction] | None = None, locate_folds: bool = False,
                harmonics: HarmonicCriterion | None = None) -> Comparison:
        """The error for the given describing functions. ``locate_folds`` also finds the fold of every jump by
        continuation (a report's: :meth:`locate_folds`); ``harmonics`` predicts the lines it selects by
        multi-harmonic balance (the model's own error; the ranking does without, and ``harmonics`` needs the
        model's own laws: ``kbar_fns`` None)."""
        predictions = self.predict(kbar_fns)
        comp = compare_predictions(self.runs, predictions)
        if locate_folds:
            self.locate_folds(comp, kbar_fns)
        if harmonics is not None:
            comp = self._with_harmonics(comp, self._multiharmonic_lines(comp, predictions, harmonics))
        return comp

    def _with_harmonics(self, comp: Comparison, balanced: list[tuple]) -> Comparison:
        """``comp`` with the lines of ``balanced`` (:meth:`_multiharmonic_lines`) predicted by multi-harmonic
        balance (the fundamental)."""
        compared, selected = dict(comp.compared), {}
        for run, lines, mh in balanced:
            mask = np.zeros(len(run.w), bool)
            if mh is not None:
                fundamental = mh.receptance(run.force_per_line[lines])[mh.converged][:, self._rows[run.name]]
                lines = lines[mh.converged]
                compared[run.name] = compared[run.name].copy()
                compared[run.name][lines] = fundamental
                mask[lines] = True
            selected[run.name] = mask
        return _scored(self.runs, comp.predicted, comp.converged, compared, comp.other_branch, comp.jumps, selected)

    def _multiharmonic_lines(self, comp: Comparison, predictions: dict[str, RunPrediction],
                             criterion: HarmonicCriterion) -> list[tuple]:
        """Each run, the lines the criterion selects, and their multi-harmonic balance (None where none is
        selected), each line started from the single-harmonic solution of the branch it was compared with."""
        structure, elements = self.model.structure, self.model.elements
        out = []
        for run in self.runs:
            pred, rows = predictions[run.name], self._rows[run.name]
            y = np.where(comp.other_branch[run.name][:, None], pred.opposite_y, pred.y)
            force = run.force_per_line
            implied = single_harmonic_distortion(structure, elements, run.excitation_dof, run.w, force, y,
                                                 criterion.n_harmonics)[:, rows].max(axis=1)
            lines = np.flatnonzero(criterion.selects(run.distortion, implied, pred.multivalued()))
            mh = (predict_multiharmonic_converged(structure, elements, run.excitation_dof, run.w[lines],
                                                  force[lines], y[lines], criterion.n_harmonics, criterion.n_time,
                                                  criterion.most_harmonics, criterion.truncation)
                  if len(lines) else None)
            out.append((run, lines, mh))
        return out

    def fundamental_bias(self, criterion: HarmonicCriterion) -> FundamentalBias:
        """Per run, (lines, elements): what the model's own harmonics add to the kbar the closed-form
        identification measures -- the fundamental's force over the fundamental's motion, by multi-harmonic
        balance at the lines the criterion selects, less the describing function at that motion's amplitude
        (docs/fitting.md, "The fundamental's bias"); zero at the other lines and where the balance did not
        converge. With it, the model's comparison with those harmonics (the same balance). Needs every element's
        laws (a time-domain force)."""
        predictions = self.predict()
        comp = compare_predictions(self.runs, predictions)
        balanced = self._multiharmonic_lines(comp, predictions, criterion)
        out = {}
        for run, lines, mh in balanced:
            bias = np.zeros((len(run.w), len(self.model.elements)), complex)
            if mh is not None:
                ok = mh.converged & (np.abs(mh.element_harmonics[:, 1]) > 0).all(axis=1)
                Y1, F1 = mh.element_harmonics[ok, 1], mh.element_forces[ok, 1]
                for i, el in enumerate(self.model.elements):
                    bias[lines[ok], i] = F1[:, i] / Y1[:, i] - el.describing_function(np.abs(Y1[:, i]),
                                                                                     run.w[lines[ok]])
            out[run.name] = bias
        return FundamentalBias(out, self._with_harmonics(comp, balanced))

    def locate_folds(self, comp: Comparison, kbar_fns: Sequence[KbarFunction] | None = None) -> None:
        """Set ``fold_hz`` of each jump of ``comp`` (the comparison made with ``kbar_fns``) not looked for yet:
        continuation from the swept solution at the last line before the jump towards the next line, up to the
        first fold on the way, where the swept branch ends. Only a report reads the fold: a comparison that
        judges a model goes without it, since a continuation costs many balances per jump."""
        fns = self._functions(kbar_fns)
        runs = {r.name: r for r in self.runs}
        for jump in comp.jumps:
            if jump.located:
                continue
            f_a, f_b = jump.predicted_between
            # one force along the continuation: the one measured at the line before the jump
            curve = continue_response(self.model.structure, self.model.elements, runs[jump.run].excitation_dof,
                                      jump.start.force, 2 * np.pi * f_a, 2 * np.pi * f_b, kbar_fns=fns,
                                      y_start=jump.start.y, until_fold=True)
            if len(curve.folds):
                jump.fold_hz = float(curve.fold_frequencies[0] / (2 * np.pi))
            jump.located = True


def compare_predictions(runs: Sequence[SineRun], predictions: dict[str, RunPrediction]) -> Comparison:
    """The error metric, per level and per line, from the predictions of every run (module docstring)."""
    compared, other_branch, jumps = {}, {}, []
    for run in runs:
        pred = predictions[run.name]
        swept_num = np.sum(np.abs(pred.swept - run.receptance) ** 2, axis=1)
        other_num = np.sum(np.abs(pred.opposite - run.receptance) ** 2, axis=1)
        # the other sweep's where both are stable and it is nearer, or where it alone found a stable solution (a
        # swept prediction that failed is none: the rig would have jumped there)
        other = (pred.multivalued() & (other_num < swept_num)) | (~pred.swept_ok & pred.opposite_ok)
        compared[run.name] = np.where(other[:, None], pred.opposite, pred.swept)
        other_branch[run.name] = other
        jumps += _jumps(run, pred, other)
    return _scored(runs, {n: p.swept for n, p in predictions.items()},
                   {n: p.swept_ok for n, p in predictions.items()}, compared, other_branch, jumps)


def _scored(runs, predicted, converged, compared, other_branch, jumps, multiharmonic=None) -> Comparison:
    """A comparison whose line-by-line predictions are ``compared``: the error, per level and per line."""
    num = den = 0.0
    chi2 = 0.0
    have_std = all(r.receptance_std is not None for r in runs)
    cap = outlier_limit(sum(np.asarray(r.receptance).size for r in runs))
    capped = 0.0
    blind = any(r.distortion is None for r in runs)
    by_level: dict[tuple, list] = {}
    residual_map = {}
    n_obs = 0
    for run in runs:
        diff = compared[run.name] - run.receptance
        line_num, line_den = _line_sums(run, compared[run.name])
        residual_map[run.name] = np.sqrt(line_num / line_den)
        rn, rd = float(line_num.sum()), float(line_den.sum())
        num, den = num + rn, den + rd
        acc = by_level.setdefault(run.control.key(), [0.0, 0.0, run])
        acc[0] += rn
        acc[1] += rd
        n_obs += 2 * diff.size
        if have_std:
            z = np.abs(diff) ** 2 / np.asarray(run.receptance_std) ** 2
            chi2 += float(np.sum(z))
            capped += float(np.sum(np.minimum(z, cap) if run.distortion is None else z))
    return Comparison(float(np.sqrt(num / den)) if den else float("nan"),
                      _level_errors(by_level.values()),
                      residual_map, predicted, converged, chi2 if have_std else None, n_obs,
                      compared, other_branch, jumps, multiharmonic or {},
                      capped if have_std and blind else None)


def _line_sums(run: SineRun, compared: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per line, the numerator and denominator of the relative FRF error: ``sum_p |h_pred - h_meas|^2`` and
    ``sum_p |h_meas|^2`` over the sensors (module docstring)."""
    return (np.sum(np.abs(compared - run.receptance) ** 2, axis=1),
            np.sum(np.abs(run.receptance) ** 2, axis=1))


def error_over(comp: Comparison, runs: Sequence[SineRun]) -> float:
    """The relative FRF error of ``comp`` restricted to ``runs`` (their lines pooled, as ``error`` pools every
    run); NaN for no runs."""
    return pooled_error([(comp, runs)])


def pooled_error(parts: Sequence[tuple[Comparison, Sequence[SineRun]]]) -> float:
    """The relative FRF error of several comparisons, each over its own runs, their lines pooled as one (a
    session whose levels were predicted by different fits); NaN for no runs."""
    num = den = 0.0
    for comp, runs in parts:
        for run in runs:
            line_num, line_den = _line_sums(run, comp.compared[run.name])
            num, den = num + float(line_num.sum()), den + float(line_den.sum())
    return float(np.sqrt(num / den)) if den else float("nan")


def chi_square_falls(base: Comparison, comp: Comparison, dof: float, false_alarm: float) -> bool:
    """Whether the FRF chi-square falls from ``base`` to ``comp`` by more than the noise explains at the
    false-alarm rate for ``dof`` parameters: the plain one, or where some run carries no harmonics the capped one
    (module docstring). True where the measurement has no standard deviations: nothing to judge against."""
    if base.chi_square is None or comp.chi_square is None:
        return True
    q = chi_square_noise_bound(1.0, dof, false_alarm)
    return bool(base.chi_square - comp.chi_square > q or (
        base.capped_chi_square is not None and comp.capped_chi_square is not None
        and base.capped_chi_square - comp.capped_chi_square > q))


def _level_errors(levels) -> list[LevelError]:
    """One LevelError per level from its sums [numerator, denominator, a run of it]: force-controlled levels
    first by force, then the others by their control DOF, quantity and target."""
    out = [LevelError(float(run.force) if run.control.mode != "force" else run.control.target,
                      float(np.sqrt(num / den)), run.control) for num, den, run in levels]
    return sorted(out, key=lambda e: e.control.order())


def _jumps(run: SineRun, pred: RunPrediction, other: np.ndarray) -> list[Jump]:
    """The jumps of one run, in sweep order: each stretch of multivalued lines that ends before the last line
    is where the swept prediction leaves its branch (between its last line and the next); the measurement left
    it where the trailing lines of the stretch measured on the other branch begin."""
    f = np.asarray(run.frequency_hz, float)
    order = np.argsort(f) if run.direction == "up" else np.argsort(-f)
    multi, on_other = pred.multivalued()[order], other[order]
    out = []
    i = 0
    while i < len(order):
        if not multi[i]:
            i += 1
            continue
        end = i
        while end + 1 < len(order) and multi[end + 1]:
            end += 1
        if end + 1 < len(order):
            first_other = end + 1
            while first_other > i and on_other[first_other - 1]:
                first_other -= 1
            before = max(first_other - 1, 0)
            a = order[end]
            out.append(Jump(run.name, run.direction, (float(f[a]), float(f[order[end + 1]])), None,
                            (float(f[order[before]]), float(f[order[first_other]])), end + 1 - first_other,
                            FoldStart(pred.y[a].copy(), float(run.force_per_line[a]))))
        i = end + 1
    return out


def gain_phrase(gain: float) -> str:
    """An error ratio ``before / after`` as a test engineer reads it: "x3.20 better" or, below 1, "x1.02 worse"
    (the factor by which the error grew)."""
    if gain >= 1.0 or gain <= 0.0 or not np.isfinite(gain):
        return f"x{gain:.2f} better"
    return f"x{1.0 / gain:.2f} worse"


def kbar_functions_with(elements, replace: dict[int, Callable]) -> list[KbarFunction]:
    """The elements' describing functions with some replaced (index -> function)."""
    return [replace.get(i, el.describing_function) for i, el in enumerate(elements)]
