"""Output files that never destroy what is already there.

Every command that writes a file goes through here:

* an existing file is refused unless the user said ``--overwrite`` (:func:`check_output`);
* an output that is one of the command's own inputs is refused even with ``--overwrite``;
* the file is written beside its destination under a temporary name and moved into place only when it is
  complete (:func:`atomic_output`): a full disk, a crash or an error leaves the old file (or no file), never a
  half-written one;
* :func:`require_free_space` refuses to start a write that cannot fit;
* an existing file that must change (a session gaining its model history) is rewritten beside itself and
  renamed over the old one (:func:`atomic_replace`), so a failure leaves it as it was;
* a path that is a symbolic link is written through: the new version replaces the file the link points to,
  beside that file, and the link stays a link (:func:`through_links`).
"""
from __future__ import annotations

import errno
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from analysis.common.errors import InputError

from app.session.file import SessionWriteError, sync_file

TEMP_PREFIX = "."
TEMP_SUFFIX = ".partial"
FREE_SPACE_CHECK = "not enough free space to"
# failures to write that say nothing about the command's input: the output, not the program, is at fault
WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EIO)


_COMMITTED: list[Path] = []


def committed_outputs() -> list[Path]:
    """The files :func:`atomic_output` moved into place in this process (as the command named them), so that a
    later failure -- standard output that cannot be written -- can say what was written (app/cli.py clears it
    when a command starts)."""
    return _COMMITTED


class NotWritten(InputError):
    """An output could not be written (full disk, read-only medium, a write that failed); nothing of it was left
    and a file it was to replace is unchanged. One line, exit status 2, like bad input: nothing was written."""


def write_failure(exc: BaseException) -> str:
    """Why a write failed, in one line: the system's words (or those of a free-space check)."""
    if isinstance(exc, OSError) and exc.strerror and exc.strerror.startswith(FREE_SPACE_CHECK):
        return exc.strerror
    if isinstance(exc, OSError) and exc.errno:
        return os.strerror(exc.errno)           # not HDF5's many lines about the same thing
    text = " ".join(str(exc).split())
    return "No space left on device" if "No space left on device" in text else text


def _not_written(path: Path, existed: bool, exc: BaseException) -> NotWritten:
    kept = "the file there is unchanged" if existed else "no file was left"
    return NotWritten(f"not written: {write_failure(exc)}; {kept}", str(path))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path, *, inputs: Iterable = (), overwrite: bool = False, field: str = "-o",
                 overwrite_flag: str = "--overwrite") -> Path:
    """Validate an output path before anything is measured or computed.

    Raises InputError (naming the file and the option) when the output is one of ``inputs``, when it exists and
    ``overwrite`` is false, or when its folder does not exist or is not writable.
    """
    path = Path(path)
    for source in inputs:
        if source is not None and (_same_file(path, Path(source)) or path.resolve() == Path(source).resolve()):
            raise InputError("is also an input of this command; choose another output file", str(path), field)
    if path.is_dir():
        raise InputError("is a folder; give a file name", str(path), field)
    if path.exists() and not overwrite:
        raise InputError(f"exists already; pass {overwrite_flag} to overwrite it", str(path), field)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("its folder does not exist", str(path), field)
    if not os.access(folder, os.W_OK):
        raise InputError("its folder is not writable", str(path), field)
    return path


def free_bytes(path) -> int:
    """Bytes free on the file system holding ``path`` (or its folder)."""
    path = Path(path)
    folder = path if path.is_dir() else (path.parent if str(path.parent) else Path("."))
    return shutil.disk_usage(folder).free


def require_free_space(path, needed: int, what: str = "write") -> None:
    """OSError(ENOSPC) naming ``path`` when fewer than ``needed`` bytes are free where it lives."""
    free = free_bytes(path)
    if free < needed:
        raise OSError(errno.ENOSPC, f"{FREE_SPACE_CHECK} {what}: {free} bytes free, {needed} needed",
                      str(path))


def temporary_path(path, keep_suffix: bool = False) -> Path:
    """Where :func:`atomic_output` writes ``path`` before moving it into place (same folder: same file system).
    ``keep_suffix``: the name still ends in ``path``'s suffix (for writers that choose the format by it)."""
    path = Path(path)
    if keep_suffix:
        return path.with_name(f"{TEMP_PREFIX}{path.stem}.{os.getpid()}{TEMP_SUFFIX}{path.suffix}")
    return path.with_name(f"{TEMP_PREFIX}{path.name}.{os.getpid()}{TEMP_SUFFIX}")


def through_links(path) -> Path:
    """Where a write to ``path`` goes: the file a symbolic link (or a chain of them) points to, else ``path``.
    A rename onto the link itself would replace the link by a regular file and leave its target as it was."""
    path = Path(path)
    return Path(os.path.realpath(path)) if path.is_symlink() else path


@contextmanager
def atomic_output(path, *, inputs: Iterable = (), overwrite: bool = False, field: str = "-o",
                  keep_suffix: bool = False) -> Iterator[Path]:
    """Write ``path`` all at once: yields a temporary path to write; on success it is synced and renamed onto
    ``path``; on any exception it is removed and ``path`` is left as it was.

    The output is checked first (:func:`check_output`)."""
    named = Path(path)
    path = through_links(check_output(path, inputs=inputs, overwrite=overwrite, field=field))
    existed = path.exists()
    temp = temporary_path(path, keep_suffix)
    try:
        yield temp
        sync_file(temp)
        os.replace(temp, path)
        _COMMITTED.append(named)
    except BaseException as exc:
        temp.unlink(missing_ok=True)
        if _is_write_failure(exc):
            raise _not_written(path, existed, exc) from exc
        raise


def _is_write_failure(exc: BaseException) -> bool:
    """A failure of the medium (full, read-only, I/O error) rather than of the data or the program: plain
    OSErrors carrying such an errno, and the session writer's reports of one."""
    if isinstance(exc, OSError) and not isinstance(exc, FileNotFoundError):
        return exc.errno in WRITE_ERRNOS or exc.errno is None
    return isinstance(exc, SessionWriteError) and "No space left on device" in str(exc)


@contextmanager
def atomic_replace(path, extra_bytes: int = 0, what: str = "rewrite") -> Iterator[Path]:
    """Change an existing file all at once: yields a temporary path beside it (empty) to write the new version
    to; on success it gets the old file's permissions, is synced and renamed onto ``path``; on any exception it
    is removed and ``path`` is untouched.

    Refuses (OSError ENOSPC, nothing written) unless the new version -- ``path``'s size plus ``extra_bytes`` --
    fits in the free space."""
    path = through_links(path)
    require_free_space(path, path.stat().st_size + extra_bytes, what)
    temp = temporary_path(path)
    try:
        yield temp
        shutil.copymode(path, temp)
        sync_file(temp)
        os.replace(temp, path)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
