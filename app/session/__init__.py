"""The session file: every measured line on the disk, readable by any HDF5 tool (docs/session-format.md).

It owns the writer process and its wire format (:mod:`.writer`, :mod:`.file`, :mod:`.wire`), the reader and its
checks (:mod:`.writer`'s ``open_session``, :mod:`.checks`, :mod:`.data`), the atomic outputs and free-space rules
shared by every command that writes a file (:mod:`.outputs`) and the repair of a file whose writer died
(:mod:`.superblock`, ``recover_session``).

It may import :mod:`analysis` only; it never imports the campaign, the commands or the GUI. Other code uses the
names below.
"""
from app.session.checks import check_format, check_run, check_run_count
from app.session.data import displacement_distortion, measurements_from_session
from app.session.file import LINES_PER_CHUNK
from app.session.outputs import WRITE_ERRNOS, atomic_output, check_output, require_free_space, write_failure
from app.session.writer import (RunData, RunSpec, Session, SessionWriteError, SessionWriter, append_model_history,
                                needs_recovery, open_session, read_model_history, recover_session)

__all__ = ["LINES_PER_CHUNK", "RunData", "RunSpec", "Session", "SessionWriteError", "SessionWriter",
           "WRITE_ERRNOS", "append_model_history", "atomic_output", "check_format", "check_output",
           "check_run", "check_run_count", "displacement_distortion", "measurements_from_session", "needs_recovery",
           "open_session", "read_model_history", "recover_session", "require_free_space", "write_failure"]
