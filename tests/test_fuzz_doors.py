"""Issue 54's hostile pass, kept as a corpus: malformed inputs at every door -- the CSV long format, UFF58 (binary
and ASCII, contactid's own tags and another system's records), plan and model TOML, session HDF5 -- each with
its verdict. The contract for every one: no traceback, no internal error (exit 1), a refusal is one line naming
the file (and where in it), exit status 2, and nothing in the folder changed -- above all nothing measured
lost. A few inputs are not faults (a BOM, CRLF line ends, a sign of a receptance): for them the verdict is the
documented result, checked by what was stored.

The corpus is generated here from valid inputs, mutated one way each; the next pass adds its cases to the lists
below. The cases run in process (``app.cli.main``), in one test per door, so that the whole file stays fast."""
from __future__ import annotations

import hashlib
import io
import re
import tempfile
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import h5py
import numpy as np
import pytest

from app.cli import main
from test_doors import FREQS, LIMITS, long_csv, write_session
from paper_structure import PAPER_STRUCTURE

MODEL = PAPER_STRUCTURE + '\n[[element]]\nname = "right"\ndof = "x2"\nlaws = ["cubic"]\n'
PLAN = ('[[stepped_sine]]\nforce = 0.8\nstart = 1.0\nstop = 1.2\nstep = 0.05\ndirection = "up"\n\n'
        + LIMITS)


@dataclass
class Hostile:
    """One malformed input: the file (name -> bytes, made from the valid inputs), the command reading it, and
    what must come of it."""

    name: str
    files: dict[str, Callable[[dict], bytes] | bytes]
    argv: tuple[str, ...]
    names: tuple[str, ...]                 # a refusal names all of these (file, field, line, record...)
    status: int = 2                        # 0: not a fault; the result is checked by ``accepted``
    accepted: Callable[[Path], None] | None = None


def _snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))}


def verdict(case: Hostile, folder: Path, inputs: dict) -> str | None:
    """Run ``case`` in ``folder``; None when it kept the contract, else what went wrong."""
    folder.mkdir()
    for name, content in case.files.items():
        (folder / name).write_bytes(content(inputs) if callable(content) else content)
    before = _snapshot(folder)
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            status = main([a.replace("{d}", str(folder)) for a in case.argv])
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else 2
    text = err.getvalue().strip()
    if len(text) > 600:
        return f"a message of {len(text)} characters: {text[:200]}..."
    if "Traceback" in text or "(run with --debug" in text:
        return f"crashed: {text}"
    if status != case.status:
        return f"exit {status}, expected {case.status}: {text}"
    if status == 2:
        if text.count("\n") or not text.startswith("contactid: error: "):
            return f"not one line: {text!r}"
        missing = [n for n in case.names if n not in text]
        if missing:
            return f"does not name {missing}: {text}"
        changed = sorted(k for k in before.keys() | _snapshot(folder).keys()
                         if before.get(k) != _snapshot(folder).get(k))
        if changed:
            return f"refused, but changed {changed}: {text}"
        return None
    try:
        if case.accepted is not None:
            case.accepted(folder)
    except AssertionError as exc:
        return f"accepted, but {exc}"
    return None


def _run_all(cases: list[Hostile], tmp_path: Path, inputs: dict) -> None:
    names = [c.name for c in cases]
    assert len(set(names)) == len(names), "two cases of one name"
    failures = [f"{c.name}: {v}" for i, c in enumerate(cases)
                if (v := verdict(c, tmp_path / f"case{i}", inputs)) is not None]
    assert not failures, "\n".join(failures)


# --------------------------------------------------------------------------- valid inputs
CSV_COLUMNS = ("std", "direction", "force_amplitude_n", "force_phase_rad", "status")


def _csv_text(folder: Path) -> str:
    """One 0.8 N level, x1 and x2 at FREQS (rows 2-31 x1, 32-61 x2), every optional force column given."""
    text = long_csv(folder / "base.csv", cells={"std": "1e-5", "direction": "up", "force_amplitude_n": "0.8",
                                                 "force_phase_rad": "0.1", "status": "complete"}).read_text()
    return text


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("doors-base")
    session = folder / "s.h5"
    write_session(session)
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["export", str(session), "--uff", str(folder / "b.uff"), "--one-file"]) == 0
    ascii_session = folder / "a.h5"
    import test_doors
    saved = test_doors.FREQS
    test_doors.FREQS = np.round(np.linspace(1.0, 3.5, 26), 6)     # lines the ASCII abscissa keeps exactly
    try:
        write_session(ascii_session)
    finally:
        test_doors.FREQS = saved
    with redirect_stdout(out):
        assert main(["export", str(ascii_session), "--uff", str(folder / "a.uff"), "--one-file", "--ascii"]) == 0
    return {"csv": _csv_text(folder), "session": session.read_bytes(), "binary_uff": (folder / "b.uff").read_bytes(),
            "ascii_uff": (folder / "a.uff").read_bytes()}


# --------------------------------------------------------------------------- CSV long format
CSV_ARGV = ("import", "{d}/c.csv", "-o", "{d}/s.h5", "--excitation", "x2")
COLUMNS = ("frequency_hz", "dof", "re", "im", "force_n", *CSV_COLUMNS)


def _cell(column: str, value: str, rows: slice | int = 5):
    """The CSV with ``column`` set to ``value`` on the data row(s) ``rows`` (file lines from 1; a slice of
    lines)."""
    k = COLUMNS.index(column)

    def make(inputs: dict) -> bytes:
        lines = inputs["csv"].splitlines()
        chosen = range(len(lines))[rows] if isinstance(rows, slice) else [rows - 1]
        for i in chosen:
            if i == 0:
                continue
            cells = lines[i].split(",")
            cells[k] = value
            lines[i] = ",".join(cells)
        return ("\n".join(lines) + "\n").encode()
    return make


def _lines(edit: Callable[[list[str]], list[str]]):
    return lambda inputs: ("\n".join(edit(inputs["csv"].splitlines())) + "\n").encode()


def _csv_stored(**expect):
    """The import's verdict for an input that is no fault: the run stored as the valid CSV gives it."""
    def check(folder: Path) -> None:
        with h5py.File(folder / "s.h5", "r") as f:
            (run,) = f["runs"].values()
            assert len(run["frequency"]) == expect.get("lines", len(FREQS)), "lines lost"
            assert run.attrs["status"] == expect.get("status", "complete"), run.attrs["status"]
    return check


CELL_FAULTS = {
    # column: values refused at one row (the line named: file line 5)
    "frequency_hz": ["nan", "inf", "-1", "0", "abc", "", "1e309", "1_0", "1e300", "1e-300", "0x10"],
    "re": ["nan", "inf", "abc", "", "1e309", "--1"],
    "im": ["nan", "-inf", "0x10", "1,0"],
    "std": ["nan", "-1", "abc", "inf"],
    "force_amplitude_n": ["nan", "-1", "0", "1e300", "abc", "1e-300"],
    "force_phase_rad": ["nan", "1e300", "100", "abc", "inf"],
    "direction": ["sideways", "UP", "1"],
    "status": ["exploded", "failed", "runing"],
    "dof": ["", "a/b", ".", "..", "x" * 5000, "x 1", "x1:y", "é"],
}
CSV_NAMES = {"im": ("c.csv", "line 5")}       # "1,0": one field more, named by its line
LEVEL_FAULTS = {   # column: values refused when every row holds them (a level)
    "force_n": ["nan", "-0.8", "0", "abc", "1e300", "1e-300", "", "inf"],
}


def csv_cases() -> list[Hostile]:
    cases = []
    for column, values in CELL_FAULTS.items():
        for value in values:
            names = CSV_NAMES.get(column, ("c.csv", f"line 5: {column}"))
            cases.append(Hostile(f"csv {column}={value[:20]!r}", {"c.csv": _cell(column, value)}, CSV_ARGV, names))
    for column, values in LEVEL_FAULTS.items():
        for value in values:
            cases.append(Hostile(f"csv level {column}={value!r}", {"c.csv": _cell(column, value, slice(1, None))},
                                 CSV_ARGV, ("c.csv", f"line 2: {column}")))
    header = "frequency_hz,dof,re,im,force_n," + ",".join(CSV_COLUMNS)
    structural = [
        ("empty file", b"", ("c.csv",)),
        ("header only", (header + "\n").encode(), ("c.csv", "line 1")),
        ("comments only", b"# nothing\n# here\n", ("c.csv", "no header")),
        ("binary garbage", bytes(range(256)) * 4, ("c.csv",)),
        ("not UTF-8", lambda i: i["csv"].encode().replace(b",x1,", b",x\xff1,", 3), ("c.csv", "0xff")),
        ("a DOF not ASCII", _lines(lambda r: r[:3] + [r[3].replace("x1", "x\xff1")] + r[4:]),
         ("c.csv", "line 4: dof")),
        ("NUL byte", _lines(lambda r: r[:3] + [r[3] + "\0"] + r[4:]), ("c.csv",)),
        ("column twice", _lines(lambda r: [r[0].replace("std", "re")] + r[1:]), ("c.csv", "line 1: header")),
        ("unknown column", _lines(lambda r: [r[0].replace("std", "sdt")] + r[1:]), ("c.csv", "line 1: header",
                                                                                      "unknown sdt")),
        ("column missing", _lines(lambda r: [x.split(",", 1)[1] for x in r]), ("c.csv", "missing frequency_hz")),
        ("row with a field more", _lines(lambda r: r[:6] + [r[6] + ",1"] + r[7:]), ("c.csv", "line 7")),
        ("row with a field less", _lines(lambda r: r[:6] + [r[6].rsplit(",", 1)[0]] + r[7:]), ("c.csv", "line 7")),
        ("a row of x1 missing", _lines(lambda r: r[:9] + r[10:]), ("c.csv", "dof x1 at 0.8 N has no row at")),
        ("a row twice", _lines(lambda r: r[:9] + [r[8]] + r[9:]), ("c.csv", "line 10: frequency_hz", "on line 9")),
        ("a row out of order", _lines(lambda r: r[:5] + [r[6], r[5]] + r[7:]), ("c.csv", "line 7: frequency_hz")),
        ("a row splitting the level", _lines(lambda r: r[:12] + [r[12].replace(",0.8,", ",0.9,", 1)] + r[13:]),
         ("c.csv", "line 13: force_n", "holds level 0.9 N")),
        ("a row of another direction", _lines(lambda r: r[:12] + [r[12].replace(",up,", ",down,")] + r[13:]),
         ("c.csv", "line 13: direction")),
        ("a DOF with spaces beside itself", _lines(lambda r: r + [x.replace(",x1,", ", x1 ,") for x in r[1:31]]),
         ("c.csv", "line 62: frequency_hz", "on line 2 already")),
        ("one force two ways on a line", _lines(lambda r: r[:40] + [r[40].replace(",0.8,0.1,", ",0.7,0.1,")]
                                                + r[41:]), ("c.csv", "line 41: force_amplitude_n", "(line 11)")),
        ("a control target without quantity", _lines(
            lambda r: [r[0] + ",control_target"] + [x + ",5.0" for x in r[1:]]), ("c.csv", "line 2: force_n")),
        ("a control quantity without target", _lines(
            lambda r: [r[0] + ",control_quantity"] + [x + ",velocity" for x in r[1:]]),
         ("c.csv", "line 2: control_quantity", "give control_target")),
        ("a response held where nothing measures", _lines(
            lambda r: [r[0] + ",control_target,control_quantity,control_dof"]
            + [x.replace(",0.8,1e-5", ",,1e-5") + ",5.0,acceleration,x9" for x in r[1:]]),
         ("c.csv", "line 2: control_dof", "x9")),
        ("a response quantity no one holds", _lines(
            lambda r: [r[0] + ",control_target,control_quantity,control_dof"]
            + [x.replace(",0.8,1e-5", ",,1e-5") + ",5.0,jerk,x2" for x in r[1:]]), ("c.csv", "control_quantity")),
        ("a very long cell", _lines(lambda r: r[:4] + [r[4].replace("x1", "x" * 1_000_000)] + r[5:]), ("c.csv",)),
    ]
    for name, content, names in structural:
        cases.append(Hostile(f"csv {name}", {"c.csv": content}, CSV_ARGV, names or ("c.csv",)))
    not_faults = [
        ("a BOM", lambda i: b"\xef\xbb\xbf" + i["csv"].encode(), _csv_stored()),
        ("CRLF line ends", lambda i: i["csv"].replace("\n", "\r\n").encode(), _csv_stored()),
        ("blank lines between rows", _lines(lambda r: r[:10] + ["", ","*9] + r[10:]), _csv_stored()),
        ("status empty on every row", _cell("status", "", slice(1, None)), _csv_stored()),
        ("status failed on every row", _cell("status", "failed", slice(1, None)), _csv_stored(status="failed")),
        ("negative real parts", _cell("re", "-0.001"), _csv_stored()),
        ("std 0 at a line (no scatter: >= 0, the session's rule)", _cell("std", "0"), _csv_stored()),
    ]
    for name, content, check in not_faults:
        cases.append(Hostile(f"csv {name}", {"c.csv": content}, CSV_ARGV, (), 0, check))
    return cases


@pytest.mark.slow
def test_the_csv_door_refuses_every_malformed_input_in_one_line(tmp_path, inputs):
    _run_all(csv_cases(), tmp_path, inputs)


# --------------------------------------------------------------------------- UFF58
UFF_ARGV = ("import", "{d}/u.uff", "-o", "{d}/s.h5")


def _uff(kind: str, edit: Callable[[bytes], bytes]):
    return lambda inputs: edit(inputs[kind])


def _cut(fraction: float):
    return lambda data: data[: int(len(data) * fraction)]


def _sub(old: bytes, new: bytes, count: int = 0):
    """Replace ``old`` by ``new`` (padded to its length where shorter: a binary record's header keeps its
    offsets); ``count`` 0: every one, else the first ``count``."""
    def edit(data: bytes) -> bytes:
        assert old in data, old
        return data.replace(old, new.ljust(len(old)) if len(new) < len(old) else new, count or -1)
    return edit


def _ascii_value(line: int, column: int, text: bytes):
    """The ASCII file with one number of a data line (of the first FRF record) replaced by ``text``."""
    def edit(data: bytes) -> bytes:
        lines = data.split(b"\n")
        first = next(i for i, x in enumerate(lines) if x.startswith(b"         0    0    0    0 NONE")) + 1
        row = lines[first + line]
        widths = [(0, 13), (13, 33), (33, 53)][column]
        lines[first + line] = row[:widths[0]] + text.rjust(widths[1] - widths[0]) + row[widths[1]:]
        return b"\n".join(lines)
    return edit


def _uff_stored(name: str):
    """The verdict for a run name that is no group name: stored under one, with a note (docs/import.md)."""
    def check(folder: Path) -> None:
        with h5py.File(folder / "s.h5", "r") as f:
            assert list(f["runs"]) == [name], list(f["runs"])
            assert len(f["runs"][name]["frequency"]) in (len(FREQS), 26)
    return check


def uff_cases() -> list[Hostile]:
    cases = []
    for kind in ("binary_uff", "ascii_uff"):
        short = kind.split("_")[0]
        for fraction in (0.02, 0.1, 0.25, 0.4, 0.5, 0.6, 0.75, 0.9, 0.99):
            cases.append(Hostile(f"uff {short} cut at {fraction:.0%}", {"u.uff": _uff(kind, _cut(fraction))},
                                 UFF_ARGV, ("u.uff",)))
        tags = [
            ("status=exploded", _sub(b"status=complete", b"status=exploded", 1), ("u.uff", "status")),
            ("status=exploded everywhere", _sub(b"status=complete", b"status=exploded"), ("u.uff", "exploded")),
            ("target= disagreeing", _sub(b"force=0.8 ", b"force=0.9 ", 1), ("u.uff",)),
            ("kind unknown", _sub(b"kind=stepped_sine", b"kind=stepped_sin2"), ("u.uff", "stepped_sin2")),
            ("force nan", _sub(b"force=0.8 ", b"force=nan "), ("u.uff", "force")),
            ("force negative", _sub(b"force=0.8 ", b"force=-.8 "), ("u.uff", "force")),
            ("force 1e9", _sub(b"force=0.8 ", b"force=1e9 "), ("u.uff", "id4", "outside the forces")),
            ("direction unknown", _sub(b"direction=up", b"direction=no"), ("u.uff", "direction")),
            ("records stated wrong", _sub(b"records=6", b"records=7"), ("u.uff", "records=")),
            ("quantity unknown", _sub(b"quantity=force_phase", b"quantity=force_phaze", 1), ("u.uff", "force_phaze")),
            ("convention reversed", _sub(b"convention=exp(+jwt)", b"convention=exp(-jwt)", 1), ("u.uff",)),
            ("no dataset 58 left", _sub(b"\n    58", b"\n    59"), ("u.uff",)),
        ]
        for name, edit, names in tags:
            cases.append(Hostile(f"uff {short} {name}", {"u.uff": _uff(kind, edit)}, UFF_ARGV, names))
        renamed = Hostile(f"uff {short} run name with a slash", {"u.uff": _uff(kind, _sub(
            b"run=sine_0.8N_up", b"run=sine/0.8N_up"))}, UFF_ARGV, (), 0, _uff_stored("sine_0.8N_up"))
        cases += [
            renamed,
            Hostile(f"uff {short} empty", {"u.uff": b""}, UFF_ARGV, ("u.uff",)),
            Hostile(f"uff {short} text", {"u.uff": b"hello\nworld\n"}, UFF_ARGV, ("u.uff",)),
            Hostile(f"uff {short} only delimiters", {"u.uff": b"    -1\n    -1\n" * 3}, UFF_ARGV, ("u.uff",)),
            Hostile(f"uff {short} a CSV named .uff", {"u.uff": lambda i: i["csv"].encode()}, UFF_ARGV, ("u.uff",)),
        ]
    ascii_values = [("nan", 0, 1, b"nan"), ("inf", 3, 2, b"inf"), ("1e999", 4, 1, b"1e999"),
                    ("text", 5, 1, b"abc"), ("negative frequency", 2, 0, b"-1.20000e+00"),
                    ("frequency out of order", 6, 0, b"1.00000e+00"), ("empty number", 7, 1, b"")]
    for name, line, column, text in ascii_values:
        cases.append(Hostile(f"uff ascii data {name}", {"u.uff": _uff("ascii_uff", _ascii_value(line, column, text))},
                             UFF_ARGV, ("u.uff",)))
    cases += [
        Hostile("uff ascii func_type 9 (PSD)", {"u.uff": _uff("ascii_uff", lambda d: re.sub(
            rb"\n    4( +0 +0 +1 )", rb"\n    9\1", d))}, UFF_ARGV, ("u.uff",)),
        Hostile("uff ascii num_pts larger", {"u.uff": _uff("ascii_uff", _sub(b"        26         0", b"        27         0",
                                                                             1))}, UFF_ARGV, ("u.uff",)),
        Hostile("uff ascii num_pts smaller", {"u.uff": _uff("ascii_uff", _sub(b"        26         0",
                                                                              b"        25         0", 1))},
                UFF_ARGV, ("u.uff",)),
        Hostile("uff ascii a record the file has not", {"u.uff": _uff("ascii_uff", lambda d: d)},
                ("import", "{d}/u.uff", "-o", "{d}/s.h5", "--kind", "sine", "--records", "99"),
                ("u.uff", "--records")),
    ]
    return cases


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")   # pyuff, reading an inf
@pytest.mark.slow
def test_the_uff_door_refuses_every_malformed_input_in_one_line(tmp_path, inputs):
    _run_all(uff_cases(), tmp_path, inputs)


# --------------------------------------------------------------------------- plan and model TOML
PLAN_ARGV = ("simulate", "paper-2dof", "{d}/p.toml", "-o", "{d}/o.h5", "--quiet")
MODEL_ARGV = ("modes", "{d}/m.toml")


def _toml(text: str, old: str, new: str) -> bytes:
    assert old in text, old
    return text.replace(old, new, 1).encode()


PLAN_FAULTS = [
    ("force text", "force = 0.8", 'force = "0.8"', "[[stepped_sine]][0].force"),
    ("force nan", "force = 0.8", "force = nan", "[[stepped_sine]][0].force"),
    ("force inf", "force = 0.8", "force = inf", "[[stepped_sine]][0].force"),
    ("force negative", "force = 0.8", "force = -0.8", "[[stepped_sine]][0].force"),
    ("force 1e300", "force = 0.8", "force = 1e300", "[[stepped_sine]][0].force"),
    ("force 1e-12", "force = 0.8", "force = 1e-12", "[[stepped_sine]][0].force"),
    ("force above the limit", "force = 0.8", "force = 8.0", "[[stepped_sine]][0].force"),
    ("start above stop", "start = 1.0", "start = 1.5", "[[stepped_sine]][0]"),
    ("step zero", "step = 0.05", "step = 0.0", "[[stepped_sine]][0].step"),
    ("step negative", "step = 0.05", "step = -0.05", "[[stepped_sine]][0].step"),
    ("a billion lines", "step = 0.05", "step = 1e-10", "[[stepped_sine]][0]"),
    ("direction unknown", 'direction = "up"', 'direction = "sideways"', "[[stepped_sine]][0].direction"),
    ("unknown key", "step = 0.05", "step = 0.05\nstpe = 1", "stpe"),
    ("response 1e300", "force = 0.8", 'response = 1e300\nquantity = "acceleration"\ndof = "x2"',
     "[[stepped_sine]][0].response"),
    ("response with a force", "force = 0.8", 'force = 0.8\nresponse = 1.0\nquantity = "acceleration"\ndof = "x2"',
     "[[stepped_sine]][0]"),
    ("response quantity unknown", "force = 0.8", 'response = 1.0\nquantity = "jerk"\ndof = "x2"',
     "[[stepped_sine]][0].quantity"),
    ("response dof not a name", "force = 0.8", 'response = 1.0\nquantity = "acceleration"\ndof = "a/b"',
     "[[stepped_sine]][0].dof"),
    ("quantity without a response", "force = 0.8", 'force = 0.8\nquantity = "velocity"',
     "[[stepped_sine]][0]"),
    ("limits text", "max_force = 5.0", 'max_force = "5"', "[limits].max_force"),
    ("limits negative", "max_force = 5.0", "max_force = -5.0", "[limits].max_force"),
    ("not TOML", "[[stepped_sine]]", "[[stepped_sine]", "p.toml"),
    ("phase resonance 1e-12", "[[stepped_sine]]",
     '[[phase_resonance]]\ndof = "x2"\nforces = [1e-12]\nstart = 1.5\n\n[[stepped_sine]]',
     "[[phase_resonance]][0].forces"),
    ("phase resonance dof not a name", "[[stepped_sine]]",
     '[[phase_resonance]]\ndof = "."\nforces = [0.1]\nstart = 1.5\n\n[[stepped_sine]]', "[[phase_resonance]][0].dof"),
]
MODEL_FAULTS = [
    ("mass text", "mass = [[1.0, 0.0], [0.0, 2.0]]", 'mass = "heavy"', "[structure].mass"),
    ("mass negative", "mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[-1.0, 0.0], [0.0, 2.0]]", "[structure].mass"),
    ("mass nan", "mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[nan, 0.0], [0.0, 2.0]]", "[structure].mass"),
    ("mass ragged", "mass = [[1.0, 0.0], [0.0, 2.0]]", "mass = [[1.0], [0.0, 2.0]]", "[structure].mass"),
    ("stiffness inf", "stiffness = [[200.0, -100.0]", "stiffness = [[inf, -100.0]", "[structure].stiffness"),
    ("stiffness wrong size", "stiffness = [[200.0, -100.0], [-100.0, 200.0]]", "stiffness = [[200.0]]",
     "[structure].stiffness"),
    ("dofs twice", 'dofs = ["x1", "x2"]', 'dofs = ["x1", "x1"]', "[structure].dofs"),
    ("dof not a name", 'dofs = ["x1", "x2"]', 'dofs = ["x1", "a/b"]', "[structure].dofs"),
    ("type unknown", 'type = "lumped"', 'type = "lumpy"', "[structure].type"),
    ("law twice", 'laws = ["cubic"]', 'laws = ["cubic", "cubic"]', "[[element]][0].laws[1].law"),
    ("law unknown", 'laws = ["cubic"]', 'laws = ["cubist"]', "cubist"),
    ("law value text", 'laws = ["cubic"]', 'laws = [{ law = "cubic", k3 = "-750" }]', "k3"),
    ("element at a DOF not in the structure", 'dof = "x2"', 'dof = "x9"', "x9"),
    ("element twice", '[[element]]\nname = "right"', '[[element]]\nname = "right"\ndof = "x1"\n\n'
                                                     '[[element]]\nname = "right"', "right"),
    ("updating path to nothing", "[[element]]", '[updating]\nparameters = ["springs[7].k"]\n\n[[element]]',
     "[updating].parameters"),
    ("updating modes beyond the structure", "[[element]]",
     '[updating]\nparameters = ["stiffness[0][0]"]\nmodes = [3]\n\n[[element]]', "[updating].modes"),
    ("updating modes twice", "[[element]]",
     '[updating]\nparameters = ["stiffness[0][0]"]\nmodes = [1, 1]\n\n[[element]]', "[updating].modes"),
    ("updating modes fewer than parameters", "[[element]]",
     '[updating]\nparameters = ["stiffness[0][0]", "mass[1][1]"]\nmodes = [1]\n\n[[element]]', "[updating].modes"),
    ("updating modes text", "[[element]]", '[updating]\nparameters = ["stiffness[0][0]"]\nmodes = ["1"]\n\n'
                                           '[[element]]', "[updating].modes"),
    ("unknown table", "[[element]]", "[elements]\nx = 1\n\n[[element]]", "elements"),
    ("not UTF-8", "[structure]", "[structure]\n# \udcff", "m.toml"),
]
MODAL = ('[structure]\ntype = "modal"\ndofs = ["x2"]\nfrequencies = [1.2]\ndamping = [0.01]\nshapes = [[0.7]]\n\n'
         '[[element]]\nname = "joint"\ndof = "x2"\nlaws = ["cubic"]\n')
MODAL_FAULTS = [
    ("modal frequency 1e300", "frequencies = [1.2]", "frequencies = [1e300]", "[structure].frequencies"),
    ("modal frequency negative", "frequencies = [1.2]", "frequencies = [-1.2]", "[structure].frequencies"),
    ("modal damping negative", "damping = [0.01]", "damping = [-0.01]", "[structure].damping"),
    ("modal shapes 1e200", "shapes = [[0.7]]", "shapes = [[1e200]]", "[structure].shapes"),
    ("modal shapes zero", "shapes = [[0.7]]", "shapes = [[0.0]]", "[structure].shapes"),
    ("modal frequencies too many", "frequencies = [1.2]", "frequencies = [1.2, 2.0]", "[structure].frequencies"),
]


def _encoded(text: str) -> bytes:
    return text.encode("utf-8", "surrogateescape")


def toml_cases() -> list[Hostile]:
    cases = [Hostile(f"plan {name}", {"p.toml": _encoded(PLAN.replace(old, new, 1))}, PLAN_ARGV, ("p.toml", where))
             for name, old, new, where in PLAN_FAULTS]
    cases += [Hostile(f"model {name}", {"m.toml": _encoded(MODEL.replace(old, new, 1))}, MODEL_ARGV,
                      ("m.toml", where)) for name, old, new, where in MODEL_FAULTS]
    cases += [Hostile(f"model {name}", {"m.toml": _encoded(MODAL.replace(old, new, 1))}, MODEL_ARGV,
                      ("m.toml", where)) for name, old, new, where in MODAL_FAULTS]
    assert all(old in (PLAN if c.name.startswith("plan") else MODEL) for c, (_, old, _, _) in
               zip(cases, PLAN_FAULTS + MODEL_FAULTS))
    return cases


def test_the_plan_and_model_doors_refuse_every_malformed_input_in_one_line(tmp_path, inputs):
    _run_all(toml_cases(), tmp_path, inputs)


# --------------------------------------------------------------------------- session HDF5
EXPORT_ARGV = ("export", "{d}/s.h5", "--csv-long", "{d}/l.csv")
RECOVER_ARGV = ("recover", "{d}/s.h5")
RUN = "runs/sine_0.8N_up"


def _h5(edit: Callable[[h5py.File], None]):
    """The valid session with ``edit`` made to it through h5py."""
    def make(inputs: dict) -> bytes:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "s.h5"
            path.write_bytes(inputs["session"])
            with h5py.File(path, "r+") as f:
                edit(f)
            return path.read_bytes()
    return make


def _attr(where: str, key: str, value):
    def edit(f: h5py.File) -> None:
        f[where].attrs[key] = value
    return edit


def _set(dataset: str, line: int, value):
    def edit(f: h5py.File) -> None:
        f[f"{RUN}/{dataset}"][line] = value
    return edit


def _delete(where: str):
    def edit(f: h5py.File) -> None:
        del f[where]
    return edit


def _replace(dataset: str, values):
    def edit(f: h5py.File) -> None:
        del f[f"{RUN}/{dataset}"]
        f[RUN].create_dataset(dataset, data=values)
    return edit


def _session_bytes(edit: Callable[[bytes], bytes]):
    return lambda inputs: edit(inputs["session"])


def _chunk_flip(dataset: str):
    """One byte of the first stored chunk of ``dataset`` flipped: its checksum fails."""
    def make(inputs: dict) -> bytes:
        with h5py.File(io.BytesIO(inputs["session"]), "r") as f:
            offset = f[f"{RUN}/{dataset}"].id.get_chunk_info(0).byte_offset
        data = bytearray(inputs["session"])
        data[offset + 3] ^= 0xFF
        return bytes(data)
    return make


SESSION_EDITS = [
    ("force nan", _attr(RUN, "force", float("nan")), "force"),
    ("force 1e300", _attr(RUN, "force", 1e300), "force"),
    ("force negative", _attr(RUN, "force", -0.8), "force"),
    ("force text", _attr(RUN, "force", "0.8 N"), "force"),
    ("status exploded", _attr(RUN, "status", "exploded"), "status"),
    ("kind unknown", _attr(RUN, "kind", "chirp"), "kind"),
    ("direction unknown", _attr(RUN, "direction", "sideways"), "direction"),
    ("sensor_dofs not JSON", _attr(RUN, "sensor_dofs", "[x1, x2"), "sensor_dofs"),
    ("sensor_dofs not a name", _attr(RUN, "sensor_dofs", '["x1", "a/b"]'), "sensor_dofs"),
    ("excitation_dof missing", lambda f: f[RUN].attrs.__delitem__("excitation_dof"), "excitation_dof"),
    ("control_dof not measured", lambda f: f[RUN].attrs.update(
        {"control": "response", "control_dof": "x9", "control_quantity": "acceleration", "control_target": 5.0,
         "control_units": "m/s^2"}), "control_dof"),
    ("frequency nan", _set("frequency", 4, np.nan), "frequency"),
    ("frequency negative", _set("frequency", 0, -1.0), "frequency"),
    ("frequency out of order", _set("frequency", 4, 9.0), "frequency"),
    ("frf inf", _set("frf/x1", 2, np.inf), "frf/x1"),
    ("force_phase 1e300", _set("force_phase", 3, 1e300), "force_phase"),
    ("force_amplitude negative", _set("force_amplitude", 3, -1.0), "force_amplitude"),
    ("frf_std negative", _set("frf_std/x2", 3, -1.0), "frf_std/x2"),
    ("frf missing", _delete(f"{RUN}/frf/x1"), "x1"),
    ("frf short", _replace("frf/x2", np.ones(3, complex)), "frf/x2"),
    ("frequency text", _replace("frequency", np.array([b"a"] * 30)), "frequency"),
    ("runs not a group", lambda f: (f.__delitem__("runs"), f.create_dataset("runs", data=1)), "runs"),
    ("format wrong", _attr("/", "format", "not-contactid"), "format"),
    ("format_version from the future", _attr("/", "format_version", 999), "format_version"),
]


def session_cases() -> list[Hostile]:
    cases = [Hostile(f"session {name}", {"s.h5": _h5(edit)}, EXPORT_ARGV, ("s.h5", where))
             for name, edit, where in SESSION_EDITS]
    for fraction in (0.0, 0.01, 0.3, 0.6, 0.95):
        cut = _session_bytes(lambda d, x=fraction: d[: int(len(d) * x)])
        cases.append(Hostile(f"session cut at {fraction:.0%}", {"s.h5": cut}, EXPORT_ARGV, ("s.h5",)))
        cases.append(Hostile(f"session cut at {fraction:.0%} recovered", {"s.h5": cut}, RECOVER_ARGV, ("s.h5",)))
    for dataset in ("frf/x1", "frequency", "force_phase"):
        cases.append(Hostile(f"session chunk of {dataset} flipped", {"s.h5": _chunk_flip(dataset)}, EXPORT_ARGV,
                             ("s.h5", dataset)))
        cases.append(Hostile(f"session chunk of {dataset} flipped, recovered", {"s.h5": _chunk_flip(dataset)},
                             RECOVER_ARGV, ("s.h5", "checksum", dataset)))
    cases += [
        Hostile("session is text", {"s.h5": b"not a session\n"}, EXPORT_ARGV, ("s.h5",)),
        Hostile("session is a plan", {"s.h5": PLAN.encode()}, RECOVER_ARGV, ("s.h5",)),
        Hostile("session of HDF5 not contactid's", {"s.h5": lambda i: _empty_hdf5()}, EXPORT_ARGV, ("s.h5",)),
    ]
    return cases


def _empty_hdf5() -> bytes:
    """An HDF5 file that is no session: one dataset, no contactid attribute."""
    data = io.BytesIO()
    with h5py.File(data, "w") as f:
        f.create_dataset("x", data=np.arange(3))
    return data.getvalue()


@pytest.mark.slow
def test_the_session_door_refuses_every_malformed_input_in_one_line(tmp_path, inputs):
    _run_all(session_cases(), tmp_path, inputs)


def test_the_corpus_is_a_pass_of_at_least_150_inputs():
    """The issue's measure of a hostile pass: 150 inputs or more over import, export, plans, models and
    recover."""
    assert len(csv_cases()) + len(uff_cases()) + len(toml_cases()) + len(session_cases()) >= 150
