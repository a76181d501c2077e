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
   step is kept in :attr:`Workbench.history` so the error falling is visible step by step.

Analysis sees only measured data (``Measurements``) and the user's model: never the rig a simulated session
came from.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass

import numpy as np

from .comparison import Comparison, HarmonicCriterion, Predictor
from .diagnosis import Candidate, ElementSamples, RankingRules, check_model_form, rank_candidates, rank_pairs
from .elements import LawTerm
from .errors import InputError
from .fit import LawFit, fit_laws
from .identify import identify_complex_stiffness
from .laws import get_law
from .linearity import LinearityVerdict, linearity_verdict
from .measurements import Measurements
from .modal_fit import ModalFit, fit_modes
from .model import Model, load_model
from .updating import UpdateResult, update_parameters


@dataclass
class ElementReport:
    """What identification found for one element."""

    name: str
    samples: ElementSamples | None
    verdict: LinearityVerdict | None
    lines_used: int
    lines_flagged: int
    fit: LawFit | None = None

    def to_json(self, element) -> dict:
        laws = []
        for j, term in enumerate(element.laws):
            entry = {"law": term.law.name, "params": dict(term.values)}
            if self.fit is not None:
                entry["stderr"] = {k: (None if not np.isfinite(v) else float(v))
                                   for k, v in self.fit.terms[j].stderr.items()}
            laws.append(entry)
        out = {"name": self.name, "verdict": None if self.verdict is None else
               ("linear" if self.verdict.linear else "nonlinear"),
               "evidence": "" if self.verdict is None else self.verdict.evidence,
               "lines_used": self.lines_used, "lines_flagged": self.lines_flagged, "laws": laws}
        if self.verdict is not None:
            out["statistic"], out["threshold"] = self.verdict.statistic, self.verdict.threshold
        return out


@dataclass
class HistoryStep:
    """One step of the model history: what was done and what error it gave."""

    step: int
    action: str
    model_toml: str
    error: float
    error_by_level: list[tuple[float, float]]
    laws: dict[str, list[dict]]

    def to_json(self) -> dict:
        return {"step": self.step, "action": self.action, "error": self.error,
                "error_by_level": [{"force": f, "error": e} for f, e in self.error_by_level],
                "laws": self.laws, "model": self.model_toml}


@dataclass
class ReferenceReport:
    """Modal fit of the random run and (optionally) the updating of the structure."""

    modal: ModalFit | None
    update: UpdateResult | None

    def text(self) -> str:
        lines = []
        if self.modal is not None:
            lines.append("modes from the random run (modal fit):")
            lines += [f"  mode {i + 1}: {f:10.4f} Hz, damping {100 * z:.3f} %"
                      for i, (f, z) in enumerate(zip(self.modal.frequency, self.modal.damping))]
        if self.update is not None:
            lines.append("reference model updated to the measured frequencies:")
            lines += ["  " + line for line in self.update.table_text().splitlines()]
        return "\n".join(lines)

    def to_json(self) -> dict:
        out: dict = {}
        if self.modal is not None:
            out["modes"] = [{"frequency": float(f), "damping": float(z)}
                            for f, z in zip(self.modal.frequency, self.modal.damping)]
        if self.update is not None:
            u = self.update
            out["updating"] = {"parameters": {p: {"before": float(b), "after": float(a)}
                                              for p, b, a in zip(u.parameters, u.before, u.after)},
                               "modes": u.modes, "measured_hz": u.measured_hz.tolist(),
                               "before_hz": u.before_hz.tolist(), "after_hz": u.after_hz.tolist()}
        return out


class Workbench:
    """Carry one model through identification, fitting, comparison and the missing-effect loop."""

    def __init__(self, model: Model, measurements: Measurements, distortion_limit: float = 0.05,
                 harmonics: HarmonicCriterion | None = HarmonicCriterion()):
        if not measurements.sine:
            raise InputError("the session has no stepped-sine run to identify from")
        missing = sorted(d for d in measurements.dofs() if d not in model.structure.dofs)
        if missing:
            raise InputError(f"measured DOF(s) {', '.join(missing)} are not in the model's structure", model.source)
        self.model = model.copy()
        self.measurements = measurements
        self.distortion_limit = distortion_limit   # lines whose displacement THD is larger: left out
        self.harmonics = harmonics                 # which lines are predicted multi-harmonically (None: none)
        self.reference: ReferenceReport | None = None
        self.reports: dict[str, ElementReport] = {}
        self.history: list[HistoryStep] = []
        self._comparison: Comparison | None = None
        self._single: Comparison | None = None
        self._predictor: Predictor | None = None

    # ------------------------------------------------------------------ reference
    def update_reference(self) -> ReferenceReport:
        """Modal fit of the random run; update the parameters named in the model's ``[updating]`` table."""
        rnd = self.measurements.random
        modal = update = None
        if rnd is not None:
            n_wanted = max(self.model.updating_modes or [len(self.model.updating_parameters) or 1])
            modal = fit_modes(rnd.frequency_hz, rnd.receptance, n_modes=n_wanted)
            if self.model.updating_parameters:
                modes = self.model.updating_modes or list(range(1, len(modal.frequency) + 1))
                if len(modal.frequency) < len(modes):
                    raise InputError(f"the random run shows {len(modal.frequency)} modes but {len(modes)} are to "
                                     "be matched", self.model.source, "[updating].modes")
                update = update_parameters(self.model.structure_table, self.model.updating_parameters,
                                           modal.frequency[: len(modes)], modes, self.model.source)
                self.model = self.model.with_structure(update.table)
                self._predictor = None
        self.reference = ReferenceReport(modal, update)
        return self.reference

    # ------------------------------------------------------------------ identification
    def identify(self) -> dict[str, ElementReport]:
        """kbar samples and a verdict for every element of the model."""
        els = self.model.elements
        if not els:
            raise InputError("the model has no [[element]] to identify", self.model.source)
        per: dict[str, list[ElementSamples]] = {e.name: [] for e in els}
        flagged = {e.name: 0 for e in els}
        for run in self.measurements.sine:
            if len(run.sensor_dofs) < len(els):
                raise InputError(f"run {run.name} measured {len(run.sensor_dofs)} FRF(s) but the model has "
                                 f"{len(els)} unknown elements: at least as many sensors as elements are needed")
            std = None if run.receptance_std is None else np.asarray(run.receptance_std, float)
            ident = identify_complex_stiffness(self.model.structure, run.receptance, run.sensor_dofs,
                                               run.excitation_dof, els, w=run.w, force=run.force_per_line,
                                               noise_std=std)
            good = ~ident.ill_conditioned & np.isfinite(ident.kbar).all(axis=1) & (ident.amplitude > 0).all(axis=1)
            if run.distortion is not None:
                good &= np.asarray(run.distortion) <= self.distortion_limit
            for i, el in enumerate(els):
                flagged[el.name] += int((~good).sum())
                kstd = None if ident.kbar_std is None else ident.kbar_std[good, i]
                per[el.name].append(ElementSamples(el.name, ident.amplitude[good, i], run.w[good],
                                                   ident.kbar[good, i], kstd, np.full(good.sum(), run.force),
                                                   el.rotational(self.model.structure)))
        self.reports = {}
        for el in els:
            samples = ElementSamples.joined(per[el.name])
            X = samples.X
            verdict = None
            if len(X) >= 4:
                k_u, x_u = samples.units
                try:
                    verdict = linearity_verdict(X, samples.w, samples.kbar, samples.kbar_std, level=samples.level,
                                                stiffness_unit=k_u, amplitude_unit=x_u)
                except InputError:
                    verdict = None
            self.reports[el.name] = ElementReport(el.name, samples if len(X) else None, verdict, len(X),
                                                  flagged[el.name])
        return self.reports

    # ------------------------------------------------------------------ fitting and comparison
    def fit(self, names: list[str] | None = None) -> None:
        """Fit the laws of the named elements (default all) to their samples; values go into the model."""
        if not self.reports:
            self.identify()
        for el in self.model.elements:
            if names is not None and el.name not in names:
                continue
            report = self.reports[el.name]
            if not el.laws:
                report.fit = None
                continue
            s = report.samples
            if s is None:
                raise InputError(f"element {el.name!r} has no well-conditioned line to fit its laws to")
            report.fit = fit_laws(el.laws, s.X, s.w, s.kbar, s.kbar_std)
            el.laws = [LawTerm(t.law, dict(report.fit.terms[j].params)) for j, t in enumerate(el.laws)]
        self._comparison = self._single = None

    @property
    def predictor(self) -> Predictor:
        if self._predictor is None:
            self._predictor = Predictor(self.model, self.measurements)
        return self._predictor

    def compare(self) -> Comparison:
        """Predict every stepped-sine run with the current model and compare."""
        if self._comparison is None:
            for el in self.model.elements:
                for t in el.laws:
                    if not t.complete:
                        raise InputError(f"element {el.name!r}: law {t.law.name} has no values; fit it first")
            self._comparison = self.predictor.compare(locate_folds=True, harmonics=self.harmonics)
        return self._comparison

    def single_harmonic_comparison(self) -> Comparison:
        """The error with every line predicted single-harmonically, as the candidates are (their gains are
        measured against it)."""
        if self.harmonics is None:
            return self.compare()
        if self._single is None:
            self._single = self.predictor.compare()
        return self._single

    def _ranking_inputs(self):
        samples = {n: r.samples for n, r in self.reports.items() if r.samples is not None}
        fits = {n: r.fit for n, r in self.reports.items()}
        linear = frozenset(n for n, r in self.reports.items() if r.verdict is not None and r.verdict.linear)
        return samples, fits, linear

    def candidates(self, laws=None, rules: RankingRules = RankingRules()) -> list[Candidate]:
        """Ranked missing-effect candidates for the current model (best first); the significant ones are checked
        against what the single-harmonic model cannot represent (:func:`analysis.diagnosis.check_model_form`)."""
        samples, fits, linear = self._ranking_inputs()
        ranked = rank_candidates(self.predictor, samples, fits, self.single_harmonic_comparison(), laws,
                                 linear_elements=linear, rules=rules)
        check_model_form(self.predictor, ranked, rules, self.harmonics_or_default.n_harmonics,
                         self.harmonics_or_default.n_time)
        return ranked

    def pair_candidates(self, element: str, pairs: list[tuple[str, str]],
                        rules: RankingRules = RankingRules()) -> list[Candidate]:
        """Pairs of laws added together to ``element``, best first, checked like single candidates."""
        samples, fits, linear = self._ranking_inputs()
        ranked = rank_pairs(self.predictor, samples, fits, self.single_harmonic_comparison(), element, pairs,
                            element in linear, rules)
        check_model_form(self.predictor, ranked, rules, self.harmonics_or_default.n_harmonics,
                         self.harmonics_or_default.n_time)
        return ranked

    @property
    def harmonics_or_default(self) -> HarmonicCriterion:
        return self.harmonics or HarmonicCriterion()

    # ------------------------------------------------------------------ the loop
    def record(self, action: str) -> HistoryStep:
        """Append the current model and its error to the history."""
        comp = self.compare()
        step = HistoryStep(len(self.history), action, self.model.to_toml(), comp.error, comp.error_by_level,
                           {el.name: [t.to_toml() for t in el.laws] for el in self.model.elements})
        self.history.append(step)
        return step

    def add(self, element: str, law: str) -> HistoryStep:
        """Add ``law`` to ``element``, refit that element and record the new error."""
        return self.add_laws(element, (law,))

    def add_laws(self, element: str, laws: tuple[str, ...]) -> HistoryStep:
        """Add ``laws`` (one, or a pair found together) to ``element``, refit it and record one step."""
        el = self.model.element(element)
        new = [get_law(law) for law in laws]
        for law, n in zip(laws, new):
            if any(t.law.name == n.name for t in el.laws):
                raise InputError(f"element {element!r} already has law {law!r}", self.model.source)
        el.laws += [LawTerm(n, {}) for n in new]
        self.fit([element])
        return self.record(f"add {element}:{'+'.join(laws)}")

    def linear_corrections(self, min_sigma: float = 5.0) -> list[str]:
        """Elements whose verdict is linear but whose kbar is a clear constant offset (more than ``min_sigma``
        standard deviations from zero) and that have no laws yet: the reference is wrong there, and the offset
        is a linear correction (the paper's k_w). Corrections of several elements are coupled -- a wrong
        reference stiffness at one place is compensated elsewhere by the updating -- so they are applied
        together, before laws are added one at a time."""
        out = []
        for el in self.model.elements:
            v = self.reports[el.name].verdict if el.name in self.reports else None
            if v is None or not v.linear or el.laws:
                continue
            if abs(v.mean_kbar) > min_sigma * max(v.mean_kbar_std, 1e-300):
                out.append(el.name)
        return out

    def apply_linear_corrections(self, names: list[str]) -> HistoryStep:
        """Add the ``linear`` law to each named element, refit them, record one history step."""
        for name in names:
            self.model.element(name).laws.append(LawTerm(get_law("linear"), {}))
        self.fit(names)
        return self.record("linear correction " + ", ".join(names))

    def undo(self) -> HistoryStep:
        """Take back the last step of the history (an added law): the previous step's laws and values return,
        the elements whose laws change are refitted, and the step is dropped. Returns the step now current."""
        if len(self.history) < 2:
            raise InputError("nothing to undo: the model is as analysis started it")
        self.history.pop()
        before = load_model(tomllib.loads(self.history[-1].model_toml), self.model.source)
        changed = []
        for el, old in zip(self.model.elements, before.elements):
            if [t.law.name for t in el.laws] != [t.law.name for t in old.laws]:
                changed.append(el.name)
            el.laws = old.laws
        self.fit(changed)                      # also drops the cached comparison
        return self.history[-1]

    def start(self) -> HistoryStep:
        """Reference, identification and fit of the model as given; the first history step."""
        if self.reference is None:
            self.update_reference()
        self.identify()
        self.fit()
        return self.record("start")

    def to_json(self, candidates: list[Candidate] | None = None) -> dict:
        comp = self.compare()
        out = {"elements": [self.reports[el.name].to_json(el) for el in self.model.elements],
               **comp.to_json(), "other_branch_hz": comp.other_branch_hz(self.measurements.sine),
               "candidates": [c.to_json() for c in (candidates or [])],
               "history": [h.to_json() for h in self.history],
               "unfinished_runs": [note.to_json() for note in self.measurements.unfinished]}
        if self.reference is not None:
            out["reference"] = self.reference.to_json()
        return out
