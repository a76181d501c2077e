"""Calls carried over a pipe to the session writer process: a JSON header and the raw bytes of NumPy arrays.

One frame is ``<8-byte little-endian header length><JSON header><array bytes>...``. The header holds the call
(method name and keyword arguments); every array (and every complex or NumPy scalar, as a 0-d array) in the
arguments is replaced by ``{"$array": i}`` and sent after the header as its raw bytes, its dtype and shape
listed in the header. Plain JSON and raw bytes only: nothing is pickled, nothing is evaluated.

A frame cut short (the sender died while writing it) reads as ``None``, like the end of the stream: a call
that was not sent whole is never executed.
"""
from __future__ import annotations

import json
import struct
from typing import BinaryIO

import numpy as np

_LENGTH = struct.Struct("<Q")


def _flatten(value, arrays: list[np.ndarray]):
    if isinstance(value, dict):
        return {str(k): _flatten(v, arrays) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_flatten(v, arrays) for v in value]
    if isinstance(value, (np.ndarray, np.generic, complex)):
        arrays.append(np.ascontiguousarray(value))
        return {"$array": len(arrays) - 1}
    return value


def _restore(value, arrays: list[np.ndarray]):
    if isinstance(value, dict):
        if set(value) == {"$array"}:
            return arrays[value["$array"]]
        return {k: _restore(v, arrays) for k, v in value.items()}
    if isinstance(value, list):
        return [_restore(v, arrays) for v in value]
    return value


def encode_call(method: str, kwargs: dict) -> list:
    """One call as the parts of its frame (bytes and array buffers), nothing written yet: an argument that cannot
    be sent fails here, with the pipe as it was."""
    arrays: list[np.ndarray] = []
    args = _flatten(kwargs, arrays)
    header = json.dumps({"method": method, "kwargs": args,
                         "arrays": [[a.dtype.str, list(a.shape)] for a in arrays]}).encode()
    return [_LENGTH.pack(len(header)), header] + [memoryview(a).cast("B") for a in arrays if a.nbytes]


def write_frame(stream: BinaryIO, parts: list) -> None:
    """Write a frame made by :func:`encode_call` and flush."""
    for part in parts:
        stream.write(part)
    stream.flush()


def send_call(stream: BinaryIO, method: str, kwargs: dict) -> int:
    """Write one call and flush; returns the bytes of array payload sent."""
    parts = encode_call(method, kwargs)
    write_frame(stream, parts)
    return sum(len(part) for part in parts[2:])


def _read_exactly(stream: BinaryIO, n: int) -> bytes | None:
    data = stream.read(n)
    return data if data is not None and len(data) == n else None


def receive_call(stream: BinaryIO) -> tuple[str, dict] | None:
    """Read one call ``(method, kwargs)``; None at the end of the stream or on a frame cut short."""
    size = _read_exactly(stream, _LENGTH.size)
    if size is None:
        return None
    header = _read_exactly(stream, _LENGTH.unpack(size)[0])
    if header is None:
        return None
    call = json.loads(header)
    arrays = []
    for dtype, shape in call["arrays"]:
        a = np.empty(shape, dtype=np.dtype(dtype))
        if a.nbytes:
            data = _read_exactly(stream, a.nbytes)
            if data is None:
                return None
            a = np.frombuffer(data, dtype=a.dtype).reshape(shape)
        arrays.append(a)
    return call["method"], _restore(call["kwargs"], arrays)


def send_reply(stream: BinaryIO, error: str | None = None) -> None:
    stream.write((json.dumps({"error": error}) + "\n").encode())
    stream.flush()


def receive_reply(stream: BinaryIO) -> str | None:
    """The error text of the writer's reply (None when the call succeeded); EOFError when it sent none."""
    line = stream.readline()
    if not line.endswith(b"\n"):
        raise EOFError("no reply")
    return json.loads(line)["error"]
