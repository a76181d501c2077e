"""Interchange formats: UFF dataset 58 (via pyuff) and CSV, from a session file.

UFF 58 records one FRF each: the run's receptance at one sensor DOF (function type 4, FRF; ordinate
displacement over force, units m/N), on the run's (generally uneven) frequency axis. Node numbers are
1-based positions of the DOF's station in the session's DOF list; the direction code is 3 (+Z) for a
lateral displacement, 5 (+Y rotation) for a rotation ``*.theta`` and 1 (+X) for a lumped DOF. The ID lines
carry the run name, the DOF names, the force level and the sweep direction, so nothing is lost.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pyuff

from analysis.errors import InputError

from .session import RunData, open_session

FUNC_FRF = 4
DATA_DISPLACEMENT, DATA_FORCE = 8, 13


def _node_and_direction(dof: str, nodes: dict[str, int]) -> tuple[int, int]:
    station, _, kind = dof.partition(".")
    node = nodes.setdefault(station, len(nodes) + 1)
    return node, {"w": 3, "theta": 5}.get(kind, 1)


def export_uff(session_path, uff_path, overwrite: bool = False) -> int:
    """Write every FRF of the session's runs to a UFF58 file; returns the number of records."""
    uff_path = Path(uff_path)
    if uff_path.exists() and not overwrite:
        raise InputError("exists already; pass --force to overwrite it", str(uff_path))
    records = []
    nodes: dict[str, int] = {}
    with open_session(session_path) as s:
        for load_case, run in enumerate(s.runs(), start=1):
            ref_node, ref_dir = _node_and_direction(run.excitation_dof, nodes)
            for dof, frf in run.frf.items():
                if not len(frf):
                    continue
                node, direction = _node_and_direction(dof, nodes)
                records.append(pyuff.prepare_58(
                    binary=0, id1=f"contactid run {run.name}",
                    id2=f"receptance {dof} / {run.excitation_dof} (m/N)",
                    id3=s.attrs.get("created", ""),
                    id4=f"{run.kind} force {run.force:g} N direction {run.direction} status {run.status}",
                    id5=f"software {s.attrs.get('software_version', '')}",
                    func_type=FUNC_FRF, load_case_id=load_case, rsp_ent_name=dof[:10], rsp_node=node,
                    rsp_dir=direction, ref_ent_name=run.excitation_dof[:10], ref_node=ref_node, ref_dir=ref_dir,
                    abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
                    ordinate_spec_data_type=DATA_DISPLACEMENT, ordinate_axis_units_lab="m",
                    orddenom_spec_data_type=DATA_FORCE, orddenom_axis_units_lab="N",
                    data=np.asarray(frf, complex), x=np.asarray(run.frequency, float)))
    if not records:
        raise InputError("has no measured FRF to export", str(session_path))
    if uff_path.exists():
        uff_path.unlink()
    uff = pyuff.UFF(str(uff_path))
    uff.write_sets(records, mode="add")
    return len(records)


def export_csv(session_path, directory, overwrite: bool = False) -> list[Path]:
    """One CSV per run: frequency, Re/Im of each FRF, and every per-line scalar quantity with its unit."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    with open_session(session_path) as s:
        for run in s.runs():
            path = directory / f"{run.name}.csv"
            if path.exists() and not overwrite:
                raise InputError("exists already; pass --force to overwrite it", str(path))
            _write_run_csv(path, run)
            written.append(path)
    return written


def _write_run_csv(path: Path, run: RunData) -> None:
    columns = [("frequency [Hz]", run.frequency)]
    for dof, frf in run.frf.items():
        columns += [(f"Re frf {dof} [m/N]", frf.real), (f"Im frf {dof} [m/N]", frf.imag)]
    for name, values in sorted(run.arrays.items()):
        if values.ndim != 1 or len(values) != len(run.frequency):
            continue                                   # per-harmonic arrays stay in the HDF5 file
        unit = run.units.get(name, "")
        if np.iscomplexobj(values):
            columns += [(f"Re {name} [{unit}]", values.real), (f"Im {name} [{unit}]", values.imag)]
        else:
            columns.append((f"{name} [{unit}]", values.astype(float)))
    with path.open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow([f"# contactid run {run.name}: {run.kind}, force {run.force:g} N, direction {run.direction}, "
                      f"status {run.status}, excitation {run.excitation_dof}"])
        out.writerow([name for name, _ in columns])
        for row in zip(*(values for _, values in columns)):
            out.writerow([repr(float(v)) for v in row])
