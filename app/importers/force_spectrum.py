"""A force spectrum record beside other systems' FRFs: the force measured at every line, as a run's
``force_amplitude`` (docs/import.md, "Force spectra").

A stepped-sine controller measures the force at each line; its export may hold that as a dataset 58 record of the
force channel next to the FRFs: function type 12 (spectrum: a linear amplitude per line) or 2 (auto spectrum: a
power per line), ordinate specific data type 13 or 9 (a force), no denominator. UFF58 does not say whether an
amplitude is a peak or an RMS value; contactid reads peak unless the record's id lines or ordinate axis label
say RMS (a sine of RMS value R has the amplitude sqrt(2) R), and the import notes which it took. An RMS the
labels deny ("peak values (not RMS)", "non-RMS") is no RMS; labels that say both peak and RMS are refused, as
they leave the factor sqrt(2) to a guess; a peak-to-peak value ("pk-pk", "peak to peak") is twice the amplitude
and is halved. An auto spectrum holds the amplitude squared (peak^2, or RMS^2 where it says RMS): a power, so a
negative or complex value is refused, never its magnitude taken. The record must share the run's load case,
that run must be stepped sine (a random run's force is one broadband RMS, not an amplitude per line), and it
must hold every line of the run once (other lines are ignored; a line given twice is refused, not one of its
values picked).
"""
from __future__ import annotations

import re

import numpy as np

from analysis.common.errors import InputError

from .idlines import ID_KEYS
from .runs import ImportedRun, check_values, sine_run_name
from .units import FORCES, FileUnits, file_default, unit_factor

FUNC_AUTO_SPECTRUM, FUNC_SPECTRUM = 2, 12
NO_DENOMINATOR = (0,)
_RMS = re.compile(r"\brms\b", re.IGNORECASE)
_NOT_RMS = re.compile(r"\b(?:not|non|no|without)[\s-]+(?:an?\s+|the\s+)?rms\b", re.IGNORECASE)
_PEAK_TO_PEAK = re.compile(r"\b(?:peak[\s-]*to[\s-]*peak|pk[\s-]*pk|p[\s-]*p)\b", re.IGNORECASE)
_PEAK = re.compile(r"\b(?:peak|pk|0[\s-]*pk|zero[\s-]*to[\s-]*peak)\b", re.IGNORECASE)
LABEL_KEYS = (*ID_KEYS, "ordinate_axis_lab", "ordinate_axis_units_lab")


def is_force_spectrum(fields: dict) -> bool:
    """A spectrum or auto spectrum of a force channel (per line, no denominator)."""
    return (int(fields.get("func_type", -1)) in (FUNC_SPECTRUM, FUNC_AUTO_SPECTRUM)
            and int(fields.get("ordinate_spec_data_type", 0)) in FORCES
            and int(fields.get("orddenom_spec_data_type", 0)) in NO_DENOMINATOR)


def _amplitude_kind(path: str, number: int, fields: dict) -> str:
    """What the record's labels say its values are: "rms", "peak-to-peak" or "peak" (also where they say
    nothing). Refused where they say two of them: the factor between them would be a guess."""
    said: dict[str, str] = {}
    for key in LABEL_KEYS:
        text = str(fields.get(key, ""))
        rms = len(_RMS.findall(text)) > len(_NOT_RMS.findall(text))     # "not RMS" is no RMS
        text = _NOT_RMS.sub(" ", text)
        if rms:
            said.setdefault("rms", key)
        if _PEAK_TO_PEAK.search(text):
            said.setdefault("peak-to-peak", key)
            text = _PEAK_TO_PEAK.sub(" ", text)
        if _PEAK.search(text):
            said.setdefault("peak", key)
    if len(said) > 1:
        (a, where_a), (b, where_b) = list(said.items())[:2]
        raise InputError(f"its labels say {a} ({where_a}) and {b} ({where_b}): the force amplitude is one of them; "
                         "correct the label", path, f"record {number}: {where_b}")
    return next(iter(said), "peak")


def _unit_factor(path: str, number: int, fields: dict, units: FileUnits | None, power: bool) -> float:
    """SI factor of the ordinate: an auto spectrum's label is a squared force (``N^2``, ``N2``, ``N²``)."""
    label = str(fields.get("ordinate_axis_units_lab", "")).strip()
    where = f"record {number}: ordinate_axis_units_lab"
    if power and label.upper() not in ("", "NONE"):
        base = re.sub(r"(\^2|\*\*2|2|²)$", "", label)
        if base == label:
            raise InputError(f"unit {label!r} is not a squared force for an auto spectrum (N^2, kN^2, lbf^2)", path,
                             where)
        return unit_factor(13, base, path, where).factor ** 2
    kind = int(fields["ordinate_spec_data_type"])
    return unit_factor(kind, label, path, where, file_default(units, fields, "ordinate")).factor


def force_amplitudes(path: str, number: int, fields: dict, units: FileUnits | None,
                     frequency: np.ndarray) -> tuple[np.ndarray, str]:
    """The force amplitude (N, peak) at each of ``frequency``'s lines, and how it was read (for the notes)."""
    power = int(fields["func_type"]) == FUNC_AUTO_SPECTRUM
    x, data = np.asarray(fields["x"], float), np.asarray(fields["data"])
    check_values(data, path, f"record {number}: data")
    if power:       # a power: its magnitude would turn a damaged or mislabelled record into forces
        real, imag = np.real(data), np.imag(data)
        bad = np.flatnonzero((real < 0) | (np.abs(imag) > 1e-9 * np.abs(real)))
        if bad.size:
            i = int(bad[0])
            raise InputError(f"line {i} at {float(x[i]):g} Hz is {complex(data[i]) if imag[i] else float(real[i])!r}: "
                             "an auto spectrum (a power, function type 2) is real and >= 0", path,
                             f"record {number}: data")
        values = np.sqrt(real * _unit_factor(path, number, fields, units, power))
    else:
        values = np.abs(data) * _unit_factor(path, number, fields, units, power)
    kind = _amplitude_kind(path, number, fields)
    values = values * {"rms": np.sqrt(2.0), "peak-to-peak": 0.5, "peak": 1.0}[kind]
    order = np.argsort(x, kind="stable")
    index = order[np.clip(np.searchsorted(x[order], frequency), 0, len(x) - 1)]
    off = np.flatnonzero(~np.isclose(x[index], frequency, rtol=1e-9, atol=0))
    if off.size:
        raise InputError(f"the force spectrum has no line at {float(frequency[off[0]])!r} Hz, a line of the FRFs "
                         "of its load case", path, f"record {number}: x")
    twice = [(int(i), int(j)) for i, j in zip(index, order[np.clip(np.searchsorted(x[order], frequency) + 1, 0,
                                                                   len(x) - 1)])
             if i != j and np.isclose(x[j], x[i], rtol=1e-9, atol=0)]
    if twice:
        i, j = twice[0]
        raise InputError(f"lines {min(i, j)} and {max(i, j)} are both at {float(x[i])!r} Hz, with "
                         f"{complex(data[i]) if np.iscomplexobj(data) else float(data[i])!r} and "
                         f"{complex(data[j]) if np.iscomplexobj(data) else float(data[j])!r}: one force a line of "
                         "the FRFs", path, f"record {number}: x")
    read = {"rms": "RMS, times sqrt(2)", "peak-to-peak": "peak-to-peak, halved",
            "peak": "read as peak amplitude: no RMS in its labels"}[kind]
    how = f"record {number}: the force at each line from {'an auto spectrum' if power else 'a spectrum'} ({read})"
    return values[index], how


def attach_force_spectra(path: str, runs: list[ImportedRun], spectra: list[tuple[int, dict]],
                         units: FileUnits | None, notes: list[str]) -> None:
    """Each force spectrum to the run of its load case, as that run's per-line ``force_amplitude``."""
    by_case = {run.load_case: run for run in runs if run.load_case is not None}
    for number, fields in spectra:
        run = by_case.get(fields.get("load_case_id", 0))
        if run is None:
            raise InputError(f"a force spectrum of load case {fields.get('load_case_id', 0)}, which has no FRF in "
                             "the file", path, f"record {number}: load_case_id")
        if run.kind != "stepped_sine":
            raise InputError(f"a force spectrum of load case {fields.get('load_case_id', 0)}, whose FRFs are read as "
                             "a random run (--kind random): a spectrum gives a stepped-sine run the force amplitude "
                             "at each line, and a random run's force is one broadband RMS; import without --kind "
                             "random, or leave the spectrum out (--records)", path, f"record {number}: func_type")
        if "force_amplitude" in run.arrays:
            raise InputError(f"a second force spectrum for run {run.name}", path, f"record {number}: func_type")
        values, how = force_amplitudes(path, number, fields, units, run.frequency)
        run.arrays["force_amplitude"] = ("N", values)
        run.records.append(number)
        notes.append(how)
        if not run.force:                  # no --force-amplitude: the level is the median force measured
            run.force = float(np.median(values))
            run.name = sine_run_name(run.force, run.direction) if run.kind == "stepped_sine" else run.name
            notes.append(f"run {run.name}: level {run.force:g} N, the median of the force spectrum (record {number})")
