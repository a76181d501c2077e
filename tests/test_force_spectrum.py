"""A force spectrum beside other systems' FRFs: the force measured at every line becomes the run's
``force_amplitude``, which the analysis uses for every amplitude (SineRun.force_per_line)."""
import re

import numpy as np
import pytest
import pyuff

from app.cli import main
from app.session import open_session
from app.session.data import measurements_from_session

LINES = np.array([10.0, 10.5, 11.0, 11.5])
FORCE = np.array([0.14, 0.19, 0.23, 0.2])          # what a controller "at 0.2 N" measures across a resonance
DOFS = ["--dof", "1+Z=x1", "--dof", "2+Z=x2"]


def _record(**fields):
    base = dict(binary=1, func_type=4, load_case_id=1, rsp_node=1, rsp_dir=3, ref_node=2, ref_dir=3,
                ordinate_spec_data_type=8, ordinate_axis_units_lab="m", orddenom_spec_data_type=13,
                orddenom_axis_units_lab="N", abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
                abscissa_spacing=0, x=LINES, data=(1 - 2j) * 1e-4 * np.arange(1, 5), id1="H1 x1/x2", id2="",
                id3="", id4="", id5="")
    base.update(fields)
    return pyuff.prepare_58(**base)


def _spectrum(values, func_type=12, label="N", id1="Force spectrum", x=None):
    """The force channel's record (node 2, the FRFs' reference), with one more line than the FRFs. pyuff
    writes no function type 12: it is written as 3 (cross spectrum) and set in the file (:func:`_write`)."""
    x = np.append(LINES, 12.0) if x is None else x
    return _record(func_type=3 if func_type == 12 else func_type, rsp_node=2, ref_node=0, ref_dir=0,
                   ordinate_spec_data_type=13, ordinate_axis_units_lab=label, orddenom_spec_data_type=0, orddenom_axis_units_lab="NONE",
                   x=x, data=np.resize(values, len(x)).astype(complex), id1=id1)


def _write(path, sets):
    """The records, with function type 3 made 12 in record 6 (its first field, five characters)."""
    pyuff.UFF(str(path)).write_sets(sets, mode="add")
    text = path.read_bytes()
    path.write_bytes(re.sub(rb"\n    3( +\d+ +\d+ +1 )", rb"\n   12\1", text, count=1))


def _import(tmp_path, spectrum, *flags):
    path = tmp_path / "c.uff"
    _write(path, [_record(), _spectrum(*spectrum)])
    out = tmp_path / "s.h5"
    return main(["import", str(path), "-o", str(out), *DOFS, *flags]), out


@pytest.mark.parametrize("spectrum, expected", [
    ((FORCE * np.exp(0.3j),), FORCE),                                   # a linear spectrum: |F| is the amplitude
    ((FORCE / np.sqrt(2), 12, "N", "Force spectrum RMS"), FORCE),      # said RMS: sqrt(2) times
    (((FORCE * 1e-3) ** 2, 2, "kN^2", "Force autopower"), FORCE),      # an auto spectrum in kN^2: its root
])
def test_the_force_at_every_line_comes_from_the_force_spectrum(tmp_path, spectrum, expected, capsys):
    rc, out = _import(tmp_path, spectrum)
    assert rc == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "record 2: the force at each line" in printed
    with open_session(out) as s:
        [name] = s.run_names()
        run = s.run(name)
        np.testing.assert_allclose(run.arrays["force_amplitude"], expected, rtol=1e-12)
        assert run.force == pytest.approx(np.median(expected), rel=1e-12)    # no --force-amplitude: the median
        [sine] = measurements_from_session(s).sine
    np.testing.assert_allclose(sine.force_per_line, expected, rtol=1e-12)


def test_a_level_given_is_kept_and_the_spectrum_still_gives_the_lines(tmp_path):
    rc, out = _import(tmp_path, (FORCE,), "--force-amplitude", "0.2")
    assert rc == 0
    with open_session(out) as s:
        run = s.run("sine_0.2N_up")
        np.testing.assert_allclose(run.arrays["force_amplitude"], FORCE, rtol=1e-12)


@pytest.mark.parametrize("spectrum, where, reason", [
    ((FORCE, 12, "N", "F", LINES[:3]), "record 2: x", "no line at 11.5 Hz"),
    ((FORCE, 2, "N", "F"), "record 2: ordinate_axis_units_lab", "not a squared force"),
    ((FORCE, 12, "furlong", "F"), "record 2: ordinate_axis_units_lab", "unit 'furlong' not known"),
    ((FORCE * 0, 12, "N", "F"), "dataset force_amplitude", "must be finite and > 0"),
])
def test_a_force_spectrum_that_does_not_fit_is_refused(tmp_path, capsys, spectrum, where, reason):
    values, func, label, id1, *x = spectrum
    path = tmp_path / "c.uff"
    _write(path, [_record(), _spectrum(values, func, label, id1, *x)])
    rc = main(["import", str(path), "-o", str(tmp_path / "s.h5"), *DOFS, "--force-amplitude", "0.2"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and where in err and reason in err, err
    assert not (tmp_path / "s.h5").exists()
