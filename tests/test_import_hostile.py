"""Hostile input to `contactid import`: every value the analysis checks is checked at import, so an import never
stores what `analyze` would later refuse; cut or edited files are refused with one line naming the file, the
record or line and the field, exit status 2, and no session is written."""
import errno
from pathlib import Path

import h5py
import numpy as np
import pytest

from app.cli import main
from app.session.writer import RunSpec, SessionWriter
from paper_structure import PAPER_STRUCTURE
from realdata import UFF

RUN = "sine_0.8N_up"
M, K = np.diag([1.0, 2.0]), np.array([[200.0, -100.0], [-100.0, 200.0]])
FREQS = np.linspace(0.8, 3.2, 6)
REAL_UFF = sorted(str(p) for p in UFF.glob("*.uff"))
UNTAGGED = ["--dof", "1=x1", "--dof", "2=x2", "--force-amplitude", "0.8"]
MODEL = PAPER_STRUCTURE + """
[[element]]
name = "right"
dof = "x2"
laws = ["cubic"]
"""


def receptance(f):
    om = 2 * np.pi * f
    return np.linalg.inv(K - om ** 2 * M + 0.02j * om * K)[:, 1]


def write_session(path, force_amplitude=None, frf_std_scale=1e-4):
    """The paper's linear 2-DOF structure, 6 lines, with every per-line quantity an export carries."""
    force_amplitude = np.full(len(FREQS), 0.8) if force_amplitude is None else force_amplitude
    w = SessionWriter(path, software_version="test")
    extras = {"frf_std/x1": ("m/N", (), "f8"), "frf_std/x2": ("m/N", (), "f8"), "force_amplitude": ("N", (), "f8"),
              "distortion": ("1", (), "f8")}
    w.begin_run(RunSpec(RUN, "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0, ["force"], ["N"], extras))
    for f, force in zip(FREQS, force_amplitude):
        H = receptance(f)
        w.append_line(f, {"x1": H[0], "x2": H[1]}, {"frf_std/x1": frf_std_scale * abs(H[0]),
                                                    "frf_std/x2": frf_std_scale * abs(H[1]),
                                                    "force_amplitude": force, "distortion": 0.01})
    w.end_run("complete")
    w.close()


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """contactid's own export of the session, ASCII and binary."""
    folder = tmp_path_factory.mktemp("hostile")
    write_session(folder / "s.h5")
    assert main(["export", str(folder / "s.h5"), "--uff", str(folder / "a.uff"), "--one-file", "--ascii"]) == 0
    assert main(["export", str(folder / "s.h5"), "--uff", str(folder / "b.uff"), "--one-file"]) == 0
    return folder


def refused(capsys, args, *names) -> str:
    """The import exits 2 with one line naming ``names`` and writes no session."""
    out = Path(args[args.index("-o") + 1])
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("contactid: error: "), err
    for name in names:
        assert str(name) in err, err
    assert not out.exists()
    return err


def edited(exported, tmp_path, edit, name="e.uff", source="a.uff") -> Path:
    path = tmp_path / name
    path.write_bytes(edit((exported / source).read_bytes()))
    return path


def untag(data: bytes) -> bytes:
    """The same records as another system writes them: free-text id lines."""
    return data.replace(b"contactid run=", b"othersys run=")


def first(old: bytes, new: bytes):
    assert len(old) == len(new)
    return lambda data: data.replace(old, new, 1)


# ----------------------------------------------------------------------------- contactid's tags
@pytest.mark.parametrize("tag,replacement,message", [
    (b"force=0.8", b"force=nan", "force=nan is not a force amplitude > 0 N"),
    (b"force=0.8", b"force=-0.8", "force=-0.8 is not a force amplitude > 0 N"),
    (b"direction=up", b"direction=sideways", "direction=sideways is not one of up, down, none"),
])
def test_impossible_tags_are_refused_naming_record_and_id_line(exported, tmp_path, capsys, tag, replacement, message):
    path = edited(exported, tmp_path, lambda d: d.replace(tag, replacement))
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")], path, "record 2", "id4", message)


def test_a_run_name_that_is_a_path_is_stored_as_one_group(exported, tmp_path, capsys):
    path = edited(exported, tmp_path, lambda d: d.replace(f"run={RUN}".encode(), b"run=../../evil"))
    out = tmp_path / "o.h5"
    assert main(["import", str(path), "-o", str(out)]) == 0
    assert "stored as _.._evil" in capsys.readouterr().out
    with h5py.File(out, "r") as f:
        assert list(f["runs"]) == ["_.._evil"] and ".." not in f and "evil" not in f


FRF_ORDINATE = b"         8    1    0    0 Displacement         m                   "
FRF_DENOMINATOR = b"        13    0    1    0 Force                N                   "


@pytest.mark.parametrize("tagged", [True, False], ids=["tagged", "untagged"])
@pytest.mark.parametrize("old,new,field", [
    (FRF_ORDINATE, FRF_ORDINATE.replace(b"m                   ", b"furlong             "),
     "record 2: ordinate_axis_units_lab"),
    (FRF_DENOMINATOR, FRF_DENOMINATOR.replace(b"        13", b"         8"), "record 2: orddenom_spec_data_type"),
    (FRF_ORDINATE, FRF_ORDINATE.replace(b"         8", b"        13"), "record 2: ordinate_spec_data_type"),
])
def test_units_and_types_are_checked_with_or_without_contactids_tags(exported, tmp_path, capsys, tagged, old, new,
                                                                     field):
    path = edited(exported, tmp_path, lambda d: first(old, new)(d if tagged else untag(d)))
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")] + ([] if tagged else UNTAGGED), path, field)


def test_the_untagged_file_itself_imports(exported, tmp_path):
    path = edited(exported, tmp_path, untag)
    assert main(["import", str(path), "-o", str(tmp_path / "o.h5")] + UNTAGGED) == 0


def test_a_per_line_record_with_an_unknown_unit_is_refused(exported, tmp_path, capsys):
    # the frf_std records (5 and 6: after the two FRFs) carry the same axes as the FRFs
    def edit(data):
        head, _, tail = data.partition(b"quantity=frf_std")
        return head + b"quantity=frf_std" + tail.replace(FRF_ORDINATE, FRF_ORDINATE.replace(
            b"m                   ", b"furlong             "), 1)
    path = edited(exported, tmp_path, edit)
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")], path, "ordinate_axis_units_lab")


def test_negative_per_line_force_amplitudes_are_refused_at_import_and_at_analysis(tmp_path, capsys):
    session = tmp_path / "neg.h5"
    write_session(session, force_amplitude=np.array([0.8, 0.8, -0.8, 0.8, 0.8, 0.8]))
    (tmp_path / "m.toml").write_text(MODEL)
    assert main(["analyze", str(session), str(tmp_path / "m.toml"), "--no-history"]) == 2
    err = capsys.readouterr().err
    assert f"run {RUN}, dataset force_amplitude: line 2 is -0.8" in err and str(session) in err
    # export applies the checks analyze does: such a session is never passed on to another tool either
    assert main(["export", str(session), "--uff", str(tmp_path / "n.uff")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"run {RUN}, dataset force_amplitude: line 2 is -0.8" in err, err
    assert not (tmp_path / "n.uff").exists()


def test_a_non_finite_standard_deviation_is_named_with_file_run_and_line(tmp_path, capsys):
    session = tmp_path / "nan.h5"
    write_session(session, frf_std_scale=np.nan)
    (tmp_path / "m.toml").write_text(MODEL)
    assert main(["analyze", str(session), str(tmp_path / "m.toml"), "--no-history"]) == 2
    err = capsys.readouterr().err
    assert f"{session}: run {RUN}, dataset frf_std/x1: line 0 is nan" in err


# ----------------------------------------------------------------------------- files cut short
def cut(fraction):
    return lambda data: data[:int(len(data) * fraction)]


@pytest.mark.parametrize("source,fraction,message", [
    ("a.uff", 0.25, "cut short"), ("a.uff", 0.5, "cut short"), ("a.uff", 0.75, "cut short"),
    ("b.uff", 0.5, "cut short"), ("b.uff", 0.25, "cut short"),
])
def test_a_file_cut_short_is_refused(exported, tmp_path, capsys, source, fraction, message):
    path = edited(exported, tmp_path, cut(fraction), source=source)
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")], path, message)


@pytest.mark.parametrize("source", ["a.uff", "b.uff"])
def test_a_file_cut_at_a_record_boundary_is_refused_by_the_record_count(exported, tmp_path, capsys, source):
    data = (exported / source).read_bytes()
    blocks = data.split(b"    -1\n    -1\n")
    assert len(blocks) == 7                                 # header, 2 FRFs, 2 frf_std, force, distortion
    path = tmp_path / "c.uff"
    path.write_bytes(b"    -1\n    -1\n".join(blocks[:4]) + b"    -1\n")
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")], path, "3 of the 6 records")


@pytest.mark.parametrize("claimed", [b"         7", b" 600000000", b"        -1", b"         0"])
def test_a_record_header_claiming_another_number_of_points_is_refused(exported, tmp_path, capsys, claimed):
    path = edited(exported, tmp_path, first(b"         6         6         0",
                                            b"         6" + claimed + b"         0"))
    more = int(claimed) > 6                    # a header promising more than follows: the record is truncated
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")], path, "record 2: num_pts",
            f"the record is truncated: its header promises {int(claimed)} points but only 6 follow" if more else
            f"the header says {int(claimed)} points, the record holds 6")


@pytest.mark.parametrize("path", REAL_UFF, ids=[Path(p).name for p in REAL_UFF])
@pytest.mark.parametrize("fraction", [0.3, 0.6])
def test_real_files_cut_short_are_refused_with_one_line(tmp_path, capsys, path, fraction):
    source = Path(path).read_bytes()
    cut_file = tmp_path / Path(path).name
    cut_file.write_bytes(source[:int(len(source) * fraction)])
    refused(capsys, ["import", str(cut_file), "-o", str(tmp_path / "o.h5"), "--excitation", "x"] + UNTAGGED,
            cut_file)


@pytest.mark.parametrize("path", REAL_UFF, ids=[Path(p).name for p in REAL_UFF])
def test_whole_real_files_are_not_taken_for_cut_ones(path):
    from app.importers.uff import read_records
    from analysis import InputError

    try:
        read_records(path)
    except InputError as exc:
        assert "cut short" not in str(exc)


def test_the_real_files_are_there():
    assert len(REAL_UFF) >= 10


# ----------------------------------------------------------------------------- CSV and flags
CSV_HEADER = "frequency_hz,force_n,dof,re,im\n"


def csv_rows(force="0.8"):
    rows = []
    for dof, k in (("x1", 0), ("x2", 1)):
        for f in FREQS:
            H = receptance(f)[k]
            rows.append(f"{float(f)!r},{force},{dof},{float(H.real)!r},{float(H.imag)!r}\n")
    return rows


@pytest.mark.parametrize("force", ["0", "-0.8", "0.0"])
def test_a_csv_force_level_that_is_no_force_is_refused_naming_the_line(tmp_path, capsys, force):
    path = tmp_path / "c.csv"
    path.write_text(CSV_HEADER + "".join(csv_rows(force)))
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5"), "--excitation", "x2"], path,
            "line 2: force_n", "not a force amplitude > 0 N")


def test_a_csv_header_naming_a_column_twice_is_refused(tmp_path, capsys):
    path = tmp_path / "c.csv"
    path.write_text("frequency_hz,force_n,dof,re,im,re\n" + "".join(r.strip() + ",1.0\n" for r in csv_rows()))
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5"), "--excitation", "x2"], path,
            "line 1: header", "column re is named twice")


def test_digits_grouped_with_underscores_are_not_a_number(tmp_path, capsys):
    path = tmp_path / "c.csv"
    rows = csv_rows()
    rows[0] = "1_000," + rows[0].split(",", 1)[1]
    path.write_text(CSV_HEADER + "".join(rows))
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5"), "--excitation", "x2"], path,
            "line 2: frequency_hz", "'1_000' is not a number")


def test_a_csv_with_excels_utf8_bom_imports(tmp_path):
    path = tmp_path / "c.csv"
    path.write_bytes(b"\xef\xbb\xbf" + (CSV_HEADER + "".join(csv_rows())).encode())
    out = tmp_path / "o.h5"
    assert main(["import", str(path), "-o", str(out), "--excitation", "x2"]) == 0
    with h5py.File(out, "r") as f:
        assert f[f"runs/{RUN}/frequency"].shape == (6,)
        assert np.allclose(f[f"runs/{RUN}/frf/x1"][()], [receptance(x)[0] for x in FREQS])


@pytest.mark.parametrize("value", ["inf", "nan", "-inf", "0"])
def test_a_force_flag_that_is_no_force_is_refused(exported, tmp_path, capsys, value):
    refused(capsys, ["import", str(exported / "a.uff"), "-o", str(tmp_path / "o.h5"), f"--force-amplitude={value}"],
            "--force-amplitude")


@pytest.mark.parametrize("maps", [["1=x1", "1=x2"], ["1+Z=x1", "1+3=x2"]])
def test_conflicting_dof_maps_are_refused(exported, tmp_path, capsys, maps):
    args = ["import", str(edited(exported, tmp_path, untag)), "-o", str(tmp_path / "o.h5"), "--force-amplitude", "0.8"]
    for m in maps:
        args += ["--dof", m]
    refused(capsys, args, "--dof", "mapped twice")


# ----------------------------------------------------------------------------- writing the session
def test_an_existing_output_is_refused_naming_imports_own_flag(exported, tmp_path, capsys):
    existing = tmp_path / "o.h5"
    existing.write_bytes(b"kept")
    assert main(["import", str(exported / "a.uff"), "-o", str(existing)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(existing) in err and "pass --overwrite" in err and "--force" not in err
    assert existing.read_bytes() == b"kept"


@pytest.mark.slow
def test_the_free_space_wanted_is_estimated_from_the_data(tmp_path):
    from app.importers.runs import SourceOptions
    from app.importers.store import estimated_bytes, read_source

    freqs = np.linspace(1.0, 100.0, 3000)
    rows = [f"{float(f)!r},{level},{dof},1e-3,-2e-3,1e-6\n" for level in ("0.2", "0.4", "0.8") for dof in ("x1", "x2")
            for f in freqs]
    path = tmp_path / "big.csv"
    path.write_text("frequency_hz,force_n,dof,re,im,std\n" + "".join(rows))
    out = tmp_path / "big.h5"
    assert main(["import", str(path), "-o", str(out), "--excitation", "x2"]) == 0
    estimate, written = estimated_bytes([read_source(str(path), SourceOptions(excitation="x2"))]), out.stat().st_size
    assert written <= estimate <= 2 * written


def test_a_write_that_fails_on_a_full_disk_is_one_line_naming_the_session(exported, tmp_path, capsys, monkeypatch):
    import app.importers.store as store

    def full(*_):
        raise OSError(errno.ENOSPC, "Can't write data (file write failed: time = Thu\n, errno = 28, error message = "
                                    "'No space left on device')")
    monkeypatch.setattr(store, "_write_runs", full)
    out = tmp_path / "o.h5"
    refused(capsys, ["import", str(exported / "a.uff"), "-o", str(out)], out,
            "not written: No space left on device; no file was left")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- contactid's own CSV, edited
@pytest.mark.parametrize("old, new, names", [
    (b"force=0.8 ", b"force=-0.8 ", ["line 2", "force=-0.8 is not a number > 0"]),
    (b" excitation=x2", b"", ["line 2", "the run line has no excitation="]),
    (b"kind=stepped_sine", b"kind=sweep", ["line 2", "kind=sweep"]),
    (b",Im frf x2 [m/N]", b",Im frf x2", ["line 3: column", "'Im frf x2' is not 'name [unit]'"]),
    (b",Im frf x2 [m/N]", b",Imag frf x2 [m/N]", ["line 3", "frf x2 has Re but not both Re and Im"]),
    (b"\n0.8,", b"\n0.8x,", ["line 4: column 1", "'0.8x' is not a number"]),
])
def test_an_edited_csv_export_is_refused_naming_line_and_field(tmp_path, capsys, old, new, names):
    write_session(tmp_path / "s.h5")
    assert main(["export", str(tmp_path / "s.h5"), "--csv", str(tmp_path / "csv")]) == 0
    path = tmp_path / "csv" / f"{RUN}.csv"
    text = path.read_bytes()
    assert old in text
    path.write_bytes(text.replace(old, new, 1))
    refused(capsys, ["import", str(path), "-o", str(tmp_path / "o.h5")], path, *names)
