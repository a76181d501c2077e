"""numba's compiler with a disk cache keyed on the sources the compiled code may read.

Every disk-cached function of the project is decorated with this module's :func:`njit` (a test checks it), so that
importing it, before any such decoration, points numba's cache at ``<base>/<key>``:

- ``key``: a hash of every ``.py`` file of analysis/ and drivers/ (paths and contents), the rooms compiled code
  lives in and reads from. numba checks a cached function against its own file only; a kernel that inlines a
  helper of another file, or reads a constant from one, would otherwise keep running the old helper after that
  file changed (docs/performance.md, "First compile of the integration loop"). Any edit there recompiles everything
  once; a stale kernel is never run.
- ``base``: ``NUMBA_CACHE_DIR`` when the user set it, else ``$XDG_CACHE_HOME/contactid/numba`` (``~/.cache/...``).
  Where neither can be written, numba's own choice stands (``__pycache__`` beside each file, whose staleness is
  then the user's).

Directories of other keys not used for :data:`KEEP_DAYS` days are removed when a new key's directory is made, so
that a checkout updated day after day does not fill the disk.

:func:`njit_fixed` and :func:`cfunc_fixed` cache a compiled function made by a factory around other compiled
functions (a law's march with its kernel fixed): numba keys such a function on a pickle of what it closes over,
and a pickled dispatcher carries an identity drawn anew in every process, so its cached copy would never be found
again.

numba's index of a function's cached copies is read, extended and written whole by each process that saves one;
:func:`_serialised` makes that a critical section per index, so that two processes saving copies of one function at
once cannot cross its entries.

A compile (or a load from the cache) is one step against a signal (:func:`_held`): LLVM hands the object code it
emits to a ctypes callback, which swallows an exception raised in it, so a Ctrl-C there was lost and the function
left without its code -- its next call raised ``RuntimeError: no compiled object yet`` in the command's place of
"interrupted". The output still goes off at once; the rest waits for the compile's end (a second signal acts at
once, as in every held step).
"""
import functools
import hashlib
import os
import shutil
import time
import types
from pathlib import Path

import numba
import numpy as np
from numba import njit  # noqa: F401  (the one import of the decorator by cached modules)
from numba.core import sigutils
from numba.core.caching import FunctionCache, IndexDataCacheFile
from numba.core.ccallback import CFunc
from numba.core.dispatcher import Dispatcher

from .held_signals import signals_held

try:
    import fcntl
except ImportError:         # not POSIX: numba's own save stands
    fcntl = None

KEEP_DAYS = 14
_ROOTS = tuple(Path(__file__).resolve().parents[2] / room for room in ("analysis", "drivers"))


def source_key(roots) -> str:
    """A 16-hex-digit hash of every ``.py`` file under ``roots`` (relative path and bytes, in sorted order)."""
    digest = hashlib.sha256()
    for root in roots:
        root = Path(root)
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root.parent)).encode())
            digest.update(b"\0")
            digest.update(path.read_bytes())
            digest.update(b"\0")
    return digest.hexdigest()[:16]


def _default_base() -> Path:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(xdg) / "contactid" / "numba"


def key_cache_on(roots, base=None) -> Path | None:
    """Point numba's disk cache at ``base/<source_key(roots)>``; return that directory, or None (cache unchanged)
    when it cannot be made or written. Must run before the decorations it is to govern: numba fixes a function's
    cache directory when it is decorated."""
    base = Path(base) if base is not None else _default_base()
    directory = base / source_key(roots)
    fresh = not directory.is_dir()
    try:
        directory.mkdir(parents=True, exist_ok=True)
        os.utime(directory)
        probe = directory / f".probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError:
        return None
    if fresh:
        _remove_unused(base, keep=directory)
    numba.config.CACHE_DIR = str(directory)
    return directory


def _remove_unused(base: Path, keep: Path) -> None:
    """Remove the directories of other keys not used for KEEP_DAYS days (ignoring what another process holds)."""
    limit = time.time() - KEEP_DAYS * 86400.0
    for other in base.iterdir():
        try:
            if other != keep and other.is_dir() and len(other.name) == 16 and other.stat().st_mtime < limit:
                shutil.rmtree(other, ignore_errors=True)
        except OSError:
            continue


def describe(value) -> tuple | str:
    """What a compiled closure's code depends on beyond the sources the cache is keyed on: a function by its module,
    name and bytecode and, recursively, what it closes over; numbers and strings by value; arrays by dtype, shape
    and bytes; tuples and lists item by item. TypeError for anything else (such a closure is not disk-cached)."""
    if isinstance(value, Dispatcher):
        value = value.py_func
    if isinstance(value, types.FunctionType):
        cells = tuple(describe(cell.cell_contents) for cell in value.__closure__ or ())
        return ("function", value.__module__, value.__qualname__, value.__code__.co_code.hex(), cells)
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, tuple(describe(item) for item in value))
    if value is None or isinstance(value, (bool, int, float, complex, str, np.number)):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, np.ndarray):
        return ("array", value.dtype.str, value.shape, hashlib.sha256(np.ascontiguousarray(value).data).hexdigest())
    raise TypeError(f"{type(value).__name__} has no stable description for the disk cache")


class _FixedClosureCache(FunctionCache):
    """numba's cache of one function, its entries keyed on :func:`describe` of the function instead of a pickle of
    its closure. Sound because the directory is keyed on the sources (module docstring): a description names the
    code of every function involved, and the directory the text that code was compiled from."""

    def __init__(self, py_func, description: str):
        super().__init__(py_func)
        self._description = description

    def _index_key(self, sig, codegen):
        return sig, codegen.magic_tuple(), (self._description,)


def njit_fixed(**options):
    """numba's ``njit(**options)`` for a function a factory compiles around other compiled functions it closes over
    (their calls inlined, no function passed at run time), disk-cached under :func:`describe` of the function; not
    cached when that has no description. Decorate the function called from Python: what it calls is compiled
    into it."""
    def decorate(py_func):
        cache = _fixed_cache(py_func)
        dispatcher = numba.njit(**options)(py_func)
        dispatcher._cache = cache or dispatcher._cache
        return dispatcher
    return decorate


def cfunc_fixed(signature):
    """numba's ``cfunc(signature)`` for a C callback a factory compiles around compiled functions it closes over,
    disk-cached as :func:`njit_fixed`'s functions are (a callback compiles when it is made)."""
    signature = sigutils.normalize_signature(signature)

    def decorate(py_func):
        cache = _fixed_cache(py_func)
        callback = CFunc(py_func, signature, locals={}, options={})
        callback._cache = cache or callback._cache
        callback.compile()
        return callback
    return decorate


def _fixed_cache(py_func) -> "_FixedClosureCache | None":
    """The cache of ``py_func`` keyed on its description; None without a description or a directory numba can
    write. Called before numba wraps ``py_func``: the function's name takes the description's hash, since numba
    names a cache's files after the function, and the closures of one factory would otherwise share one index.
    :func:`_serialised` keeps a shared index whole where ``flock`` exists; files of their own keep the closures
    apart everywhere, and each index small."""
    try:
        description = hashlib.sha256(repr(describe(py_func)).encode()).hexdigest()
    except TypeError:
        return None
    py_func.__qualname__ = f"{py_func.__qualname__}_{description[:16]}"
    try:
        return _FixedClosureCache(py_func, description)
    except RuntimeError:
        return None


def _serialised(save):
    """``IndexDataCacheFile.save`` under an exclusive lock on a file beside the index (POSIX ``flock``). Two
    processes that read the index before either writes it would both name their data file after the same free
    number, and the one that writes its index last keeps its key pointing at the data the other wrote last: a
    function loads the code compiled for another signature (numba compiles, for example, a law's update for arrays
    from Python and for pointers from the rig simulator). An interrupt or a request to terminate that arrives
    during the save acts once it is done: numba writes the index before the data, and a process ended between the
    two leaves an index naming a data file never written, or an older one of the same number
    (:class:`analysis.common.held_signals.signals_held`: held for the main thread's Python handler, where a signal
    mask would hold it only for a thread the process's other threads stand in for)."""
    def locked_save(self, key, data):
        try:
            lock = open(f"{self._index_path}.lock", "a")
        except OSError:                  # numba's own save then meets the same trouble and says so
            return save(self, key, data)
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            with signals_held():
                return save(self, key, data)     # closing the file releases the lock
    return locked_save


def _held(compile_):
    """``compile_`` (numba's compile of a dispatcher or a C callback) run whole, a signal acting at its end."""
    @functools.wraps(compile_)
    def held_compile(*args, **kwargs):
        with signals_held():
            return compile_(*args, **kwargs)
    return held_compile


_numba_save = IndexDataCacheFile.save
if fcntl is not None:
    IndexDataCacheFile.save = _serialised(_numba_save)
Dispatcher.compile = _held(Dispatcher.compile)
CFunc.compile = _held(CFunc.compile)
key_cache_on(_ROOTS)
