"""Reading values out of TOML tables with errors that name the field."""
from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import InputError


def read_toml_text(path: str | Path) -> str:
    """A TOML file's text; InputError naming the file when it is missing, a folder, or not UTF-8. A UTF-8 byte
    order mark (which some editors write) is dropped."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", str(path)) from None
    except IsADirectoryError:
        raise InputError("is a folder, not a TOML file", str(path)) from None
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror}", str(path)) from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        what = "an HDF5 file (a session?)" if data.startswith(b"\x89HDF") else "not UTF-8 text"
        raise InputError(f"{what}, not a TOML file (byte offset {exc.start})", str(path)) from None


def parse_toml(text: str, source: str | None) -> dict:
    """Parse TOML text; InputError naming the file (and line) on a syntax error or absurd nesting."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", source) from None
    except RecursionError:
        raise InputError("not valid TOML here: arrays or tables nested too deeply", source) from None


def load_toml(path: str | Path) -> dict:
    """Parse a TOML file (:func:`read_toml_text`, :func:`parse_toml`)."""
    return parse_toml(read_toml_text(path), str(path))


class Fields:
    """A view of one table that knows its place in the file, for error messages."""

    def __init__(self, table: Any, source: str | None, where: str):
        if not isinstance(table, Mapping):
            raise InputError(f"must be a table, got {type(table).__name__}", source, where)
        self.table = table
        self.source = source
        self.where = where

    def error(self, key: str | None, message: str) -> InputError:
        return InputError(message, self.source, self.path(key))

    def path(self, key: str | None) -> str:
        if key is None:
            return self.where
        return f"{self.where}.{key}" if self.where else key

    def has(self, key: str) -> bool:
        return key in self.table

    def require(self, key: str) -> Any:
        if key not in self.table:
            raise self.error(key, "is required")
        return self.table[key]

    def sub(self, key: str, default_empty: bool = False) -> "Fields":
        if key not in self.table and default_empty:
            return Fields({}, self.source, self.path(key))
        return Fields(self.require(key), self.source, self.path(key))

    def number(self, key: str, default: float | None = None, *, positive: bool = False,
               nonnegative: bool = False) -> float:
        if key not in self.table:
            if default is None:
                raise self.error(key, "is required")
            return default
        return self.check_number(key, self.table[key], positive=positive, nonnegative=nonnegative)

    def check_number(self, key: str, value: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {value!r}")
        if positive and value <= 0:
            raise self.error(key, f"must be > 0, got {value!r}")
        if nonnegative and value < 0:
            raise self.error(key, f"must be >= 0, got {value!r}")
        return value

    def string(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        if key not in self.table:
            if default is None:
                raise self.error(key, "is required")
            return default
        value = self.table[key]
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(choices)}; got {value!r}")
        return value

    def boolean(self, key: str) -> bool:
        value = self.require(key)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

    def strings(self, key: str) -> list[str]:
        value = self.require(key)
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.error(key, f"must be a list of strings, got {value!r}")
        return list(value)

    def matrix(self, key: str, n: int) -> np.ndarray:
        value = self.require(key)
        rows = value if isinstance(value, list) else None
        if rows is None or len(rows) != n or not all(isinstance(r, list) and len(r) == n for r in rows):
            raise self.error(key, f"must be a {n}x{n} matrix (a list of {n} rows of {n} numbers)")
        try:
            out = np.array([[self.check_number(key, x) for x in r] for r in rows], float)
        except InputError:
            raise self.error(key, "every entry must be a finite number") from None
        return out

    def list_of_tables(self, key: str) -> list["Fields"]:
        value = self.table.get(key, [])
        if not isinstance(value, list):
            raise self.error(key, "must be a list of tables")
        return [Fields(v, self.source, f"{self.path(key)}[{i}]") for i, v in enumerate(value)]

    def unknown_keys(self, allowed: set[str]) -> None:
        extra = sorted(set(self.table) - allowed)
        if extra:
            raise self.error(extra[0], f"unknown key (allowed here: {', '.join(sorted(allowed))})")
