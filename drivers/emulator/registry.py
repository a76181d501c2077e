"""Which emulated rigs the ``sim://`` URL handler can reach in this process.

URL form::

    sim://<rig>/<instrument>[?option=value&...]

``<rig>`` names a rig registered with :func:`register`. If none is
registered under that name, the handler builds the rig on first use with the
backend factory that the application hands in (:func:`set_backend_factory`; the app
installs the rig simulator of the built-in rig of that name, with the rig file's
``[faults]``) and closes it when its last link closes. Without a factory only
registered rigs are reachable: the emulator never imports the simulation itself. ``<instrument>`` is ``shaker`` or ``daq``.

Options: ``fast=1`` (only for a rig the handler builds; a registered rig keeps its
own mode, and ``fast`` must then match it), ``seed=N`` (seed of the link's fault
generator, also handed to the factory), and the link faults of
:mod:`drivers.faults` (``drop``, ``flip``, ``stall``, ``stall_time``,
``disconnect``, ``scpi_error``, ``overrun``), which replace the rig's own faults
for that link.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping
from urllib.parse import parse_qsl, urlsplit

from analysis.common.errors import InputError

from ..faults import FAULT_KEYS, ROLES, parse_query_value

from .core import EmulatedRig

if TYPE_CHECKING:
    from .link import InstrumentLink

BackendFactory = Callable[[str, int | None], tuple[Any, Mapping[str, Any] | None]]
"""``factory(name, seed) -> (backend, faults table or None)``."""


_lock = threading.Lock()
_rigs: dict[str, "EmulatedRig"] = {}
_built: dict[str, int] = {}          # rigs built by the handler -> open link count
_factory: BackendFactory | None = None


def register(rig: EmulatedRig, name: str | None = None) -> EmulatedRig:
    """Make ``rig`` reachable as ``sim://<name>/...`` (default: its own name) until it closes.

    ValueError if the name is taken by another rig."""
    name = name or rig.name
    with _lock:
        if _rigs.get(name, rig) is not rig:
            raise ValueError(f"an emulated rig named {name!r} is already registered")
        _rigs[name] = rig
    rig.on_close(unregister)
    return rig


def unregister(rig: EmulatedRig) -> None:
    """Forget ``rig`` under every name it was registered with."""
    with _lock:
        for name in [n for n, r in _rigs.items() if r is rig]:
            del _rigs[name]
            _built.pop(name, None)


def find_rig(name: str) -> EmulatedRig | None:
    """The rig reachable as ``sim://<name>/...``, if any."""
    with _lock:
        return _rigs.get(name)


def set_backend_factory(factory: BackendFactory | None) -> None:
    """Set how the handler builds an unregistered rig (None: it builds none)."""
    global _factory
    _factory = factory


@dataclass(frozen=True)
class SimUrl:
    """A parsed ``sim://`` URL."""

    rig: str
    instrument: str
    fast: bool | None
    seed: int | None
    faults: dict[str, Any]


def parse_sim_url(url: str) -> SimUrl:
    """Split and check a ``sim://`` URL; InputError naming the URL on any problem."""
    parts = urlsplit(url)
    if parts.scheme.lower() != "sim":
        raise InputError("not a sim:// URL", url)
    instrument = parts.path.strip("/").lower()
    if not parts.netloc or instrument not in ROLES:
        raise InputError(f"expected sim://<rig>/<{'|'.join(ROLES)}>", url)
    fast = seed = None
    faults: dict[str, Any] = {}
    for key, value in parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query)):
        if key == "fast":
            if value not in ("0", "1"):
                raise InputError(f"fast must be 0 or 1, got {value!r}", url, "fast")
            fast = value == "1"
        elif key == "seed":
            seed = int(parse_query_value("seed", value))
            faults["seed"] = seed
        elif key in FAULT_KEYS:
            faults[key] = parse_query_value(key, value)
        else:
            raise InputError(f"unknown option (known: fast, {', '.join(FAULT_KEYS)})", url, key)
    return SimUrl(parts.netloc, instrument, fast, seed, faults)


def _find_or_build(spec: SimUrl, url: str) -> EmulatedRig:
    with _lock:
        rig = _rigs.get(spec.rig)
        if rig is not None:
            if spec.fast is not None and spec.fast == rig.paced:
                mode = "paced" if rig.paced else "fast"
                raise InputError(f"rig {spec.rig!r} is already running {mode}", url, "fast")
            if spec.rig in _built:
                _built[spec.rig] += 1
            return rig
        if _factory is None:
            raise InputError(f"no emulated rig named {spec.rig!r} is running in this process", url)
        backend, faults = _factory(spec.rig, spec.seed)
        rig = EmulatedRig(backend, paced=not spec.fast, name=spec.rig, faults=faults).start()
        rig.on_close(unregister)
        _rigs[spec.rig] = rig
        _built[spec.rig] = 1
        return rig


def _release(name: str, rig: EmulatedRig) -> None:
    with _lock:
        if name not in _built:
            return
        _built[name] -= 1
        if _built[name] > 0:
            return
    rig.close()


def open_sim_link(url: str) -> "InstrumentLink":
    """The link a ``sim://`` port talks through (the rig is built first if needed)."""
    spec = parse_sim_url(url)
    rig = _find_or_build(spec, url)
    try:
        faults = None
        if spec.faults:
            faults = rig.default_faults[spec.instrument].updated(spec.faults, url)
        link = rig.connect(spec.instrument, faults)
    except BaseException:
        _release(spec.rig, rig)
        raise
    link.on_close(lambda _: _release(spec.rig, rig))
    return link
