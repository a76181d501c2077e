"""The model workbench: reference model, identification, verdicts, fits, prediction, error, missing effects.

One object carries a model through the loop a test engineer works (docs/workbench.md):

1. :meth:`Workbench.update_reference` -- natural frequencies and damping from the random run (modal fit),
   then the structure parameters marked uncertain updated to them (eigenvalue sensitivity);
2. :meth:`Workbench.identify` -- kbar of every element at every well-conditioned stepped-sine line and force
   level, with its standard deviation, and a linear/nonlinear verdict per element. Lines whose motion is far
   from harmonic (displacement THD above ``distortion_limit``, 5 %: stick-slip with stops, impacts) are left
   out, since a describing function describes a harmonic motion;
3. :meth:`Workbench.fit` -- each element's laws fitted to its kbar samples;
4. :meth:`Workbench.compare` -- FRFs of every run predicted by harmonic balance, the error and where it fails;
5. :meth:`Workbench.candidates` / :meth:`Workbench.add` -- the ranked missing effects, and adding one; every
   step is kept in :attr:`Workbench.history` so the error falling is visible step by step;
6. :meth:`Workbench.unexplained` -- the elements whose kbar their laws leave unexplained (an effect outside the
   library), each with the error a non-parametric part would give (``add(element, "nonparametric")`` adds it).

Analysis sees only measured data (``Measurements``) and the user's model: never the rig a simulated session
came from.
"""
from __future__ import annotations

from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, replace
from typing import Callable, Iterator

import numpy as np

from ..common.errors import InputError
from ..common.fixed_point import secant_step
from ..common.measurements import Measurements, SineRun
from ..fitting.fit import LawFit, fit_laws
from ..fitting.limits import fit_in_limits, settle_in_limits
from ..identification.between_runs import BetweenRuns, ErrorFloor, RunSensitivity, between_runs, frf_error_floor
from ..identification.identify import identify_complex_stiffness
from ..identification.linearity import LinearityVerdict, linearity_verdict
from ..laws import get_law
from ..laws.base import LimitForm, LimitReading
from ..linear.reference import ReferenceReport, reference_from_random
from ..mechanics.elements import Element, LawTerm
from ..mechanics.model import Model
from ..mechanics.nonparametric import NAME as NONPARAMETRIC, NonParametric, fit_nonparametric
from ..missing.diagnosis import Candidate, ElementSamples, RankingRules, check_model_form, rank_candidates, rank_pairs
from ..missing.unexplained import NonParametricOffer, offer_nonparametric, unexplained
from ..prediction.comparison import Comparison, FundamentalBias, HarmonicCriterion, LevelError, Predictor
from ..prediction.frf_refinement import refine_against_frfs, terms_function
from ..search.discovery import AmplitudeDependence, Discovery, DiscoveryRules, amplitude_dependence, discover


@dataclass
class ElementReport:
    """What identification found for one element."""

    name: str
    samples: ElementSamples | None
    verdict: LinearityVerdict | None
    lines_used: int
    lines_flagged: int
    fit: LawFit | None = None
    yardstick: BetweenRuns | None = None    # the scatter between runs against the line noise; None without noise

    def to_json(self, element) -> dict:
        laws = []
        for j, term in enumerate(element.laws):
            reading = self.reading(term)
            # a parameter its limit leaves open is no finding (docs/laws.md, "Limits"): null, as in the text;
            # the model file keeps the fitted value, which the prediction needs
            open_in_limit = set() if reading is None else set(reading.undetermined)
            entry = {"law": term.law.name,
                     "params": {k: (None if k in open_in_limit else v) for k, v in term.values.items()},
                     "from_reference": term.law.from_reference}
            undetermined = set(open_in_limit)
            if self.fit is not None:
                entry["stderr"] = {k: (None if k in open_in_limit or not np.isfinite(v) else float(v))
                                   for k, v in self.fit.terms[j].stderr.items()}
                undetermined |= set(self.fit.terms[j].undetermined)
            if self.fit is not None or reading is not None:
                entry["undetermined"] = [k for k in term.values if k in undetermined]
            if reading is not None:
                entry["reading"] = reading.to_json()
                found = None if self.fit is None else self.fit.terms[j].limit
                if found is not None:       # the limit's own fit: the errors of the combination it determines
                    entry["reading"]["stderr"] = {k: float(found.stderr[k]) for k in reading.values
                                                  if k in found.stderr}
            laws.append(entry)
        out = {"name": self.name, "verdict": None if self.verdict is None else
               ("linear" if self.verdict.linear else "nonlinear"),
               "evidence": "" if self.verdict is None else self.verdict.evidence,
               "lines_used": self.lines_used, "lines_flagged": self.lines_flagged, "laws": laws,
               "in_reference": element.in_reference}
        if element.origin is not None:
            out["origin"] = {"amplitude": element.origin.X, "frequency": element.origin.hz}
        if self.verdict is not None:
            out["statistic"], out["threshold"] = self.verdict.statistic, self.verdict.threshold
        if self.yardstick is not None:
            out["yardstick"] = self.yardstick.to_json()
        if self.fit is not None:
            out["not_identifiable"] = [d.to_json() for d in self.fit.degeneracies]
            out["correlated"] = [c.to_json() for c in self.fit.correlated]
            out["lines_excluded_hz"] = self.excluded_hz()
            out["lines_excluded_share"] = self.fit.outlier_share
            out["fit_describes_data"] = self.fit.describes_the_data
        if element.nonparametric is not None:
            out[NONPARAMETRIC] = element.nonparametric.to_toml()
        return out

    def reading(self, term: LawTerm) -> LimitReading | None:
        """The limit a fitted term sits in over this element's amplitudes (:meth:`Law.reading`), if any."""
        if self.samples is None or not len(self.samples.X) or not term.complete:
            return None
        return term.law.reading(term.values, float(self.samples.X.min()), float(self.samples.X.max()))

    def excluded_hz(self) -> list[float]:
        """Frequencies, Hz, of the lines the fit left out as not following the fitted laws."""
        if self.fit is None or self.fit.excluded is None or self.samples is None:
            return []
        return sorted(float(w) / (2 * np.pi) for w in self.samples.w[self.fit.excluded])


@dataclass
class HistoryStep:
    """One step of the model history: what was done and what error it gave."""

    step: int
    action: str
    model_toml: str
    error: float
    error_by_level: list[LevelError]
    laws: dict[str, list[dict]]

    def to_json(self) -> dict:
        return {"step": self.step, "action": self.action, "error": self.error,
                "error_by_level": [e.to_json() for e in self.error_by_level],
                "laws": self.laws, "model": self.model_toml}


# a locked point is identified from only where one harmonic describes its motion this well (displacement THD)
LOCKED_DISTORTION = 0.01

#: The correction of the fundamental's bias is at its fixed point (:meth:`Workbench._corrected`) where the bias of
#: the model a pass fits departs from the correction it was fitted with by at most this share of the larger; at
#: most ``BIAS_PASSES`` passes, each a multi-harmonic balance of the lines with harmonics and a refit
BIAS_SETTLED = 1e-2
BIAS_PASSES = 6


def _overruled(verdict: LinearityVerdict, found: AmplitudeDependence | None) -> LinearityVerdict:
    """A linear verdict with the law found departing from it (:func:`analysis.search.discovery.amplitude_dependence`):
    nonlinear, and its evidence says why."""
    if found is None:
        return verdict
    return replace(verdict, linear=False, evidence=f"{verdict.evidence} Yet {found.text()}.")


def _nonzero(bias: dict[str, np.ndarray]) -> bool:
    """Whether a kbar bias (run -> (lines, elements)) changes any sample."""
    return any(np.any(b) for b in bias.values())


def _settled_key(element: Element, term: LawTerm) -> tuple:
    """A clearance law's values as :attr:`Workbench._settled` holds them: with the laws beside it on its element,
    whose fit the restart judged."""
    return element.name, tuple(t.law.name for t in element.laws), term.law.name, tuple(sorted(term.values.items()))


@dataclass(frozen=True)
class _FittedState:
    """What a refit changes, to go back to: the kbar bias taken out, the element reports, each element's laws and
    non-parametric part, and the error floor (identified again from the samples less the bias)."""

    bias: dict[str, np.ndarray]
    reports: dict[str, ElementReport]
    fits: dict[str, LawFit | None]       # each report's fit (a refit without identification sets it in place)
    parts: list[tuple[list[LawTerm], NonParametric | None]]
    error_floor: ErrorFloor | None


def _harmonic_points(lines: SineRun, limit: float) -> SineRun:
    """The locked points of a phase-resonance run with those whose displacement THD exceeds ``limit`` marked as
    distorted (left out of the identification like any line beyond the distortion limit). A locked point sits at
    the largest amplitude of its force, often beyond every swept line: there one point has the leverage of many
    lines on an amplitude law, and the first-harmonic error of a describing function at a few per cent THD bends
    the law by percents and the FRF error of the levels swept by several times (docs/workbench.md)."""
    if lines.distortion is None:
        return lines
    d = np.asarray(lines.distortion, float)
    return replace(lines, distortion=np.where(d <= limit, d, np.inf))


class Workbench:
    """Carry one model through identification, fitting, comparison and the missing-effect loop."""

    def __init__(self, model: Model, measurements: Measurements, distortion_limit: float = 0.05,
                 harmonics: HarmonicCriterion | None = HarmonicCriterion(),
                 yardsticks: dict[str, BetweenRuns] | None = None, started_at_fit: bool = False,
                 limits: dict[str, dict[int, LimitForm]] | None = None):
        if not measurements.sine:
            raise InputError("the session has no stepped-sine run to identify from")
        missing = sorted(d for d in measurements.dofs() if d not in model.structure.dofs)
        if missing:
            raise InputError(f"measured DOF(s) {', '.join(missing)} are not in the model's structure", model.source)
        self.model = model.copy()
        self.measurements = measurements
        self.distortion_limit = distortion_limit   # lines whose displacement THD is larger: left out
        self.harmonics = harmonics                 # which lines are predicted multi-harmonically (None: none)
        # element -> the scatter between runs measured on the whole test, for a workbench on part of its levels
        self._given_yardsticks = dict(yardsticks or {})
        # (element, its laws, law, values) of each clearance law whose values a restart from the FRF-refined laws
        # judged, or a fit of the same laws started from such values reached (:meth:`_corrected_from_refined`); a
        # model started at the whole test's fit (a held-out check's refit on part of its levels) starts at such values
        self._settled: set[tuple] = set()
        if started_at_fit:
            self._settle_clearances()
        # element -> term index -> the limit form the whole test's fit took that law in, for a workbench on part
        # of its levels (:meth:`limits`)
        self._given_limits = dict(limits or {})
        self.reference: ReferenceReport | None = None
        self.reports: dict[str, ElementReport] = {}
        self.history: list[HistoryStep] = []
        self._comparison: Comparison | None = None
        self._single: Comparison | None = None
        self._predictor: Predictor | None = None
        self._offers: tuple[Comparison, float, list[NonParametricOffer]] | None = None
        # run -> (lines, elements): the model's own harmonics in the identified kbar, taken out of the samples on
        # data without harmonics (:meth:`_correct_fundamental_bias`)
        self._kbar_bias: dict[str, np.ndarray] = {}
        # the FRF error a model right in every law would show: the FRFs' noise and the scatter between runs
        self.error_floor: ErrorFloor | None = None
        # the criterion of discovery and the model-form check where no line is predicted with harmonics
        self._default_harmonics = HarmonicCriterion()
        self._states: dict[int, _FittedState] = {}   # history index -> the fitted state it recorded

    # ------------------------------------------------------------------ reference
    def update_reference(self) -> ReferenceReport:
        """Modal fit of the random run; update the parameters named in the model's ``[updating]`` table."""
        self.reference = reference_from_random(self.model, self.measurements.random)
        if self.reference.update is not None:
            self.model = self.model.with_structure(self.reference.update.table)
            self._predictor = None
        return self.reference

    # ------------------------------------------------------------------ identification
    def identify(self) -> dict[str, ElementReport]:
        """kbar samples and a verdict for every element of the model (less the model's own harmonics on data
        without them, :meth:`_correct_fundamental_bias`)."""
        els = self.model.elements
        if not els:
            raise InputError("the model has no [[element]] to identify", self.model.source)
        per: dict[str, list[ElementSamples]] = {e.name: [] for e in els}
        flagged = {e.name: 0 for e in els}
        sensitivities = []
        for run, level in self._identified_runs():
            if len(run.sensor_dofs) < len(els):
                raise InputError(f"run {run.name} measured {len(run.sensor_dofs)} FRF(s) but the model has "
                                 f"{len(els)} unknown elements: at least as many sensors as elements are needed")
            std = None if run.receptance_std is None else np.asarray(run.receptance_std, float)
            ident = identify_complex_stiffness(self.model.structure, run.receptance, run.sensor_dofs,
                                               run.excitation_dof, els, w=run.w, force=run.force_per_line,
                                               noise_std=std)
            if any(run is r for r in self.measurements.sine):     # the runs the FRF error pools
                sensitivities.append(RunSensitivity(run.receptance, std, ident.frf_per_kbar))
            bias = self._kbar_bias.get(run.name)
            if bias is not None and bias.shape == ident.kbar.shape:
                ident.kbar = ident.kbar - bias
            good = ~ident.ill_conditioned & np.isfinite(ident.kbar).all(axis=1) & (ident.amplitude > 0).all(axis=1)
            if run.distortion is not None:
                good &= np.asarray(run.distortion) <= self.distortion_limit
            for i, el in enumerate(els):
                flagged[el.name] += int((~good).sum())
                kstd = None if ident.kbar_std is None else ident.kbar_std[good, i]
                per[el.name].append(ElementSamples(el.name, ident.amplitude[good, i], run.w[good],
                                                   ident.kbar[good, i], kstd, level[good],
                                                   el.rotational(self.model.structure)))
        self.reports = {}
        for el in els:
            samples = ElementSamples.joined(per[el.name])
            yardstick = self._yardstick(samples, self._given_yardsticks.get(el.name))
            X = samples.X
            verdict = None
            if len(X) >= 4:
                k_u, x_u = samples.units
                try:
                    verdict = linearity_verdict(X, samples.w, samples.kbar, samples.kbar_std, level=samples.level,
                                                stiffness_unit=k_u, amplitude_unit=x_u)
                except InputError:
                    verdict = None
                if verdict is not None and verdict.linear:
                    verdict = _overruled(verdict, amplitude_dependence(samples, robust=self.harmonics_blind))
            self.reports[el.name] = ElementReport(el.name, samples if len(X) else None, verdict, len(X),
                                                  flagged[el.name], yardstick=yardstick)
        self._floor_is(frf_error_floor(sensitivities, [self.reports[e.name].yardstick for e in els],
                                       [e.name for e in els]))
        return self.reports

    def _floor_is(self, floor: ErrorFloor | None) -> None:
        """The FRF error the test itself allows, and the harmonics that resolve it
        (:meth:`analysis.prediction.comparison.HarmonicCriterion.resolving`) where it is the floor of the samples
        as identified: a correction of the fundamental's bias moves the floor a little, and a criterion that moved
        with it would judge the passes of one correction, and the fit it keeps, each with other harmonics."""
        self.error_floor = floor
        if not _nonzero(self._kbar_bias):
            total = None if floor is None else floor.total
            self._default_harmonics = self._default_harmonics.resolving(total)
            if self.harmonics is not None:
                self.harmonics = self.harmonics.resolving(total)

    def yardsticks(self) -> dict[str, BetweenRuns]:
        """Element -> the scatter between runs its samples were judged by (elements without noise left out)."""
        return {name: r.yardstick for name, r in self.reports.items() if r.yardstick is not None}

    def limits(self) -> dict[str, dict[int, LimitForm]]:
        """Element -> term index -> the limit form its law was taken in (:mod:`analysis.fitting.limits`), for the
        laws the fits took in a limit. A refit on part of the levels fits those laws as the same forms: which
        limit a law sits in over the test's amplitudes is a finding of the whole test, and a part of its levels
        determines no more than the whole does. Left free, the law's parameters on a part slide along the
        direction the whole test did not determine (an Iwan joint in micro-slip slipping through at a force the
        data never showed), and what the part's fit predicts would measure where its search stopped there, not
        the model."""
        return {name: found for name, r in self.reports.items() if r.fit is not None
                and (found := {j: t.limit.law for j, t in enumerate(r.fit.terms) if t.limit is not None})}

    @staticmethod
    def _yardstick(samples: ElementSamples, given: BetweenRuns | None) -> BetweenRuns | None:
        """The scatter between runs of an element's samples (``given``: measured on the whole test, for a
        workbench on part of its levels); where it rules over the line noise, the samples' standard deviations take
        it on (``sqrt(std^2 + tau^2)``), so that every judgement downstream -- the verdict, the fits' outliers and
        intervals, discovery's criteria -- is relative to how well the test repeats
        (:mod:`analysis.identification.between_runs`). None where the samples carry no noise.

        A refit on part of the levels inherits the whole test's: how well the test repeats is a property of the
        test, not of the laws, and a part of its runs overlaps too little to measure it (a half of twelve levels
        gives six groups, too few for the sign test), so each part would otherwise be judged by another noise
        than the whole and its held-out error would measure the difference."""
        if samples.kbar_std is None or not len(samples.X):
            return None
        yardstick = given if given is not None else between_runs(samples.X, samples.w, samples.kbar,
                                                                  samples.kbar_std)
        samples.kbar_std = yardstick.combined(samples.kbar_std)
        return yardstick

    def _identified_runs(self) -> list[tuple[SineRun, np.ndarray]]:
        """Every run identified from, with the level of each line: the stepped-sine runs (their level), then the
        phase-resonance runs' locked points (each at its own force, the one that took it to its amplitude)."""
        out = [(run, np.full(len(run.frequency_hz), run.force)) for run in self.measurements.sine]
        return out + [(_harmonic_points(p.lines, LOCKED_DISTORTION), p.lines.force_per_line)
                      for p in self.measurements.phase if p.lines is not None]

    # ------------------------------------------------------------------ fitting and comparison
    def fit(self, names: list[str] | None = None) -> None:
        """Fit the laws of the named elements (default all) to their samples; values go into the model. On data
        without harmonics, the samples are then corrected by the fitted model's own harmonics and every element
        refitted (:meth:`_correct_fundamental_bias`), whose comparison with harmonics of the fit it keeps is the
        fitted model's own (kept for :meth:`compare`)."""
        if not self.reports:
            self.identify()
        unsettled = self._unsettled_clearances()
        self._fit_elements(names)
        known = self._correct_fundamental_bias(unsettled)
        self._comparison = known
        self._single = None

    def _fit_elements(self, names: list[str] | None) -> None:
        for el in self.model.elements:
            if names is not None and el.name not in names:
                continue
            report = self.reports[el.name]
            report.fit = None
            if not el.laws and el.nonparametric is None:
                continue
            s = report.samples
            if s is None:
                raise InputError(f"element {el.name!r} has no well-conditioned line to fit its laws to")
            if el.laws:
                held = self._given_limits.get(el.name)
                options = dict(exclude_outliers=self.harmonics_blind, surroundings=el.surroundings)
                fit = fit_in_limits(el.laws, held, s.X, s.w, s.kbar, s.kbar_std, **options) if held else None
                if fit is None:
                    fit = fit_laws(el.laws, s.X, s.w, s.kbar, s.kbar_std, **options)
                    fit = settle_in_limits(fit, el.laws, s.X, s.w, s.kbar, s.kbar_std,
                                           false_alarm=RankingRules().false_alarm, **options)
                report.fit = fit
                el.laws = [LawTerm(t.law, dict(report.fit.terms[j].params)) for j, t in enumerate(el.laws)]
            if el.nonparametric is not None:
                self._fit_nonparametric(el)

    def _correct_fundamental_bias(self, unsettled: list[int]) -> Comparison | None:
        """On data without harmonics, the kbar the closed form identifies at a line is the fundamental's force over
        the fundamental's motion; where the joint's motion is not sinusoidal (friction that sticks for part of the
        cycle) that departs from every describing function, and laws fitted to it are biased and leave a misfit
        that another law can fill. Where the model's forces are known (:meth:`_forces_known`), the fitted model's own
        departure at each line (:meth:`analysis.prediction.comparison.Predictor.fundamental_bias`) is subtracted from the
        samples and every element refitted, until the correction is the bias of the model fitted with it
        (:meth:`_corrected`). The corrected fit is refused where it
        predicts the FRFs, with harmonics, worse than the fit it corrects by a law's margin
        (:meth:`_corrected_is_kept`). ``unsettled``: the elements whose clearance laws started this fit at values
        no restart judged (:meth:`_corrected_from_refined`). Returns the comparison with harmonics of the fit it
        leaves (None where it made none)."""
        criterion = self._harmonics()
        if not (self.harmonics_blind and criterion is not None and self._forces_known()):
            if _nonzero(self._kbar_bias):
                self._kbar_bias = {}
                self.identify()
                self._fit_elements(None)
            return None
        found = self.predictor.fundamental_bias(criterion)
        kept = found.comparison                 # of the fit kept so far, with harmonics
        if _nonzero(found.bias) or _nonzero(self._kbar_bias):
            before = self._fitted_state()
            corrected = self._corrected(criterion, found)
            if self._corrected_is_kept(found.comparison, corrected.error):
                kept = corrected
            else:
                self._restore(before)
        return self._corrected_from_refined(criterion, kept, unsettled)

    def _forces_known(self) -> bool:
        """Whether the model gives every element a time-domain force and some law is fitted: every law with its
        values, and no non-parametric part. An element without laws exerts none in the model, and the model's
        harmonics -- what the bias is -- are as known with it as without it: waiting for a law there would leave
        every other element's laws fitted to biased samples for as long as one joint is found to have none."""
        els = self.model.elements
        return (any(el.laws for el in els)
                and all(el.time_domain and all(t.complete for t in el.laws) for el in els))

    def _fitted_state(self) -> _FittedState:
        return _FittedState(self._kbar_bias, self.reports, {n: r.fit for n, r in self.reports.items()},
                            [(list(el.laws), el.nonparametric) for el in self.model.elements], self.error_floor)

    def _restore(self, state: _FittedState) -> None:
        self._kbar_bias, self.reports = state.bias, state.reports
        self._floor_is(state.error_floor)
        for name, fit in state.fits.items():
            self.reports[name].fit = fit
        for el, (laws, nonparametric) in zip(self.model.elements, state.parts):
            # a list of its own: a law added to the model must not enter the state it was restored from
            el.laws, el.nonparametric = list(laws), nonparametric

    def _corrected(self, criterion: HarmonicCriterion, found: FundamentalBias, fitted: bool = True) -> Comparison:
        """The samples corrected by the bias of the model fitted to them: the fixed point ``b = B(b)`` of the map
        from a correction ``b`` (run -> (lines, elements)) to the bias ``B`` of the model fitted to the samples
        less ``b``, started at the correction in place, ``found`` the bias of the model fitted with it (``fitted``;
        otherwise the bias of other laws, a start that is no point of the map: the secant steps begin a pass later,
        from the first point on it). A pass
        ``b <- B(b)`` overshoots where a law's harmonics grow with its size: a law fitted too stiff has larger
        harmonics, whose bias, corrected, fits it too soft, and so on; the passes then oscillate about the fixed
        point, and the fit one pass leaves can predict the FRFs worse than the uncorrected one. Secant steps on
        ``B(b) - b`` (:func:`analysis.common.fixed_point.secant_step`) reach it in a few passes where the map is
        smooth, until ``B(b)`` and ``b`` differ by at most :data:`BIAS_SETTLED` of the larger, or a pass leaves the
        FRF error with harmonics within that share of the fit's before it (the FRFs, which judge the fit, no longer
        tell the passes apart). Converging, the secant steps shrink the departure faster than geometrically; a
        secant step that does not halve the departure the secant step before it left ends them (a contact whose
        harmonics switch on and off with its
        stiffness: further passes cost a balance each and find nothing), as does :data:`BIAS_PASSES`. The FRFs
        judge the passes: the one whose fit predicts them with harmonics best is left, and its comparison
        returned."""
        runs = sorted(found.bias)
        shapes = [found.bias[n].shape for n in runs]
        ends = np.cumsum([0] + [int(np.prod(shape)) for shape in shapes])

        def flat(bias: dict[str, np.ndarray]) -> np.ndarray:
            return np.concatenate([np.asarray(bias.get(n, np.zeros(shape)), complex).ravel()
                                   for n, shape in zip(runs, shapes)])

        def unflat(v: np.ndarray) -> dict[str, np.ndarray]:
            return {n: v[a:b].reshape(shape) for n, shape, a, b in zip(runs, shapes, ends[:-1], ends[1:])}

        # previous: the last point of the map, (b, B(b) - b), the secant's other end
        x, g, previous, best, last = flat(self._kbar_bias), flat(found.bias), None, None, np.inf
        for _ in range(BIAS_PASSES):
            secant = previous is not None
            step = secant_step(x, g - x, previous)
            x, previous, before = step, (x, g - x) if fitted else None, found.comparison.error
            fitted = True
            self._refit_less(unflat(x))
            found = self.predictor.fundamental_bias(criterion)
            g = flat(found.bias)
            if best is None or found.comparison.error < best[0].error:
                best = (found.comparison, self._fitted_state())
            departure = np.linalg.norm(g - x) / max(np.linalg.norm(g), np.linalg.norm(x), 1e-300)
            unchanged = abs(found.comparison.error - before) <= BIAS_SETTLED * before
            if departure <= BIAS_SETTLED or unchanged or departure > last / 2:
                break
            last = departure if secant else np.inf          # a plain step's departure is no secant's to halve
        self._restore(best[1])
        return best[0]

    def _refit_less(self, bias: dict[str, np.ndarray]) -> None:
        """Every element identified again less ``bias`` and refitted, from its laws' current values."""
        self._kbar_bias = bias
        self.identify()
        self._fit_elements(None)

    def _corrected_from_refined(self, criterion: HarmonicCriterion, kept: Comparison,
                                unsettled: list[int]) -> Comparison:
        """A clearance's corrected fit can have more than one fixed point: the bias of a model fitted at one
        contact stiffness moves the kbar so that the same stiffness fits it best: the kbar fit and every corrected
        pass after it can stay at a wrong contact stiffness, whose misfit the loop then credits to another law.
        Started from the laws refined against the FRFs
        (:func:`analysis.prediction.frf_refinement.refine_against_frfs`, single-harmonic), a corrected pass can
        reach the right one. So where an element's clearance law started the fit at values no such restart has
        judged with the laws beside it (``unsettled``: a law just added to the element or taken off it, or values
        given with the model), the corrected fit is also started
        from its FRF-refined laws, and the fixed point the FRFs with harmonics prefer by the margin a law must bring
        (``RankingRules.min_gain``) is kept (``kept``: the current fit's comparison with harmonics; returned, or
        the restart's where it is kept).

        The restart chooses the basin once for a set of laws: a fit of the same laws that starts at values it chose
        -- a refit, a held-out check's refit on part of the levels (``started_at_fit``) -- starts in the basin the
        FRFs preferred, and what it reaches is settled as well (:attr:`_settled`); a restart there would compare
        that basin with the one it already lost to. A law beside the clearance moves what the clearance fits, and
        so its fixed points: a set with another law is judged anew."""
        if unsettled:
            before = self._fitted_state()
            for i in unsettled:
                self.model.elements[i].laws = self._refined_against_frfs(i)
            restarted = self._corrected(criterion, self.predictor.fundamental_bias(criterion), fitted=False)
            if restarted.error * RankingRules().min_gain <= kept.error:
                kept = restarted
            else:
                self._restore(before)
        self._settle_clearances()
        return kept

    def _unsettled_clearances(self) -> list[int]:
        """The elements with a clearance law whose values are not settled (:meth:`_corrected_from_refined`)."""
        return [i for i, el in enumerate(self.model.elements)
                if any(t.law.kind == "clearance" and _settled_key(el, t) not in self._settled for t in el.laws)]

    def _settle_clearances(self) -> None:
        """Every clearance law's values as they stand settled (:meth:`_corrected_from_refined`)."""
        self._settled |= {_settled_key(el, t) for el in self.model.elements for t in el.laws
                          if t.law.kind == "clearance" and t.complete}

    def _refined_against_frfs(self, i: int) -> list[LawTerm]:
        """Element ``i``'s laws with every parameter its kbar fit sees (:meth:`LawFit.seen`) refined against the
        FRFs single-harmonically, the other elements held at their laws."""
        els = self.model.elements
        others = {j: terms_function(el.laws) for j, el in enumerate(els) if j != i}
        free = self.reports[els[i].name].fit.seen()
        return refine_against_frfs(self.predictor, i, els[i].laws, free, others).terms

    def _corrected_is_kept(self, before: Comparison, corrected: float) -> bool:
        """The balance's own sliders never stick (a Coulomb slider's force is sgn(v) along the balanced motion, whose
        velocity only crosses zero), so its bias can be wrong where a joint sticks and slips in turn, and the
        corrected fit then predicts the FRFs with harmonics worse than the fit it corrects. The FRFs decide, by the
        margin a law must bring (``RankingRules.min_gain``): the corrected fit is the consistent one, its samples
        less its own model's harmonics (:meth:`_corrected`), and within that margin the FRFs cannot tell it from
        the fit it corrects."""
        return corrected <= RankingRules().min_gain * before.error

    @property
    def harmonics_blind(self) -> bool:
        """Some run carries no harmonics (imported FRFs): no line could be left out as far from harmonic, so
        the fits leave out the lines whose kbar does not follow the fitted laws (docs/fitting.md, "Outliers")."""
        return any(run.distortion is None for run in self.measurements.sine)

    @property
    def predictor(self) -> Predictor:
        if self._predictor is None:
            self._predictor = Predictor(self.model, self.measurements)
        return self._predictor

    def compare(self, folds: bool = False) -> Comparison:
        """Predict every stepped-sine run with the current model and compare. ``folds``: each jump's fold located
        too (:meth:`Predictor.locate_folds`), for a report; no judgement reads it."""
        if self._comparison is None:
            for el in self.model.elements:
                for t in el.laws:
                    if not t.complete:
                        raise InputError(f"element {el.name!r}: law {t.law.name} has no values; fit it first")
            self._comparison = self.predictor.compare(harmonics=self._harmonics())
        if folds:
            self.predictor.locate_folds(self._comparison)
        return self._comparison

    def _harmonics(self) -> HarmonicCriterion | None:
        """The harmonic criterion, or None where an element has a non-parametric part (no time-domain force to
        predict harmonics with: every line single-harmonic)."""
        return self.harmonics if all(el.time_domain for el in self.model.elements) else None

    def single_harmonic_comparison(self) -> Comparison:
        """The error with every line predicted single-harmonically, as the candidates are (their gains are
        measured against it)."""
        if self._harmonics() is None:
            return self.compare()
        if self._single is None:
            self._single = self.predictor.compare()
        return self._single

    def _ranking_inputs(self):
        # an element with a non-parametric part is explained by construction: no candidate there, and its
        # current kbar (laws plus the part) is the element's own describing function
        finished = {el.name for el in self.model.elements if el.nonparametric is not None}
        samples = {n: r.samples for n, r in self.reports.items() if r.samples is not None and n not in finished}
        fits = {n: (None if n in finished else r.fit) for n, r in self.reports.items()}
        linear = frozenset(n for n, r in self.reports.items() if r.verdict is not None and r.verdict.linear)
        return samples, fits, linear

    def candidates(self, laws=None, rules: RankingRules = RankingRules()) -> list[Candidate]:
        """Ranked missing-effect candidates for the current model (best first); the significant ones are checked
        against what the single-harmonic model cannot represent (:func:`analysis.missing.diagnosis.check_model_form`)."""
        samples, fits, linear = self._ranking_inputs()
        ranked = rank_candidates(self.predictor, samples, fits, self.single_harmonic_comparison(), laws,
                                 linear_elements=linear, rules=rules, robust=self.harmonics_blind)
        check_model_form(self.predictor, ranked, rules, self.harmonics_or_default)
        return ranked

    def pair_candidates(self, element: str, pairs: list[tuple[str, str]],
                        rules: RankingRules = RankingRules()) -> list[Candidate]:
        """Pairs of laws added together to ``element``, best first, checked like single candidates."""
        samples, fits, linear = self._ranking_inputs()
        ranked = rank_pairs(self.predictor, samples, fits, self.single_harmonic_comparison(), element, pairs,
                            element in linear, rules)
        check_model_form(self.predictor, ranked, rules, self.harmonics_or_default)
        return ranked

    @property
    def harmonics_or_default(self) -> HarmonicCriterion:
        return self.harmonics or self._default_harmonics

    # ------------------------------------------------------------------ the loop
    def record(self, action: str) -> HistoryStep:
        """Append the current model and its error to the history."""
        comp = self.compare()
        step = HistoryStep(len(self.history), action, self.model.to_toml(), comp.error, comp.error_by_level,
                           {el.name: [t.to_toml() for t in el.laws] +
                            ([{"law": NONPARAMETRIC, **el.nonparametric.to_toml()}] if el.nonparametric else [])
                            for el in self.model.elements})
        self.history.append(step)
        self._states[step.step] = self._fitted_state()
        return step

    def add(self, element: str, law: str) -> HistoryStep:
        """Add ``law`` (or the non-parametric part, ``"nonparametric"``) to ``element``, refit that element and
        record the new error."""
        if law == NONPARAMETRIC:
            return self._add_nonparametric(self.model.element(element))
        return self.add_laws(element, (law,))

    def add_laws(self, element: str, laws: tuple[str, ...], action: str = "add") -> HistoryStep:
        """Add ``laws`` (one, or several found together) to ``element``, refit it and record one step
        (``action``: the word the history starts the step with)."""
        el = self.model.element(element)
        new = [el.law(law) for law in laws]
        for law, n in zip(laws, new):
            if any(t.law.name == n.name for t in el.laws):
                raise InputError(f"element {element!r} already has law {law!r}", self.model.source)
        el.laws += [LawTerm(n, {}) for n in new]
        self.fit([element])
        return self.record(f"{action} {element}:{'+'.join(laws)}")

    def error_without(self, element: str, law: str) -> float:
        """The model's error (:meth:`compare`) with ``law`` taken off ``element`` and that element refitted; the
        model, its fits and its history are left as they were."""
        with self.without(element, law):
            return self.compare().error

    def law_names(self, element: str) -> tuple[str, ...]:
        """The names of the laws ``element`` holds, in its order."""
        return tuple(t.law.name for t in self.model.element(element).laws)

    def without(self, element: str, law: str) -> AbstractContextManager["Workbench"]:
        """This workbench with ``law`` taken off ``element`` and that element refitted, for as long as the block
        runs; then the model, its fits and its history as they were (nothing recorded), whatever the block
        raised."""
        return self.read_as(element, tuple(n for n in self.law_names(element) if n != law))

    @contextmanager
    def read_as(self, element: str, laws: tuple[str, ...]) -> Iterator["Workbench"]:
        """This workbench with ``element``'s laws ``laws`` (those it holds keep their values, the others start
        fresh) and that element refitted, for as long as the block runs; then the model, its fits and its history
        as they were (nothing recorded), whatever the block raised."""
        el = self.model.element(element)
        state, caches = self._fitted_state(), (self._comparison, self._single, self._offers)
        el.laws = self._terms(el, laws)
        try:
            self.fit([element])
            yield self
        finally:
            self._restore(state)
            self._comparison, self._single, self._offers = caches

    def replace_laws(self, element: str, laws: tuple[str, ...], action: str = "replace") -> HistoryStep:
        """``element``'s laws made ``laws`` (those it holds keep their values as starting values), the element
        refitted and one step recorded."""
        el = self.model.element(element)
        el.laws = self._terms(el, laws)
        self.fit([element])
        return self.record(f"{action} {element}:{'+'.join(laws)}")

    @staticmethod
    def _terms(el, laws: tuple[str, ...]) -> list[LawTerm]:
        held = {t.law.name: t for t in el.laws}
        return [held.get(name) or LawTerm(el.law(name), {}) for name in laws]

    def take_back(self, element: str, law: str, action: str = "take back") -> HistoryStep:
        """Take ``law`` off ``element``, refit it and record one step."""
        el = self.model.element(element)
        if not any(t.law.name == law for t in el.laws):
            raise InputError(f"element {element!r} has no law {law!r}", self.model.source)
        el.laws = [t for t in el.laws if t.law.name != law]
        self.fit([element])
        return self.record(f"{action} {element}:{law}")

    def discover(self, rules: DiscoveryRules = DiscoveryRules(),
                 note: Callable[[str], None] | None = None) -> Discovery:
        """The laws of every element that has none (:func:`analysis.search.discovery.discover`); the model is not
        changed (``add_laws`` adds a choice)."""
        samples, _, linear = self._ranking_inputs()
        return discover(self.predictor, samples, linear, rules, self.harmonics_or_default, note,
                        self.harmonics_blind)

    def _fit_nonparametric(self, el) -> None:
        """The element's non-parametric part fitted to what its (fitted) laws leave of its kbar samples."""
        report = self.reports[el.name]
        s = report.samples
        left = s.kbar - (report.fit.describing_function(s.X, s.w) if report.fit else 0.0)
        el.nonparametric = fit_nonparametric(s.X, s.w, left, s.kbar_std).model

    def _add_nonparametric(self, el) -> HistoryStep:
        if el.nonparametric is not None:
            raise InputError(f"element {el.name!r} already has a non-parametric part", self.model.source)
        if not self.reports:
            self.fit()                          # identified and the laws fitted: the part takes what they leave
        if self.reports[el.name].samples is None:
            raise InputError(f"element {el.name!r} has no well-conditioned line to fit a non-parametric part to")
        self._fit_nonparametric(el)
        self._comparison = self._single = None
        return self.record(f"add {el.name}:{NONPARAMETRIC}")

    def unexplained(self, false_alarm: float = 1e-3) -> list[NonParametricOffer]:
        """The elements whose kbar departs from their laws by much more than the noise
        (:func:`analysis.missing.unexplained.unexplained`), each with the error a non-parametric part would give. Only
        elements with laws: where none is on yet, the library has not been tried and the candidates are the
        advice. Kept until the model changes (the report and the JSON both ask)."""
        base = self.single_harmonic_comparison()
        if self._offers is not None and self._offers[0] is base and self._offers[1] == false_alarm:
            return self._offers[2]
        out = []
        for i, el in enumerate(self.model.elements):
            report = self.reports.get(el.name)
            if report is None or report.samples is None or el.nonparametric is not None or not el.laws:
                continue
            finding = unexplained(report.samples, report.fit, false_alarm)
            if finding is not None:
                out.append(offer_nonparametric(self.predictor, base, i, report.samples, report.fit, finding))
        self._offers = (base, false_alarm, out)
        return out

    def linear_corrections(self, min_sigma: float = 5.0) -> list[str]:
        """Elements whose verdict is linear but whose kbar is a clear constant offset (more than ``min_sigma``
        standard deviations from zero, and explained by the ``linear`` law: :meth:`_linear_law_explains`) and
        that have no laws yet: the reference is wrong there, and the offset is a linear correction (the paper's
        k_w). Corrections of several elements are coupled -- a wrong reference stiffness at one place is
        compensated elsewhere by the updating -- so they are applied together, before laws are added one at a
        time."""
        out = []
        for el in self.model.elements:
            report = self.reports.get(el.name)
            v = report.verdict if report is not None else None
            if v is None or not v.linear or el.laws:
                continue
            if abs(v.mean_kbar) > min_sigma * max(v.mean_kbar_std, 1e-300) and self._linear_law_explains(report):
                out.append(el.name)
        return out

    def _linear_law_explains(self, report: ElementReport) -> bool:
        """Whether the ``linear`` law (k + j c w) fitted to the element's kbar leaves nothing the detector of
        effects outside the library finds (:func:`analysis.missing.unexplained.unexplained`). A linear verdict only says
        kbar does not move with the amplitude: a kbar that moves with the frequency in another way (a stiffness
        growing with w) is no constant offset, and the element is left to the ranking, where the linear law
        competes with the laws that may explain it."""
        s = report.samples
        fit = fit_laws([LawTerm(get_law("linear"), {})], s.X, s.w, s.kbar, s.kbar_std,
                       exclude_outliers=self.harmonics_blind)
        return unexplained(s, fit) is None

    def apply_linear_corrections(self, names: list[str]) -> HistoryStep:
        """Add the ``linear`` law to each named element, refit them, record one history step."""
        for name in names:
            self.model.element(name).laws.append(LawTerm(get_law("linear"), {}))
        self.fit(names)
        return self.record("linear correction " + ", ".join(names))

    def undo(self) -> HistoryStep:
        """Take back the last step of the history (an added law): the model returns exactly as the previous step
        recorded it (:meth:`_return_to`), and the step is dropped. Returns the step now current."""
        if len(self.history) < 2:
            raise InputError("nothing to undo: the model is as analysis started it")
        del self._states[self.history.pop().step]
        self._return_to(len(self.history) - 1)
        return self.history[-1]

    def back_to(self, index: int, action: str) -> HistoryStep:
        """The model exactly as history step ``index`` recorded it (:meth:`_return_to`), recorded again as a new
        step (``action``): the steps after it stay in the history."""
        self._return_to(index)
        return self.record(action)

    def drop_unfinished(self) -> None:
        """The model as the last history step recorded it: what a step stopped before its record
        (:mod:`analysis.common.interrupt`) had changed -- laws added, values refitted -- is undone, nothing
        refitted."""
        self._return_to(len(self.history) - 1)
        self._offers = None

    def _return_to(self, index: int) -> None:
        """The fitted state history step ``index`` recorded -- laws, values, reports and the kbar bias taken out
        -- restored, not refitted: refitted, even from the values the step had, the bias correction of data
        without harmonics can settle at another fixed point (docs/fitting.md)."""
        self._restore(self._states[self.history[index].step])
        self._comparison = self._single = None

    def start(self) -> HistoryStep:
        """Reference, identification and fit of the model as given; the first history step."""
        self.prepare()
        return self.record("start")

    def prepare(self) -> None:
        """Reference, identification and fit of the model as given, nothing recorded: a refit wanted for what
        its model predicts elsewhere, not for its own error (whose comparison costs a prediction of every line)."""
        if self.reference is None:
            self.update_reference()
        self.identify()
        self.fit()

    def to_json(self, candidates: list[Candidate] | None = None) -> dict:
        comp = self.compare(folds=True)
        out = {"elements": [self.reports[el.name].to_json(el) for el in self.model.elements],
               **comp.to_json(), "single_harmonic_error": self.single_harmonic_comparison().error,
               "other_branch_hz": comp.other_branch_hz(self.measurements.sine),
               "candidates": [c.to_json() for c in (candidates or [])],
               "unexplained": [o.to_json() for o in self.unexplained()],
               "history": [h.to_json() for h in self.history],
               "unfinished_runs": [note.to_json() for note in self.measurements.unfinished],
               "unresolved_lines": [note.to_json() for note in self.measurements.unresolved],
               "error_floor": None if self.error_floor is None else self.error_floor.to_json()}
        if self.reference is not None:
            out["reference"] = self.reference.to_json()
        return out
