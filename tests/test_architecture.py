"""The house rules, read from the source with ``ast`` (docs/architecture.md): no import cycle anywhere in the
project, dependencies one way (analysis <- drivers.simulation <- drivers.emulator <- app; drivers never import
app), and every document a module or a doc cites exists in the repository."""
import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("analysis", "drivers", "app")
SCRIPTS = ("tests", "benchmarks")     # imported by bare module name (pytest and script sys.path)


def _module_files() -> dict[str, Path]:
    """Dotted module name -> file, for the packages (``pkg.sub``) and the script folders (bare names)."""
    mods = {}
    for top in PACKAGES:
        for f in (ROOT / top).rglob("*.py"):
            parts = f.relative_to(ROOT).with_suffix("").parts
            mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    for top in SCRIPTS:
        for f in (ROOT / top).glob("*.py"):
            mods[f.stem] = f
    return mods


MODULES = _module_files()


def _in_type_checking(tree: ast.AST) -> set[int]:
    """ids of the nodes inside ``if TYPE_CHECKING:`` blocks (annotations only: never executed)."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip |= {id(n) for sub in node.body for n in ast.walk(sub)}
    return skip


def _resolve(name: str) -> str | None:
    """The project module an imported dotted name lands in (the longest known prefix), or None."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str, runtime_only: bool) -> set[str]:
    """Project modules ``module`` imports anywhere in its file (top level or in functions).

    ``from pkg import name`` depends on the module ``pkg.name`` when there is one, else on ``pkg``'s
    ``__init__`` (which hands the name on)."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _in_type_checking(tree) if runtime_only else set()
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[: len(package) - node.level + 1] if node.level else [])
            prefix = ".".join(p for p in (base, node.module or "") if p)
            targets = [f"{prefix}.{a.name}" if f"{prefix}.{a.name}" in MODULES else prefix for a in node.names]
        else:
            continue
        found |= {m for m in map(_resolve, targets) if m and m != module}
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _layer(module: str) -> str:
    parts = module.split(".")
    if parts[0] == "drivers" and len(parts) > 1 and parts[1] in ("simulation", "emulator"):
        return f"drivers.{parts[1]}"
    return parts[0] if parts[0] in PACKAGES else "scripts"


# what each layer may import besides itself (docs/architecture.md)
ALLOWED = {
    "analysis": set(),
    "drivers.simulation": {"analysis"},
    "drivers.emulator": {"analysis", "drivers"},       # its physics is handed in: never drivers.simulation
    "drivers": {"analysis", "drivers.emulator", "drivers.simulation"},
    "app": {"analysis", "drivers", "drivers.emulator", "drivers.simulation"},
}


@pytest.mark.slow
def test_no_import_cycle_anywhere():
    graph = {m: _imports(m, runtime_only=True) for m in MODULES}
    assert _cycles(graph) == []


@pytest.mark.slow
def test_imports_follow_the_layering():
    wrong = [f"{m} imports {target}" for m in MODULES if _layer(m) in ALLOWED
             for target in sorted(_imports(m, runtime_only=False))
             if _layer(target) != _layer(m) and _layer(target) not in ALLOWED[_layer(m)]]
    assert wrong == []


COMMANDS = {"app.cli", "app.analyze", "app.demo", "app.export", "app.predict", "app.report"}


def _room(module: str) -> str:
    """app's packages are rooms (docs/architecture.md): the campaign, the session, the GUI, the importers."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "app" and len(parts) > 1 else parts[0]


def _room_rule_broken(module: str, target: str) -> bool:
    """The campaign and the importers reach the session only through the session package's public names; the GUI
    reaches both only through their packages' names; the session knows nothing above it; no room but the GUI
    imports a command."""
    src, dst = _room(module), _room(target)
    if src == dst:
        return False
    inside = target not in ("app.session", "app.campaign")        # a module inside a room, not its front door
    if src in ("app.campaign", "app.importers") and dst == "app.session":
        return inside
    if src == "app.gui" and dst in ("app.session", "app.campaign"):
        return inside
    if src == "app.session" and (dst in ("app.campaign", "app.gui", "app.importers") or target in COMMANDS):
        return True
    if src == "app.importers":
        return dst.startswith("app")          # other systems' files need only the analysis and the session
    return src == "app.campaign" and (dst in ("app.gui", "app.importers") or target in COMMANDS)


def test_app_rooms_talk_through_their_front_doors():
    wrong = [f"{m} imports {t}" for m in MODULES if m.startswith("app.")
             for t in sorted(_imports(m, runtime_only=False)) if _room_rule_broken(m, t)]
    assert wrong == []


def test_the_room_rules_bite():
    assert _room_rule_broken("app.campaign.engine", "app.session.writer")
    assert not _room_rule_broken("app.campaign.engine", "app.session")
    assert _room_rule_broken("app.gui.lab", "app.campaign.plan")
    assert _room_rule_broken("app.session.writer", "app.campaign")
    assert _room_rule_broken("app.session.data", "app.analyze")
    assert not _room_rule_broken("app.session.writer", "app.session.file")
    assert _room_rule_broken("app.importers.store", "app.campaign")
    assert "app.session" in _imports("app.campaign.engine", False)


def test_the_checks_see_the_imports():
    # guards against a checker that finds nothing: known edges of each kind are seen
    assert "analysis.laws" in _imports("analysis.mechanics.elements", runtime_only=False)           # absolute
    assert "drivers.simulation.kernels" in _imports("drivers.simulation.simulator", False)  # from . import x
    assert "drivers" in _imports("app.campaign.engine", False)                            # a name from __init__
    assert "drivers.simulation.simulator" in _imports("app.cli", False)                   # inside a function
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _layer("drivers.emulator.core") == "drivers.emulator" and _layer("drivers.scpi") == "drivers"


# analysis/'s rooms in the order of the method: each imports only the rooms before it (analysis/__init__.py)
ANALYSIS_ROOMS = ("common", "laws", "mechanics", "signals", "linear", "identification", "fitting", "prediction",
                  "missing", "search", "loop")


def _analysis_rule_broken(module: str, target: str) -> bool:
    """A module of analysis/ imports a later room's module, or the package's front door (which would load every
    room for one name), or lies outside every room."""
    if not (module.startswith("analysis.") and target.startswith("analysis")):
        return False
    src, dst = module.split(".")[1], target.split(".")[1] if "." in target else None
    if src not in ANALYSIS_ROOMS or dst not in ANALYSIS_ROOMS:
        return True
    return ANALYSIS_ROOMS.index(dst) > ANALYSIS_ROOMS.index(src)


def test_analysis_rooms_import_only_the_rooms_before_them():
    assert sorted(p.name for p in (ROOT / "analysis").iterdir() if p.suffix == ".py") == ["__init__.py"]
    rooms = {p.name for p in (ROOT / "analysis").iterdir() if (p / "__init__.py").is_file()}
    assert rooms == set(ANALYSIS_ROOMS)
    wrong = [f"{m} imports {t}" for m in MODULES if m.startswith("analysis.")
             for t in sorted(_imports(m, runtime_only=False)) if _analysis_rule_broken(m, t)]
    assert wrong == []


def test_the_analysis_room_rules_bite():
    assert _analysis_rule_broken("analysis.fitting.fit", "analysis.prediction.comparison")
    assert _analysis_rule_broken("analysis.common.tables", "analysis.mechanics.structures")
    assert _analysis_rule_broken("analysis.prediction.comparison", "analysis")
    assert _analysis_rule_broken("analysis.fit", "analysis.common.errors")           # outside every room
    assert not _analysis_rule_broken("analysis.prediction.comparison", "analysis.fitting.fit")
    assert not _analysis_rule_broken("analysis.loop.workbench", "analysis.loop.auto")
    assert "analysis.common.statistics" in _imports("analysis.prediction.comparison", False)


CITATION = re.compile(r"(?<![\w/.-])((?:[\w.-]+/)*[\w.-]+\.md)\b")
URL = re.compile(r"\w+://\S+")


def _cited(path: Path) -> list[str]:
    return CITATION.findall(URL.sub("", path.read_text(encoding="utf-8")))


def _citing_files() -> list[Path]:
    files = [f for top in PACKAGES + SCRIPTS for f in (ROOT / top).rglob("*.py")]
    return files + sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def _exists(citation: str, where: Path) -> bool:
    """A citation is a path from the repository root (``docs/laws.md``) or from the citing file's folder (a
    relative Markdown link)."""
    return (ROOT / citation).is_file() or (where.parent / citation).is_file()


@pytest.mark.parametrize("path", _citing_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_cited_document_exists(path):
    missing = [c for c in _cited(path) if not _exists(c, path)]
    assert missing == [], f"{path.relative_to(ROOT)} cites documents that are not in the repository"


def test_citations_are_found():
    cited = _cited(ROOT / "app" / "session" / "writer.py")
    assert "docs/session-format.md" in cited
    md = ".md"   # kept apart so that this file cites nothing itself
    text = f"see SPEC{md} §3, (docs/x{md}) and https://example.org/y{md}"
    assert CITATION.findall(URL.sub("", text)) == [f"SPEC{md}", f"docs/x{md}"]


#: How a case that prompted a rule is named: a random case by its seed or index, a measured specimen or a test rig
#: by what it is called (docs/discovery.md and docs/import.md keep them)
CASE_NAME = re.compile(r"seed \d{3,}|random (case )?\d+|brake-reuss|3-dof chain|on the (demo )?beam\b", re.I)


def _cases_named(text: str) -> list[int]:
    """Line numbers of ``text`` that name a case."""
    return [i for i, line in enumerate(text.splitlines(), 1) if CASE_NAME.search(line)]


def test_the_method_names_no_case_that_prompted_a_rule():
    """analysis/ states each rule and its reason, never the case that prompted it (docs/architecture.md, "The
    packages"): a rule written for a case fits that case, and its reason must hold without it. The cases and the
    measurements behind a rule live in docs/."""
    named = [f"{f.relative_to(ROOT)}:{i}" for f in sorted((ROOT / "analysis").rglob("*.py"))
             for i in _cases_named(f.read_text(encoding="utf-8"))]
    assert named == [], f"these lines name a case: {', '.join(named)}"


def test_the_case_name_check_bites():
    text = ("(331236 random 14: a cubic)\nfrom seed 300885\non the measured Brake-Reuss beam\n"
            "on the 3-DOF chain\non the demo beam linear.k\nthe stiffness of a beam, random draws")
    assert _cases_named(text) == [1, 2, 3, 4, 5]


def test_todays_performance_table_names_real_benchmarks():
    text = (ROOT / "docs/performance.md").read_text(encoding="utf-8")
    table = text.split("## Today's figures", 1)[1].split("\n## ", 1)[0]
    scripts = re.findall(r"python (benchmarks/\w+\.py)", table)
    assert len(scripts) >= 10
    assert [s for s in scripts if not (ROOT / s).is_file()] == []


def _compiled_functions(tree: ast.AST):
    """The functions of a module compiled by numba: decorated with ``njit`` (bare or called), or passed to it
    (``njit(...)(function)``)."""
    passed = {node.args[0].id for node in ast.walk(tree)
              if isinstance(node, ast.Call) and "njit" in ast.unparse(node.func)
              and node.args and isinstance(node.args[0], ast.Name)}
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and (node.name in passed
                                                  or any("njit" in ast.unparse(d) for d in node.decorator_list)):
            yield node


def _slice_copies(function: ast.FunctionDef) -> list[int]:
    """Lines of ``function`` that assign an expression (not a number) to a slice of an array."""
    lines = []
    for node in ast.walk(function):
        if isinstance(node, (ast.Assign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            sliced = any(isinstance(t, ast.Subscript) and any(isinstance(s, ast.Slice) for s in ast.walk(t.slice))
                         for t in targets)
            number = isinstance(node.value, ast.Constant) or (
                isinstance(node.value, ast.UnaryOp) and isinstance(node.value.operand, ast.Constant))
            if sliced and not number:
                lines.append(node.lineno)
    return lines


@pytest.mark.slow          # it reads every compiled function's source: over a second on the two-core machine
def test_no_compiled_loop_copies_a_slice_from_an_array():
    """A slice assigned from an array makes numba compile the text of its shape-mismatch error (string
    formatting, about 3 s of CPU): once per clone in a disk-cached loop, in every process in one compiled per
    process (docs/performance.md). Compiled loops copy element by element."""
    found = {f"{path.relative_to(ROOT)}:{line}"
             for path in MODULES.values()
             for function in _compiled_functions(ast.parse(path.read_text()))
             for line in _slice_copies(function)}
    assert not found, sorted(found)


def test_the_slice_copy_check_bites():
    tree = ast.parse("@njit\ndef f(a, b):\n    a[:] = 0.0\n    a[1:] = b\n    a[0] = b[0]\n")
    (function,) = _compiled_functions(tree)
    assert _slice_copies(function) == [4]
    tree = ast.parse("def g(a, b):\n    a[:] = b\n\ndef h(a, b):\n    a[:] = b\n\nG = njit(cache=True)(g)\n")
    assert [f.name for f in _compiled_functions(tree)] == ["g"]


def _disk_cached(tree: ast.AST) -> bool:
    """Whether a module disk-caches compiled code (a ``jit`` call with ``cache=True``, ``njit_fixed`` or
    ``cfunc_fixed``)."""
    return any(isinstance(node, ast.Call) and (
        ast.unparse(node.func).endswith(("njit_fixed", "cfunc_fixed"))
        or "jit" in ast.unparse(node.func)
        and any(k.arg == "cache" and ast.unparse(k.value) == "True" for k in node.keywords))
        for node in ast.walk(tree))


def _cached_without_the_keyed_cache(tree: ast.AST) -> bool:
    """Whether a module disk-caches compiled code with a decorator not taken from analysis/common/compiled.py,
    whose import keys the cache on the sources."""
    cached = _disk_cached(tree)
    keyed = any(isinstance(node, ast.ImportFrom) and (node.module or "").endswith("compiled")
                and any(alias.name == "njit" for alias in node.names) for node in ast.walk(tree))
    direct = any(isinstance(node, ast.ImportFrom) and node.module == "numba"
                 and any(alias.name in ("njit", "jit") for alias in node.names) for node in ast.walk(tree))
    return cached and (direct or not keyed)


def test_every_disk_cached_function_uses_the_keyed_cache():
    """numba checks a cached function against its own file only: a kernel inlining a helper of another file
    would run the old helper after that file changed. The cache directory is keyed on the sources
    (analysis/common/compiled.py) when a cached module takes its decorator from there (docs/performance.md)."""
    marks = ("cache=True", "_fixed(")               # the text first: parsing every module is slow
    trees = {path.relative_to(ROOT): ast.parse(text) for path in MODULES.values()
             if any(mark in (text := path.read_text()) for mark in marks)}
    found = sorted(str(path) for path, tree in trees.items() if _cached_without_the_keyed_cache(tree))
    assert not found, found
    cached = [path for path, tree in trees.items() if _disk_cached(tree)]
    assert cached and all(path.parts[0] in ("analysis", "drivers") for path in cached), cached   # the key's rooms


def test_the_keyed_cache_check_bites():
    assert _cached_without_the_keyed_cache(ast.parse("from numba import njit\n@njit(cache=True)\ndef f(): pass\n"))
    assert not _cached_without_the_keyed_cache(ast.parse(
        "from ..common.compiled import njit\n@njit(cache=True)\ndef f(): pass\n"))
    assert not _cached_without_the_keyed_cache(ast.parse("from numba import njit\n@njit\ndef f(): pass\n"))
    assert _cached_without_the_keyed_cache(ast.parse("import numba\nf = numba.njit(cache=True)(g)\n"))
    assert _disk_cached(ast.parse("from ..common.compiled import njit_fixed\n@njit_fixed()\ndef f(): pass\n"))
    assert _disk_cached(ast.parse("from ..common.compiled import cfunc_fixed\n@cfunc_fixed(s)\ndef f(): pass\n"))
