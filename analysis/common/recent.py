"""A few values kept by key, the most recently asked last and the oldest dropped: for work asked again and again
at nearby arguments (a fit's evaluations a step apart), where an unbounded cache would only grow."""
from __future__ import annotations

from typing import Generic, Hashable, TypeVar

V = TypeVar("V")


class Recent(Generic[V]):
    """At most ``size`` values by key; :meth:`get` and :meth:`keep` make a key the most recent."""

    def __init__(self, size: int):
        self.size = size
        self._values: dict[Hashable, V] = {}

    def get(self, key: Hashable) -> V | None:
        value = self._values.pop(key, None)
        if value is not None:
            self._values[key] = value
        return value

    def keep(self, key: Hashable, value: V) -> V:
        self._values.pop(key, None)
        self._values[key] = value
        while len(self._values) > self.size:
            del self._values[next(iter(self._values))]
        return value
