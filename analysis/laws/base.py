"""What every element law provides.

A law is one physical mechanism of an element (NLvib style): a time-domain force
with its internal state, and the describing function -- the equivalent complex
stiffness ``kbar(X, w) = (A1 + j B1) / X`` of the force's fundamental under
``x = X sin(w t)`` (docs/contracts.md §1).

The describing function is written once, as a sum of *basis* functions weighted by
the parameters that enter it linearly: ``kbar = sum_j lin_j * basis_j(X, w; shape)``.
The fitter uses the same basis (variable projection), so a law's describing function
and its fitted form can never disagree.

Some laws are fitted in a parametrisation different from the contract's, so that
more parameters enter linearly: jenkins is fitted as ``kt`` (linear) and the slip
displacement ``xs = fs / kt`` (shape). ``to_fit`` / ``from_fit`` convert.

The time-domain force is a numba kernel ``kernel(x, v, p, s) -> f``: ``x`` and
``v`` the element displacement and velocity, ``p`` the contract parameters in the
order of ``params`` followed by the constants the law derives from them
(``kernel_constants``; ``parameter_vector`` builds the whole), ``s`` the law's state
(updated in place). A law whose state is large also provides the kernel with the state
read and written apart, ``update(x, v, p, s, out) -> f`` (``out`` may be ``s``), and
``commit(out, s)``, which copies into ``s`` what an update wrote: a simulator evaluates
a law about twice a step from the same committed state, and without these it copies
the whole state for every evaluation. Both only index ``p``, ``s`` and ``out``, which
are arrays from Python and C pointers from the simulator. For rate-independent
hysteretic laws the update is exact along any monotone path between two calls, so
a marched force is exact at the sample points. Laws with a jump in the velocity
sign (dry friction) also provide ``stick_limit(x, p)``: the largest force the
mechanism can hold at zero velocity, which a time integrator needs to model true
stick.

A law class also carries what the rest of the product says about it, so that adding a
law is adding one module: ``force_text`` and ``kbar_text`` (the formulas of the
docs/laws.md table, which is generated from the classes), ``explanation`` (the physics
sentence of a missing-effect candidate, a template over :class:`SignatureWords`) and
``visible_in_kbar`` (whether kbar alone can reveal the law; one whose kbar is a constant
the linear law already reproduces is not proposed by the diagnosis).
"""
from __future__ import annotations

import functools
import math
import string
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar, Mapping

import numpy as np

from ..common.compiled import njit, njit_fixed
from ..common.errors import InputError
from ..common.recent import Recent
from ..common.wording import parameter_words


@dataclass(frozen=True)
class Param:
    """One parameter of a law.

    ``unit`` is a template in ``{F}`` (force) and ``{L}`` (displacement) so the same
    law renders as N/m^3 on a translational DOF and N·m/rad^3 on a rotational one.
    ``lower_open`` excludes the lower bound itself (a stiffness that must be strictly
    positive, an exponent that must exceed -1).
    """

    name: str
    unit: str
    description: str
    lower: float = -math.inf
    upper: float = math.inf
    lower_open: bool = False

    def admits(self, value: float) -> bool:
        """Whether ``value`` is finite and inside the bounds."""
        above = value > self.lower if self.lower_open else value >= self.lower
        return math.isfinite(value) and above and value <= self.upper

    @property
    def range_text(self) -> str:
        return f"{'(' if self.lower_open else '['}{self.lower}, {self.upper}]"

    @property
    def bounds_text(self) -> str:
        """The bounds as an inequality, e.g. ``-1 < chi <= 1``; empty when the value is free."""
        low, high = math.isfinite(self.lower), math.isfinite(self.upper)
        if low and high:
            return f"{self.lower:g} {'<' if self.lower_open else '<='} {self.name} <= {self.upper:g}"
        if low:
            return f"{self.name} {'>' if self.lower_open else '>='} {self.lower:g}"
        return f"{self.name} <= {self.upper:g}" if high else ""

    def render_unit(self, rotational: bool = False) -> str:
        return render_unit(self.unit, rotational)


def render_unit(template: str, rotational: bool = False) -> str:
    """A unit template in ``{F}`` and ``{L}`` on a translational (N, m) or rotational (N·m, rad) DOF."""
    force, length = ("N·m", "rad") if rotational else ("N", "m")
    return template.replace("{F}", force).replace("{L}", length)


@dataclass(frozen=True)
class SignatureWords:
    """The signature of an element's kbar in words: the fields a law's ``explanation`` template may use."""

    re: str         # how Re kbar changes over the amplitudes, e.g. "Re kbar rises from 1e+04 to 2e+04 N/m (12 sigma)"
    im: str         # the same for Im kbar, with its log-slopes in X and w
    re_slope: str   # log-slope of the change of Re kbar against X, e.g. "+2.00" (or "n/a")
    mean_re: str    # mean Re kbar with its unit, e.g. "+1.2e+03 N/m"
    mean_im: str
    spring: str     # "hardening" where Re kbar rises with the amplitude, else "softening"


EXPLANATION_FIELDS = frozenset(f.name for f in fields(SignatureWords))
# What every concrete law class must define (the rest has defaults in Law).
@dataclass(frozen=True)
class LimitReading:
    """What a fitted law is over the amplitudes measured where its values sit in one of its limits: the limit's
    name, the combination of parameters the data determine there (name -> value, with a unit template in
    ``{F}`` and ``{L}`` as :class:`Param`'s), why the law is read so, and the contract parameters the data do not
    determine apart. A law read in a limit is that limit's law on these data: its other parameters are not
    findings, and the values a fit leaves them at (1e32 for a stiffness nothing bounds) are not shown."""

    limit: str
    values: dict[str, float]
    units: dict[str, str]
    why: str
    undetermined: tuple[str, ...]

    def values_text(self, rotational: bool = False, stderr: Mapping[str, float] | None = None,
                    undetermined: tuple[str, ...] = ()) -> str:
        """``kt = 2e+05 N/m, chi = 0.3, D = 1.2e-06 N·m``; with the standard errors of a fit of the limit's own
        form (:class:`LimitForm`), each value with its spread, and the ones that fit leaves open not shown."""
        stderr = stderr or {}
        return ", ".join(parameter_words(k, v, stderr.get(k), k in undetermined,
                                         render_unit(self.units[k], rotational), digits=5)
                         for k, v in self.values.items())

    def to_json(self) -> dict:
        return {"limit": self.limit, "values": dict(self.values), "why": self.why,
                "undetermined": list(self.undetermined)}


#: A saturating spring saturates below every amplitude measured where its softening displacement 1 / beta is at
#: most this fraction of the smallest (a decade below, as a Jenkins slider's slip reads as Coulomb friction)
SATURATED_BELOW = 0.1


def saturated_spring(alpha: float, beta: float, X_min: float, force: str) -> LimitReading | None:
    """The reading of a saturating spring ``alpha s(beta x)`` (s odd, bounded, slope 1 at 0) whose softening
    displacement lies a decade or more below the smallest amplitude measured (``1 / beta <= SATURATED_BELOW
    X_min``): over the data it is the saturated spring ``force`` sgn(x), kbar = 4 ``force`` / (pi X), its force
    at saturation determined by alpha and beta not (any larger beta reads the same)."""
    if not beta * X_min * SATURATED_BELOW >= 1.0:
        return None
    return LimitReading(
        "saturated spring", {"alpha": alpha}, {"alpha": "{F}"},
        f"the spring saturates a decade or more below the smallest amplitude (softening displacement {1.0 / beta:.3g} "
        f"against {X_min:.3g}): kbar is a saturated force's, 4 {force} / (pi X), and only alpha is determined",
        ("beta",))


REQUIRED = ("name", "kind", "summary", "params", "linear", "example", "kernel", "force_text", "kbar_text",
            "explanation")

# The kinds of physics a law belongs to. Laws of one kind have describing functions that can coincide over a range
# of amplitude (a Jenkins element in gross slip is Coulomb friction; a quintic and a cubic both harden), and one
# joint has at most one mechanism of each kind: model discovery combines laws of different kinds only.
KINDS = {
    "linear": "kbar independent of amplitude: a linear spring and damper, or a spring stiffer on one side (bilinear)",
    "stiffness": "Re kbar moves with amplitude, Im flat: a hardening or softening conservative spring",
    "rate stiffness": "Re kbar moves with frequency, not amplitude",
    "damping": "Im kbar grows with the velocity amplitude: viscous-like nonlinear damping",
    "friction": "Im kbar from a slip force, in gross slip or micro-slip, with or without a normal load that "
                "follows the motion",
    "clearance": "Re kbar rises past a threshold amplitude: a clearance that closes, on both sides or one",
}


@functools.lru_cache(maxsize=None)
def _marcher(kernel):
    """The march of a sampled history through one law's kernel, compiled with the kernel fixed.

    Passed as an argument, a jitted kernel is typed anew by numba at every call (about 25 us: more than a
    512-sample march of most laws, and the AFT and a placed contact's balance march thousands of times);
    fixed, a call passes only arrays. Disk-cached per kernel (analysis.common.compiled.njit_fixed): compiling
    costs 0.1-0.8 s per law, which every process paid before."""
    @njit_fixed()
    def march(x, v, p, s):
        f = np.empty(x.shape[0])
        for i in range(x.shape[0]):
            f[i] = kernel(x[i], v[i], p, s)
        return f
    return march


@functools.lru_cache(maxsize=None)
def _periodic_marcher(kernel):
    """:func:`_marcher` over periodic motions: each row of (B, T) samples of one period is marched ``periods``
    times from the state ``s0`` and the force of the last period kept (a hysteretic law settles on its closed
    loop in the first); the rows independent of one another (a solver's trial motions, one per line and per
    perturbation, in one call). ``turning_points_only``: the periods before the last visit only the samples where
    the motion turns and each period's ends -- a rate-independent hysteretic law's update is exact along any
    monotone path between two calls (module docstring), so its state after them is the state the march through
    every sample leaves, bit for bit, at a few calls per period instead of T."""
    @njit_fixed()
    def march_periods(x, v, p, s0, s, periods, turning_points_only, f):
        # the state and the output passed in, copied by loops: no allocation to compile
        n = x.shape[1]
        for b in range(x.shape[0]):
            for j in range(s0.shape[0]):
                s[j] = s0[j]
            for _ in range(periods - 1):
                for i in range(n):
                    # a sample between two others on one side of it is on a monotone path: skipped; NaN is not
                    if (turning_points_only and 0 < i < n - 1
                            and (x[b, i + 1] - x[b, i]) * (x[b, i] - x[b, i - 1]) > 0.0):
                        continue
                    kernel(x[b, i], v[b, i], p, s)
            for i in range(n):
                f[b, i] = kernel(x[b, i], v[b, i], p, s)
    return march_periods


def broadcast(X, w) -> tuple[np.ndarray, np.ndarray]:
    """Amplitudes ``X`` and lines ``w`` broadcast to one shape; returned as they are where they have it already
    (a solver's batch: the common case, where ``np.broadcast_arrays``'s overhead costs more than a small law's
    arithmetic)."""
    X, w = np.asarray(X), np.asarray(w)
    if X.shape == w.shape:
        return X, w
    X, w = np.broadcast_arrays(X, w)
    return X, w


#: What is left of a basis column less its spring and damper at the origin, relative to the column, below which the
#: column counts as cancelled (:meth:`Origin.less`): rounding leaves about 1e-16, a law's own departure far more
CANCELLED = 1e-12


@dataclass(frozen=True)
class Origin:
    """Where an element's laws are measured from when its reference was made from a measured level: the element's
    amplitude ``X`` (m, or rad for a rotation) at that level's resonance and the resonance's frequency ``w``
    (rad/s), whose lines decide the reference's modal damping and frequency (docs/laws.md, "Measured from the
    reference"). The reference holds the joint as it was there, its dissipation included; a law measured from the
    origin adds only its change from that state."""

    X: float
    w: float

    @property
    def hz(self) -> float:
        """The origin's frequency in Hz, as model files and reports give it."""
        return self.w / (2.0 * math.pi)

    def text(self) -> str:
        return f"amplitude {self.X:.4g}, {self.hz:.6g} Hz"

    def less(self, basis: np.ndarray, at_origin: np.ndarray, w) -> np.ndarray:
        """``basis`` (p, ...) less the spring and viscous damper equal to the complex stiffnesses ``at_origin``
        (p,) at the origin's line: ``B - (Re a + j Im a w / w0)`` at the lines ``w`` (broadcast to the samples).
        A damper and not a constant loss, so that the time-domain force is a law's (``c v`` with c = Im a / w0);
        the lines of a reference's level lie within a few per cent of its resonance, where the two agree."""
        a = np.asarray(at_origin, complex).reshape((-1,) + (1,) * (basis.ndim - 1))
        out = basis - (a.real + 1j * a.imag * (np.asarray(w, float) / self.w))
        # a column that is itself a spring or a damper (a viscous term c w) is cancelled to round-off: what rounding
        # leaves of it is no direction, and a fit that scales its columns to unit length would see one there
        size = np.abs(basis).reshape(len(basis), -1).max(axis=1, initial=0.0)
        left = np.abs(out).reshape(len(out), -1).max(axis=1, initial=0.0)
        out[left <= CANCELLED * size] = 0.0
        return out


class KbarFunction:
    """``f(X, w) -> kbar`` of a law at fixed parameter values (:meth:`Law.kbar_function`): the sum of the law's
    basis functions times its linear coefficients, at its shape values. A class, not a closure, so that a fit
    that holds one can come back from another process (:mod:`analysis.common.parallel`)."""

    __slots__ = ("law", "coefficients", "shape")

    def __init__(self, law: "Law", coefficients: tuple[float, ...], shape: dict[str, float]):
        self.law, self.coefficients, self.shape = law, coefficients, shape

    def __call__(self, X, w):
        B = self.law.basis(np.asarray(X, float), np.asarray(w, float), **self.shape)
        out = self.coefficients[0] * B[0]
        for c, b in zip(self.coefficients[1:], B[1:]):
            out = out + c * b
        return out


class Law(ABC):
    """Base class of the element laws; one subclass (and one module) per law."""

    name: ClassVar[str]
    kind: ClassVar[str]             # one of KINDS
    summary: ClassVar[str]
    params: ClassVar[tuple[Param, ...]]
    # Fit parametrisation: names entering kbar linearly, and the shape parameters
    # (entering nonlinearly). Default: the contract parameters split in two.
    linear: ClassVar[tuple[str, ...]]
    shape: ClassVar[tuple[Param, ...]] = ()
    n_state: ClassVar[int] = 0
    hysteretic: ClassVar[bool] = False
    # Whether kbar depends on the amplitude X (False: a linear law, possibly frequency dependent)
    amplitude_dependent: ClassVar[bool] = True
    kernel: ClassVar[Any]
    stick_limit: ClassVar[Any] = None
    # The kernel with the state read and written apart, and the copy of what it wrote (module docstring);
    # None: a simulator copies the whole state before each evaluation and at each commit
    update: ClassVar[Any] = None
    commit: ClassVar[Any] = None
    # Typical values on a translational DOF (for tests, docs and fit starting points)
    # and the amplitude range over which the law's effect is visible.
    example: ClassVar[dict[str, float]]
    example_amplitude: ClassVar[tuple[float, float]] = (1e-4, 1e-1)
    # The formulas of the docs/laws.md table, plain text (docs_row escapes the pipes for markdown)
    force_text: ClassVar[str]
    kbar_text: ClassVar[str]
    # The physics sentence of a missing-effect candidate: a str.format template over SignatureWords' fields
    explanation: ClassVar[str]
    # False where the formula's kbar is a constant the linear law already reproduces (only the law's harmonics, or
    # its kbar placed in a structure, reveal it)
    visible_in_kbar: ClassVar[bool] = True
    # True where the force is its small-amplitude tangent k0 x + c0 x' at every amplitude and state (a spring
    # and damper): a time integrator that moves k0 and c0 into its linear part has nothing left to solve for
    tangent_exact: ClassVar[bool] = False
    # True where the force's harmonics are of the order of its fundamental (a contact that closes: one-sided, with a
    # mean and even harmonics, or a clearance on both sides, with odd ones; a spring stiffer on one side, with a
    # mean and even harmonics as large as the difference): they move the structure, which
    # changes how far the contact closes and so kbar. Where the law sits in a structure its kbar is then placed
    # there (analysis/mechanics/surroundings.py) rather than taken from the formula alone. Such a law is stateless,
    # velocity-free and has one linear parameter scaling its whole force.
    placed: ClassVar[bool] = False
    # True for the law measured from its small-amplitude state (:meth:`relative`)
    from_reference: ClassVar[bool] = False
    # where such a law is measured from when not from no amplitude (:class:`Origin`, :meth:`relative`)
    origin: ClassVar["Origin | None"] = None

    def __init_subclass__(cls, **kwargs):
        # A jitted function stored on a class binds like a method; keep the numba
        # functions plain so ``law.kernel(x, v, p, s)`` and ``law.stick_limit(x, p)``
        # work from Python as well as from jitted code.
        super().__init_subclass__(**kwargs)
        for attr in ("kernel", "stick_limit", "update", "commit"):
            value = cls.__dict__.get(attr)
            if value is not None and not isinstance(value, staticmethod):
                setattr(cls, attr, staticmethod(value))
        # A law that lacks part of its description fails when it is defined, not in the middle of a ranking.
        if getattr(cls.basis, "__isabstractmethod__", False):
            return
        missing = [a for a in REQUIRED if not hasattr(cls, a)]
        if missing:
            raise TypeError(f"law class {cls.__name__} lacks {', '.join(missing)}")
        if cls.kind not in KINDS:
            raise TypeError(f"law {cls.name!r}: kind {cls.kind!r} is not one of {', '.join(KINDS)}")
        if cls.placed and (len(cls.linear) != 1 or cls.n_state or cls.hysteretic):
            raise TypeError(f"law class {cls.__name__}: a placed law needs one linear parameter scaling its force "
                            "and no state")
        if (cls.update is None) != (cls.commit is None):
            raise TypeError(f"law class {cls.__name__} defines one of update and commit without the other")
        unknown = {f for _, f, _, _ in string.Formatter().parse(cls.explanation) if f is not None} - EXPLANATION_FIELDS
        if unknown:
            raise TypeError(f"law {cls.name!r}: explanation uses unknown field(s) {', '.join(sorted(unknown))} "
                            f"(known: {', '.join(sorted(EXPLANATION_FIELDS))})")

    # --- describing function -------------------------------------------------
    @abstractmethod
    def basis(self, X, w, **shape) -> np.ndarray:
        """Basis functions of kbar, shape ``(len(linear),) + broadcast(X, w).shape``.

        ``X`` (element amplitude, m or rad, > 0) and ``w`` (rad/s) broadcast.
        """

    def describing_function(self, X, w, **params) -> np.ndarray:
        """Equivalent complex stiffness kbar(X, w), complex, broadcast over X and w.

        Parameters are the contract parameters (docs/contracts.md §2) by name.
        """
        return self.kbar_function(**params)(X, w)

    def kbar_function(self, **params):
        """``f(X, w) -> kbar`` for fixed parameter values, validated once (solvers call it many times)."""
        values = self.check_params(params, complete=True)
        lin, shp = self.to_fit(values)
        return KbarFunction(self, tuple(lin[n] for n in self.linear), shp)

    # --- what the product says about the law -------------------------------
    def explain(self, words: SignatureWords) -> str:
        """The physics behind a kbar signature, as this law explains it."""
        return self.explanation.format(**asdict(words))

    def parameter_text(self) -> str:
        """The parameters for the docs table: name, unit translational (rotational), bounds."""
        out = []
        for p in self.params:
            unit, rot = p.render_unit(), p.render_unit(rotational=True)
            text = p.name + (" (dimensionless)" if unit == "1" else f" {unit}" if unit == rot else f" {unit} ({rot})")
            out.append(text + (f", {p.bounds_text}" if p.bounds_text else ""))
        return "; ".join(out)

    def docs_row(self) -> str:
        """This law's row of the docs/laws.md law table."""
        # a shape parameter outside the contract says what it is (jenkins' xs = fs / kt)
        shape = [p.name if p.name in self.param_names else f"{p.name} ({p.description})" for p in self.shape]
        fit = ", ".join(self.linear) + " / " + (", ".join(shape) or "–")
        cells = (self.name, self.kind, self.parameter_text(), self.force_text, self.kbar_text, fit,
                 "yes" if self.visible_in_kbar
                 else "placed in its structure" if self.placed else "no (only harmonics)")
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    # --- measured from the reference's state --------------------------------
    def small_amplitude_basis(self, **shape) -> np.ndarray | None:
        """The limit of :meth:`basis` as X -> 0, shape ``(len(linear),)``, real: the stiffness per linear
        parameter the law has before anything slips, saturates or opens. None where kbar vanishes there or has
        no finite limit (a slider that holds rigidly): nothing a reference could hold."""
        return None

    def basis_from_small_amplitude(self, X, w, **shape) -> np.ndarray:
        """:meth:`basis` less :meth:`small_amplitude_basis`, shape ``(len(linear),) + X.shape``: what the law
        measured from the reference adds. By subtraction here; a law whose basis is its small-amplitude value
        plus a departure that vanishes as X -> 0 computes the departure itself where the subtraction would lose
        it to round-off (a fit can run the linear parameter to 1e16 and more, where a relative departure below
        1e-16 is then a finite stiffness)."""
        B = self.basis(X, w, **shape)
        k0 = self.small_amplitude_basis(**shape)
        return B if k0 is None else B - np.asarray(k0, float).reshape((-1,) + (1,) * (B.ndim - 1))

    def __reduce_ex__(self, protocol):
        """A law of the library, or the library law's :meth:`relative`, crosses a pipe as its name and comes back as
        the very object the library holds (:mod:`analysis.common.parallel`): a relative law's class is made at run
        time and could not be found by name, and code compares laws by identity. Other laws (a limit's form, whose
        values are its own) as any object."""
        library = LIBRARY.get(self.name)
        if library is self or (library is not None and self.from_reference
                               and library.relative(self.origin) is self):
            return _library_law, (self.name, library is not self, self.origin)
        return super().__reduce_ex__(protocol)

    def relative(self, origin: "Origin | None" = None) -> "Law":
        """This law measured from its small-amplitude state: kbar(X, w) - kbar(0+), force f(x) - k0 x with k0 the
        small-amplitude stiffness at the law's values (:meth:`small_amplitude_basis`). The law an element uses
        where its reference structure was made from a measured level and so holds the element's small-amplitude
        stiffness already (docs/laws.md, "Measured from the reference"): added to such a reference, the law
        itself would hold it twice. The same law, name and parameters; itself where it has no small-amplitude
        stiffness.

        With ``origin``, measured from the element's state at the origin instead, where the reference was made:
        kbar(X, w) less the spring and damper equal to kbar(X0, w0) (:meth:`Origin.less`), force f less
        ``k x + c v``. The reference holds the law's stiffness and dissipation at that amplitude; from no
        amplitude, the law would add them a second time. Not for a law without amplitude dependence (measured
        from anywhere it would vanish: it corrects the reference itself) nor for a contact placed in its
        structure (its kbar at the origin is its balance's, which no spring and damper carry; it is the
        small-amplitude one, none, where the contact is open there)."""
        if origin is not None and (self.placed or not self.amplitude_dependent):
            origin = None
        if self.from_reference:
            return self if origin == self.origin else self.measured_from.relative(origin)
        cls = type(self)
        if (cls, origin) not in _RELATIVE:       # decided once per law class and origin: fits ask at every term
            nothing = origin is None and self.small_amplitude_basis(**_example_shape(self)) is None
            _RELATIVE[cls, origin] = self if nothing else _relative_class(cls, origin)()
        return _RELATIVE[cls, origin]

    def reading(self, values: Mapping[str, float], X_min: float, X_max: float) -> LimitReading | None:
        """The limit the fitted ``values`` put the law in over the amplitudes ``X_min..X_max`` measured, or None
        where it is read as itself (docs/laws.md, "Limits"). Laws with a slip or softening scale that data can
        leave outside their range override this."""
        return None

    def limit_forms(self, X_max: float) -> tuple["LimitForm", ...]:
        """The law's limits over amplitudes up to ``X_max`` that leave a flat direction in its own parameters,
        each as a law of the combination the data then determine (:class:`LimitForm`). A fit of the law is
        refitted as each form, and the form taken where the law fits no better by more than the noise explains
        (:func:`analysis.fitting.limits.settle_in_limits`): the law is then read in that limit whatever point of
        the flat direction its own fit stopped at. None for most laws."""
        return ()

    def placed_start(self, values: Mapping[str, float]) -> dict:
        """Where a fit of this placed law starts its placement (analysis/fitting/placed.py), from ``values``, those
        its formula's fit gave: by default there."""
        return dict(values)

    # --- parametrisation -----------------------------------------------------
    def to_fit(self, values: Mapping[str, float]) -> tuple[dict, dict]:
        """Contract parameters -> (linear, shape) fit parameters."""
        return ({n: values[n] for n in self.linear},
                {p.name: values[p.name] for p in self.shape})

    def from_fit(self, linear: Mapping[str, float], shape: Mapping[str, float]) -> dict:
        """(linear, shape) fit parameters -> contract parameters."""
        out = dict(linear)
        out.update(shape)
        return {p.name: out[p.name] for p in self.params}

    def fit_jacobian(self, linear: Mapping[str, float], shape: Mapping[str, float]) -> np.ndarray:
        """d(contract params)/d(fit params), rows in ``params`` order and columns in
        ``linear`` then ``shape`` order; used to carry standard errors across."""
        names = list(self.linear) + [p.name for p in self.shape]
        x0 = np.array([*(linear[n] for n in self.linear), *(shape[p.name] for p in self.shape)], float)

        def contract(x):
            lin = dict(zip(self.linear, x[: len(self.linear)]))
            shp = dict(zip([p.name for p in self.shape], x[len(self.linear):]))
            d = self.from_fit(lin, shp)
            return np.array([d[p.name] for p in self.params])

        J = np.empty((len(self.params), len(names)))
        for j in range(len(names)):
            h = 1e-7 * max(abs(x0[j]), 1e-12)
            xp, xm = x0.copy(), x0.copy()
            xp[j] += h
            xm[j] -= h
            J[:, j] = (contract(xp) - contract(xm)) / (2 * h)
        return J

    # --- parameters ----------------------------------------------------------
    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def check_params(self, values: Mapping[str, Any], complete: bool = False,
                     source: str | None = None, field: str | None = None) -> dict[str, float]:
        """Validate parameter names and values; return them as floats.

        Raises InputError naming the field for a misspelt or missing name, a value
        that is not a finite number, or one outside the parameter's bounds.
        """
        known = {p.name: p for p in self.params}
        out: dict[str, float] = {}
        for key, value in values.items():
            if key not in known:
                raise InputError(
                    f"law '{self.name}' has no parameter '{key}' (its parameters: {', '.join(known)})",
                    source, f"{field}.{key}" if field else key)
            try:
                number = float(value)
            except (TypeError, ValueError):
                raise InputError(f"must be a number, got {value!r}", source,
                                 f"{field}.{key}" if field else key) from None
            p = known[key]
            if not p.admits(number):
                raise InputError(f"{number!r} is outside the allowed range {p.range_text}",
                                 source, f"{field}.{key}" if field else key)
            out[key] = number
        if complete:
            missing = [n for n in known if n not in out]
            if missing:
                raise InputError(f"law '{self.name}' needs parameter(s) {', '.join(missing)}",
                                 source, field)
        return out

    def unit(self, name: str, rotational: bool = False) -> str:
        for p in (*self.params, *self.shape):
            if p.name == name:
                return p.render_unit(rotational)
        raise KeyError(name)

    # --- time domain ---------------------------------------------------------
    def parameter_vector(self, **params) -> np.ndarray:
        """What the kernel takes as ``p``: the contract parameters in the order of ``params``, then the
        law's :meth:`kernel_constants`."""
        values = self.check_params(params, complete=True)
        contract = [values[p.name] for p in self.params]
        return np.array(contract + list(self.kernel_constants(*contract)), float)

    def kernel_constants(self, *contract: float) -> tuple[float, ...]:
        """Constants the kernel derives from the contract parameters, computed once per parameter vector
        instead of at every call (none by default)."""
        return ()

    def initial_state(self, p: np.ndarray) -> np.ndarray:
        """State at rest (x = 0, never moved)."""
        return np.zeros(max(self.n_state, 1))

    def force(self, x, v, state: np.ndarray | None = None, **params) -> np.ndarray:
        """Time-domain force along a sampled history ``x[i], v[i]`` (1-D arrays).

        The state starts at rest unless given, and is updated in place when given.
        """
        return self.march(x, v, self.parameter_vector(**params), state)

    def march(self, x, v, p: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        """:meth:`force` with the kernel's parameter vector ``p`` (:meth:`parameter_vector`) already built: for
        solvers that evaluate the force many times at the same values."""
        s = self.initial_state(p) if state is None else state
        return _marcher(self.kernel)(np.ascontiguousarray(x, float), np.ascontiguousarray(v, float), p, s)

    def march_periodic(self, x, v, p: np.ndarray) -> np.ndarray:
        """The force over the second period of each row of ``x``, ``v`` (B, T: one period of a periodic motion),
        marched twice from rest (a hysteretic law's first period through its turning points alone: the same
        state); a law without state once. The rows are independent of one another."""
        x, v = np.ascontiguousarray(x, float), np.ascontiguousarray(v, float)
        s0 = self.initial_state(p)
        f = np.empty(x.shape)
        _periodic_marcher(self.kernel)(x, v, p, s0, np.empty_like(s0), 2 if self.n_state else 1,
                                       self.hysteretic, f)
        return f

    def __repr__(self) -> str:
        return f"<law {self.name}({', '.join(self.param_names)})>"


_RELATIVE: dict[tuple[type, "Origin | None"], Law] = {}
#: The law library by name, filled where each of its laws is made (analysis.laws, as ``LAWS``): a law crosses a
#: pipe as its name in it (:meth:`Law.__reduce_ex__`)
LIBRARY: dict[str, Law] = {}


def _example_shape(law: Law) -> dict[str, float]:
    return law.to_fit(law.check_params(law.example, complete=True))[1]


class LimitForm(Law):
    """A law's limit as a law of the combination the data determine there: fitted like any law (its own contract
    parameters are that combination), never simulated; :meth:`law_values` places it back in the law it is a limit
    of, for the model to predict with."""

    kernel = None
    force_text = "the limit of the law it belongs to (a fit form, never simulated)"
    explanation = "{re} and {im}"
    # the form's small-amplitude stiffness, where it has one: a linear spring beside it adds the same column
    stiffness: str | None = None

    @abstractmethod
    def law_values(self, values: Mapping[str, float], stiffness_seen: bool = True) -> dict[str, float] | None:
        """The contract values of the law this is a limit of that sit in the limit with the combination
        ``values``; None where no values of that law do. ``stiffness_seen`` False: the data determine the form's
        :attr:`stiffness` only in a sum with another law's, and the law is placed with a stiffness of its own
        choosing (the other law takes the difference)."""


def _library_law(name: str, relative: bool, origin: "Origin | None" = None) -> Law:
    """The library's law ``name``, or its :meth:`Law.relative` (:meth:`Law.__reduce_ex__`)."""
    return LIBRARY[name].relative(origin) if relative else LIBRARY[name]


def _relative_class(cls: type, origin: "Origin | None") -> type:
    """The subclass of law class ``cls`` measured from its small-amplitude state, or from ``origin``
    (:meth:`Law.relative`): the basis less its X -> 0 limit (and less its offset at the origin), and the kernel
    (and update) less ``k x + c v``, with k and c appended to the kernel's parameter vector after the law's own
    constants (c = 0 without an origin)."""
    library = LIBRARY.get(cls.name)
    law = library if type(library) is cls else cls()
    contract = law.check_params(law.example, complete=True)
    at = len(law.params) + len(law.kernel_constants(*(contract[p.name] for p in law.params)))
    members = {
        "from_reference": True,
        "origin": origin,
        "__doc__": f"{cls.__doc__ or cls.__name__} Measured from its "
                   f"{'small-amplitude state' if origin is None else 'state at an origin'} (Law.relative).",
        "basis": _relative_basis,
        "measured_from": law,       # the law itself, whose basis this one's is less its small-amplitude state
        "kernel_constants": _relative_constants,
        "kernel": _less_spring_and_damper(cls.kernel, at),
        "stick_limit": None,        # a model's law, never simulated: the simulator takes its rig's laws
    }
    if cls.update is not None:
        members["update"] = _less_spring_and_damper_update(cls.update, at)
        members["commit"] = cls.commit
    return type(f"Relative{cls.__name__}", (cls,), members)


def _relative_basis(self, X, w, **shape):
    B = self.measured_from.basis_from_small_amplitude(X, w, **shape)
    return B if self.origin is None else self.origin.less(B, _at_origin(self, shape), w)


def _at_origin(self, shape) -> np.ndarray:
    """The relative law's basis from its small-amplitude state at its origin, shape (len(linear),) complex. It
    depends on the shape parameters alone, which a prediction holds while it asks for kbar at every line and
    every Newton step: the last few are kept by their values (scalars only)."""
    try:
        key = tuple((name, float(value)) for name, value in sorted(shape.items()))
    except TypeError:
        key = None
    kept = None if key is None else _ORIGIN_BASES.get((self, key))
    if kept is None:
        kept = np.asarray(self.measured_from.basis_from_small_amplitude(self.origin.X, self.origin.w, **shape),
                          complex).reshape(-1)
        kept.setflags(write=False)
        if key is not None:
            _ORIGIN_BASES.keep((self, key), kept)
    return kept


#: (relative law, its shape values) -> its basis at its origin (:func:`_at_origin`)
_ORIGIN_BASES: Recent[np.ndarray] = Recent(32)


def _relative_constants(self, *contract):
    base = super(type(self), self).kernel_constants(*contract)
    linear, shape = self.to_fit(dict(zip(self.param_names, contract)))
    coefficients = np.array([linear[n] for n in self.linear], float)
    k0 = super(type(self), self).small_amplitude_basis(**shape)
    k = 0.0 if k0 is None else float(coefficients @ np.asarray(k0, float))
    c = 0.0
    if self.origin is not None:
        a = complex(coefficients @ _at_origin(self, shape))
        k, c = k + a.real, a.imag / self.origin.w
    return (*base, k, c)


def _inlined(kernel):
    """The law's compiled ``kernel`` compiled again to be inlined where it is called: a kernel called from a wrapper
    that a compiled march calls in turn stays a call, which costs more than most laws' arithmetic (a relative
    Jenkins element marched twenty times slower than its law: docs/performance.md, "A hysteretic law's periodic
    march")."""
    return njit(inline="always")(kernel.py_func)


@functools.lru_cache(maxsize=None)
def _less_spring_and_damper(kernel, at: int):
    """``kernel - p[at] x - p[at + 1] v``: once per law kernel, whatever the origin (its k and c are constants)."""
    kernel = _inlined(kernel)

    @njit
    def relative(x, v, p, s):
        return kernel(x, v, p, s) - p[at] * x - p[at + 1] * v
    return relative


@functools.lru_cache(maxsize=None)
def _less_spring_and_damper_update(update, at: int):
    update = _inlined(update)

    @njit
    def relative(x, v, p, s, out):
        return update(x, v, p, s, out) - p[at] * x - p[at + 1] * v
    return relative
