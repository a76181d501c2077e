"""Fuzz corpus: sessions edited, truncated and bit-flipped (made from a small simulated session), run against
every command that reads a session; a refusal is one line naming the file, exit 2, and no file changes."""
import hashlib
import io

import h5py
import numpy as np
import pytest

from conftest import MODEL
from fuzz_runner import Case, check, params, run_case

RUN = "runs/sine_0.8N_up"


def _attr(path, name, value):
    def edit(f):
        f[path].attrs[name] = value
    return edit


def _dataset(path, make):
    """Replace dataset ``path`` by ``make(old values)`` (None: remove it)."""
    def edit(f):
        old = f[path][()]
        del f[path]
        new = make(old)
        if new is not None:
            f.create_dataset(path, data=new)
    return edit


def _many_runs(count):
    def edit(f):
        del f[RUN]["raw"]
        for i in range(count):
            f.copy(f[RUN], f"runs/sine_{1 + i}N_up")
            f[f"runs/sine_{1 + i}N_up"].attrs["force"] = float(1 + i)
    return edit


EDITS = [
    ("format version from the future", _attr("/", "format_version", 99)),
    ("format version text", _attr("/", "format_version", "two")),
    ("run kind unknown", _attr(RUN, "kind", "swept")),
    ("run status unknown", _attr(RUN, "status", "done")),
    ("run direction sideways", _attr(RUN, "direction", "sideways")),
    ("run force negative", _attr(RUN, "force", -0.8)),
    ("run force NaN", _attr(RUN, "force", float("nan"))),
    ("run force text", _attr(RUN, "force", "heavy")),
    ("excitation dof empty", _attr(RUN, "excitation_dof", "")),
    ("sensor dofs not JSON", _attr(RUN, "sensor_dofs", "[x1, x2")),
    ("sensor dofs empty", _attr(RUN, "sensor_dofs", "[]")),
    ("sensor dofs repeated", _attr(RUN, "sensor_dofs", '["x1", "x1"]')),
    ("sensor dof without FRF", _attr(RUN, "sensor_dofs", '["x1", "x9"]')),
    ("frequencies all equal", _dataset(f"{RUN}/frequency", lambda f: np.full_like(f, f[0]))),
    ("frequency axis reversed", _dataset(f"{RUN}/frequency", lambda f: f[::-1].copy())),
    ("frequency NaN", _dataset(f"{RUN}/frequency", lambda f: np.where(np.arange(len(f)) == 2, np.nan, f))),
    ("frequency negative", _dataset(f"{RUN}/frequency", lambda f: -f)),
    ("frequencies absurd", _dataset(f"{RUN}/frequency", lambda f: f * 1e300)),
    ("frequencies tiny", _dataset(f"{RUN}/frequency", lambda f: f * 1e-300)),
    ("frequency 2-D", _dataset(f"{RUN}/frequency", lambda f: np.stack([f, f], axis=1))),
    ("frequency text", _dataset(f"{RUN}/frequency", lambda f: np.array([b"1 Hz"] * len(f)))),
    ("frequency missing", _dataset(f"{RUN}/frequency", lambda f: None)),
    ("FRF 2-D", _dataset(f"{RUN}/frf/x1", lambda h: np.stack([h, h], axis=1))),
    ("FRF real", _dataset(f"{RUN}/frf/x1", lambda h: h.real)),
    ("FRF NaN", _dataset(f"{RUN}/frf/x1", lambda h: h * np.nan)),
    ("FRF missing", _dataset(f"{RUN}/frf/x2", lambda h: None)),
    ("FRF one line more", _dataset(f"{RUN}/frf/x1", lambda h: np.append(h, h[-1]))),
    ("FRF one line less", _dataset(f"{RUN}/frf/x1", lambda h: h[:-1])),
    ("force amplitude 2-D", _dataset(f"{RUN}/force_amplitude", lambda a: np.stack([a, a], axis=1))),
    ("runs not a group", lambda f: (f.__delitem__("runs"), f.create_dataset("runs", data=1))),
    ("no runs", lambda f: f.__delitem__("runs")),
    ("thousands of runs", _many_runs(2000)),
]

COMMANDS = [("analyze", "{d}/s.h5", "{d}/model.toml", "--no-history"),
            ("export", "{d}/s.h5", "--csv", "{d}/csv"),
            ("export", "{d}/s.h5", "--uff", "{d}/s.uff")]


RECOVER = ("recover", "{d}/s.h5")


_EDITED: dict[tuple[int, bytes], bytes] = {}


def edited(edit):
    """The simulated session with ``edit`` applied (made when the case runs, once per edit and session: every
    command that reads a session gets the same bytes, and thousands of runs take seconds to write)."""
    def make(inputs) -> bytes:
        key = (id(edit), hashlib.sha256(inputs["session"]).digest())
        if key not in _EDITED:
            buffer = io.BytesIO(inputs["session"])
            with h5py.File(buffer, "r+") as f:
                edit(f)
            _EDITED[key] = buffer.getvalue()
        return _EDITED[key]
    return make


def truncated(fraction):
    return lambda inputs: inputs["session"][: int(len(inputs["session"]) * fraction)]


def flipped(position):
    """One bit flipped at ``position`` (0..1) of the file."""
    def make(inputs) -> bytes:
        data = bytearray(inputs["session"])
        data[int(position * (len(data) - 1))] ^= 0x10
        return bytes(data)
    return make


def cases():
    model = MODEL.encode()
    for name, edit in EDITS:
        for argv in COMMANDS:
            yield Case("session-edit", name, argv, {"s.h5": edited(edit), "model.toml": model}, names=("s.h5",))
        # recover leaves a session closed normally alone (exit 0) whatever it holds, or refuses it
        yield Case("session-edit", name, RECOVER, {"s.h5": edited(edit)}, statuses=(0, 2), names=("s.h5",))
    for fraction in (0.05, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99):
        yield Case("session-truncated", f"cut to {fraction:.0%}", RECOVER, {"s.h5": truncated(fraction)},
                   names=("s.h5",))
        for argv in COMMANDS:
            yield Case("session-truncated", f"cut to {fraction:.0%}", argv,
                       {"s.h5": truncated(fraction), "model.toml": model}, names=("s.h5",))
    # a flipped bit is refused where it breaks the file's structure or a dataset's checksum, and most land where
    # the command runs through (exit 0): the contract here is no traceback, no hang, no file changed
    for position in np.linspace(0, 1, 24):
        yield Case("session-bit-flip", f"bit 4 at {position:.3f} of the file", COMMANDS[0],
                   {"s.h5": flipped(position), "model.toml": model}, statuses=(0, 2), names=("s.h5",))


CASES = list(cases())


@pytest.mark.parametrize("case", params(CASES))
def test_a_damaged_session_is_refused_in_one_line_and_left_as_it_was(case, tmp_path, small_session):
    check(case, run_case(case, tmp_path, {"session": small_session}))
