"""The user's model (docs/contracts.md §4): a reference structure plus unknown elements with believed laws.

A model file has the ``[structure]`` table, ``[[element]]`` entries (laws optional, values optional starting
values) and optionally ``[updating]`` naming the structure parameters that are uncertain::

    [updating]
    parameters = ["springs[1].k", "youngs_modulus"]   # paths into [structure]
    modes = [1, 2, 3]                                  # measured modes to match (default 1..len(parameters)+)

A fitted model also says what it was fitted to, so that a prediction of the same session can tell the levels it
saw from those it did not (``contactid predict``, docs/workbench.md §6)::

    [fitted]
    session = "beam.h5"                                 # the session's file name
    session_created = "2026-11-30T10:12:03+00:00"       # the session's ``created`` attribute: which session
    levels = ["0.2 N", "0.8 N"]                         # the levels the fit used (their labels)

:meth:`Model.to_toml` writes a model back (fitted values, updated structure) in the same format.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from ..common.errors import InputError
from ..common.quantities import FORCE_RANGE, FREQUENCY_RANGE, RESPONSE_RANGE
from ..common.tables import Fields
from .elements import IN_REFERENCE, ORIGIN, Element, LawTerm, load_elements
from .nonparametric import NAME as NONPARAMETRIC
from .structures import Structure, load_structure, structure_parameter
from .surroundings import surroundings_of

# The top-level keys of a rig file (docs/contracts.md §3, docs/rig-simulator.md). A rig file is also a valid model
# file -- its laws' values are read as starting values -- so a model file may carry them; they are not read.
RIG_TABLES = frozenset({"name", "structure", "element", "excitation", "sensors", "noise", "shaker", "daq",
                        "generator", "simulation", "faults"})
MODEL_TABLES = frozenset({"structure", "element", "updating", "fitted"})

# A law term's values are physical when its force stays finite and at most MAX_LAW_FORCE (N; N·m on a rotation)
# at every motion a lab measures: amplitudes X up to RESPONSE_RANGE's largest displacement (1 m; 1 rad), velocity
# w X up to its largest velocity (1 km/s) and acceleration w^2 X up to its largest acceleration (1e6 m/s^2), at
# frequencies across FREQUENCY_RANGE. The bound lies ninety orders above the largest force a lab applies
# (FORCE_RANGE: 1 MN), so no value a fit or a lab gives comes near it, and far enough below where the analysis's
# squares of forces and receptances overflow (1e154) that a prediction stays finite. A value beyond it (a cubic
# k3 = 1e300) is a typing slip: refused when the model is read (docs/contracts.md §4; docs/session-format.md,
# *Quantities*).
MAX_LAW_FORCE = 1e100


@dataclass(frozen=True)
class FittedOn:
    """The session and levels a model's values were fitted to (the ``[fitted]`` table): ``created`` is the
    session's ``created`` attribute, which tells one session from another whatever its file is called;
    ``levels`` are the labels of the levels the fit used (:meth:`analysis.common.measurements.Control.label`)."""

    session: str
    created: str
    levels: tuple[str, ...]

    def saw(self, created: str, label: str) -> bool | None:
        """Whether the fit used level ``label`` of the session created at ``created``: None where the model
        was fitted to another session (every level of it is unseen, but not a level held out of the fit)."""
        if created != self.created:
            return None
        return label in self.levels

    def to_toml(self) -> list[str]:
        return ["[fitted]", f"session = {_toml_value(self.session)}",
                f"session_created = {_toml_value(self.created)}", f"levels = {_toml_value(list(self.levels))}"]


@dataclass
class Model:
    """Reference structure, unknown elements and what may be updated."""

    structure_table: dict
    structure: Structure
    elements: list[Element]
    updating_parameters: list[str] = field(default_factory=list)
    updating_modes: list[int] | None = None
    source: str | None = None
    fitted_on: FittedOn | None = None

    def __post_init__(self):
        self.place_elements(keep=True)

    def place_elements(self, keep: bool = False) -> None:
        """Give every element the structure around it (a contact law's kbar depends on it); ``keep``: an element
        that has them (a copy's, sharing the receptances computed) keeps them."""
        for el in self.elements:
            if not (keep and el.surroundings is not None):
                el.surroundings = surroundings_of(self.structure, el.vector(self.structure), el.in_reference,
                                                  el.origin)

    def element(self, name: str) -> Element:
        for el in self.elements:
            if el.name == name:
                return el
        raise InputError(f"no element named {name!r} (elements: {', '.join(e.name for e in self.elements)})",
                         self.source)

    def copy(self) -> "Model":
        return Model(copy.deepcopy(self.structure_table), self.structure,
                     [Element(e.name, e.dofs, [LawTerm(t.law, dict(t.values)) for t in e.laws], e.nonparametric,
                             e.surroundings, e.in_reference, e.origin)
                      for e in self.elements],
                     list(self.updating_parameters), self.updating_modes, self.source, self.fitted_on)

    def with_structure(self, table: dict) -> "Model":
        m = self.copy()
        m.structure_table = copy.deepcopy(table)
        m.structure = load_structure(table, self.source)
        m.place_elements()
        return m

    def describe(self) -> str:
        """One line per element: its laws and values."""
        lines = []
        for el in self.elements:
            where = el.dofs[0] if el.grounded else f"{el.dofs[0]}-{el.dofs[1]}"
            parts = [_term_text(t) for t in el.laws]
            if el.nonparametric is not None:
                parts.append(el.nonparametric.describe("rad" if el.rotational(self.structure) else "m"))
            laws = " + ".join(parts) or "(reference only)"
            lines.append(f"{el.name} [{where}]: {laws}")
        return "\n".join(lines)

    def to_toml(self) -> str:
        """The model as a TOML model file (the structure as updated, laws with their values)."""
        out = ["[structure]"]
        out += [f"{k} = {_toml_value(v)}" for k, v in self.structure_table.items()]
        if self.updating_parameters:
            out += ["", "[updating]", f"parameters = {_toml_value(self.updating_parameters)}"]
            if self.updating_modes:
                out.append(f"modes = {_toml_value(self.updating_modes)}")
        for el in self.elements:
            out += ["", "[[element]]", f"name = {_toml_value(el.name)}"]
            out.append(f"dof = {_toml_value(el.dofs[0])}" if el.grounded else f"between = {_toml_value(list(el.dofs))}")
            laws = ", ".join("{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in t.to_toml().items()) + " }"
                             for t in el.laws)
            out.append(f"laws = [{laws}]")
            if el.in_reference:
                out.append(f"{IN_REFERENCE} = true")
            if el.origin is not None:
                out.append(f"{ORIGIN} = {{ amplitude = {_toml_value(el.origin.X)}, "
                           f"frequency = {_toml_value(el.origin.hz)} }}")
            if el.nonparametric is not None:
                out.append(f"{NONPARAMETRIC} = {_toml_value(el.nonparametric.to_toml())}")
        if self.fitted_on is not None:
            out += [""] + self.fitted_on.to_toml()
        return "\n".join(out) + "\n"


def _term_text(t: LawTerm) -> str:
    values = ", ".join(f"{k}={v:.4g}" for k, v in t.values.items())
    return f"{t.law.name}({values})"


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else "nan"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    return _toml_value(float(v))


def load_model(document: dict, source: str | None = None) -> Model:
    """Build a Model from a parsed model (or rig) file."""
    root = Fields(document, source, "")
    root.unknown_keys(set(MODEL_TABLES | RIG_TABLES))
    structure_table = root.require("structure")
    structure = load_structure(structure_table, source)
    elements = load_elements(document, structure, source, complete=False)
    for i, el in enumerate(elements):
        for j, term in enumerate(el.laws):
            check_law_force(term.law, term.values, source, f"[[element]][{i}].laws[{j}]")
    params, modes = [], None
    if root.has("updating"):
        up = root.sub("updating")
        up.where = "[updating]"
        up.unknown_keys({"parameters", "modes"})
        params = up.strings("parameters")
        for path in params:         # checked when the model is read, whether or not a session is updated with it
            structure_parameter(structure_table, path, source)
        if len(set(params)) != len(params):
            raise up.error("parameters", "names a parameter twice")
        if up.has("modes"):
            raw = up.table["modes"]
            if not isinstance(raw, list) or not raw or not all(isinstance(m, int) and not isinstance(m, bool)
                                                                and m >= 1 for m in raw):
                raise up.error("modes", "must be a list of mode numbers (1 = lowest)")
            # checked when the model is read, as the parameters are: a mode the structure has not is a slip
            # whether or not a session with a random run ever updates it
            beyond = [m for m in raw if m > structure.n]
            if beyond:
                raise up.error("modes", f"mode {beyond[0]}, but the structure has {structure.n} mode(s) (one per DOF)")
            if len(set(raw)) != len(raw):
                raise up.error("modes", f"names mode {next(m for m in raw if raw.count(m) > 1)} twice")
            if len(raw) < len(params):
                raise up.error("modes", f"{len(raw)} mode(s) cannot determine the {len(params)} parameters of "
                                        "[updating].parameters; name at least as many modes")
            modes = list(raw)
    return Model(copy.deepcopy(structure_table), structure, elements, params, modes, source, _fitted_on(root))


def _fitted_on(root: Fields) -> FittedOn | None:
    if not root.has("fitted"):
        return None
    t = root.sub("fitted")
    t.where = "[fitted]"
    t.unknown_keys({"session", "session_created", "levels"})
    return FittedOn(t.string("session"), t.string("session_created"), tuple(t.strings("levels")))


def _lab_motions() -> tuple[np.ndarray, np.ndarray]:
    """(X, w) pairs spanning the motions a lab measures (see MAX_LAW_FORCE): amplitudes from 1e-12 to the largest
    that the displacement, velocity and acceleration bounds of RESPONSE_RANGE allow at each frequency."""
    w = 2 * np.pi * np.geomspace(*FREQUENCY_RANGE, 19)
    largest = np.minimum.reduce([np.full_like(w, RESPONSE_RANGE["displacement"][1]),
                                 RESPONSE_RANGE["velocity"][1] / w, RESPONSE_RANGE["acceleration"][1] / w ** 2])
    X = np.geomspace(1e-12, 1.0, 13)[:, None] * largest[None, :]
    return X.ravel(), np.broadcast_to(w, X.shape).ravel()


def _benign(param) -> float:
    """A value of ``param`` that adds no force: 0 where it is allowed, else 1."""
    return 0.0 if param.admits(0.0) else 1.0


def _largest_force(law, values: dict) -> float:
    """The largest |force| of the law's fundamental, |kbar(X, w)| X, over the motions a lab measures (inf where
    it is not finite); parameters not given count as adding no force."""
    full = {p.name: values.get(p.name, _benign(p)) for p in law.params}
    X, w = _lab_motions()
    with np.errstate(all="ignore"):
        try:
            force = np.abs(law.describing_function(X, w, **full)) * X
        except (ArithmeticError, ValueError, InputError):
            return math.inf
    return float(np.max(force)) if np.all(np.isfinite(force)) else math.inf


def check_law_force(law, values: dict, source: str | None, where: str) -> None:
    """Refuse a law term whose values make a force no contact carries (above MAX_LAW_FORCE, or not finite) at a
    motion a lab measures, naming the parameter at fault: the first whose value, set to add no force, brings the
    force back within the bound (the whole term where no one parameter does)."""
    largest = _largest_force(law, values)
    if largest <= MAX_LAW_FORCE:
        return
    size = "is not finite" if not math.isfinite(largest) else f"reaches {largest:.3g} N"
    bound = (f"its force {size} at the motions a lab measures (up to {RESPONSE_RANGE['displacement'][1]:g} m, "
             f"{RESPONSE_RANGE['velocity'][1]:g} m/s, {RESPONSE_RANGE['acceleration'][1]:g} m/s^2), above the "
             f"{MAX_LAW_FORCE:g} N no physical law reaches (a lab applies at most {FORCE_RANGE[1]:g} N; N·m and rad "
             "on a rotation): no finite prediction")
    for p in law.params:
        if p.name in values and _largest_force(law, {**values, p.name: _benign(p)}) <= MAX_LAW_FORCE:
            raise InputError(f"{values[p.name]!r}: {bound}", source, f"{where}.{p.name}")
    raise InputError(f"law {law.name!r} with {', '.join(f'{k} = {v!r}' for k, v in values.items())}: {bound}",
                     source, where)
