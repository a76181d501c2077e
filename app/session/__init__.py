"""The session file: every measured line on the disk, readable by any HDF5 tool (docs/session-format.md).

It owns the writer process and its wire format (:mod:`.writer`, :mod:`.file`, :mod:`.wire`), the reader and its
checks (:mod:`.writer`'s ``open_session``, :mod:`.checks`, :mod:`.data`), the atomic outputs and free-space rules
shared by every command that writes a file (:mod:`.outputs`) and the repair of a file whose writer died
(:mod:`.superblock`, ``recover_session``).

It may import :mod:`analysis` only; it never imports the campaign, the commands or the GUI. Other code uses the
names below. They are imported when first asked for: the writer process (``python -m app.session``) imports this
package before :mod:`.file`, and needs NumPy and h5py only, not the reader, its checks and :mod:`analysis`.
"""
import importlib

_WHERE = {
    "check_control": "checks", "check_format": "checks", "check_run": "checks", "check_run_count": "checks",
    "displacement_distortion": "data", "measurements_from_session": "data",
    "LINES_PER_CHUNK": "file",
    "WRITE_ERRNOS": "outputs", "atomic_output": "outputs", "check_output": "outputs", "require_free_space": "outputs",
    "write_failure": "outputs",
    "RunData": "writer", "RunSpec": "writer", "Session": "writer", "SessionWriteError": "writer",
    "SessionWriter": "writer", "append_model_history": "writer", "needs_recovery": "writer", "open_session": "writer",
    "read_model_history": "writer", "recover_session": "writer",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
