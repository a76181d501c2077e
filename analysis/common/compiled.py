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
"""
import hashlib
import os
import shutil
import time
from pathlib import Path

import numba
from numba import njit  # noqa: F401  (the one import of the decorator by cached modules)

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


key_cache_on(_ROOTS)
