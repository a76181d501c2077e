"""What model discovery returns and the rules it runs by (the overview: analysis/search/discovery.py,
docs/discovery.md): the settings (:class:`DiscoveryRules`), one set of laws fitted to an element's kbar
(:class:`LawSet`), one comparison of the FRFs' walk (:class:`WalkStep`), a set the data cannot part from the
choice with the test that would (:class:`Separation`), and each element's and the whole discovery's result with
their text and JSON (:class:`ElementDiscovery`, :class:`Discovery`).

Records only, nothing that fits, judges or chooses: every later module of the search builds on them, and a reader
of a discovery (the loop, the report) needs no more than these.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..fitting.fit import LawFit
from ..laws.base import broadcast
from ..missing.diagnosis import RankingRules
from ..prediction.comparison import gain_phrase


@dataclass(frozen=True)
class DiscoveryRules:
    """The settings of model discovery (the overview in discovery.py)."""

    max_laws: int = 3                 # laws in one set at most
    triple_pool: int = 8              # best pairs extended to sets of three
    walk_width: int = 3               # sets of each size the FRFs judge (:func:`_shortlists`)
    max_correlation: float = 0.995    # parameters of two laws of a set this correlated: not separate effects
    screening_grid: int = 4           # shape-parameter grid points per parameter while sets are screened
    screening_starts: int = 1         # local searches per screening fit
    screening_evaluations: int = 30   # residual evaluations per local search while screening
    placed_pool: int = 8              # best sets with a contact law refitted placed (with their smaller sets)
    ranking: RankingRules = RankingRules()   # min_gain, certain_gain, false_alarm, model_form_thd


@dataclass
class LawSet:
    """One set of laws fitted to one element's kbar."""

    laws: tuple[str, ...]
    fit: LawFit | None                # None for the empty set
    chi_square: float
    n_parameters: int
    criterion: float = np.inf         # chi2 / s^2 + p ln(2N), set once s^2 is known
    tied: bool = False                # a law of it adds no direction of its own (:func:`_adds_nothing`)

    @property
    def name(self) -> str:
        return "+".join(self.laws) if self.laws else "no law"

    def describing_function(self, X, w) -> np.ndarray:
        X, w = broadcast(np.asarray(X, float), np.asarray(w, float))
        return self.fit.describing_function(X, w) if self.fit is not None else np.zeros(X.shape, complex)


@dataclass
class Separation:
    """Where an indistinguishable set's describing function parts from the chosen one's."""

    laws: tuple[str, ...]
    test: str                          # the test that would separate them, in words

    def to_json(self) -> dict:
        return {"laws": list(self.laws), "test": self.test}


@dataclass
class WalkStep:
    """One comparison of the walk: a set tried against the element's current choice, with the FRF errors."""

    laws: tuple[str, ...]
    error: float                       # single-harmonic FRF error with it
    error_before: float                # ... with the current choice
    taken: bool
    multiharmonic_gain: float | None = None
    why: str = ""
    not_itself: bool = False           # not taken because the kbar does not show a law of it as itself, or does
    #                                    not call for it beside the laws taken: the next set of its size is tried
    seen_in_frfs: str = ""             # the sizes the FRFs determine where the kbar leaves them open
    instead: tuple[str, ...] = ()      # the set without a law the kbar does not show beside friction, to try next
    by_kbar: bool = False              # refused for what the element's own kbar shows (:meth:`_Judge._veto`), which
    #                                    the laws the other elements take do not change

    @property
    def gain(self) -> float:
        return self.error_before / self.error if self.error > 0 else float("inf")

    def text(self) -> str:
        name = "+".join(self.laws) if self.laws else "no law"
        mh = "" if self.multiharmonic_gain is None else f", {gain_phrase(self.multiharmonic_gain)} with harmonics"
        verdict = "taken" if self.taken else f"not taken{': ' + self.why if self.why else ''}"
        if self.taken and self.seen_in_frfs:
            verdict += f" (its kbar leaves the size open; the FRFs refined give {self.seen_in_frfs})"
        return f"{name}: {self.error:.3g} ({gain_phrase(self.gain)} single-harmonic{mh}), {verdict}"

    def to_json(self) -> dict:
        return {"laws": list(self.laws), "error": self.error, "error_before": self.error_before, "gain": self.gain,
                "taken": self.taken, "multiharmonic_gain": self.multiharmonic_gain, "why": self.why,
                "seen_in_frfs": self.seen_in_frfs, "by_kbar": self.by_kbar}


@dataclass
class ElementDiscovery:
    """What discovery found for one element."""

    element: str
    chosen: LawSet
    scale: float                       # s^2: the best set's reduced chi-square, at least 1
    sets_fitted: int
    explanations: list[str]
    equivalents: list[Separation] = field(default_factory=list)
    walk: list[WalkStep] = field(default_factory=list)
    simplified_from: tuple[str, ...] | None = None   # the set the FRFs took, where a simpler alike one replaced it
    # the readings of its kbar the walk chose among: by size, every set of its shortlist as the kbar criterion
    # ranks them, then every other set of that size the walk tried, in its order (what the loop weighs again by
    # the FRFs where the model stays above what the test allows)
    readings: tuple[tuple[str, ...], ...] = ()

    @property
    def laws(self) -> tuple[str, ...]:
        return self.chosen.laws

    def text(self) -> str:
        out = [f"{self.element}: {self.chosen.name} ({self.chosen.n_parameters} parameter(s); {self.sets_fitted} "
               f"sets of up to three laws fitted to its kbar)"]
        out += [f"  {e}" for e in self.explanations]
        if self.equivalents:
            out.append("  indistinguishable on these data (they fit its kbar as well, and the FRFs within the margin "
                       "a law must bring; the simplest is taken): "
                       + "; ".join(f"{'+'.join(s.laws)} ({s.test})" for s in self.equivalents))
        if self.walk:
            out.append("  judged by the FRFs: " + "; ".join(s.text() for s in self.walk))
        if self.simplified_from:
            out.append(f"  taken as {self.chosen.name} rather than {'+'.join(self.simplified_from)}: it fits the "
                       "kbar as well with fewer parameters, fewer laws whose kbar depends on the amplitude or fewer "
                       "shape parameters")
        return "\n".join(out)

    def to_json(self) -> dict:
        return {"element": self.element, "laws": list(self.chosen.laws), "n_parameters": self.chosen.n_parameters,
                "kbar_chi_square": self.chosen.chi_square, "kbar_scale": self.scale,
                "sets_fitted": self.sets_fitted, "explanations": self.explanations,
                "indistinguishable": [s.to_json() for s in self.equivalents],
                "walk": [s.to_json() for s in self.walk],
                "simplified_from": None if self.simplified_from is None else list(self.simplified_from),
                "readings": [list(r) for r in self.readings]}


@dataclass
class Discovery:
    """The laws found for every element that had none, in the order they are best added."""

    elements: list[ElementDiscovery]

    def text(self) -> str:
        if not self.elements:
            return "model discovery: no element without laws"
        return "\n".join(["model discovery (laws chosen per element from its kbar, judged by the FRFs):"] +
                         ["  " + line for e in self.elements for line in e.text().splitlines()])

    def to_json(self) -> dict:
        return {"elements": [e.to_json() for e in self.elements]}
