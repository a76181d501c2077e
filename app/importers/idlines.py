"""contactid's machine-readable UFF58 id lines: what a record is, in five 80-character lines.

Every record contactid exports carries, as ``key=value`` words (values without spaces)::

    id1  contactid run=<run name> quantity=<frf | frf_std | force_amplitude | force_phase | distortion | coherence |
         random_error>
    id2  rsp=<response DOF name> ref=<excitation DOF name>
    id3  <ISO 8601 time the session was created> [sample_rate=<Hz> segment_length=<samples>]
         [control=<response | open_loop> at=<DOF> [held=<displacement | velocity | acceleration> target=<SI>]]
    id4  kind=<stepped_sine | random> force=<N, exact decimal> direction=<up | down | none> status=<status>
    id5  software=contactid-<version> convention=exp(+jwt) records=<records of the run in the file>

(id3's Welch words only on a random run with a Welch segment: the analysis takes its leakage allowance from
them; its control words only on a level not held at its force -- the run attributes ``control*`` of
docs/session-format.md by :data:`CONTROL_TAGS`; without them the level was held at ``force``), so ``contactid
import`` needs no flags for contactid's own files, and knows when a file cut short lost whole records of a run
(``records=`` is absent from files written before it was added). Records of other systems have free-text id
lines; they are kept in the session's provenance but not interpreted.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from analysis.common.errors import InputError
from analysis.common.measurements import Control
from analysis.common.quantities import dof_name_problem, force_problem, held_without_target

from app.session import check_control

ID_KEYS = ("id1", "id2", "id3", "id4", "id5")     # pyuff's names of a record's five id lines
MARK = "contactid"
CONVENTION = "exp(+jwt)"
ID_WIDTH = 80
KINDS = ("stepped_sine", "random")
DIRECTIONS = ("up", "down", "none")
# id-line tag -> the run attribute it carries (shorter than the attribute: an id line holds 80 characters)
CONTROL_TAGS = {"control": "control", "at": "control_dof", "held": "control_quantity", "target": "control_target"}
STATUSES = ("complete", "failed", "aborted", "running")     # a session's run statuses (running: stored aborted)
# what every record of one run states alike, with the id line that states it
RUN_WORDS = (("kind", "id4"), ("force", "id4"), ("direction", "id4"), ("status", "id4"), ("reference", "id2"),
             ("records", "id5"), ("sample_rate", "id3"), ("segment_length", "id3"), ("control", "id3"))
QUANTITIES = ("frf", "frf_std", "force_amplitude", "force_phase", "distortion", "coherence", "random_error")


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
    control: Control | None = None       # how the level was held (None: at ``force``)


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
        "id3": _id3(tag, created, where),
        "id4": _line([_word("kind", tag.kind, where), f"force={float(tag.force)!r}",
                      _word("direction", tag.direction, where), _word("status", tag.status, where)], where, "id4"),
        "id5": _line([_word("software", f"contactid-{software or 'unknown'}", where),
                      f"convention={CONVENTION}"] + ([f"records={tag.records}"] if tag.records else []),
                     where, "id5"),
    }


def _id3(tag: RecordTag, created: str, where: str) -> str:
    """The creation time, then a random run's sample rate and segment length and a level's control (the time
    is shortened, never they: they decide the analysis's leakage allowance and the level's label)."""
    words = control_words(tag.control, where) if tag.control else []
    # to the second: a reader of the line needs no more, and the width is the tags'
    created = re.sub(r"(T\d\d:\d\d:\d\d)\.\d+", r"\1", created)
    if tag.sample_rate and tag.segment_length:
        words = [f"sample_rate={float(tag.sample_rate)!r}", f"segment_length={int(tag.segment_length)}", *words]
    if not words:
        return created[:ID_WIDTH]
    tail = _line(words, where, "id3")
    return f"{created[:max(ID_WIDTH - len(tail) - 1, 0)]} {tail}".strip()


def control_words(control: Control, where: str) -> list[str]:
    """The ``key=value`` words of how a level was held; none for force control (what their absence means)."""
    if control.mode == "force":
        return []
    words = [_word("control", control.mode, where), _word("at", control.dof, where)]
    if control.response:
        words += [_word("held", control.quantity, where), f"target={float(control.target)!r}"]
    return words


def read_control(words: dict[str, str], excitation: str, force: float, where: str, line: str) -> Control:
    """A level's control from its words, by the rules of a session's run attributes (``check_control``);
    errors name ``where``, ``line`` and the tag."""
    attrs = {attr: words[tag] for tag, attr in CONTROL_TAGS.items() if tag in words}
    held = [tag for tag in ("held", "target") if tag in words]
    if held and words.get("control", "force") in ("force", "open_loop"):      # the words of every door (analysis/common/quantities.py)
        raise InputError(f"{held[0]}= {held_without_target('control=response')}", where, line)
    if "control_target" in attrs:
        try:
            attrs["control_target"] = float(attrs["control_target"])
        except ValueError:
            raise InputError(f"target={words['target']!r} is not a number", where, line) from None
    tags = {attr: tag for tag, attr in CONTROL_TAGS.items()}

    def error(what: str, message: str) -> InputError:
        return InputError(f"{tags[what.removeprefix('attribute ')]}= {message}", where, line)

    return check_control(attrs, excitation, force, error)


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
    for key in ("rsp", "ref"):         # a DOF name by the rule of every door (analysis/common/quantities.py)
        if dof_name_problem(values[key]):
            raise InputError(f"{key}= {dof_name_problem(values[key])}", where, "id2")
    if values["quantity"] not in QUANTITIES:
        raise InputError(f"unknown quantity {values['quantity']!r} (known: {', '.join(QUANTITIES)})", where, "id1")
    try:
        force = float(values["force"])
    except ValueError:
        raise InputError(f"force={values['force']!r} is not a number", where, "id4") from None
    if not (math.isfinite(force) and force > 0):
        raise InputError(f"force={values['force']} is not a force amplitude > 0 N", where, "id4")
    if force_problem(force):        # the range of every door (analysis/common/quantities.py)
        raise InputError(f"force= {force_problem(force)}", where, "id4")
    for key, allowed in (("kind", KINDS), ("direction", DIRECTIONS), ("status", STATUSES)):
        if values[key] not in allowed:
            raise InputError(f"{key}={values[key]} is not one of {', '.join(allowed)}", where, "id4")
    convention = _words(ids.get("id5", "")).get("convention", CONVENTION)
    if convention != CONVENTION:        # contactid writes one convention: another would reverse every phase
        raise InputError(f"convention={convention} is not contactid's {CONVENTION}: the record's phases would be "
                         "read reversed", where, "id5")
    records = _words(ids.get("id5", "")).get("records")
    if records is not None and not (records.isdigit() and int(records) > 0):
        raise InputError(f"records={records} is not a count of records", where, "id5")
    fs, segment = _welch(ids, where)
    control = read_control(_words(ids.get("id3", "")), values["ref"], force, where, "id3")
    return RecordTag(values["run"], values["quantity"], values["rsp"], values["ref"], values["kind"], force,
                     values["direction"], values["status"], int(records) if records else None, fs, segment,
                     control)


def disagreement(tag: RecordTag, first: RecordTag) -> tuple[str, str] | None:
    """The first word (and its id line) in which two records of one run disagree, or None: a run is one level,
    one status, one control, and a record stating otherwise is damaged or edited -- which one is right is not
    for the import to pick."""
    for key, line in RUN_WORDS:
        if getattr(tag, key) != getattr(first, key):
            return key, line
    return None
