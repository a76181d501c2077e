"""Reference linear structures: lumped systems and 2D Euler-Bernoulli beams.

Both are built from the ``[structure]`` TOML table (docs/contracts.md §3) by
:func:`load_structure` and give named DOFs, mass/stiffness/damping matrices, the
receptance matrix H(w) and the normal modes.
"""
from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..common.errors import InputError
from ..common.quantities import dof_name_problem, frequency_problem
from ..common.tables import Fields

BOUNDARIES = ("clamped", "pinned", "free")
# A finer beam is refused: the stiffness's condition number grows as the element count to the fourth power, and
# beyond about 1000 elements round-off in the eigenproblem costs more than the mesh gains (first cantilever
# frequency: 5e-8 off at 20 elements, 1e-4 at 800, 4e-3 at 2000), while the dense matrices grow to 128 MB each.
MAX_BEAM_ELEMENTS = 1000
# Reciprocal condition number (1-norm, diagonally scaled) below which a matrix counts as singular: about 8
# units of round-off. Clamped beams of 800 and 2000 elements have 2.5e-13 and 6e-15; a rigid-body mode 1e-17.
SINGULAR_RCOND = 8 * np.finfo(float).eps
# A damping matrix may be singular (undamped DOFs) but not negative beyond round-off of its scaled entries.
SEMIDEFINITE_SHIFT = 1e-12


def dof_suggestions(name, dofs: list[str], shown: int = 12) -> str:
    """The DOFs to offer for a name that is not one: the closest spellings first, then the others, up to
    ``shown`` names in all, so that a long list never cuts off the one the user meant."""
    close = difflib.get_close_matches(str(name), dofs, n=3, cutoff=0.6)
    ordered = close + [d for d in dofs if d not in close]
    listed = ", ".join(ordered[:shown]) + (", ..." if len(ordered) > shown else "")
    if not close:
        return f"its DOFs: {listed}"
    return f"did you mean {close[0]!r}? its DOFs, closest first: {listed}"


@dataclass
class Structure:
    """A linear structure ``M x'' + C x' + K x = F`` with named DOFs.

    Attributes
    ----------
    dofs : list of str
        DOF names in matrix order.
    M, K, C : ndarray, shape (n, n)
        Mass (kg or kg·m^2), stiffness (N/m, N/rad, N·m/rad ...) and viscous damping.
    rotational : set of str
        Names of the DOFs that are rotations (rad) rather than displacements (m).
    description : str
        One line saying what was built (type, mesh, boundaries).
    """

    dofs: list[str]
    M: np.ndarray
    K: np.ndarray
    C: np.ndarray
    rotational: set[str] = field(default_factory=set)
    description: str = ""
    source: str | None = None

    def __post_init__(self):
        self._index = {name: i for i, name in enumerate(self.dofs)}

    # --- names ---------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.dofs)

    def index(self, name: str, field: str | None = None) -> int:
        """Matrix index of DOF ``name``; InputError naming ``field`` if unknown."""
        try:
            return self._index[name]
        except (KeyError, TypeError):
            raise InputError(f"DOF {name!r} is not in the structure ({dof_suggestions(name, self.dofs)})",
                             self.source, field) from None

    def is_rotational(self, name: str) -> bool:
        return name in self.rotational

    # --- frequency response --------------------------------------------------
    def dynamic_stiffness(self, w) -> np.ndarray:
        """Z(w) = K - w^2 M + j w C, shape (len(w), n, n); ``w`` in rad/s."""
        w = np.atleast_1d(np.asarray(w, float))[:, None, None]
        return self.K[None] - w**2 * self.M[None] + 1j * w * self.C[None]

    def frf(self, w, columns=None, method: str = "direct", n_modes: int | None = None) -> np.ndarray:
        """Receptance H(w) = Z(w)^-1 (m/N), complex.

        Parameters
        ----------
        w : array_like, shape (L,)
            Angular frequencies, rad/s.
        columns : sequence of int or str, optional
            Excitation DOFs (indices or names); default all, giving shape (L, n, n).
            With columns the result has shape (L, n, len(columns)).
        method : {"direct", "modal"}
            "direct" solves Z H = I per line (no explicit inverse). "modal" sums the
            lowest ``n_modes`` normal modes; it needs classical damping (C
            diagonalised by the modes) -- see :meth:`modal_truncation_error`.
        """
        w = np.atleast_1d(np.asarray(w, float))
        cols = self._columns(columns)
        if method == "direct":
            return self.response(w, np.eye(self.n)[:, cols])
        if method == "modal":
            return self._modal_frf(w, cols, n_modes)
        raise ValueError(f"method must be 'direct' or 'modal', got {method!r}")

    def response(self, w, loads) -> np.ndarray:
        """Complex amplitudes Z(w)^-1 @ loads, shape (len(w), n, m), for ``loads`` of shape
        (n, m) (the same at every line) or (len(w), n, m)."""
        w = np.atleast_1d(np.asarray(w, float))
        loads = np.asarray(loads)
        rhs = np.broadcast_to(loads, (len(w),) + loads.shape[-2:]) if loads.ndim == 2 else loads
        return np.linalg.solve(self.dynamic_stiffness(w), rhs)

    def _columns(self, columns) -> list[int]:
        if columns is None:
            return list(range(self.n))
        return [c if isinstance(c, (int, np.integer)) else self.index(c) for c in columns]

    def _modal_frf(self, w, cols, n_modes):
        freqs_hz, phi = self.modes()
        m = phi.shape[1] if n_modes is None else int(n_modes)
        if not 1 <= m <= phi.shape[1]:
            raise ValueError(f"n_modes must be between 1 and {phi.shape[1]}, got {n_modes}")
        phi = phi[:, :m]
        modal_c = phi.T @ self.C @ phi
        off = modal_c - np.diag(np.diag(modal_c))
        if np.abs(off).max(initial=0.0) > 1e-9 * max(np.abs(modal_c).max(initial=0.0), 1e-300):
            raise ValueError("modal superposition needs classical damping (C diagonal in the "
                             "normal modes); use method='direct'")
        wr2 = (2 * np.pi * freqs_hz[:m]) ** 2
        denom = wr2[None, :] - w[:, None] ** 2 + 1j * w[:, None] * np.diag(modal_c)[None, :]
        return np.einsum("ir,lr,jr->lij", phi, 1.0 / denom, phi[cols, :])

    def modal_truncation_error(self, w, n_modes: int, columns=None) -> float:
        """Largest relative error of the ``n_modes`` modal FRF against the direct
        solution over the lines ``w`` (max |H_modal - H| / max |H|)."""
        exact = self.frf(w, columns)
        approx = self.frf(w, columns, method="modal", n_modes=n_modes)
        return float(np.abs(approx - exact).max() / np.abs(exact).max())

    # --- modes ---------------------------------------------------------------
    def modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Undamped normal modes: (frequencies in Hz ascending, mass-normalised shapes (n, n))."""
        if not hasattr(self, "_modes"):
            lam, phi = scipy.linalg.eigh(self.K, self.M)
            self._modes = (np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi), phi)
        return self._modes

    def natural_frequencies(self) -> np.ndarray:
        """Undamped natural frequencies, Hz, ascending."""
        return self.modes()[0].copy()

    def with_matrices(self, M=None, K=None, C=None, description: str | None = None) -> "Structure":
        """A copy with some matrices replaced (model updating, added effects)."""
        return Structure(list(self.dofs), self.M if M is None else M, self.K if K is None else K,
                         self.C if C is None else C, set(self.rotational),
                         self.description if description is None else description, self.source)


_PATH = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]|\.")


def split_parameter_path(path: str) -> list[str | int]:
    parts: list[str | int] = []
    pos = 0
    for m in _PATH.finditer(path):
        if m.start() != pos:
            break
        pos = m.end()
        if m.group(1):
            parts.append(m.group(1))
        elif m.group(2):
            parts.append(int(m.group(2)))
    if pos != len(path) or not parts or not isinstance(parts[0], str):
        raise ValueError(path)
    return parts


def structure_parameter(table: dict, path: str, source: str | None = None) -> float:
    """The number at ``path`` in the structure table (an ``[updating]`` parameter, analysis/linear/updating.py:
    ``"springs[1].k"``); InputError naming the path if there is none, or if it is not a positive number."""
    node = table
    try:
        for part in split_parameter_path(path):
            node = node[part]
    except (KeyError, IndexError, TypeError, ValueError):
        raise InputError(f"no structure parameter at {path!r}", source, "[updating].parameters") from None
    if isinstance(node, bool) or not isinstance(node, (int, float)) or node <= 0:
        raise InputError(f"{path!r} must be a positive number to be updated (got {node!r})", source,
                         "[updating].parameters")
    return float(node)


def _dof_names(f: Fields, dofs: list[str]) -> None:
    """The DOF names of a model hold to the rule of every door (analysis/common/quantities.py): the session
    names its datasets by them."""
    for d in dofs:
        if dof_name_problem(d):
            raise f.error("dofs", dof_name_problem(d))


def load_structure(table: dict, source: str | None = None) -> Structure:
    """Build a Structure from the ``[structure]`` table (a dict, as read by tomllib).

    Raises InputError naming ``source`` and the field for a malformed table,
    unknown type, non-symmetric or indefinite matrices, or a singular structure.
    """
    f = Fields(table, source, "[structure]")
    kind = f.string("type", choices=("lumped", "beam", "modal"))
    if kind == "modal":
        return _modal(f)
    s = _lumped(f) if kind == "lumped" else _beam(f)
    _check_physical(s, f)
    return s


@dataclass
class ModalStructure(Structure):
    """A structure known by its modes at the measured DOFs (``type = "modal"``, docs/structures.md):

        H(w) = sum_r phi_r phi_r^T / (w_r^2 - w^2 + 2 j zeta_r w_r w) + B + D / w^2

    with mass-normalised shape entries ``phi_r`` (1/sqrt(kg)), the residual flexibility ``B`` (m/N, the modes
    above the band) and the residual inertia term ``D`` (the modes below it; a rigid mass m gives -1/m).
    ``M, K, C`` are the modes' own realisation ``Phi^-T diag(.) Phi^-1`` (as many modes as DOFs), which is what
    the natural frequencies and the eigenvalue checks use; receptances include the residual terms."""

    frequency_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    damping: np.ndarray = field(default_factory=lambda: np.zeros(0))
    shapes: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))         # (modes, dofs)
    residual_flexibility: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    residual_inertia: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def response(self, w, loads) -> np.ndarray:
        w = np.atleast_1d(np.asarray(w, float))
        loads = np.asarray(loads)
        wr = 2 * np.pi * self.frequency_hz
        q = 1.0 / (wr[None, :] ** 2 - w[:, None] ** 2 + 2j * self.damping[None, :] * wr[None, :] * w[:, None])
        # at w = 0 (the mean of a multi-harmonic balance) the residual inertia is left out: it stands for modes
        # below the band, whose static flexibility is not known (a free-free structure has none)
        inverse_w2 = np.divide(1.0, w ** 2, out=np.zeros_like(w), where=w > 0)
        H = np.einsum("rp,lr,rq->lpq", self.shapes, q, self.shapes) + self.residual_flexibility[None] \
            + self.residual_inertia[None] * inverse_w2[:, None, None]
        return H @ loads

    def modes(self) -> tuple[np.ndarray, np.ndarray]:
        return self.frequency_hz.copy(), self.shapes.T.copy()


def _modal(f: Fields) -> ModalStructure:
    f.unknown_keys({"type", "dofs", "frequencies", "damping", "shapes", "residual_flexibility", "residual_inertia"})
    dofs = f.strings("dofs")
    if not dofs or len(set(dofs)) != len(dofs):
        raise f.error("dofs", "must name at least one DOF, each once")
    _dof_names(f, dofs)
    n = len(dofs)
    freqs = _positive_list(f, "frequencies", n, positive=True)
    for i, hz in enumerate(freqs):   # the range of every door's frequencies (analysis/common/quantities.py)
        if frequency_problem(hz):
            raise f.error("frequencies", f"mode {i + 1} is {frequency_problem(hz)}")
    zeta = _positive_list(f, "damping", n, positive=False)
    if (zeta >= 1).any():
        raise f.error("damping", "damping ratios must be below 1")
    raw = f.require("shapes")
    if not isinstance(raw, list) or len(raw) != n or not all(isinstance(r, list) and len(r) == n for r in raw):
        raise f.error("shapes", f"must be {n} modes of {n} entries (one per DOF, 1/sqrt(kg)): as many modes as DOFs")
    shapes = np.array([[f.check_number("shapes", x) for x in r] for r in raw], float)
    if np.linalg.matrix_rank(shapes) < n:
        raise f.error("shapes", "the mode shapes are not independent at the DOFs")
    B = f.matrix("residual_flexibility", n) if f.has("residual_flexibility") else np.zeros((n, n))
    D = f.matrix("residual_inertia", n) if f.has("residual_inertia") else np.zeros((n, n))
    inv = np.linalg.inv(shapes)                                   # Phi^-T with Phi = shapes^T
    wr = 2 * np.pi * freqs
    with np.errstate(all="ignore"):
        M, K, C = (inv @ np.diag(d) @ inv.T for d in (np.ones(n), wr ** 2, 2 * zeta * wr))
    _check_realisation(f, M, K, C)
    return ModalStructure(dofs, M, K, C, set(), f"modal, {n} mode{'s' * (n > 1)}", f.source, freqs, zeta, shapes,
                          B, D)


MAX_CONDITION = 1e12     # of a modal structure's realised mass and stiffness: beyond it no solve of the model holds


def _check_realisation(f: Fields, M: np.ndarray, K: np.ndarray, C: np.ndarray) -> None:
    """The mass, stiffness and damping a modal structure's shapes and frequencies realise must be finite, the
    mass and stiffness positive definite and solvable (condition below MAX_CONDITION): shapes of 1e200 /
    sqrt(kg) give a mass of 1e-400 kg, which is 0 in floating point, and every analysis of it fails."""
    for key, matrix in (("shapes", M), ("frequencies", K)):
        eig = np.linalg.eigvalsh(matrix) if np.isfinite(matrix).all() else np.array([np.nan])
        if not (np.isfinite(eig).all() and eig.min() > 0 and eig.max() < MAX_CONDITION * eig.min()):
            what = "mass" if key == "shapes" else "stiffness"
            raise f.error(key, f"realise a {what} matrix that is not finite and positive definite within a condition "
                               f"of {MAX_CONDITION:g} (eigenvalues {eig.min():.3g} to {eig.max():.3g}): no "
                               "structure has such modes")
    if not np.isfinite(C).all():
        raise f.error("damping", "realises a damping matrix that is not finite")


def _positive_list(f: Fields, key: str, n: int, positive: bool) -> np.ndarray:
    raw = f.require(key)
    if not isinstance(raw, list) or len(raw) != n:
        raise f.error(key, f"must be a list of {n} numbers (one per mode, as many modes as DOFs)")
    return np.array([f.check_number(key, x, positive=positive, nonnegative=not positive) for x in raw], float)


def _lumped(f: Fields) -> Structure:
    f.unknown_keys({"type", "dofs", "mass", "stiffness", "damping", "rayleigh", "springs", "masses"})
    dofs = f.strings("dofs")
    if not dofs:
        raise f.error("dofs", "must name at least one DOF")
    if len(set(dofs)) != len(dofs):
        raise f.error("dofs", "DOF names must be unique")
    _dof_names(f, dofs)
    n = len(dofs)
    M, K = f.matrix("mass", n), f.matrix("stiffness", n)
    s = Structure(dofs, M, K, np.zeros((n, n)), set(), "lumped", f.source)
    _add_points(s, f)
    if f.has("damping") and f.has("rayleigh"):
        raise f.error("rayleigh", "give either damping or rayleigh, not both")
    if f.has("damping"):
        s.C = f.matrix("damping", n)
    elif f.has("rayleigh"):
        r = f.table["rayleigh"]
        if not isinstance(r, list) or len(r) != 2:
            raise f.error("rayleigh", "must be [a_mass, b_stiffness]")
        a, b = (f.check_number("rayleigh", x, nonnegative=True) for x in r)
        s.C = a * s.M + b * s.K
    return s


def _add_points(s: Structure, f: Fields) -> None:
    """Grounded point springs and point masses (``springs``, ``masses``)."""
    for g in f.list_of_tables("springs"):
        g.unknown_keys({"dof", "k"})
        i = s.index(g.string("dof"), g.path("dof"))
        s.K[i, i] += g.number("k")
    for g in f.list_of_tables("masses"):
        g.unknown_keys({"dof", "m"})
        i = s.index(g.string("dof"), g.path("dof"))
        s.M[i, i] += g.number("m", nonnegative=True)
    s.__post_init__()


def _beam(f: Fields) -> Structure:
    f.unknown_keys({"type", "length", "youngs_modulus", "density", "width", "thickness", "elements",
                    "left", "right", "points", "springs", "masses", "damping"})
    length = f.number("length", positive=True)
    E = f.number("youngs_modulus", positive=True)
    rho = f.number("density", positive=True)
    b, h = f.number("width", positive=True), f.number("thickness", positive=True)
    n_el = f.table.get("elements", 20)
    if isinstance(n_el, bool) or not isinstance(n_el, int) or n_el < 1:
        raise f.error("elements", f"must be a whole number >= 1, got {n_el!r}")
    if n_el > MAX_BEAM_ELEMENTS:
        raise f.error("elements", f"{n_el} elements is more than the {MAX_BEAM_ELEMENTS} a beam may have "
                                  "(finer meshes lose more to round-off than they gain; see docs/structures.md)")
    left, right = f.string("left", "clamped", BOUNDARIES), f.string("right", "free", BOUNDARIES)
    points = f.sub("points", default_empty=True)
    stations = {}
    for name, x in points.table.items():
        if not isinstance(name, str) or not name.replace("_", "").isalnum() or name[0].isdigit():
            raise points.error(name, "station names must be identifiers such as A, B, tip")
        x = points.check_number(name, x)
        if not 0.0 <= x <= length:
            raise points.error(name, f"station at {x} m lies outside the beam [0, {length}]")
        stations[name] = x
    nodes_x = _mesh(length, n_el, sorted(set(stations.values())))
    area, inertia = b * h, b * h**3 / 12.0
    n_nodes = len(nodes_x)
    Kf = np.zeros((2 * n_nodes, 2 * n_nodes))
    Mf = np.zeros_like(Kf)
    for e in range(n_nodes - 1):
        le = nodes_x[e + 1] - nodes_x[e]
        ke, me = _beam_element(E * inertia, rho * area, le)
        sl = slice(2 * e, 2 * e + 4)
        Kf[sl, sl] += ke
        Mf[sl, sl] += me
    node_names = [f"n{i}" for i in range(n_nodes)]
    for name, x in stations.items():
        node_names[int(np.argmin(np.abs(nodes_x - x)))] = name
    names = [f"{nn}.{d}" for nn in node_names for d in ("w", "theta")]
    fixed = set()
    for end, node in ((left, 0), (right, n_nodes - 1)):
        if end in ("clamped", "pinned"):
            fixed.add(2 * node)
        if end == "clamped":
            fixed.add(2 * node + 1)
    keep = [i for i in range(2 * n_nodes) if i not in fixed]
    if not keep:
        raise f.error("elements", f"the {left}-{right} boundaries leave no DOF free: use more elements")
    dofs = [names[i] for i in keep]
    s = Structure(dofs, Mf[np.ix_(keep, keep)], Kf[np.ix_(keep, keep)], np.zeros((len(keep),) * 2),
                  {d for d in dofs if d.endswith(".theta")},
                  f"beam, {n_nodes - 1} Euler-Bernoulli elements, {left}-{right}, L = {length} m", f.source)
    constrained = {names[i]: i for i in fixed}
    for g in (*f.list_of_tables("springs"), *f.list_of_tables("masses")):
        dof = g.table.get("dof")
        if dof in constrained:
            raise g.error("dof", f"DOF {dof!r} is fixed by the {left if constrained[dof] < 2 else right} "
                                 "boundary; a spring or mass there has no effect")
    _add_points(s, f)
    damping = f.sub("damping", default_empty=True)
    damping.unknown_keys({"stiffness_proportional", "mass_proportional"})
    # Stiffness-proportional damping uses K with the boundary springs, as the paper's C = 1e-5 K.
    s.C = (damping.number("mass_proportional", 0.0, nonnegative=True) * s.M
           + damping.number("stiffness_proportional", 0.0, nonnegative=True) * s.K)
    return s


def _mesh(length: float, n_el: int, stations: list[float]) -> np.ndarray:
    """Node positions: about ``n_el`` elements spread in proportion to segment length,
    with every station on a node."""
    keys = sorted({0.0, length, *stations})
    seg = np.diff(keys)
    share = seg / length * n_el
    counts = np.maximum(1, np.floor(share).astype(int))
    for i in np.argsort(-(share - np.floor(share))):
        if counts.sum() >= n_el:
            break
        counts[i] += 1
    return np.concatenate([np.linspace(a, b, c, endpoint=False) for a, b, c in zip(keys[:-1], keys[1:], counts)]
                          + [[length]])


def _beam_element(EI: float, rho_a: float, le: float) -> tuple[np.ndarray, np.ndarray]:
    """Consistent stiffness and mass of a 2-node Euler-Bernoulli element (w1, t1, w2, t2)."""
    l2 = le * le
    k = EI / le**3 * np.array([[12, 6 * le, -12, 6 * le],
                               [6 * le, 4 * l2, -6 * le, 2 * l2],
                               [-12, -6 * le, 12, -6 * le],
                               [6 * le, 2 * l2, -6 * le, 4 * l2]])
    m = rho_a * le / 420.0 * np.array([[156, 22 * le, 54, -13 * le],
                                       [22 * le, 4 * l2, 13 * le, -3 * l2],
                                       [54, 13 * le, 156, -22 * le],
                                       [-13 * le, -3 * l2, -22 * le, 4 * l2]])
    return k, m


def definiteness(A: np.ndarray, semidefinite: bool = False) -> tuple[bool, int | None]:
    """Whether the symmetric matrix ``A`` is positive definite (or semidefinite), and if not, the index of a
    DOF whose own diagonal entry is already wrong (zero or negative; None when only the whole is singular).

    The test runs on the diagonally scaled matrix ``D^-1/2 A D^-1/2``: it is invariant to the units of each
    DOF (metres beside radians) and to the mesh, where the eigenvalues of ``A`` itself spread as the element
    count to the fourth power and a fixed ratio of them calls a fine clamped beam singular. A definite matrix
    must then factor (Cholesky) with a reciprocal condition number above :data:`SINGULAR_RCOND`; a rigid-body
    mode or mechanism leaves it at round-off (about 1e-17). Semidefinite: rows with nothing on the diagonal
    must be empty, and the rest, scaled, plus ``SEMIDEFINITE_SHIFT`` times the identity must factor.
    """
    A = np.asarray(A, float)
    d = np.diag(A).copy()
    wrong = (d < 0) | (d == 0) & (np.abs(A).sum(axis=1) > 0) if semidefinite else d <= 0
    if wrong.any():
        return False, int(np.flatnonzero(wrong)[0])
    live = d > 0
    A, d = A[np.ix_(live, live)], d[live]
    if not len(d):
        return True, None
    scale = 1.0 / np.sqrt(d)
    S = A * scale[:, None] * scale[None, :]
    if semidefinite:
        S = S + SEMIDEFINITE_SHIFT * np.eye(len(d))
    factor, info = scipy.linalg.lapack.dpotrf(S, lower=0, clean=0)
    if info != 0 or semidefinite:
        return info == 0, None
    rcond, info = scipy.linalg.lapack.dpocon(factor, np.abs(S).sum(axis=0).max())
    return bool(info == 0 and rcond > SINGULAR_RCOND), None


def _check_physical(s: Structure, f: Fields) -> None:
    for key, A in (("mass", s.M), ("stiffness", s.K), ("damping", s.C)):
        scale = np.abs(A).max(initial=0.0)
        if np.abs(A - A.T).max(initial=0.0) > 1e-12 * max(scale, 1e-300):
            raise f.error(key, "matrix must be symmetric")
    for key, A, hint in (("mass", s.M, "a DOF has no mass, or a mass is negative"),
                         ("stiffness", s.K, "the structure can move as a rigid body or is unstable: add a "
                                            "support or boundary spring")):
        ok, where = definiteness(A)
        if not ok:
            at = "" if where is None else f" (DOF {s.dofs[where]!r} has a {key} of zero or less)"
            raise f.error(key, f"{key} matrix is not positive definite{at}: {hint}")
    ok, where = definiteness(s.C, semidefinite=True)
    if not ok:
        at = "" if where is None else f" (at DOF {s.dofs[where]!r})"
        raise f.error("damping", f"damping matrix must not be negative{at} (it would add energy)")
