"""Reading what can still be read of a damaged session, bounded in retries and in time (``contactid recover``).

A session whose writer stopped in the middle of a write (a crash, a disk filled by another program while a run was
being closed) may hold objects whose metadata was cut short. HDF5 refuses most of them, but some it reads forever:
an attribute whose object header continuation lies past what reached the disk made a read spin inside the HDF5
library, where no Python timeout reaches. So the salvage runs in a child process (``python -m
app.session salvage``) that names every attribute and object before it reads it; when one is not read within its
time (:func:`_allowed_seconds`) the child is killed, the item is left out, and the salvage starts again without it.

The metadata reads of a SWMR reader are bounded too (:func:`swmr_read_access`): HDF5 retries a metadata read whose
checksum fails, by default for hours in all.
"""
from __future__ import annotations

import ctypes
import functools
import io
import json
import os
import select
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
from h5py._objects import phil

from analysis.common.child import python_child

from app.session.superblock import clear_write_flags

# A SWMR reader retries a metadata read whose checksum fails (it may race the writer) with a doubling pause --
# by default 100 times, hours in all, so a truncated or damaged file would hang the reader. 20 attempts wait
# about a second in all: ample for a writer's flush, and a damaged file is reported at once.
SWMR_READ_ATTEMPTS = 20
ITEM_SECONDS = 10.0
"""Time allowed to read one attribute, group or small dataset of a damaged file (whole sessions read in well under
a second on a loaded machine; a read that takes this long has gone round in circles)."""
COPY_BYTES_PER_SECOND = 10e6
"""Slowest copy rate allowed for a dataset's stored bytes (gzip-compressed raw data on a slow medium) on top of
:data:`ITEM_SECONDS`."""
START_SECONDS = 60.0
"""Time allowed for the child's start (Python, NumPy and h5py imported on a loaded machine) before its first read."""
MAX_STALLS = 8
"""Items whose read did not finish that a salvage leaves out before it gives up on the file."""
STALLED = "reading it did not finish"


@functools.cache
def _hdf5_library():
    """The HDF5 library h5py runs on (to reach a file-access setting h5py does not wrap), or None."""
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "libhdf5" in line and "libhdf5_hl" not in line}
        return ctypes.CDLL(sorted(paths)[0]) if paths else None
    except (OSError, IndexError):
        return None


def swmr_read_access() -> h5py.h5p.PropFAID:
    """File access for a SWMR reader whose metadata reads are retried :data:`SWMR_READ_ATTEMPTS` times."""
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_libver_bounds(h5py.h5f.LIBVER_LATEST, h5py.h5f.LIBVER_LATEST)
    library = _hdf5_library()
    if library is not None and hasattr(library, "H5Pset_metadata_read_attempts"):
        # HDF5 is not built thread-safe: h5py's lock serialises every call into it, and this one, made past
        # h5py, must hold that lock too, or it corrupts a call another thread is making (a crash)
        with phil:
            library.H5Pset_metadata_read_attempts(ctypes.c_int64(fapl.id), ctypes.c_uint(SWMR_READ_ATTEMPTS))
    return fapl


class SalvageError(RuntimeError):
    """The damaged session could not be read far enough to copy it (its message says what was left out)."""


# --------------------------------------------------------------------------- the child: copy, naming each read
_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)


def _allowed_seconds(nbytes: int = 0) -> float:
    return ITEM_SECONDS + nbytes / COPY_BYTES_PER_SECOND


def _announce(item: str, nbytes: int = 0) -> None:
    """Tell the parent which item is read next and how many bytes it holds."""
    print(json.dumps({"item": item, "bytes": int(nbytes)}), flush=True)


def _salvage(src: h5py.Group, dst: h5py.Group, skip: set[str], lost: list[str]) -> None:
    """Copy ``src`` into ``dst`` item by item; what cannot be read (a write cut short by a full disk) is left out
    and named in ``lost``, and the items in ``skip`` (reads that did not finish before) are not touched."""
    for key in src.attrs:
        item = f"{src.name}@{key}"
        if item in skip:
            continue
        _announce(item)
        try:
            dst.attrs[key] = src.attrs[key]
        except _ERRORS:
            lost.append(item)
    for key in src:
        item = f"{src.name.rstrip('/')}/{key}"
        if item in skip:
            continue
        _announce(item)
        try:
            obj = src[key]
            if isinstance(obj, h5py.Group):
                _salvage(obj, dst.create_group(key), skip, lost)
            else:
                _announce(item, obj.id.get_storage_size())
                src.copy(obj, dst, name=key)
        except _ERRORS:
            if key in dst:
                del dst[key]
            lost.append(item)


def _open_source(path: Path, image: bool) -> h5py.File:
    """The damaged file for reading: as an in-memory image with its "open for writing" flags cleared (a writer
    that stopped outside SWMR mode), or as a SWMR reader with bounded retries."""
    if image:
        with open(path, "rb") as fh:
            data = io.BytesIO(fh.read())
        clear_write_flags(data)
        return h5py.File(data, "r")
    fid = h5py.h5f.open(os.fsencode(path), h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ, fapl=swmr_read_access())
    return h5py.File(fid)


def _child(source: str, target: str, image: bool, skip: list[str]) -> int:
    lost: list[str] = []
    try:
        src = _open_source(Path(source), image)
    except _ERRORS as exc:
        print(json.dumps({"failed": " ".join(str(exc).split())}), flush=True)
        return 0
    try:
        with src, h5py.File(target, "w", libver="latest") as dst:
            _salvage(src, dst, set(skip), lost)
    except OSError as exc:                         # the copy could not be written (a full disk): not the source
        print(json.dumps({"unwritten": exc.errno or 0, "why": " ".join(str(exc).split())}), flush=True)
        return 0
    print(json.dumps({"lost": lost}), flush=True)
    return 0


# --------------------------------------------------------------------------- the parent: bound each read in time
@dataclass
class _Attempt:
    """How one salvage child ended: with what it could not read, with the item whose read did not finish, or
    with the file refused as a whole."""

    lost: list[str] | None = None
    stalled_on: str | None = None
    failed: str = ""
    unwritten: OSError | None = None


@dataclass
class _Reader:
    """The child's report lines, read with a deadline."""

    proc: subprocess.Popen
    buffer: bytes = b""
    lines: list[bytes] = field(default_factory=list)

    def next_line(self, deadline: float) -> bytes | None:
        """The next line, or None when the deadline passes or the child's output ends first."""
        fd = self.proc.stdout.fileno()
        while not self.lines:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, 65536)
            if not chunk:
                return None
            self.buffer += chunk
            *complete, self.buffer = self.buffer.split(b"\n")
            self.lines += [line for line in complete if line]
        return self.lines.pop(0)


def _attempt(source: Path, target: Path, image: bool, skip: list[str]) -> _Attempt:
    command, env = python_child("app.session", "salvage", str(source), str(target), "image" if image else "swmr",
                                json.dumps(skip))
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                            env=env)
    reader, item = _Reader(proc), "the file's superblock"
    deadline = time.monotonic() + START_SECONDS + _allowed_seconds()
    try:
        while True:
            line = reader.next_line(deadline)
            if line is None:                            # stuck in a read, or killed by one (a crash in HDF5)
                return _Attempt(stalled_on=item)
            report = json.loads(line)
            if "item" in report:
                item, deadline = report["item"], time.monotonic() + _allowed_seconds(report["bytes"])
            elif "lost" in report:
                return _Attempt(lost=report["lost"])
            elif "unwritten" in report:
                errno = report["unwritten"]
                return _Attempt(unwritten=OSError(errno, report["why"]) if errno else OSError(report["why"]))
            else:
                return _Attempt(failed=report["failed"])
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()


def salvage(source: Path, target: Path, image: bool) -> list[str]:
    """Copy everything of the damaged session ``source`` that can be read into a new file ``target``; returns
    what was left out (``/path`` of an object, ``/path@name`` of an attribute). ``image``: read it as an
    in-memory image with its write flags cleared (left open outside SWMR mode), else as a SWMR reader.

    SalvageError when the file cannot be opened at all or more than :data:`MAX_STALLS` reads do not finish;
    OSError when the copy cannot be written."""
    stalled: list[str] = []
    while True:
        outcome = _attempt(source, target, image, stalled)
        if outcome.unwritten is not None:
            raise outcome.unwritten
        if outcome.failed:
            raise SalvageError(f"not a readable HDF5 session ({outcome.failed})")
        if outcome.lost is not None:
            return [f"{item} ({STALLED})" for item in stalled] + outcome.lost
        stalled.append(outcome.stalled_on)
        if outcome.stalled_on == "the file's superblock" or len(stalled) > MAX_STALLS:
            raise SalvageError(f"{STALLED} for: {', '.join(stalled)}")


def child_main(argv: list[str]) -> int:
    """``python -m app.session salvage SOURCE TARGET image|swmr SKIP_JSON``: one salvage attempt."""
    return _child(argv[0], argv[1], argv[2] == "image", json.loads(argv[3]))
