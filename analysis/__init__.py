"""contactid numerics: structures, element laws, identification, fitting.

Pure numerics -- no Qt, no serial ports, no files beyond TOML tables handed in.
Stable entry points (docs/contracts.md §8): :func:`load_structure`, :func:`describing_function`.
"""
from .elements import Element, LawTerm, load_elements
from .errors import InputError
from .laws import LAWS, describing_function, get_law
from .structures import Structure, load_structure

__all__ = ["Element", "InputError", "LAWS", "LawTerm", "Structure", "describing_function", "get_law",
           "load_elements", "load_structure"]
