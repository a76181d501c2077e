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

from ..common.errors import InputError
from ..common.tables import Fields
from .elements import Element, LawTerm, load_elements
from .nonparametric import NAME as NONPARAMETRIC
from .structures import Structure, load_structure, structure_parameter
from .surroundings import surroundings_of

# The top-level keys of a rig file (docs/contracts.md §3, docs/rig-simulator.md). A rig file is also a valid model
# file -- its laws' values are read as starting values -- so a model file may carry them; they are not read.
RIG_TABLES = frozenset({"name", "structure", "element", "excitation", "sensors", "noise", "shaker", "daq",
                        "generator", "simulation", "faults"})
MODEL_TABLES = frozenset({"structure", "element", "updating", "fitted"})


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
                el.surroundings = surroundings_of(self.structure, el.vector(self.structure))

    def element(self, name: str) -> Element:
        for el in self.elements:
            if el.name == name:
                return el
        raise InputError(f"no element named {name!r} (elements: {', '.join(e.name for e in self.elements)})",
                         self.source)

    def copy(self) -> "Model":
        return Model(copy.deepcopy(self.structure_table), self.structure,
                     [Element(e.name, e.dofs, [LawTerm(t.law, dict(t.values)) for t in e.laws], e.nonparametric,
                             e.surroundings)
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
