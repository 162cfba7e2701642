"""Run records: the per-step log (steps.jsonl), its schema, durable appends.

Why this module exists: a trial's only ground truth is ``runs/<name>/steps.jsonl``
(schema: docs/ARCHITECTURE.md, "Run records"). Every number the project reports (the
summary, the protocol table, the cumulative plots, the live counters after a resume)
is recomputed from it by ``testbed.records.metrics``, so the report and the trial can
never disagree.

::

    fleet loop ── write_step ──► steps.jsonl  (append, flush, fsync: a crash tears at
                                     │          most the last line)
                                     ▼
    report / resume ◄── read_steps (drops a torn last line) ──► summarize / cumulative
                                                                      │
                                           summary.json ◄── atomic_write_json

A row's optional fields beyond the schema's required ones: ``wall_time`` and ``duration_s``
(section 9), ``faults``, and, only in runs whose humans can be away (the web console),
``away`` (the humans not available at that step's allocation) and ``released`` (the
interventions ended before it because their human was gone: ``{"robot", "human",
"why"}``). Absent means none, so the rows of other runs are unchanged.

Everything else a run keeps (summary, config, checkpoints) is replaced atomically
(temp file in the same folder, fsync, ``os.replace``, fsync the folder), so a reader
sees either the old or the new file, never half of one.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, Final

from testbed.core.atomic import atomic_write_json, fsync_dir, json_default
from testbed.core.types import NUM_ACTIONS, Mode

__all__ = [
    "ARM_FIELDS",
    "STEPS_FILE",
    "STEP_FIELDS",
    "SUMMARY_FILE",
    "RecordError",
    "RunWriter",
    "read_steps",
    "truncate_torn_tail",
    "validate_step",
]

STEPS_FILE: Final = "steps.jsonl"
SUMMARY_FILE: Final = "summary.json"
_MODES: Final = frozenset(m.value for m in Mode)
HUMAN_MODES: Final = frozenset({Mode.TELEOP.value, Mode.RESET.value})
IDLE_MODES: Final = frozenset({Mode.IDLE.value, Mode.RESET.value})
_NOHUMAN_MODES: Final = frozenset({Mode.AUTONOMOUS.value, Mode.IDLE.value})
# A refused push (the host could not push, e.g. the cube was not found) counts as neither
# autonomous nor human (docs/notes/core.md); the human of a refused teleop step is kept.

STEP_FIELDS: Final[dict[str, bool]] = {
    "t": True, "robots": True, "faults": False, "away": False, "released": False,
    "wall_time": False, "duration_s": False}
"""Every key of a step row that :func:`validate_step` checks, and whether it is required.
docs/ARCHITECTURE.md's "Run records" lists the same keys (optional ones with ``?``):
``tests/testbed/test_records.py`` holds the two and the validator's behaviour equal, so
a new key is added here, in the validator and in the doc together."""
ARM_FIELDS: Final[dict[str, bool]] = {
    "robot": True, "mode": True, "human": True, "action": True, "success": True,
    "violation": True, "uncertainty": True, "risk": True, "key": True, "refused": False,
    "served": False, "first": False, "monitor": False, "waited": False, "readings": False}
"""The same for each entry of a row's ``robots``."""


class RecordError(ValueError):
    """A run record that does not follow the run-record schema; the message says where."""


# ------------------------------------------------------------------------ schema
def _is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: object) -> bool:
    return (isinstance(v, int | float) and not isinstance(v, bool)
            and math.isfinite(float(v)))


def _check_intervention(row: dict[str, Any], where: str, human: object) -> None:
    """``served`` (an int >= 0, only with a human), ``first`` (``{"steps": served,
    "s": seconds >= 0 or null}``, only with ``served``) and ``waited`` (an int >= 1,
    only without a human): optional, as rows written before them have none."""
    waited = row.get("waited")
    if "waited" in row and not (_is_int(waited) and waited >= 1 and human is None):
        raise RecordError(f"{where}.waited must be an int >= 1 on an arm with no human, "
                          f"got {waited!r} (human {human!r})")
    served = row.get("served")
    if "served" in row and not (_is_int(served) and served >= 0 and human is not None):
        raise RecordError(f"{where}.served must be an int >= 0 on an arm with a human, "
                          f"got {served!r} (human {human!r})")
    if "first" not in row:
        return
    first = row["first"]
    if not (isinstance(first, dict) and first.get("steps") == served and "served" in row):
        raise RecordError(f"{where}.first must be {{\"steps\": served, \"s\": ...}}, got "
                          f"{first!r} (served {served!r})")
    secs = first.get("s")
    if secs is not None and not (_is_number(secs) and secs >= 0):
        raise RecordError(f"{where}.first.s must be a number >= 0 or null, got {secs!r}")


def validate_step(obj: object) -> None:
    """Raise ``RecordError`` naming the field unless ``obj`` is a valid step row.

    Extra fields are allowed (the row is extensible); the listed ones must be there
    with their types, robots must be unique, and the human must match the mode:
    autonomous and idle arms have none, teleop and reset arms have one, a refused arm
    may have one (a teleop push the host refused) and says why in ``refused``.
    ``wall_time`` and ``duration_s`` (timing for the lab) are optional, so records
    written before them still read, but must be finite numbers >= 0 when present; so
    are ``faults`` (robot -> reason), ``away`` (a list of human indices) and
    ``released`` (a list of ``{"robot": one of the row's robots, "human": int >= 0,
    "why": str}``), and an arm's ``monitor`` (the failure monitor's scores beyond
    uncertainty and risk: name -> finite number), ``readings`` (what the robot host
    measured of the arm's push: name -> finite number) and ``waited`` (steps waited for
    a human, on an arm with none). Every key checked: ``STEP_FIELDS``, ``ARM_FIELDS``.
    """
    if not isinstance(obj, dict):
        raise RecordError(f"step must be a JSON object, got {type(obj).__name__}")
    t = obj.get("t")
    if not _is_int(t) or t < 0:
        raise RecordError(f"t must be an int >= 0, got {t!r}")
    for timing in ("wall_time", "duration_s"):
        if timing in obj and not (_is_number(obj[timing]) and obj[timing] >= 0):
            raise RecordError(f"{timing} must be a finite number >= 0, got {obj[timing]!r}")
    robots = obj.get("robots")
    if not isinstance(robots, list):
        raise RecordError(f"robots must be a list, got {type(robots).__name__}")
    seen: set[str] = set()
    for i, row in enumerate(robots):
        where = f"robots[{i}]"
        if not isinstance(row, dict):
            raise RecordError(f"{where} must be an object")
        name = row.get("robot")
        if not isinstance(name, str) or not name:
            raise RecordError(f"{where}.robot must be a non-empty string, got {name!r}")
        if name in seen:
            raise RecordError(f"{where}.robot {name!r} appears twice")
        seen.add(name)
        mode = row.get("mode")
        if mode not in _MODES:
            raise RecordError(f"{where}.mode must be one of {sorted(_MODES)}, got {mode!r}")
        human = row.get("human", ...)
        if human is ... or not (human is None or (_is_int(human) and human >= 0)):
            raise RecordError(f"{where}.human must be an int >= 0 or null, got "
                              f"{'nothing' if human is ... else repr(human)}")
        if mode in HUMAN_MODES and human is None:
            raise RecordError(f"{where}: mode {mode!r} needs a human")
        if mode in _NOHUMAN_MODES and human is not None:
            raise RecordError(f"{where}: mode {mode!r} cannot have a human")
        refused = row.get("refused")
        if mode == Mode.REFUSED.value and not (isinstance(refused, str) and refused):
            raise RecordError(f"{where}: mode 'refused' needs the reason in refused, got "
                              f"{refused!r}")
        if "refused" in row and mode != Mode.REFUSED.value:
            raise RecordError(f"{where}.refused is only for mode 'refused', got mode {mode!r}")
        _check_intervention(row, where, human)
        action = row.get("action", ...)
        if action is ... or not (action is None or (_is_int(action)
                                                    and 0 <= action < NUM_ACTIONS)):
            raise RecordError(f"{where}.action must be an int in [0, {NUM_ACTIONS}) or "
                              f"null, got {'nothing' if action is ... else repr(action)}")
        for flag in ("success", "violation"):
            if not isinstance(row.get(flag), bool):
                raise RecordError(f"{where}.{flag} must be a bool, got {row.get(flag)!r}")
        for sig in ("uncertainty", "risk"):
            value = row.get(sig, ...)
            if value is ... or not (value is None or _is_number(value)):
                raise RecordError(f"{where}.{sig} must be a finite number or null, got "
                                  f"{'nothing' if value is ... else repr(value)}")
        key = row.get("key")
        if not isinstance(key, list) or not all(_is_number(k) for k in key):
            raise RecordError(f"{where}.key must be a list of finite numbers, got {key!r}")
        for named, what in (("monitor", "signal names"), ("readings", "reading names")):
            values = row.get(named, {})
            if not (isinstance(values, dict) and all(
                    isinstance(k, str) and _is_number(v) for k, v in values.items())):
                raise RecordError(f"{where}.{named} must map {what} to finite numbers, "
                                  f"got {values!r}")
    _validate_presence(obj, seen)


def _validate_presence(obj: dict[str, Any], robots: set[str]) -> None:
    """The optional ``faults`` (robot -> the host's reason), ``away`` and ``released``
    of a step row (away humans, web console)."""
    faults = obj.get("faults", {})
    if not (isinstance(faults, dict) and all(
            isinstance(k, str) and isinstance(v, str) for k, v in faults.items())):
        raise RecordError(f"faults must map robots to reasons (strings), got {faults!r}")
    if "away" in obj:
        away = obj["away"]
        if not isinstance(away, list) or not all(_is_int(h) and h >= 0 for h in away):
            raise RecordError(f"away must be a list of human indices (ints >= 0), got {away!r}")
    if "released" in obj:
        released = obj["released"]
        if not isinstance(released, list):
            raise RecordError(f"released must be a list, got {type(released).__name__}")
        for i, entry in enumerate(released):
            ok = (isinstance(entry, dict) and isinstance(entry.get("robot"), str)
                  and entry["robot"] in robots
                  and _is_int(entry.get("human")) and entry["human"] >= 0
                  and isinstance(entry.get("why"), str) and entry["why"] != "")
            if not ok:
                raise RecordError(f"released[{i}] must be {{robot: one of the row's robots, "
                                  f"human: int >= 0, why: str}}, got {entry!r}")


# ------------------------------------------------------------------------ writing
def truncate_torn_tail(path: str | os.PathLike[str]) -> int:
    """Cut a torn last line (bytes after the last newline) off a JSONL file.

    Returns how many bytes were removed (0 if the file ends in a newline or does not
    exist). Resume calls this (``RunWriter`` does on open) so a new step is never
    glued onto half of an old one.
    """
    p = Path(path)
    if not p.exists():
        return 0
    with open(p, "r+b") as f:
        size = f.seek(0, os.SEEK_END)
        if size == 0:
            return 0
        # Walk back in blocks to the last newline.
        pos, block = size, 65536
        keep = 0
        while pos > 0:
            start = max(0, pos - block)
            f.seek(start)
            chunk = f.read(pos - start)
            nl = chunk.rfind(b"\n")
            if nl >= 0:
                keep = start + nl + 1
                break
            pos = start
        removed = size - keep
        if removed:
            f.truncate(keep)
            f.flush()
            os.fsync(f.fileno())
    return removed


class RunWriter:
    """Appends one JSON line per timestep to ``<run_dir>/steps.jsonl``, durably.

    Every :meth:`write_step` is written, flushed and fsynced before it returns, so a
    crash loses at most the step being written (a torn last line). Opening an
    existing log (resume) first cuts such a torn line off.
    """

    def __init__(self, run_dir: str | os.PathLike[str], *, validate: bool = True) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.path = self.run_dir / STEPS_FILE
        self.validate = validate
        self.torn_bytes_dropped = truncate_torn_tail(self.path)
        created = not self.path.exists()
        self._file = open(self.path, "a", encoding="utf-8")  # noqa: SIM115 (closed in close())
        if created:
            fsync_dir(self.run_dir)

    def write_step(self, obj: Mapping[str, Any]) -> None:
        """Append ``obj`` as one line, then flush and fsync."""
        if self._file.closed:
            raise ValueError(f"{self.path}: the run writer is closed")
        if self.validate:
            validate_step(dict(obj))
        line = json.dumps(obj, separators=(",", ":"), allow_nan=False, default=json_default)
        self._file.write(line + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def write_summary(self, summary: Mapping[str, Any]) -> None:
        """Atomically (re)write ``<run_dir>/summary.json``."""
        atomic_write_json(self.run_dir / SUMMARY_FILE, dict(summary))

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


# ------------------------------------------------------------------------ reading
def read_steps(path: str | os.PathLike[str], *, validate: bool = True) -> list[dict[str, Any]]:
    """Read a steps.jsonl (or a run folder holding one); a torn last line is dropped.

    The last line is torn when it lacks its final newline (the writer ends every step
    with one). Any other unreadable line (bad JSON, not an object, blank, or, with
    ``validate``, a schema error) raises ``RecordError`` naming the line number.
    """
    p = Path(path)
    if p.is_dir():
        p = p / STEPS_FILE
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise RecordError(f"{p}: cannot read ({exc.strerror})") from None
    lines = data.split(b"\n")
    lines.pop()  # after the last newline: b"" or the torn tail
    steps: list[dict[str, Any]] = []
    for number, raw in enumerate(lines, start=1):
        try:
            obj = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise RecordError(f"{p}:{number}: not a JSON line ({exc})") from None
        if validate:
            try:
                validate_step(obj)
            except RecordError as exc:
                raise RecordError(f"{p}:{number}: {exc}") from None
        elif not isinstance(obj, dict):
            raise RecordError(f"{p}:{number}: not a JSON object")
        steps.append(obj)
    return steps


