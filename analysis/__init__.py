"""contactid numerics: structures, element laws, identification, fitting.

Pure numerics -- no Qt, no serial ports, no files beyond TOML tables handed in.
Stable entry points (docs/contracts.md §8): :func:`load_structure`, :func:`describing_function`.

The names below are imported on first use, so that ``import analysis.errors`` (the command line's start-up) does
not load numba and scipy (docs/performance.md, "Start-up").
"""
from importlib import import_module

_EXPORTS = {"Element": ".elements", "LawTerm": ".elements", "load_elements": ".elements",
            "InputError": ".errors",
            "LAWS": ".laws", "describing_function": ".laws", "get_law": ".laws",
            "Structure": ".structures", "load_structure": ".structures"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'analysis' has no attribute {name!r}")
    value = getattr(import_module(_EXPORTS[name], __name__), name)
    globals()[name] = value            # once imported, an ordinary attribute
    return value
