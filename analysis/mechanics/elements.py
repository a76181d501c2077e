"""Unknown (or simulated) elements: where they sit and which laws they obey.

An element is grounded at one DOF (``dof = "x1"``) or acts between two
(``between = ["x1", "x2"]``); its displacement is ``x_a`` or ``x_a - x_b``
(docs/contracts.md §1). Its force is the sum of its law terms, plus, in a model, an optional non-parametric
part fitted to the identified kbar where no law explains it (:mod:`analysis.mechanics.nonparametric`: a describing
function only, so an element carrying one has no time-domain force).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..common.errors import InputError
from ..common.tables import Fields
from ..laws import Law, get_law
from ..laws.base import Origin, broadcast
from .nonparametric import NAME as NONPARAMETRIC, NonParametric
from .structures import Structure
from .surroundings import Surroundings, linear_part, placed_kbar, surroundings_of

#: The model file's key of an element whose reference holds its small-amplitude stiffness (docs/contracts.md §4)
IN_REFERENCE = "in_reference"
#: ... and of where its laws are measured from, the state the reference holds it in (docs/contracts.md §4)
ORIGIN = "origin"


@dataclass
class LawTerm:
    """One law on an element with its parameter values (possibly partial: starting values)."""

    law: Law
    values: dict[str, float] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return all(name in self.values for name in self.law.param_names)

    def describing_function(self, X, w) -> np.ndarray:
        key = tuple(self.values.items())
        cached = getattr(self, "_kbar", None)
        if cached is None or cached[0] != key:          # values may be edited in place: rebuild then
            cached = self._kbar = (key, self.law.kbar_function(**self.values))
        return cached[1](X, w)

    def to_toml(self) -> dict:
        return {"law": self.law.name, **self.values}


@dataclass
class Element:
    """An element of the structure: a name, its DOF(s) and its laws."""

    name: str
    dofs: tuple[str, ...]  # (a,) grounded, or (a, b) between
    laws: list[LawTerm] = field(default_factory=list)
    nonparametric: NonParametric | None = None     # what the laws leave of kbar, where no law explains it
    # the structure around the element (set where it is read into a structure): a contact law's kbar is placed in it
    surroundings: Surroundings | None = field(default=None, compare=False, repr=False)
    # the reference structure holds the element's small-amplitude stiffness (it was made from a measured level):
    # every law of the element is measured from its small-amplitude state (analysis.laws.base.Law.relative)
    in_reference: bool = False
    # ... and where the reference records the element's state at the level it was made from, the laws are measured
    # from that state (analysis.laws.base.Origin)
    origin: Origin | None = None

    def law(self, name: str, source: str | None = None, field: str | None = None) -> Law:
        """The law called ``name`` as this element uses it: measured from its small-amplitude state where the
        reference holds that state (:attr:`in_reference`), from :attr:`origin` where it has one."""
        return _element_law(name, self.in_reference, self.origin, source, field)

    @property
    def time_domain(self) -> bool:
        """Whether the element has a time-domain force (every part is a law): needed to simulate it and to
        predict it with harmonics."""
        return self.nonparametric is None

    @property
    def grounded(self) -> bool:
        return len(self.dofs) == 1

    def indices(self, structure: Structure) -> tuple[int, int | None]:
        a = structure.index(self.dofs[0])
        return a, (structure.index(self.dofs[1]) if len(self.dofs) == 2 else None)

    def vector(self, structure: Structure) -> np.ndarray:
        """e with x_element = e @ x: +1 at a, -1 at b."""
        e = np.zeros(structure.n)
        a, b = self.indices(structure)
        e[a] = 1.0
        if b is not None:
            e[b] = -1.0
        return e

    def rotational(self, structure: Structure) -> bool:
        return structure.is_rotational(self.dofs[0])

    def placed_surroundings(self) -> Surroundings | None:
        """The surroundings with the element's own amplitude-independent laws in parallel; None without
        surroundings or without a contact law (nothing to place)."""
        if self.surroundings is None or not any(t.law.placed for t in self.laws):
            return None
        return self.surroundings.with_parallel(linear_part([(t.law, t.values) for t in self.laws if t.complete]))

    def describing_function(self, X, w) -> np.ndarray:
        """Sum of the law terms' kbar and the non-parametric part's (0 when the element has neither); the contact
        laws' kbar placed in the element's surroundings (analysis/mechanics/surroundings.py) where the element has them."""
        X, w = broadcast(np.asarray(X, float), np.asarray(w, float))
        total = np.zeros(X.shape, complex)
        around = self.placed_surroundings()
        placed = [t for t in self.laws if around is not None and t.law.placed and t.complete]
        if placed:          # one mean and one set of harmonics for the element, whatever its placed laws
            total = total + placed_kbar([(t.law, t.values) for t in placed], X, w, around)
        for term in self.laws:
            if not any(term is t for t in placed):
                total = total + term.describing_function(X, w)
        if self.nonparametric is not None:
            total = total + self.nonparametric.describing_function(X, w)
        return total


def _element_law(name: str, in_reference: bool, origin: Origin | None, source: str | None,
                 field: str | None) -> Law:
    law = get_law(name, source, field)
    return law.relative(origin) if in_reference else law


def _origin(f: Fields, in_reference: bool) -> Origin | None:
    """The element's ``origin = { amplitude = X0, frequency = f0 }`` (m or rad; Hz), where it has one: only beside
    ``in_reference = true``, which it refines."""
    if not f.has(ORIGIN):
        return None
    if not in_reference:
        raise f.error(ORIGIN, "is where the laws of an element whose reference holds it are measured from: it "
                              f"needs {IN_REFERENCE} = true")
    o = f.sub(ORIGIN)
    o.unknown_keys({"amplitude", "frequency"})
    return Origin(o.number("amplitude", positive=True), 2.0 * math.pi * o.number("frequency", positive=True))


def load_elements(document: dict, structure: Structure, source: str | None = None,
                  complete: bool = False) -> list[Element]:
    """Read the ``[[element]]`` array of a rig or model file.

    ``complete=True`` (rig files: the truth) requires every parameter of every law;
    otherwise (model files) values are optional starting values, and an element may carry a fitted
    ``nonparametric`` table (knots and values, :class:`analysis.mechanics.nonparametric.NonParametric`), which a rig file
    may not: it has no time-domain force to simulate.
    """
    root = Fields(document, source, "")
    elements: list[Element] = []
    seen: set[str] = set()
    for i, f in enumerate(root.list_of_tables("element")):
        f.where = f"[[element]][{i}]"
        f.unknown_keys({"name", "dof", "between", "laws", NONPARAMETRIC, IN_REFERENCE, ORIGIN})
        in_reference = False
        if f.has(IN_REFERENCE):
            if complete:
                raise f.error(IN_REFERENCE, "a rig's element is the truth, with its whole force: it cannot be "
                                            "measured from a reference")
            in_reference = f.boolean(IN_REFERENCE)
        origin = _origin(f, in_reference)
        name = f.string("name")
        if not name or name != name.strip() or ":" in name:
            raise f.error("name", f"{name!r} is not an element name: give a non-empty name without a colon "
                                  "and without spaces around it (--add ELEMENT:LAW must be able to name it)")
        if name in seen:
            raise f.error("name", f"element name {name!r} is used twice")
        seen.add(name)
        if f.has("dof") == f.has("between"):
            raise f.error(None, "give exactly one of dof (grounded) or between = [a, b]")
        if f.has("dof"):
            dofs = (f.string("dof"),)
            structure.index(dofs[0], f.path("dof"))
        else:
            dofs = tuple(f.strings("between"))
            if len(dofs) != 2 or dofs[0] == dofs[1]:
                raise f.error("between", "must name two different DOFs")
            for d in dofs:
                structure.index(d, f.path("between"))
            if structure.is_rotational(dofs[0]) != structure.is_rotational(dofs[1]):
                raise f.error("between", "cannot join a rotation to a displacement")
        raw = f.table.get("laws", [])
        if not isinstance(raw, list):
            raise f.error("laws", "must be a list of law names or tables")
        terms = []
        for j, entry in enumerate(raw):
            where = f.path(f"laws[{j}]")
            if isinstance(entry, str):
                entry = {"law": entry}
            if not isinstance(entry, dict) or "law" not in entry:
                raise InputError("each law is a name or a table with a 'law' key", source, where)
            law = _element_law(entry["law"], in_reference, origin, source, f"{where}.law")
            values = {k: v for k, v in entry.items() if k != "law"}
            numbers = Fields(values, source, where)
            for key, value in values.items():
                if key in law.param_names:      # TOML numbers only: "-750" or true is not a stiffness
                    numbers.check_number(key, value)
            twice = next((k for k, t in enumerate(terms) if t.law.name == law.name), None)
            if twice is not None:       # one term a law: two are one law whose parameters no fit tells apart
                raise InputError(f"law {law.name!r} is named twice on element {name!r} (laws[{twice}] and "
                                 f"laws[{j}]): name each law once; one term carries its whole force", source,
                                 f"{where}.law")
            terms.append(LawTerm(law, law.check_params(values, complete, source, where)))
        part = None
        if f.has(NONPARAMETRIC):
            if complete:
                raise f.error(NONPARAMETRIC, "a rig's element needs laws with a time-domain force; a "
                              "non-parametric part has none and cannot be simulated")
            part = NonParametric.from_toml(f.table[NONPARAMETRIC], source, f.path(NONPARAMETRIC))
        element = Element(name, dofs, terms, part, in_reference=in_reference, origin=origin)
        element.surroundings = surroundings_of(structure, element.vector(structure), in_reference, origin)
        elements.append(element)
    return elements
