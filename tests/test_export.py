"""UFF58 and CSV export, read back independently."""
import csv

import numpy as np
import pytest
import pyuff

from analysis import InputError
from app.export import export_csv, export_uff
from app.session import RunSpec, SessionWriter


@pytest.fixture
def session(tmp_path):
    path = tmp_path / "s.h5"
    w = SessionWriter(path, software_version="9.9")
    w.begin_run(RunSpec("sine_0.5N_up", "stepped_sine", 0.5, "up", "A.w", ["A.w", "B.theta"], 1000.0,
                        ["force"], ["N"], extras={"force_amplitude": ("N", (), "f8"), "thd/force": ("1", (), "f8")}))
    freqs = np.array([50.0, 50.5, 51.25, 51.5, 53.0])          # uneven, as after refinement
    for i, f in enumerate(freqs):
        w.append_line(f, {"A.w": (1 + 1j) * 1e-5 * (i + 1), "B.theta": -2e-4j * (i + 1)},
                      {"force_amplitude": 0.5 + 1e-3 * i, "thd/force": 0.01 * i})
    w.end_run("complete")
    w.close()
    return path, freqs


def test_uff58_round_trip_with_uneven_axis(session, tmp_path):
    path, freqs = session
    out = tmp_path / "s.uff"
    assert export_uff(path, out) == 2
    sets = pyuff.UFF(str(out)).read_sets()
    assert len(sets) == 2
    by_name = {s["rsp_ent_name"].strip(): s for s in sets}
    a = by_name["A.w"]
    assert a["type"] == 58 and a["func_type"] == 4
    np.testing.assert_allclose(a["x"], freqs, rtol=1e-6)
    np.testing.assert_allclose(a["data"], (1 + 1j) * 1e-5 * np.arange(1, 6), rtol=1e-6)
    assert a["rsp_dir"] == 3 and by_name["B.theta"]["rsp_dir"] == 5
    assert "force 0.5 N direction up" in a["id4"]
    with pytest.raises(InputError, match="exists already"):
        export_uff(path, out)


def test_csv_has_units_and_all_lines(session, tmp_path):
    path, freqs = session
    [written] = export_csv(path, tmp_path / "csv")
    rows = list(csv.reader(written.open()))
    header = rows[1]
    assert header[0] == "frequency [Hz]" and "Re frf A.w [m/N]" in header and "force_amplitude [N]" in header
    data = np.array(rows[2:], float)
    np.testing.assert_allclose(data[:, 0], freqs)
    np.testing.assert_allclose(data[:, header.index("Im frf B.theta [m/N]")], -2e-4 * np.arange(1, 6))
