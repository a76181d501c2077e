"""A session's stepped-sine runs in the CSV long format that ``contactid import`` reads (docs/import.md).

One row per line, level and sensor DOF, with what the analysis reads of each line: the receptance, its standard
deviation (``std``: on the rows of each run that stores one, empty on the others), the force
measured at the line (``force_amplitude_n``, its phase where stored), how the level was held (``control_*`` for a
response-controlled level, ``force_n`` otherwise) and the run's ``status`` (complete, failed or aborted).
Numbers are written as Python's shortest round-trip decimals, so an import gives the analysis the same numbers.
Random runs have no place in the format (an import of it makes stepped-sine runs): they are left out and named.
What a written run holds and no column carries -- per-line datasets such as the displacement ``distortion`` the
analysis reads (or the harmonics it comes from), a campaign's ``force_target``, and why a run failed
(``end_reason``) or that its writer died (``incomplete``) -- is named in :attr:`CsvLongExport.not_carried`, as
the UFF and per-run CSV exports name theirs.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

from analysis.common.errors import InputError

from app.session.outputs import atomic_output, check_output, require_free_space
from app.session.writer import open_session
from app.session.checks import CheckedRun, check_format, check_run, check_run_count, refuse_saw_nothing

COLUMNS = ["frequency_hz", "force_n", "dof", "re", "im", "direction", "force_amplitude_n", "force_phase_rad",
           "control_dof", "control_quantity", "control_target", "status"]
BYTES_PER_ROW = 200                     # generous, for the free-space check


@dataclass
class CsvLongExport:
    """What :func:`export_csv_long` wrote: the runs written and those left out (random runs)."""

    path: Path
    runs: list[str] = field(default_factory=list)
    left_out: list[str] = field(default_factory=list)
    without_std: list[str] = field(default_factory=list)    # runs written with empty std cells (none stored)
    not_carried: list[str] = field(default_factory=list)    # "<run>: <datasets and attributes>" no column holds


def _checked_runs(path: Path) -> list[CheckedRun]:
    with open_session(path) as s:
        check_format(s.attrs, str(path))
        check_run_count(s.run_names(), str(path))
        return [c for c in (check_run(run, str(path)) for run in s.runs()) if c.lines]


def _with_std(c: CheckedRun) -> bool:
    """Whether the run stores a standard deviation (finite and >= 0 at every line, as the session reader and the
    import hold it). The import takes a DOF's std on all its rows or none: a DOF without one has its cells
    empty, the others keep theirs."""
    return any(f"frf_std/{d}" in c.run.arrays for d in c.sensor_dofs)


# the per-line datasets a column carries (force_phasor: rebuilt by the import from amplitude and phase)
CARRIED = ("force_amplitude", "force_phase")


def _not_carried(c: CheckedRun) -> list[str]:
    """What of the run no column of the format carries: its other per-line datasets, the displacement distortion
    the analysis reads where it comes from the harmonics, and the attributes no format carries."""
    from app.export import _distortion, attributes_not_carried

    arrays = c.run.arrays
    carried = set(CARRIED) | {f"frf_std/{d}" for d in c.sensor_dofs}
    if all(name in arrays for name in CARRIED):
        carried.add("force_phasor")
    names = sorted(name for name in arrays if name not in carried)
    if "distortion" not in names and _distortion(c.run) is not None:
        names.append("distortion (from the harmonics)")
    return names + attributes_not_carried(c.run)


def _number(x) -> str:
    return repr(float(x))


def _rows(checked: CheckedRun, with_std: bool | None):
    """The run's rows; ``with_std`` None: the file has no std column, False: this run's std cells are empty."""
    run, n, control = checked.run, checked.lines, checked.control
    response = control.mode == "response"
    level = ["" if response else _number(run.force)]
    held = [control.dof, control.quantity, _number(control.target)] if response else ["", "", ""]
    force = run.arrays.get("force_amplitude")
    phase = run.arrays.get("force_phase")
    for i in range(n):
        measured = ["" if force is None else _number(force[i]), "" if phase is None else _number(phase[i])]
        for d in checked.sensor_dofs:
            h = complex(run.frf[d][i])
            row = [_number(run.frequency[i]), *level, d, _number(h.real), _number(h.imag), run.attrs["direction"],
                   *measured, *held, run.status]
            std = run.arrays.get(f"frf_std/{d}") if with_std else None
            yield row + (["" if std is None else _number(std[i])] if with_std is not None else [])


def export_csv_long(session_path, path, overwrite: bool = False) -> CsvLongExport:
    """Write every stepped-sine run of the session into one CSV long-format file."""
    session_path, path = Path(session_path), Path(path)
    check_output(path, inputs=[session_path], overwrite=overwrite, field="--csv-long")
    checked = _checked_runs(session_path)
    sine = [c for c in checked if c.run.kind == "stepped_sine"]
    if not sine:
        raise InputError("has no stepped-sine run with lines: the CSV long format holds stepped-sine levels",
                         str(session_path))
    for c in sine:
        refuse_saw_nothing(c, str(session_path), "the CSV long format")
    out = CsvLongExport(path, [c.run.name for c in sine], [c.run.name for c in checked if c.run.kind != "stepped_sine"])
    with_std = {c.run.name: _with_std(c) for c in sine}
    any_std = any(with_std.values())
    out.without_std = [name for name, has in with_std.items() if any_std and not has]
    out.not_carried = [f"{c.run.name}: {', '.join(names)}" for c in sine for names in [_not_carried(c)] if names]
    require_free_space(path, BYTES_PER_ROW * sum(c.lines * len(c.sensor_dofs) for c in sine) + 4096,
                       "export the CSV long format")
    with atomic_output(path, inputs=[session_path], overwrite=overwrite, field="--csv-long") as temp:
        with temp.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(COLUMNS + (["std"] if any_std else []))
            for c in sine:
                writer.writerows(_rows(c, with_std[c.run.name] if any_std else None))
    return out
