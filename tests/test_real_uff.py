"""Other systems' real UFF files (tests/data/uff, its README.md): each imports or is refused with one
line naming the file, the record and the field (exit 2). What imports is checked against an independent reading
of the numbers (the text files the FRFs were written from); what is refused is refused for the reason the raw
text of the file shows."""
import re
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from app.session import open_session
from realdata import UFF

REAL = UFF
ROVING = REAL / "measurement_FRF_from_meas_point_txt.uff"

# file -> (fragments the one-line refusal must hold: the record and field, then the reason)
REFUSED = {
    "MPSTD_Set001_2024_10_08_10_27_07.uff": ("record 1: ordinate_spec_data_type", "no force channel",
                                             "record 4: acceleration (12)"),
    "MPSTD_Set001_2024_10_08_10_27_07_fixed_test.uff": ("record 1: ordinate_spec_data_type", "no force channel"),
    "Sample_UFF58_ascii.uff": ("record 1: ordinate_spec_data_type", "no force channel", "sound pressure (21)"),
    "Sample_UFF58b_bin.uff": ("record 1: ordinate_spec_data_type", "no force channel", "sound pressure (21)"),
    "TestLab_161_164_18_15_82_no58.uff": ("holds no dataset 58 record", "151, 164, 18, 15, 82"),
    "binary8byte.uff": ("record 1: ordinate_spec_data_type", "no force channel", "acceleration (12)"),
    "dataset_milestone_in_header.uff": ("record 1: num_pts", "truncated", "promises 2508876 points"),
    "measurement_FRF_from_meas_point_txt.uff": ("record 2: ref_node", "3 different references", "roving-hammer",
                                                "--records 1"),
    "non_ascii_header.uff": ("record 1: ordinate_spec_data_type", "type 1 (general) is not displacement"),
    "sample_dataset58_psd.uff": ("record 1: func_type", "function type 9 is a power spectral density (PSD)"),
    "time-history-not-all-columns-filled.uff": ("record 1: ordinate_spec_data_type", "no force channel",
                                                "general (1)"),
}
FLAGS = ["--force-amplitude", "1", "--dof", "1=x1", "--excitation", "x1"]


def one_line_error(capsys, args) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("contactid: error: "), err
    assert "Traceback" not in err
    return err


def test_every_real_file_is_in_the_table():
    assert sorted(p.name for p in REAL.glob("*.uff")) == sorted(REFUSED)


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_a_real_file_is_refused_naming_file_record_field_and_reason(name, tmp_path, capsys):
    out = tmp_path / "s.h5"
    err = one_line_error(capsys, ["import", str(REAL / name), "-o", str(out), *FLAGS])
    for fragment in (str(REAL / name), *REFUSED[name]):
        assert fragment in err, err
    assert not out.exists()


def _header_lines(path: Path) -> list[str]:
    """The raw text of the first dataset 58's eleven header lines (after its '-1' and '58' lines)."""
    lines = path.read_bytes().decode("latin-1").splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "58") + 1
    return lines[start:start + 11]


def _data_values(path: Path) -> list[float]:
    """Every number after the header of the file's only dataset 58, up to its closing -1, read as text."""
    lines = path.read_bytes().decode("latin-1").splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "58") + 12
    end = next(i for i in range(start, len(lines)) if lines[i].strip() == "-1")
    return [float(v) for line in lines[start:end] for v in line.split()]


def test_the_reasons_are_those_the_raw_text_shows():
    """Read without pyuff: record 6 (function type) and record 7 (number of points) of the header lines."""
    psd = _header_lines(REAL / "sample_dataset58_psd.uff")
    assert int(psd[5].split()[0]) == 9                                   # record 6, field 1: PSD
    truncated = REAL / "dataset_milestone_in_header.uff"
    assert int(_header_lines(truncated)[6].split()[1]) == 2508876        # record 7, field 2: points promised
    assert len(_data_values(truncated)) < 100                            # ... and one line of them follows


def test_a_partial_last_line_is_read_whole():
    """The HBM catman file's last data line holds one value: all 13 are read, equal to the raw text."""
    from app.importers.uff import read_records

    path = REAL / "time-history-not-all-columns-filled.uff"
    [record], _, _ = read_records(str(path))
    raw = _data_values(path)
    assert len(raw) == 13 and int(_header_lines(path)[6].split()[1]) == 13
    np.testing.assert_allclose(record.fields["data"], raw, rtol=1e-6)


def _meas_point(k: int) -> np.ndarray:
    """meas_point_<k>.txt: one '(re+imj)' per line, parsed as text (never evaluated)."""
    number = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
    pattern = re.compile(rf"^\(?({number})({number})j\)?$")
    values = []
    for line in (REAL / f"meas_point_{k}.txt").read_text().split():
        re_, im = pattern.match(line).groups()
        values.append(complex(float(re_), float(im)))
    return np.array(values)


@pytest.mark.parametrize("reference", [1, 2, 3])
def test_one_reference_of_the_roving_hammer_file_imports_with_records(reference, tmp_path, capsys):
    """--records picks the FRF of one reference; the receptance stored is the accelerance of the text file over
    -(2 pi f)^2, at 1 Hz lines (0 Hz left out), with the reference's node as the excitation."""
    out = tmp_path / "s.h5"
    args = ["import", str(ROVING), "-o", str(out), "--records", str(reference), "--force-amplitude", "1",
            "--dof", "1+X=x1", "--dof", f"{reference}+X=h{reference}" if reference != 1 else "1+X=x1"]
    sign = 1.0
    if reference == 1:
        # the drive point: its Im says the force's sign is reversed against exp(+jwt); refused until the flag
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "(drive point)" in err and "give --force-sign -1" in err
        args, sign = args + ["--force-sign", "-1"], -1.0
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "left out (--records)" in printed and "SI assumed" in printed and "0 Hz is left out" in printed
    accelerance = _meas_point(reference)
    with open_session(out) as s:
        [name] = s.run_names()
        run = s.run(name)
        assert run.excitation_dof == ("x1" if reference == 1 else f"h{reference}")
        f = run.frequency
        np.testing.assert_array_equal(f, np.arange(1.0, 1001.0))
        np.testing.assert_allclose(sign * run.frf["x1"] * -(2 * np.pi * f) ** 2, accelerance[1:], rtol=1e-9,
                                   atol=1e-15)


def test_records_of_two_references_are_refused_again_and_unknown_records_named(tmp_path, capsys):
    args = ["import", str(ROVING), "-o", str(tmp_path / "s.h5"), *FLAGS]
    err = one_line_error(capsys, args + ["--records", "1,3"])
    assert "record 3: ref_node: the FRFs have 2 different references" in err, err
    err = one_line_error(capsys, args + ["--records", "1,7"])
    assert f"{ROVING}: --records: record 7 is not a dataset 58 record of the file" in err, err
    err = one_line_error(capsys, args + ["--records", "1;3"])
    assert "--records" in err and "'1;3'" in err, err
    csv_file = tmp_path / "c.csv"
    csv_file.write_text("frequency_hz,force_n,dof,re,im\n1.0,1.0,x1,1e-3,-1e-3\n")
    err = one_line_error(capsys, ["import", str(csv_file), "-o", str(tmp_path / "s.h5"), "--excitation", "x1",
                                  "--records", "1"])
    assert f"{csv_file}: --records: only a UFF file has records to pick; this is a CSV file" in err, err
