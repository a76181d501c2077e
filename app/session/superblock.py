"""The HDF5 superblock's "file is open for writing" flags, cleared the way the HDF5 tool ``h5clear`` does.

A process that dies, or whose disk fills, while it has a session open for writing leaves these flags set in the
file's superblock, and every HDF5 reader then refuses the file ("file is already open for write", or "file is not
already open for SWMR writing" when it was open outside SWMR mode). h5py cannot clear them, and ``h5clear`` is not
installed everywhere, so :func:`clear_write_flags` rewrites the few superblock bytes itself: the flags, the end of
file address (raised to the file's real size, as ``h5clear --increment`` does, since a write cut short may have
left data past the address stored) and the superblock checksum (Bob Jenkins' lookup3, as HDF5 computes it).

Only superblock versions 2 and 3 (``libver="latest"``, what contactid writes) carry these flags. Callers use this on
an in-memory image of a session, never on the file itself.
"""
from __future__ import annotations

import os

SIGNATURE = b"\x89HDF\r\n\x1a\n"
_MASK = 0xFFFFFFFF


def _rot(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & _MASK


def lookup3(data: bytes, initval: int = 0) -> int:
    """Bob Jenkins' ``hashlittle`` (lookup3.c), the checksum of HDF5 metadata (``H5_checksum_lookup3``)."""
    length = len(data)
    a = b = c = (0xDEADBEEF + length + initval) & _MASK
    i = 0
    while length > 12:
        a = (a + int.from_bytes(data[i:i + 4], "little")) & _MASK
        b = (b + int.from_bytes(data[i + 4:i + 8], "little")) & _MASK
        c = (c + int.from_bytes(data[i + 8:i + 12], "little")) & _MASK
        a = (a - c) & _MASK; a ^= _rot(c, 4); c = (c + b) & _MASK      # noqa: E702 (the reference's mix)
        b = (b - a) & _MASK; b ^= _rot(a, 6); a = (a + c) & _MASK      # noqa: E702
        c = (c - b) & _MASK; c ^= _rot(b, 8); b = (b + a) & _MASK      # noqa: E702
        a = (a - c) & _MASK; a ^= _rot(c, 16); c = (c + b) & _MASK     # noqa: E702
        b = (b - a) & _MASK; b ^= _rot(a, 19); a = (a + c) & _MASK     # noqa: E702
        c = (c - b) & _MASK; c ^= _rot(b, 4); b = (b + a) & _MASK      # noqa: E702
        length -= 12
        i += 12
    if length == 0:
        return c
    tail = data[i:] + bytes(12 - length)
    a = (a + int.from_bytes(tail[0:4], "little")) & _MASK
    b = (b + int.from_bytes(tail[4:8], "little")) & _MASK
    c = (c + int.from_bytes(tail[8:12], "little")) & _MASK
    c ^= b; c = (c - _rot(b, 14)) & _MASK      # noqa: E702 (the reference's final mix)
    a ^= c; a = (a - _rot(c, 11)) & _MASK      # noqa: E702
    b ^= a; b = (b - _rot(a, 25)) & _MASK      # noqa: E702
    c ^= b; c = (c - _rot(b, 16)) & _MASK      # noqa: E702
    a ^= c; a = (a - _rot(c, 4)) & _MASK       # noqa: E702
    b ^= a; b = (b - _rot(a, 14)) & _MASK      # noqa: E702
    c ^= b; c = (c - _rot(b, 24)) & _MASK      # noqa: E702
    return c


def _size(fh) -> int:
    return fh.seek(0, os.SEEK_END)


def _superblock_offset(fh) -> int | None:
    """Where the superblock starts: at 0, or after a user block of 512, 1024, 2048, ... bytes."""
    size = _size(fh)
    offset = 0
    while offset + len(SIGNATURE) <= size:
        fh.seek(offset)
        if fh.read(len(SIGNATURE)) == SIGNATURE:
            return offset
        offset = 512 if offset == 0 else offset * 2
    return None


def write_flags(path) -> int | None:
    """The superblock's file consistency flags (bit 0: open for writing, bit 2: open for SWMR writing), or None
    when the file is not HDF5 or its superblock (version 0 or 1) has none."""
    with open(path, "rb") as fh:
        start = _superblock_offset(fh)
        if start is None:
            return None
        fh.seek(start + 8)
        head = fh.read(4)
    return head[3] if len(head) == 4 and head[0] in (2, 3) else None


def clear_write_flags(fh) -> bool:
    """Clear the superblock's "open for writing" flags of the HDF5 file open in ``fh`` (binary, writable: a file
    or an in-memory image); whether anything was changed."""
    start = _superblock_offset(fh)
    if start is None:
        return False
    fh.seek(start)
    offsets = fh.read(12)[9]
    fh.seek(start)
    block = bytearray(fh.read(12 + 4 * offsets + 4))
    if block[8] not in (2, 3) or not block[11]:
        return False
    body = 12 + 4 * offsets
    if int.from_bytes(block[body:], "little") != lookup3(bytes(block[:body])):
        return False                              # not a superblock this knows how to rewrite
    block[11] = 0
    eof = slice(12 + 2 * offsets, 12 + 3 * offsets)
    size = _size(fh) - start
    block[eof] = max(int.from_bytes(block[eof], "little"), size).to_bytes(offsets, "little")
    block[body:] = lookup3(bytes(block[:body])).to_bytes(4, "little")
    fh.seek(start)
    fh.write(block)
    return True
