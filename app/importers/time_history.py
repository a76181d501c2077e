"""Time histories of a random run (UFF58 function type 1) to a random run, with the project's estimator.

One force channel and one or more responses (displacement, velocity or acceleration), all with the same
sample interval and length. FRFs are Welch-averaged by :class:`analysis.signals.frf_estimation.FRFEstimator` (Hann,
50 % overlap) with segments of the campaign's length (8 s) or shorter, so that at least
``MIN_AVERAGES`` segments fit; the lines kept are those the excitation reached: force autospectrum at least
``BAND_FRACTION`` of its largest value, above 0 Hz.
"""
from __future__ import annotations

import numpy as np

from analysis.common.errors import InputError
from analysis.signals.frf_estimation import FRFEstimator

from .runs import ImportedRun, RawRecord, SourceOptions
from .uff_codes import data_type_name
from .units import FORCES, PREFIX, RESPONSES, SI_UNITS, FileUnits, file_default, to_receptance, unit_factor

MIN_AVERAGES = 8
BAND_FRACTION = 1e-2
TIME_TYPES = (0, 17)                 # unknown or time


def _where(number: int, name: str) -> str:
    return f"record {number}: {name}"


def _channel(path: str, number: int, fields: dict, units: FileUnits | None) -> tuple[int, np.ndarray, float]:
    """(specific data type, samples in SI, sample interval) of one time-history record."""
    kind = int(fields.get("ordinate_spec_data_type", 0))
    if kind not in RESPONSES and kind not in FORCES:
        raise InputError(f"ordinate specific data type {kind} ({data_type_name(kind)}) is neither a force (13, 9) "
                         "nor a displacement, velocity or acceleration (8, 11, 12)", path,
                         _where(number, "ordinate_spec_data_type"))
    if int(fields.get("abscissa_spec_data_type", 0)) not in TIME_TYPES:
        raise InputError("the abscissa of a time history must be time", path, _where(number, "abscissa_spec_data_type"))
    x = np.asarray(fields["x"], float)
    data = np.asarray(fields["data"])
    if np.iscomplexobj(data) or len(x) < 2:
        raise InputError("a time history must hold real samples (at least 2)", path, _where(number, "data"))
    bad = np.flatnonzero(~np.isfinite(data))
    if bad.size:
        raise InputError(f"sample {int(bad[0])} is not a finite number", path, _where(number, "data"))
    dt = float(x[1] - x[0])
    if not dt > 0 or not np.allclose(np.diff(x), dt, rtol=1e-6):
        raise InputError("time samples must be evenly spaced and rising", path, _where(number, "x"))
    factor = unit_factor(kind, fields.get("ordinate_axis_units_lab", ""), path,
                         _where(number, "ordinate_axis_units_lab"), file_default(units, fields, "ordinate")).factor
    return kind, data * factor, dt


RANDOM_SEGMENT_SECONDS = 8.0  # imported time histories carry no plan: a power of two near this many seconds


def segment_length(fs: float, samples: int) -> int:
    """A power-of-two segment near RANDOM_SEGMENT_SECONDS or shorter, so MIN_AVERAGES segments fit."""
    longest = int(2 ** np.ceil(np.log2(RANDOM_SEGMENT_SECONDS * fs)))
    fitting = int(2 ** np.floor(np.log2(max(2 * samples / (MIN_AVERAGES + 1), 8))))
    return max(8, min(longest, fitting))


def _require_force(path: str, records: list[tuple[int, dict]]) -> None:
    """The real reason first: time histories without a force channel make no FRF, whatever else they are."""
    kinds = [int(fields.get("ordinate_spec_data_type", 0)) for _, fields in records]
    if any(k in FORCES for k in kinds):
        return
    held = "; ".join(f"record {n}: {data_type_name(k)} ({k})" for (n, _), k in zip(records, kinds))
    raise InputError(f"no force channel among the time histories ({held}): a random run needs the excitation "
                     "force (ordinate specific data type 13 or 9) beside the responses; nothing imported", path,
                     _where(records[0][0], "ordinate_spec_data_type"))


def random_run_from_time_histories(path: str, records: list[tuple[int, dict]], options: SourceOptions,
                                   units: FileUnits | None, notes: list[str]) -> ImportedRun:
    _require_force(path, records)
    channels = [(number, fields, *_channel(path, number, fields, units)) for number, fields in records]
    forces = [c for c in channels if c[2] in FORCES]
    if len(forces) > 1:
        raise InputError(f"a second force channel (first: record {forces[0][0]}); one excitation per run", path,
                         _where(forces[1][0], "ordinate_spec_data_type"))
    number, fields, _, force, dt = forces[0]
    for n, _, _, data, step in channels:
        if len(data) != len(force) or not np.isclose(step, dt, rtol=1e-9):
            raise InputError(f"{len(data)} samples every {step:g} s, but the force (record {number}) has "
                             f"{len(force)} every {dt:g} s", path, _where(n, "num_pts"))
    mapped = options.dof_name(int(fields.get("rsp_node", 0)), int(fields.get("rsp_dir", 0)))
    excitation = mapped[0] if mapped else options.excitation
    if excitation is None:
        raise InputError("the force channel's node is not mapped: give --dof NODE=NAME or --excitation NAME", path,
                         _where(number, "rsp_node"))
    responses, names = [], []
    for n, f, kind, data, _ in channels:
        if kind in FORCES:
            continue
        node, direction = int(f.get("rsp_node", 0)), int(f.get("rsp_dir", 0))
        dof = options.dof_name(node, direction)
        if dof is None:
            raise InputError(f"node {node} direction {direction:+d} is not mapped to a model DOF (give --dof "
                             f"{node}{'-' if direction < 0 else '+'}{abs(direction)}=NAME)", path, _where(n, "rsp_node"))
        responses.append((kind, dof[1] * data))
        names.append(dof[0])
    if not responses:
        raise InputError("a force but no response channel", path, _where(number, "func_type"))
    fs = 1.0 / dt
    est = FRFEstimator(fs, segment_length(fs, len(force)))
    stacked = np.stack([r[1] for r in responses], axis=1)
    try:
        est.add_data(force, stacked)
        band = est.frequency > 0
        psd = est.get_force_autospectrum()
    except ValueError as exc:
        raise InputError(f"too short for one averaging segment ({exc})", path, _where(number, "num_pts")) from None
    band &= psd >= BAND_FRACTION * psd[band].max()
    f = est.frequency[band]
    kinds = [r[0] for r in responses]
    estimates = {"frf": est.get_H1(), "h2": est.get_H2(), "hv": est.get_Hv()}
    frf = {d: to_receptance(estimates["frf"][band, p], f, kinds[p]) for p, d in enumerate(names)}
    arrays = {"force_psd": ("N^2/Hz", psd[band])}
    for p, d in enumerate(names):
        arrays[f"h2/{d}"] = ("m/N", to_receptance(estimates["h2"][band, p], f, kinds[p]))
        arrays[f"hv/{d}"] = ("m/N", to_receptance(estimates["hv"][band, p], f, kinds[p]))
        arrays[f"coherence/{d}"] = ("1", est.get_coherence()[band, p])
        arrays[f"random_error/{d}"] = ("1", est.get_random_error()[band, p])
    notes.append(f"random run from time histories: {est.n_averages} averages of {est.segment_length} samples, "
                 f"{len(f)} lines from {f[0]:g} to {f[-1]:g} Hz")
    raw = RawRecord(["force"] + [f"{PREFIX[k]}:{d}" for k, d in zip(kinds, names)],
                    ["N"] + [SI_UNITS[k] for k in kinds], np.column_stack([force, stacked]))
    return ImportedRun("random", "random", float(np.std(force)), "none", excitation, f, frf, arrays, source=path,
                       records=[n for n, _ in records], raw=raw, sample_rate=fs,
                       segment_length=est.segment_length)
