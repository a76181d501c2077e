"""The hidden-effect matrix: named cases, how their data are made, and how a diagnosis of them is scored.

A case is a rig (a structure with its unknown elements), the laws the rig really has at those elements, which of
them the analysis model lacks (the hidden effects) and the measurement noise. The model handed to the diagnosis
has the rig's elements with only the laws that are not hidden (by name, no values). Most cases are measured
through the whole campaign stack on the emulated rig; a few come from an independent RK4 integrator of this file
and reach the workbench as a user's imported CSV. docs/workbench.md ("The hidden-effect matrix") publishes the
scores; ``benchmarks/hidden_effect_matrix.py`` runs every case, the tests a subset.
"""
from __future__ import annotations

import csv
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.loop.auto import run_auto
from analysis.laws import LAWS
from analysis.laws.base import KINDS
from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench
from app.importers.runs import SourceOptions
from app.importers.store import ImportRequest, import_files
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from app.session.writer import open_session
from app.session.data import measurements_from_session
from drivers.simulation.rig import parse_rig
from test_hidden_effects import BEAM, BEAM_IO, LUMPED, LUMPED_IO, LUMPED_PLAN

# --------------------------------------------------------------------------------------------- law kinds
# What a diagnosis must get right is the kind of physics, not the law's exact name: laws of one kind have
# describing functions that coincide over a range of amplitude (a Jenkins element in gross slip is Coulomb
# friction; a quintic and a cubic both harden), so the data cannot always tell them apart. Each law class names
# its kind (analysis.laws.base.KINDS).
LAW_KINDS: dict[str, frozenset[str]] = {kind: frozenset(n for n, law in LAWS.items() if law.kind == kind)
                                        for kind in KINDS}


def law_kind(law: str) -> str:
    """The kind of a law of the library (``LAW_KINDS``)."""
    for kind, laws in LAW_KINDS.items():
        if law in laws:
            return kind
    raise KeyError(f"law {law!r} has no kind in LAW_KINDS")


# --------------------------------------------------------------------------------------------- records
@dataclass(frozen=True)
class Site:
    """An unknown element of a bench: its name and where it acts (``dof = "x1"`` or ``between = [...]``)."""

    name: str
    placement: str


@dataclass(frozen=True)
class Bench:
    """A structure with its unknown elements, instruments and stepped-sine plan (rig and model files share the
    structure; docs/contracts.md §3-§5)."""

    name: str
    structure: str
    io: str
    plan: str
    sites: tuple[Site, ...]


@dataclass(frozen=True)
class Law:
    """One law the rig has at one element, with its true values."""

    element: str
    law: str
    values: tuple[tuple[str, float], ...]

    def toml(self) -> str:
        # v0: the independent integrator's regularisation of Coulomb friction, not a parameter of the law
        return "{ " + ", ".join([f'law = "{self.law}"'] + [f"{k} = {v!r}" for k, v in self.values if k != "v0"]) \
            + " }"

    @property
    def kind(self) -> str:
        return law_kind(self.law)


@dataclass(frozen=True)
class Case:
    """One matrix case: the rig's laws, which of them the model lacks, the relative noise and the data source
    ("simulator": a campaign on the emulated rig; "rk4": the independent integrator, imported as CSV)."""

    name: str
    bench: Bench
    laws: tuple[Law, ...]
    hidden: tuple[Law, ...]
    noise: float
    source: str = "simulator"
    data_of: str = ""               # the case whose data this one shares (its "from empty" variant), else ""

    @property
    def data_name(self) -> str:
        """The name the data are made under (the noise seed): a variant shares its case's data."""
        return self.data_of or self.name

    def from_empty(self) -> Case:
        """The same rig and data, the model with no law at all: discovery must find every law."""
        return Case(f"{self.name} from empty", self.bench, self.laws, self.laws, self.noise, self.source, self.name)

    def rig_toml(self) -> str:
        seed = _seed(self.data_name)
        noise = f"\n[noise]\nforce = {self.noise!r}\nacceleration = {self.noise!r}\nseed = {seed}\n"
        return (f'name = "{self.name}"\n' + self.bench.structure + self._elements(self.laws) + self.bench.io
                + noise)

    def plan_toml(self) -> str:
        """The bench's plan; above 1 % noise the steady-state check is loosened as a user would for a noisy rig
        (at 2 % the default 0.2 % agreement of successive records held 31 of 57 lines at the settling limit)."""
        return self.bench.plan + (NOISY_SETTLE if self.noise > 0.01 else "")

    def model_toml(self) -> str:
        known = tuple(law for law in self.laws if law not in self.hidden)
        return self.bench.structure + self._elements(known, names_only=True)

    def rig_laws_toml(self, values: bool) -> str:
        """The structure with every law of the rig at its joints: names only (a model whose laws are to be fitted),
        or at the rig's values."""
        return self.bench.structure + self._elements(self.laws, names_only=not values)

    def _elements(self, laws: tuple[Law, ...], names_only: bool = False) -> str:
        out = ""
        for site in self.bench.sites:
            terms = [f'"{law.law}"' if names_only else law.toml() for law in laws if law.element == site.name]
            out += f'\n[[element]]\nname = "{site.name}"\n{site.placement}\nlaws = [{", ".join(terms)}]\n'
        return out


NOISY_SETTLE = "\n[settle]\ntolerance = 0.01\n"


def _seed(name: str) -> int:
    """A noise seed fixed by the case name (not Python's salted hash)."""
    return sum(ord(c) * 31 ** i for i, c in enumerate(name)) % 100_000


# --------------------------------------------------------------------------------------------- benches
LUMPED2 = Bench("2-DOF", LUMPED, LUMPED_IO, LUMPED_PLAN, (Site("a", 'dof = "x1"'), Site("b", 'dof = "x2"')))

CHAIN3_STRUCTURE = """
[structure]
type = "lumped"
dofs = ["x1", "x2", "x3"]
mass = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
stiffness = [[3000.0, -1000.0, 0.0], [-1000.0, 2000.0, -1000.0], [0.0, -1000.0, 2000.0]]
rayleigh = [0.3, 1.0e-4]
"""
CHAIN3_IO = LUMPED_IO.replace('dof = "x2"', 'dof = "x3"').replace('["x1", "x2"]', '["x1", "x2", "x3"]')
# modes at 4.37, 7.87 and 9.81 Hz: the element between x1 and x2 moves in the first two
CHAIN3_PLAN = LUMPED_PLAN.replace("start = 5.0", "start = 3.4").replace("stop = 11.0", "stop = 8.6")
CHAIN3 = Bench("3-DOF chain", CHAIN3_STRUCTURE, CHAIN3_IO, CHAIN3_PLAN,
               (Site("j", 'between = ["x1", "x2"]'), Site("g", 'dof = "x3"')))

# three levels: the micro-slip of a joint shows over a range of amplitude
BEAM_PLAN3 = "".join(f'[[stepped_sine]]\nforce = {f}\nstart = 50.0\nstop = 56.0\nstep = 0.4\ndirection = "up"\n'
                     for f in (0.05, 0.3, 1.2)) + "[limits]\nmax_force = 5.0\nmax_acceleration = 400.0\n"
BEAM3 = Bench("beam", BEAM, BEAM_IO, BEAM_PLAN3,
              (Site("normal", 'dof = "O.w"'), Site("tangential", 'dof = "O.theta"')))


def _law(element: str, law: str, **values: float) -> Law:
    return Law(element, law, tuple(values.items()))


def _case(name, bench, laws, hidden=None, noise=0.003, source="simulator") -> Case:
    """``hidden`` defaults to every law of the rig."""
    laws = tuple(laws)
    return Case(name, bench, laws, laws if hidden is None else tuple(hidden), noise, source)


A_CUBIC = _law("a", "cubic", k3=1.0e5)
A_QUAD = _law("a", "quadratic_damping", c2=3.0)
B_QUAD = _law("b", "quadratic_damping", c2=3.0)
A_COULOMB = _law("a", "coulomb", fs=0.08)
J_CUBIC = _law("j", "cubic", k3=1.0e5)
J_COULOMB = _law("j", "coulomb", fs=0.08)

CASES: tuple[Case, ...] = (
    # 2-DOF, one effect: every law family of the library
    _case("2dof linear", LUMPED2, [_law("a", "linear", k=400.0, c=0.0)], noise=0.001),
    _case("2dof bilinear", LUMPED2, [_law("b", "bilinear", k_pos=600.0, k_neg=200.0)], noise=0.005),
    _case("2dof cubic", LUMPED2, [A_CUBIC], noise=0.003),
    _case("2dof softening cubic", LUMPED2, [_law("b", "cubic", k3=-2.0e4)], noise=0.01),
    _case("2dof quintic", LUMPED2, [_law("a", "quintic", k5=5.0e6)], noise=0.005),
    _case("2dof tanh softening", LUMPED2, [_law("b", "tanh_softening", alpha=20.0, beta=20.0)], noise=0.003),
    _case("2dof arctan softening", LUMPED2, [_law("a", "arctan_softening", alpha=15.0, beta=25.0)], noise=0.02),
    _case("2dof velocity stiffness", LUMPED2, [_law("a", "velocity_stiffness", gamma=4.0)], noise=0.003),
    _case("2dof quadratic damping", LUMPED2, [A_QUAD], noise=0.01),
    _case("2dof cubic damping", LUMPED2, [_law("b", "cubic_damping", c3=0.05)], noise=0.002),
    _case("2dof coulomb", LUMPED2, [A_COULOMB], noise=0.005),
    _case("2dof anderson-ferri", LUMPED2, [_law("b", "anderson_ferri", a=0.1, b=30.0, c=0.0)], noise=0.003),
    _case("2dof jenkins", LUMPED2, [_law("b", "jenkins", kt=400.0, fs=0.5)], noise=0.01),
    _case("2dof gap", LUMPED2, [_law("a", "gap", k=2000.0, gap=0.003)], noise=0.003),
    _case("2dof unilateral", LUMPED2, [_law("b", "unilateral", k=1000.0, gap=0.002)], noise=0.005),
    # 2-DOF, two effects: on different elements, on the same element, one of two known
    _case("2dof cubic + damping elsewhere", LUMPED2, [A_CUBIC, B_QUAD], noise=0.003),
    _case("2dof cubic + damping same element", LUMPED2, [A_CUBIC, A_QUAD], noise=0.005),
    _case("2dof gap + friction elsewhere", LUMPED2, [_law("a", "gap", k=2000.0, gap=0.003),
                                                      _law("b", "coulomb", fs=0.08)], noise=0.02),
    _case("2dof damping missing beside cubic", LUMPED2, [A_CUBIC, B_QUAD], hidden=[B_QUAD], noise=0.001),
    # 2-DOF, nothing missing
    _case("2dof nothing missing (cubic known)", LUMPED2, [_law("a", "cubic", k3=2.0e5)], hidden=[], noise=0.003),
    _case("2dof nothing missing (linear rig)", LUMPED2, [], noise=0.01),
    # 3-DOF chain, the element between two masses
    _case("3dof cubic between masses", CHAIN3, [J_CUBIC], noise=0.003),
    _case("3dof coulomb between masses", CHAIN3, [J_COULOMB], noise=0.005),
    _case("3dof damping between + cubic at x3", CHAIN3, [_law("j", "quadratic_damping", c2=3.0),
                                                         _law("g", "cubic", k3=1.0e5)], noise=0.01),
    _case("3dof cubic + friction between", CHAIN3, [J_CUBIC, J_COULOMB], noise=0.003),
    _case("3dof nothing missing (coulomb known)", CHAIN3, [J_COULOMB], hidden=[], noise=0.02),
    # the beam's contact
    _case("beam jenkins", BEAM3, [_law("tangential", "jenkins", kt=152.0, fs=0.4)], noise=0.003),
    _case("beam iwan", BEAM3, [_law("tangential", "iwan", kt=152.0, fs=3.0, chi=-0.5, beta=0.1)], noise=0.005),
    _case("beam nothing missing (iwan known)", BEAM3,
          [_law("tangential", "iwan", kt=152.0, fs=3.0, chi=-0.5, beta=0.1)], hidden=[], noise=0.003),
    # data from the independent integrator below
    _case("rk4 2dof cubic + damping elsewhere", LUMPED2, [A_CUBIC, B_QUAD], noise=0.003, source="rk4"),
    _case("rk4 3dof cubic between masses", CHAIN3, [J_CUBIC], noise=0.005, source="rk4"),
    # the emulated rig's integrator stopped on this one ("the element forces have no solution")
    _case("rk4 2dof gap", LUMPED2, [_law("a", "gap", k=2000.0, gap=0.003)], noise=0.003, source="rk4"),
    _case("rk4 2dof nothing missing (cubic known)", LUMPED2, [_law("a", "cubic", k3=2.0e5)], hidden=[],
          noise=0.01, source="rk4"),
    # two laws on each of two elements, none known: the paper's own example is of this kind
    _case("2dof two joints: cubic + damping at a and cubic + friction at b", LUMPED2,
          [A_CUBIC, A_QUAD, _law("b", "cubic", k3=-2.0e4), _law("b", "coulomb", fs=0.08)], noise=0.003),
    _case("2dof two joints: cubic + friction at a and gap + damping at b", LUMPED2,
          [A_CUBIC, A_COULOMB, _law("b", "gap", k=2000.0, gap=0.003), B_QUAD], noise=0.005),
    _case("3dof two joints: cubic + friction between and damping + cubic at x3", CHAIN3,
          [J_CUBIC, J_COULOMB, _law("g", "quadratic_damping", c2=3.0), _law("g", "cubic", k3=1.0e5)],
          noise=0.003),
    _case("rk4 2dof two joints: cubic + damping at a and gap + damping at b", LUMPED2,
          [A_CUBIC, A_QUAD, _law("b", "gap", k=2000.0, gap=0.003), B_QUAD], noise=0.003, source="rk4"),
)
# every case with a known law again from a model with none
CASES = CASES + tuple(c.from_empty() for c in CASES if len(c.hidden) < len(c.laws))


def case(name: str) -> Case:
    return next(c for c in CASES if c.name == name)


# --------------------------------------------------------------------------------------------- data
def simulated_session(c: Case, folder: Path) -> Path:
    """The case's plan run on its emulated rig through the drivers, into a session."""
    rig = parse_rig(c.rig_toml(), f"{c.name}.toml")
    path = folder / "session.h5"
    with emulated_instruments(rig, seed=_seed(c.data_name)) as inst:
        plan = c.plan_toml()
        summary = run_plan(parse_plan(tomllib.loads(plan), plan), inst, path)
    if not summary.complete:
        raise RuntimeError(f"case {c.name!r}: the campaign is incomplete: {summary.text().splitlines()[-1]}")
    return path


@dataclass(frozen=True)
class Lumped:
    """The matrices of a lumped bench, read here from its TOML (the integrator below uses none of the analysis)."""

    dofs: list[str]
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray

    @classmethod
    def of(cls, bench: Bench) -> Lumped:
        s = tomllib.loads(bench.structure)["structure"]
        M, K = np.array(s["mass"], float), np.array(s["stiffness"], float)
        a, b = s["rayleigh"]
        return cls(list(s["dofs"]), M, a * M + b * K, K)


def _site_vector(site: Site, dofs: list[str]) -> np.ndarray:
    """e such that the element's displacement is e . x and its force acts on the DOFs as e f."""
    where = tomllib.loads(site.placement)
    e = np.zeros(len(dofs))
    if "dof" in where:
        e[dofs.index(where["dof"])] = 1.0
    else:
        first, second = where["between"]
        e[dofs.index(first)], e[dofs.index(second)] = 1.0, -1.0
    return e


# Coulomb friction in the independent integrator: fs tanh(v / v0), v0 this fraction of the element's velocity
# amplitude scale (``COULOMB_V0`` m/s unless a case says otherwise); a fixed-step RK4 needs no switch then.
COULOMB_V0 = 1e-4


def _law_force(law: Law, d: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The element forces the independent integrator knows, written from their physics (continuous forces only:
    a fixed-step RK4 would need a tiny step at a friction's switch, so Coulomb friction is a steep tanh)."""
    p = dict(law.values)
    forces = {
        "linear": lambda: p.get("k", 0.0) * d + p.get("c", 0.0) * v,
        "cubic": lambda: p["k3"] * d ** 3,
        "quintic": lambda: p["k5"] * d ** 5,
        "quadratic_damping": lambda: p["c2"] * np.abs(v) * v,
        "cubic_damping": lambda: p["c3"] * v ** 3,
        "tanh_softening": lambda: p["alpha"] * np.tanh(p["beta"] * d),
        "arctan_softening": lambda: p["alpha"] * np.arctan(p["beta"] * d),
        "gap": lambda: np.where(np.abs(d) > p["gap"], p["k"] * (d - p["gap"] * np.sign(d)), 0.0),
        "unilateral": lambda: np.where(d > p["gap"], p["k"] * (d - p["gap"]), 0.0),
        "coulomb": lambda: p["fs"] * np.tanh(v / p.get("v0", COULOMB_V0)),
    }
    if law.law not in forces:
        raise ValueError(f"the independent integrator has no force for law {law.law!r}")
    return forces[law.law]()


def rk4_receptance(c: Case, freqs: np.ndarray, forces: np.ndarray, settle_seconds: float = 40.0,
                   per_period: int = 48, keep: int = 4) -> np.ndarray:
    """RK4 of M x'' + C x' + K x + sum_e e f_e(e.x, e.v) = F sin(wt) at the excitation DOF, from rest, every line
    (``freqs``, Hz) at every force (``forces``, N) at once, each with its own step (``per_period`` per period) for
    at least ``settle_seconds`` (ten times the slowest modal decay time of the benches); the fundamental phasor X
    of every DOF (x = Im X e^{jwt}) over the last ``keep`` periods, over F: shape (levels, L, n)."""
    lumped = Lumped.of(c.bench)
    n = len(lumped.dofs)
    sites = {s.name: _site_vector(s, lumped.dofs) for s in c.bench.sites}
    q = lumped.dofs.index(tomllib.loads(c.bench.io)["excitation"]["dof"])
    F, f_hz = np.meshgrid(np.asarray(forces, float), np.asarray(freqs, float), indexing="ij")
    F, w = F.reshape(-1, 1), 2 * np.pi * f_hz.reshape(-1, 1)
    dt = 2 * np.pi / w / per_period
    Minv = np.linalg.inv(lumped.M)

    def rhs(t, y):
        x, v = y[:, :n], y[:, n:]
        f = x @ lumped.K.T + v @ lumped.C.T
        for law in c.laws:
            e = sites[law.element]
            f += _law_force(law, x @ e, v @ e)[:, None] * e
        f[:, q] -= F[:, 0] * np.sin(w[:, 0] * t[:, 0])
        return np.hstack([v, -f @ Minv.T])

    y, t = np.zeros((len(w), 2 * n)), np.zeros((len(w), 1))
    fundamental = np.zeros((len(w), n), complex)
    settle = int(np.ceil(settle_seconds * np.max(freqs))) * per_period
    for i in range(settle + keep * per_period):
        if i >= settle:
            fundamental += y[:, :n] * (np.sin(w * t) + 1j * np.cos(w * t))
        k1 = rhs(t, y)
        k2 = rhs(t + dt / 2, y + dt / 2 * k1)
        k3 = rhs(t + dt / 2, y + dt / 2 * k2)
        k4 = rhs(t + dt, y + dt * k3)
        y, t = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), t + dt
    return (fundamental * 2 / (keep * per_period) / F).reshape(len(forces), len(freqs), n)


# Lines of the integrator's cases: as finely as a user sweeps by hand. (The FRF noise of imported data is
# estimated from 15 neighbouring lines; at the plans' 0.4 Hz it came out 3-6 x the truth.)
RK4_STEP = 0.1
# the random stream of imported_session's perturbation (one for every case: it is no draw of the case)
PERTURBATION_STREAM = 12345


def _plan_lines(bench: Bench, step: float = RK4_STEP) -> tuple[np.ndarray, list[float]]:
    """The lines (at ``step`` over the plan's band) and the force levels of the bench's plan."""
    runs = tomllib.loads(bench.plan)["stepped_sine"]
    r = runs[0]
    n = int(round((r["stop"] - r["start"]) / step)) + 1
    return np.linspace(r["start"], r["stop"], n), [float(run["force"]) for run in runs]


def imported_session(c: Case, folder: Path, settle_seconds: float = 40.0, per_period: int = 48,
                     line_step: float = RK4_STEP, perturbation: float = 0.0) -> Path:
    """RK4 receptances with relative circular noise, written as a user's CSV with their standard deviation (as a
    controller that measured it exports them) and imported (``contactid import``). Without it the noise is
    estimated from the FRF (docs/import.md), which at 0.1 Hz lines across a 0.06 Hz wide resonance came out 2-4 x
    the truth there and hid the cubic between the 3-DOF chain's masses. ``perturbation``: every receptance then
    moved by that relative amount times a normal draw of a stream of its own, the same for every case -- a change
    of the data far below their noise, which no measurement could tell, to measure how stable an answer is
    (benchmarks/random_discovery.py ``--perturb``)."""
    freqs, forces = _plan_lines(c.bench, line_step)
    rng = np.random.default_rng(_seed(c.data_name))
    dofs = Lumped.of(c.bench).dofs
    exact = rk4_receptance(c, freqs, forces, settle_seconds, per_period)
    std = c.noise * np.abs(exact)
    H = exact + std / np.sqrt(2) * (rng.normal(size=exact.shape) + 1j * rng.normal(size=exact.shape))
    if perturbation:
        H = H * (1.0 + perturbation * np.random.default_rng(PERTURBATION_STREAM).normal(size=H.shape))
    table = folder / "frf.csv"
    with open(table, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["frequency_hz", "force_n", "dof", "re", "im", "std"])
        for F, H_level, std_level in zip(forces, H, std):
            for p, dof in enumerate(dofs):
                for f, h, s in zip(freqs, H_level[:, p], std_level[:, p]):
                    out.writerow([repr(float(f)), F, dof, repr(float(h.real)), repr(float(h.imag)), repr(float(s))])
    session = folder / "imported.h5"
    excitation = tomllib.loads(c.bench.io)["excitation"]["dof"]
    import_files(ImportRequest([(str(table), SourceOptions(excitation=excitation))], str(session)))
    return session


def case_session(c: Case, folder: Path) -> Path:
    """The case's data: a campaign on the emulated rig, or the independent integrator's imported CSV."""
    return imported_session(c, folder) if c.source == "rk4" else simulated_session(c, folder)


def started_workbench(c: Case, folder: Path, session: Path | None = None) -> Workbench:
    """The case's data (``session``: already made, e.g. for the case whose data it shares), and a workbench on
    the model without the hidden laws, started."""
    session = session or case_session(c, folder)
    with open_session(session) as s:
        measurements = measurements_from_session(s)
    wb = Workbench(load_model(tomllib.loads(c.model_toml()), f"{c.name} model"), measurements)
    wb.start()
    return wb


# --------------------------------------------------------------------------------------------- scoring
@dataclass(frozen=True)
class Found:
    """What the diagnosis made of one hidden effect: the kind of law it added at that element (or "nothing")."""

    element: str
    law: str
    kind: str
    found: str

    @property
    def right(self) -> bool:
        return self.found == self.kind


@dataclass(frozen=True)
class Outcome:
    """The score of one case."""

    case: str
    structure: str
    source: str
    noise: float
    effects: tuple[Found, ...]
    added: tuple[str, ...]            # "element:law" in the order added
    false_alarms: tuple[str, ...]     # added laws the rig does not have
    errors: tuple[float, ...]         # the history's errors, first to last
    stopped: str

    @classmethod
    def broken(cls, c: Case, reason: str) -> Outcome:
        """A case that could not be measured or diagnosed: nothing found, ``reason`` as why it stopped."""
        return cls(c.name, c.bench.name, c.source, c.noise,
                   tuple(Found(h.element, h.law, h.kind, NOTHING) for h in c.hidden), (), (), (), reason)

    @property
    def measured(self) -> bool:
        return bool(self.errors)

    @property
    def error_fall(self) -> float:
        return self.errors[0] / self.errors[-1] if self.errors else float("nan")

    @property
    def right(self) -> bool:
        return all(f.right for f in self.effects) and not self.false_alarms

    def to_json(self) -> dict:
        return {"case": self.case, "structure": self.structure, "source": self.source, "noise": self.noise,
                "effects": [vars(f) for f in self.effects], "added": list(self.added),
                "false_alarms": list(self.false_alarms), "errors": list(self.errors), "stopped": self.stopped}

    @classmethod
    def from_json(cls, d: dict) -> Outcome:
        return cls(d["case"], d["structure"], d["source"], d["noise"], tuple(Found(**f) for f in d["effects"]),
                   tuple(d["added"]), tuple(d["false_alarms"]), tuple(d["errors"]), d["stopped"])


def added_laws(wb: Workbench, at: int | None = None) -> list[tuple[str, str]]:
    """(element, law) of every law in the final model (or in history step ``at``'s) that the first history step
    did not have."""
    first = wb.history[0].laws
    held = ({el.name: [t.law.name for t in el.laws] for el in wb.model.elements} if at is None else
            {name: [t["law"] for t in terms] for name, terms in wb.history[at].laws.items()})
    out = []
    for el in wb.model.elements:
        before = [t["law"] for t in first[el.name]]
        for name in held[el.name]:
            if name in before:
                before.remove(name)
            else:
                out.append((el.name, name))
    return out


def score(c: Case, wb: Workbench, stopped: str, at: int | None = None) -> Outcome:
    """Each hidden effect is found when a law of its kind was added at its element (one added law answers one
    effect); every added law left over is a false alarm: a law the rig does not have. ``at``: the model of that
    history step scored, not the final one."""
    pool = added_laws(wb, at)
    effects = []
    for h in c.hidden:
        mine = [a for a in pool if a[0] == h.element]
        match = next((a for a in mine if law_kind(a[1]) == h.kind), None)
        if match is not None:
            pool.remove(match)
        found = h.kind if match is not None else (law_kind(mine[0][1]) if mine else "nothing")
        effects.append(Found(h.element, h.law, h.kind, found))
    order = [f"{e}:{law}" for e, law in added_laws(wb, at)]
    history = wb.history if at is None else wb.history[:at + 1]
    return Outcome(c.name, c.bench.name, c.source, c.noise, tuple(effects), tuple(order),
                   tuple(f"{e}:{law}" for e, law in pool), tuple(h.error for h in history), stopped)


LOOP_NAME = "run_auto (analysis/loop/auto.py: discovery first), default AutoRules"


def run_case(c: Case, folder: Path, session: Path | None = None) -> Outcome:
    """Measure the case (unless ``session`` holds its data), run the missing-effect loop on the model without
    its hidden laws, score the result."""
    wb = started_workbench(c, folder, session)
    return score(c, wb, run_auto(wb).stopped)


# --------------------------------------------------------------------------------------------- the table
GOAL_RIGHT = 0.95        # share of cases right
GOAL_FALL = 5.0          # error fall of every right answer
DONE_FALL = 10.0         # error fall the 2- and 3-DOF cases must reach
LUMPED_BENCHES = ("2-DOF", "3-DOF chain")
BEGIN = "<!-- hidden-effect matrix generated by python benchmarks/hidden_effect_matrix.py: do not edit -->"
END = "<!-- end of hidden-effect matrix -->"
NOTHING = "nothing"


@dataclass(frozen=True)
class Summary:
    cases: int
    right: int
    effects: int
    effects_right: int
    false_alarms: int
    min_fall_right: float     # smallest error fall among the right answers with a hidden effect (inf: none)
    lumped: int               # 2- and 3-DOF cases with hidden effects (the "done when")
    lumped_done: int          # of those: right, with the error falling at least DONE_FALL
    unmeasured: int           # cases whose data could not be made: not counted above

    @classmethod
    def of(cls, outcomes: list[Outcome]) -> Summary:
        everything, outcomes = outcomes, [o for o in outcomes if o.measured]
        falls = [o.error_fall for o in outcomes if o.right and o.effects]
        lumped = [o for o in outcomes if o.structure in LUMPED_BENCHES and o.effects]
        return cls(len(outcomes), sum(o.right for o in outcomes), sum(len(o.effects) for o in outcomes),
                   sum(f.right for o in outcomes for f in o.effects), sum(len(o.false_alarms) for o in outcomes),
                   min(falls, default=float("inf")), len(lumped),
                   sum(o.right and o.error_fall >= DONE_FALL for o in lumped), len(everything) - len(outcomes))

    @property
    def goal_met(self) -> bool:
        return (self.right >= GOAL_RIGHT * self.cases and self.false_alarms == 0
                and self.min_fall_right >= GOAL_FALL)

    def text(self) -> str:
        return (f"{self.right}/{self.cases} cases right ({100 * self.right / max(self.cases, 1):.0f} %), "
                f"{self.effects_right}/{self.effects} hidden effects found with the right element and kind, "
                f"{self.false_alarms} false alarm{'s' * (self.false_alarms != 1)}, smallest error fall of a "
                f"right answer x{self.min_fall_right:.3g}; goal (>= 95 % right, no false alarm, every right "
                f"answer >= x5): {'met' if self.goal_met else 'not met'}. 2- and 3-DOF cases with hidden effects "
                f"found whole, with nothing added the rig does not have and the error falling >= x{DONE_FALL:g}: "
                f"{self.lumped_done}/{self.lumped}"
                + (f". Not counted: {self.unmeasured} case{'s' * (self.unmeasured != 1)} whose data could not be "
                   "made (below)" if self.unmeasured else ""))


def confusion(outcomes: list[Outcome]) -> dict[tuple[str, str], int]:
    """(true kind, kind found at that element) -> count, over every hidden effect; the false alarms count in the
    row ``nothing`` (the rig has no such law there), under the kind of the law added."""
    out: dict[tuple[str, str], int] = {}
    for o in (o for o in outcomes if o.measured):
        for f in o.effects:
            out[f.kind, f.found] = out.get((f.kind, f.found), 0) + 1
        for alarm in o.false_alarms:
            key = (NOTHING, law_kind(alarm.split(":")[1]))
            out[key] = out.get(key, 0) + 1
    return out


def _fmt_fall(o: Outcome) -> str:
    if not o.measured:
        return "--"
    return f"{o.errors[0]:.3g} -> {o.errors[-1]:.3g} (x{o.error_fall:.3g})"


def _short(text: str, limit: int = 160) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def render(outcomes: list[Outcome], date: str, loop: str) -> str:
    """The docs section between ``BEGIN`` and ``END`` (markers included)."""
    kinds = list(LAW_KINDS)
    table = confusion(outcomes)
    rows = [r for r in kinds + [NOTHING] if any(k[0] == r for k in table)]
    cols = [c for c in kinds + [NOTHING] if any(k[1] == c for k in table)]
    lines = [BEGIN, f"Run {date}, loop: {loop}.", "", Summary.of(outcomes).text() + ".", "",
             "Confusion of law kinds (rows: the hidden effect's kind, or `nothing` for a law the rig does not "
             "have; columns: the kind added at that element):", "",
             "| true \\ found | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    lines += [f"| {r} | " + " | ".join(str(table.get((r, c), "")) for c in cols) + " |" for r in rows]
    lines += ["", "| case | structure | data | noise | hidden | added | error | verdict |",
              "|---|---|---|---|---|---|---|---|"]
    for o in outcomes:
        hidden = ", ".join(f"{f.element}:{f.law}" for f in o.effects) or NOTHING
        verdict = f"not measured: {_short(o.stopped)}" if not o.measured else "right" if o.right else "; ".join(
            [f"{f.element}:{f.law} found {f.found}" for f in o.effects if not f.right]
            + [f"false alarm {a}" for a in o.false_alarms])
        lines.append(f"| {o.case} | {o.structure} | {o.source} | {100 * o.noise:g} % | {hidden} | "
                     f"{', '.join(o.added) or '--'} | {_fmt_fall(o)} | {verdict} |")
    return "\n".join(lines + [END])


def replace_section(doc: str, section: str) -> str:
    """``doc`` with the text between the markers replaced by ``section``."""
    start, end = doc.index(BEGIN), doc.index(END) + len(END)
    return doc[:start] + section + doc[end:]


def progress_line(i: int, n: int, o: Outcome, seconds: float) -> str:
    verdict = "right" if o.right else "WRONG"
    return (f"[{i}/{n}] {o.case} ({o.structure}, {o.source}, {100 * o.noise:g} %): {verdict}; added "
            f"{', '.join(o.added) or 'nothing'}; error {_fmt_fall(o)}; {o.stopped}; {seconds:.0f} s")
