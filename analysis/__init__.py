"""contactid numerics: the method in rooms, each importing only the rooms before it (docs/architecture.md).

Pure numerics -- no Qt, no serial ports, no files beyond TOML tables handed in. The rooms, in their order:

- ``common``: errors, TOML tables, measurement records, the statistics every judgement shares, numbers in words;
- ``laws``: one class per physical law (kernel, describing function, explanation, docs row);
- ``mechanics``: structures, the surroundings of an element, elements, models, the non-parametric element;
- ``signals``: estimators on time data and FRFs (harmonics, transients, H1/H2/Hv, FRF noise, the drive, modal fit);
- ``linear``: the reference linear model and its updating;
- ``identification``: the element's complex stiffness in closed form, and whether it is linear;
- ``fitting``: laws fitted to the identified stiffness;
- ``prediction``: harmonic balance, model against measurement, backbones, laws refined against the FRFs;
- ``missing``: what the model misses, ranked, and what no law of the library explains;
- ``search``: model discovery (law sets for elements that have none);
- ``loop``: the workbench that carries a model through all of it, and the automatic loop.

Stable entry points (docs/contracts.md §8): :func:`load_structure`, :func:`describing_function`. The names below
are imported on first use, so that ``import analysis.common.errors`` (the command line's start-up) does not load
numba and scipy (docs/performance.md, "Start-up"). Modules keep the flat names they had before the rooms
(``analysis.fit``, ``analysis.workbench``, ...): an import of one gives the room's module itself, the same object,
so that a patch through either name reaches the code that runs.
"""
import importlib.abc
import importlib.util
import sys
from importlib import import_module

_EXPORTS = {"Element": ".mechanics.elements", "LawTerm": ".mechanics.elements",
            "load_elements": ".mechanics.elements", "InputError": ".common.errors",
            "LAWS": ".laws", "describing_function": ".laws", "get_law": ".laws",
            "Structure": ".mechanics.structures", "load_structure": ".mechanics.structures"}

# the flat module names of before the rooms -> their room's module
MOVED = {"errors": "common.errors", "tables": "common.tables", "measurements": "common.measurements",
         "numbers": "common.wording",
         "structures": "mechanics.structures", "surroundings": "mechanics.surroundings",
         "elements": "mechanics.elements", "model": "mechanics.model", "nonparametric": "mechanics.nonparametric",
         "harmonics": "signals.harmonics", "transient_fit": "signals.transient_fit",
         "frf_estimation": "signals.frf_estimation", "frf_noise": "signals.frf_noise",
         "drive_prediction": "signals.drive_prediction", "modal_fit": "signals.modal_fit",
         "reference": "linear.reference", "updating": "linear.updating",
         "level_reference": "linear.level_reference",
         "identify": "identification.identify", "sherman_morrison": "identification.sherman_morrison",
         "linearity": "identification.linearity",
         "fit": "fitting.fit", "friction_fundamental": "fitting.friction_fundamental",
         "harmonic_balance": "prediction.harmonic_balance", "comparison": "prediction.comparison",
         "backbone": "prediction.backbone", "frf_refinement": "prediction.frf_refinement",
         "diagnosis": "missing.diagnosis", "unexplained": "missing.unexplained", "misfit": "missing.misfit",
         "modal_judge": "missing.modal_judge",
         "discovery": "search.discovery",
         "workbench": "loop.workbench", "auto": "loop.auto"}

__all__ = sorted(_EXPORTS)


class _FlatNames(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``analysis.<flat name>`` as the room's module object itself (not a copy that re-exports it)."""

    def __init__(self):
        self.own_specs = {}

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.rpartition(".")
        if package == __name__ and name in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        module = import_module(f"{__name__}.{MOVED[spec.name.rpartition('.')[2]]}")
        self.own_specs[spec.name] = module.__spec__
        return module

    def exec_module(self, module):
        """The room's module ran when it was imported; it keeps its own spec, which the import machinery replaced
        with the flat name's (relative imports inside its functions resolve against it)."""
        module.__spec__ = self.own_specs.pop(module.__spec__.name)


if not any(isinstance(finder, _FlatNames) for finder in sys.meta_path):
    sys.meta_path.append(_FlatNames())


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name], __name__), name)
    elif name in MOVED:
        value = import_module(f".{MOVED[name]}", __name__)
    else:
        raise AttributeError(f"module 'analysis' has no attribute {name!r}")
    globals()[name] = value            # once imported, an ordinary attribute
    return value
