"""contactid's machine-readable UFF58 id lines: what a record is, in five 80-character lines.

Every record contactid exports carries, as ``key=value`` words (values without spaces)::

    id1  contactid run=<run name> quantity=<frf | frf_std | force_amplitude | distortion | coherence | random_error>
    id2  rsp=<response DOF name> ref=<excitation DOF name>
    id3  <ISO 8601 time the session was created> [sample_rate=<Hz> segment_length=<samples>]
    id4  kind=<stepped_sine | random> force=<N, exact decimal> direction=<up | down | none> status=<status>
    id5  software=contactid-<version> convention=exp(+jwt) records=<records of the run in the file>

(id3's words only on a random run with a Welch segment: the analysis takes its leakage allowance from them),
so ``contactid import`` needs no flags for contactid's own files, and knows when a file cut short lost whole
records of a run (``records=`` is absent from files written before it was added). Records of other systems have
free-text id lines; they are kept in the session's provenance but not interpreted.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from analysis.errors import InputError

ID_KEYS = ("id1", "id2", "id3", "id4", "id5")     # pyuff's names of a record's five id lines
MARK = "contactid"
CONVENTION = "exp(+jwt)"
ID_WIDTH = 80
KINDS = ("stepped_sine", "random")
DIRECTIONS = ("up", "down", "none")
QUANTITIES = ("frf", "frf_std", "force_amplitude", "distortion", "coherence", "random_error")


@dataclass
class RecordTag:
    """What one contactid record holds."""

    run: str
    quantity: str
    response: str
    reference: str
    kind: str
    force: float
    direction: str
    status: str
    records: int | None = None       # records the run has in its file (None: not stated)
    sample_rate: float | None = None     # Hz, and samples per Welch segment: a random run's resolution
    segment_length: int | None = None


def _word(key: str, value: str, where: str) -> str:
    if not value or any(c.isspace() for c in value) or "=" in value:
        raise InputError(f"{key} {value!r} cannot be written as one word (no spaces or '=')", where, key)
    return f"{key}={value}"


def _line(words: list[str], where: str, name: str) -> str:
    text = " ".join(words)
    if len(text) > ID_WIDTH:
        raise InputError(f"is {len(text)} characters, more than the {ID_WIDTH} of a UFF id line: {text!r}",
                         where, name)
    return text


def encode(tag: RecordTag, created: str, software: str, where: str) -> dict[str, str]:
    """The five id lines of a record (``where`` names the run for errors)."""
    return {
        "id1": _line([MARK, _word("run", tag.run, where), _word("quantity", tag.quantity, where)], where, "id1"),
        "id2": _line([_word("rsp", tag.response, where), _word("ref", tag.reference, where)], where, "id2"),
        "id3": _id3(tag, created),
        "id4": _line([_word("kind", tag.kind, where), f"force={float(tag.force)!r}",
                      _word("direction", tag.direction, where), _word("status", tag.status, where)], where, "id4"),
        "id5": _line([_word("software", f"contactid-{software or 'unknown'}", where),
                      f"convention={CONVENTION}"] + ([f"records={tag.records}"] if tag.records else []),
                     where, "id5"),
    }


def _id3(tag: RecordTag, created: str) -> str:
    """The creation time, then a random run's sample rate and segment length (the time is shortened, never
    they: they decide the analysis's leakage allowance)."""
    if not (tag.sample_rate and tag.segment_length):
        return created[:ID_WIDTH]
    tail = f"sample_rate={float(tag.sample_rate)!r} segment_length={int(tag.segment_length)}"
    return f"{created[:ID_WIDTH - len(tail) - 1]} {tail}".strip()


def _welch(ids: dict[str, str], where: str) -> tuple[float | None, int | None]:
    """id3's sample rate (Hz) and segment length (samples), None where not stated; both or neither."""
    words = _words(ids.get("id3", ""))
    if "sample_rate" not in words and "segment_length" not in words:
        return None, None
    rate, length = words.get("sample_rate", ""), words.get("segment_length", "")
    try:
        fs = float(rate)
    except ValueError:
        raise InputError(f"sample_rate={rate!r} is not a number", where, "id3") from None
    if not (math.isfinite(fs) and fs > 0):
        raise InputError(f"sample_rate={rate} is not a sample rate > 0 Hz", where, "id3")
    if not (length.isdigit() and int(length) > 0):
        raise InputError(f"segment_length={length!r} is not a number of samples > 0", where, "id3")
    return fs, int(length)


def _words(line: str) -> dict[str, str]:
    return dict(w.split("=", 1) for w in line.split() if "=" in w)


def decode(ids: dict[str, str], where: str) -> RecordTag | None:
    """The tag of a contactid record, or None for another system's record.

    A record that claims to be contactid's but lacks a key is refused (``where`` names file and record)."""
    first = _words(ids.get("id1", ""))
    if not ids.get("id1", "").startswith(MARK + " ") or "run" not in first:
        return None
    values = {**first, **_words(ids.get("id2", "")), **_words(ids.get("id4", ""))}
    for key, line in (("quantity", "id1"), ("rsp", "id2"), ("ref", "id2"), ("kind", "id4"), ("force", "id4"),
                      ("direction", "id4"), ("status", "id4")):
        if key not in values:
            raise InputError(f"contactid record without {key}=", where, line)
    if values["quantity"] not in QUANTITIES:
        raise InputError(f"unknown quantity {values['quantity']!r} (known: {', '.join(QUANTITIES)})", where, "id1")
    try:
        force = float(values["force"])
    except ValueError:
        raise InputError(f"force={values['force']!r} is not a number", where, "id4") from None
    if not (math.isfinite(force) and force > 0):
        raise InputError(f"force={values['force']} is not a force amplitude > 0 N", where, "id4")
    for key, allowed in (("kind", KINDS), ("direction", DIRECTIONS)):
        if values[key] not in allowed:
            raise InputError(f"{key}={values[key]} is not one of {', '.join(allowed)}", where, "id4")
    records = _words(ids.get("id5", "")).get("records")
    if records is not None and not (records.isdigit() and int(records) > 0):
        raise InputError(f"records={records} is not a count of records", where, "id5")
    fs, segment = _welch(ids, where)
    return RecordTag(values["run"], values["quantity"], values["rsp"], values["ref"], values["kind"], force,
                     values["direction"], values["status"], int(records) if records else None, fs, segment)
