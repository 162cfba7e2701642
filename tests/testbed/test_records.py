"""Run records: the step schema, durable appends, torn tails, and every metric."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.atomic import atomic_write_bytes, atomic_write_json
from testbed.core.types import IMAGE_SIZE, Mode
from testbed.records.metrics import cumulative, rohe, summarize
from testbed.records.step_record import ArmStep, StepRecord
from testbed.records.steps import (
    ARM_FIELDS,
    STEP_FIELDS,
    STEPS_FILE,
    RecordError,
    RunWriter,
    read_steps,
    truncate_torn_tail,
    validate_step,
)


def robot(name: str, mode: str, human: int | None = None, *, action: int | None = None,
          success: bool = False, violation: bool = False) -> dict[str, Any]:
    return {"robot": name, "mode": mode, "human": human, "action": action,
            "success": success, "violation": violation, "uncertainty": 0.1, "risk": None,
            "key": [0.0, 0.1]}


# A hand-built 4-step log of 3 robots and 2 humans; the expected totals by hand:
#   successes 3 (t0 a, t2 b, t3 c); hard_resets 2 (t0 c, t2 a);
#   idle: t1 c idle, t2 c reset, t3 a idle, t3 c reset -> 4 (idle or reset);
#   human actions: t0 b teleop, t1 b teleop, t2 c reset, t3 b teleop, t3 c reset -> 5.
LOG: list[dict[str, Any]] = [
    {"t": 0, "robots": [robot("h/a", "autonomous", action=1, success=True),
                        robot("h/b", "teleop", 0, action=2),
                        robot("h/c", "autonomous", action=0, violation=True)]},
    {"t": 1, "robots": [robot("h/a", "autonomous", action=3),
                        robot("h/b", "teleop", 0, action=2),
                        robot("h/c", "idle")]},
    {"t": 2, "robots": [robot("h/a", "autonomous", action=3, violation=True),
                        robot("h/b", "autonomous", action=0, success=True),
                        robot("h/c", "reset", 1)]},
    {"t": 3, "robots": [robot("h/a", "idle"),
                        robot("h/b", "teleop", 0, action=1),
                        robot("h/c", "reset", 1, success=True)]},
]


def write_log(path: Path, rows: list[dict[str, Any]], tail: bytes = b"") -> Path:
    path.write_bytes(b"".join(json.dumps(r).encode() + b"\n" for r in rows) + tail)
    return path


# --------------------------------------------------------------------- metrics


def test_summarize_a_hand_built_log() -> None:
    s = summarize(LOG, "cur", num_humans=2)
    assert s == {
        "algorithm": "cur", "steps": 4, "num_robots": 3, "num_humans": 2,
        "successes": 3, "hard_resets": 2, "idle_time": 4, "human_actions": 5,
        "rohe": pytest.approx((2 / 3) * 3 / (1 + 5)),
        "teleop_steps": 3, "reset_steps": 2, "fault_steps": 0, "refused_steps": 0,
        "last_t": 3,
    }
    assert summarize(LOG, "cur", num_humans=2, num_robots=4)["rohe"] == pytest.approx(
        (2 / 4) * 3 / 6)


def test_rohe_is_the_papers_formula() -> None:
    assert rohe(10, 0, num_humans=2, num_robots=4) == 5.0
    assert rohe(10, 4, num_humans=10, num_robots=100) == pytest.approx(0.1 * 10 / 5)
    assert rohe(3, 1, num_humans=2, num_robots=0) == 0.0


def test_summarize_counts_faults_but_not_as_effort() -> None:
    rows = [{"t": 0, "robots": [robot("h/a", "fault"), robot("h/b", "fault", 1)]}]
    s = summarize(rows, "bc", num_humans=2)
    assert (s["fault_steps"], s["human_actions"], s["idle_time"]) == (2, 0, 0)


def test_summarize_counts_refused_as_neither_autonomous_nor_human() -> None:
    rows = [{"t": 0, "wall_time": 1.7e9, "duration_s": 0.8,
             "robots": [robot("h/a", "refused", action=2) | {"refused": "cube not found"},
                        robot("h/b", "refused", 1, action=0) | {"refused": "cube not found"},
                        robot("h/c", "autonomous", action=1, success=True)]}]
    for row in rows:
        validate_step(row)
    s = summarize(rows, "cur", num_humans=2)
    assert (s["refused_steps"], s["human_actions"], s["idle_time"], s["teleop_steps"],
            s["successes"]) == (2, 0, 0, 0, 1)
    assert s["rohe"] == pytest.approx((2 / 3) * 1 / 1)


def test_summarize_empty_log() -> None:
    s = summarize([], "random", num_humans=2)
    assert (s["steps"], s["num_robots"], s["successes"], s["rohe"], s["last_t"]) == \
        (0, 0, 0, 0.0, None)


def test_summarize_refuses_a_log_whose_t_does_not_increase() -> None:
    with pytest.raises(RecordError, match=r"t=1 does not increase \(previous t=1\)"):
        summarize([LOG[0], LOG[1], LOG[1]], "cur", num_humans=2)


def test_cumulative_curves_end_at_the_summary() -> None:
    curves = cumulative(LOG, num_humans=2)
    np.testing.assert_array_equal(curves["t"], [0, 1, 2, 3])
    np.testing.assert_array_equal(curves["successes"], [1, 1, 2, 3])
    np.testing.assert_array_equal(curves["hard_resets"], [1, 1, 2, 2])
    np.testing.assert_array_equal(curves["idle_time"], [0, 1, 2, 4])
    np.testing.assert_array_equal(curves["human_actions"], [1, 2, 3, 5])
    np.testing.assert_allclose(curves["rohe"],
                               (2 / 3) * np.array([1, 1, 2, 3]) / (1 + np.array([1, 2, 3, 5])))
    s = summarize(LOG, "cur", num_humans=2)
    for k in ("successes", "hard_resets", "idle_time", "human_actions", "rohe"):
        assert curves[k][-1] == pytest.approx(s[k])
    assert "rohe" not in cumulative(LOG)


# ---------------------------------------------------------------------- reading


def test_read_steps_drops_a_torn_last_line(tmp_path: Path) -> None:
    path = write_log(tmp_path / STEPS_FILE, LOG, tail=b'{"t": 4, "robots": [{"rob')
    assert read_steps(path) == LOG
    assert summarize(read_steps(path), "cur", 2)["successes"] == 3
    # A run folder works too.
    assert read_steps(tmp_path) == LOG


def test_read_steps_drops_a_last_line_without_its_newline_even_if_complete(
        tmp_path: Path) -> None:
    # The writer ends every step with a newline; without it the step did not finish.
    path = write_log(tmp_path / STEPS_FILE, LOG[:3], tail=json.dumps(LOG[3]).encode())
    assert read_steps(path) == LOG[:3]


def test_read_steps_drops_nul_padding_left_by_a_crash(tmp_path: Path) -> None:
    path = write_log(tmp_path / STEPS_FILE, LOG, tail=b"\0" * 100)
    assert read_steps(path) == LOG


@pytest.mark.parametrize(
    ("bad_line", "match"),
    [(b'{"t": 1, "rob', r":2: not a JSON line"),
     (b"", r":2: not a JSON line"),
     (b"[1, 2]", r":2: step must be a JSON object"),
     (b'{"t": 1, "robots": [{"robot": "x"}]}', r":2: robots\[0\]\.mode must be one of")],
)
def test_any_other_bad_line_is_an_error_naming_its_number(
        tmp_path: Path, bad_line: bytes, match: str) -> None:
    path = tmp_path / STEPS_FILE
    path.write_bytes(json.dumps(LOG[0]).encode() + b"\n" + bad_line + b"\n"
                     + json.dumps(LOG[2]).encode() + b"\n")
    with pytest.raises(RecordError, match=match):
        read_steps(path)


def test_read_steps_without_validation_still_wants_objects(tmp_path: Path) -> None:
    path = tmp_path / STEPS_FILE
    path.write_bytes(b'{"t": 0, "anything": 1}\n3\n')
    with pytest.raises(RecordError, match=r":2: not a JSON object"):
        read_steps(path, validate=False)
    path.write_bytes(b'{"t": 0, "anything": 1}\n')
    assert read_steps(path, validate=False) == [{"t": 0, "anything": 1}]


def test_read_steps_of_a_missing_or_empty_file(tmp_path: Path) -> None:
    with pytest.raises(RecordError, match="cannot read"):
        read_steps(tmp_path / "nope.jsonl")
    (tmp_path / STEPS_FILE).write_bytes(b"")
    assert read_steps(tmp_path / STEPS_FILE) == []


# ------------------------------------------------------------------ torn tails


def test_truncate_torn_tail(tmp_path: Path) -> None:
    path = write_log(tmp_path / STEPS_FILE, LOG[:2], tail=b'{"t": 2, "ro')
    size = path.stat().st_size
    assert truncate_torn_tail(path) == len(b'{"t": 2, "ro')
    assert path.stat().st_size == size - 12
    assert read_steps(path) == LOG[:2]
    assert truncate_torn_tail(path) == 0
    assert truncate_torn_tail(tmp_path / "missing.jsonl") == 0


def test_truncate_a_tail_longer_than_a_block_and_a_file_with_no_newline(
        tmp_path: Path) -> None:
    path = write_log(tmp_path / STEPS_FILE, LOG[:1], tail=b"x" * 200_000)
    assert truncate_torn_tail(path) == 200_000
    assert read_steps(path) == LOG[:1]
    lone = tmp_path / "lone.jsonl"
    lone.write_bytes(b'{"t": 0')
    assert truncate_torn_tail(lone) == 7 and lone.read_bytes() == b""


# ---------------------------------------------------------------------- writing


def test_run_writer_appends_flushes_and_fsyncs_every_step(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    real_fsync = os.fsync

    def counting_fsync(fd: int) -> None:
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", counting_fsync)
    run = tmp_path / "runs" / "cur-s0"
    with RunWriter(run) as w:
        for i, row in enumerate(LOG[:2]):
            before = len(synced)
            w.write_step(row)
            assert len(synced) > before
            # Readable by another reader right away: flushed, one line each.
            assert read_steps(run) == LOG[: i + 1]
    with RunWriter(run) as w:  # resume: append, never truncate whole lines
        w.write_step(LOG[2])
        w.write_step(LOG[3])
    assert read_steps(run) == LOG
    assert (run / STEPS_FILE).read_text().count("\n") == 4


def test_run_writer_cuts_a_torn_tail_before_appending(tmp_path: Path) -> None:
    write_log(tmp_path / STEPS_FILE, LOG[:2], tail=b'{"t": 2, "rob')
    with RunWriter(tmp_path) as w:
        assert w.torn_bytes_dropped == 13
        w.write_step(LOG[2])
    assert read_steps(tmp_path) == LOG[:3]


def test_run_writer_refuses_bad_rows_and_writes_numpy_scalars(tmp_path: Path) -> None:
    with RunWriter(tmp_path) as w:
        with pytest.raises(RecordError, match=r"robots\[0\]\.success must be a bool"):
            w.write_step({"t": 0, "robots": [robot("h/a", "autonomous") | {"success": 1}]})
        row = {"t": np.int64(0), "robots": [robot("h/a", "teleop", 0, action=2)],
               "extra": np.float32(0.5)}
        w.validate = False  # numpy ints are not JSON ints until written
        w.write_step(row)
        with pytest.raises(ValueError, match="Out of range float values"):
            w.write_step({"t": 1, "robots": [], "bad": float("nan")})
    assert read_steps(tmp_path)[0]["extra"] == 0.5
    with pytest.raises(ValueError, match="closed"):
        w.write_step(LOG[0])


def test_write_summary_is_atomic_json(tmp_path: Path) -> None:
    with RunWriter(tmp_path) as w:
        for row in LOG:
            w.write_step(row)
        w.write_summary(summarize(read_steps(tmp_path), "cur", num_humans=2))
    data = json.loads((tmp_path / "summary.json").read_text())
    assert data["human_actions"] == 5 and data["algorithm"] == "cur"


# ------------------------------------------------------------------ atomic writes


def test_atomic_write_bytes_replaces_and_leaves_no_temp(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    target = tmp_path / "sub" / "ckpt.bin"
    atomic_write_bytes(target, b"one")
    atomic_write_bytes(target, b"two")
    assert target.read_bytes() == b"two"
    assert sorted(p.name for p in target.parent.iterdir()) == ["ckpt.bin"]
    assert len(synced) >= 4  # file and folder, twice


def test_atomic_write_failure_keeps_the_old_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "state.json"
    atomic_write_json(target, {"t": 1, "arr": np.arange(2), "x": np.float64(0.5)})
    assert json.loads(target.read_text()) == {"t": 1, "arr": [0, 1], "x": 0.5}
    with pytest.raises(ValueError):
        atomic_write_json(target, {"t": float("nan")})

    def broken_replace(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(target, b"garbage")
    assert json.loads(target.read_text())["t"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["state.json"]


# ---------------------------------------------------------------------- schema


def test_valid_rows_pass() -> None:
    for row in LOG:
        validate_step(row)
    validate_step({"t": 0, "robots": [], "faults": {"h/a": "timeout"}})  # extras allowed
    validate_step({"t": 0, "robots": [robot("h/a", "fault", 1)]})
    # Timing, and a push the host refused (with or without a human)
    validate_step({"t": 3, "wall_time": 1.7e9, "duration_s": 0.0, "robots": [
        robot("h/a", "refused", action=1) | {"refused": "cube not found"},
        robot("h/b", "refused", 0, action=1) | {"refused": "arm violating"}]})


@pytest.mark.parametrize(
    ("patch", "match"),
    [({"mode": "flying"}, r"robots\[0\]\.mode must be one of"),
     ({"mode": "teleop", "human": None}, r"mode 'teleop' needs a human"),
     ({"mode": "reset", "human": None}, r"mode 'reset' needs a human"),
     ({"mode": "autonomous", "human": 0}, r"mode 'autonomous' cannot have a human"),
     ({"mode": "idle", "human": 1}, r"mode 'idle' cannot have a human"),
     ({"human": -1, "mode": "teleop"}, r"human must be an int >= 0 or null"),
     ({"human": True, "mode": "teleop"}, r"human must be an int"),
     ({"action": 4}, r"action must be an int in \[0, 4\)"),
     ({"action": 1.0}, r"action must be an int"),
     ({"success": None}, r"success must be a bool"),
     ({"violation": 0}, r"violation must be a bool"),
     ({"uncertainty": "high"}, r"uncertainty must be a finite number or null"),
     ({"risk": float("inf")}, r"risk must be a finite number or null"),
     ({"key": [1, "a"]}, r"key must be a list of finite numbers"),
     ({"key": 1.0}, r"key must be a list"),
     ({"robot": ""}, r"robot must be a non-empty string"),
     ({"mode": "refused"}, r"mode 'refused' needs the reason in refused, got None"),
     ({"mode": "refused", "refused": ""}, r"needs the reason in refused"),
     ({"refused": "cube not found"}, r"refused is only for mode 'refused'"),
     ({"waited": 0}, r"waited must be an int >= 1 on an arm with no human"),
     ({"waited": 2.0}, r"waited must be an int"),
     ({"mode": "refused", "refused": "x", "human": 0, "waited": 2},
      r"waited must be an int >= 1 on an arm with no human, got 2 \(human 0\)")],
)
def test_bad_rows_name_the_field(patch: dict[str, Any], match: str) -> None:
    row = {"t": 0, "robots": [robot("h/a", "autonomous", action=1) | patch]}
    with pytest.raises(RecordError, match=match):
        validate_step(row)


@pytest.mark.parametrize(
    ("row", "match"),
    [({"robots": []}, r"t must be an int >= 0"),
     ({"t": -1, "robots": []}, r"t must be an int >= 0"),
     ({"t": True, "robots": []}, r"t must be an int"),
     ({"t": 0}, r"robots must be a list"),
     ({"t": 0, "robots": [1]}, r"robots\[0\] must be an object"),
     ({"t": 0, "robots": [robot("h/a", "idle"), robot("h/a", "idle")]}, r"appears twice"),
     ({"t": 0, "robots": [{k: v for k, v in robot("h/a", "idle").items() if k != "human"}]},
      r"human must be an int >= 0 or null, got nothing"),
     ({"t": 0, "robots": [], "wall_time": "noon"}, r"wall_time must be a finite number >= 0"),
     ({"t": 0, "robots": [], "duration_s": -0.1}, r"duration_s must be a finite number >= 0"),
     ({"t": 0, "robots": [], "duration_s": float("nan")}, r"duration_s must be a finite")],
)
def test_bad_steps_name_the_field(row: dict[str, Any], match: str) -> None:
    with pytest.raises(RecordError, match=match):
        validate_step(row)


# ------------------------------------------------------- the schema as documented
DOC = Path(__file__).resolve().parents[2] / "docs" / "ARCHITECTURE.md"


def documented_keys() -> tuple[dict[str, bool], dict[str, bool]]:
    """docs/ARCHITECTURE.md's steps.jsonl line ("Run records"): the keys of a row and of
    each arm, each with whether it is required (no ``?`` after it); keys nested deeper
    (``first``'s ``steps``, ``s``) are the field's own shape, not keys of the row."""
    section = DOC.read_text(encoding="utf-8").split("## Run records", 1)[1]
    start = section.index('`{"t": int')
    block = section[start + 1: section.index("}`", start) + 1]
    step: dict[str, bool] = {}
    arm: dict[str, bool] = {}
    depth = 0
    for m in re.finditer(r'"(\w+)"(\?)?:|[\[\]{}]', block):
        if m.group(0) in "{[":
            depth += 1
        elif m.group(0) in "}]":
            depth -= 1
        elif depth in (1, 3):  # the row's object; an arm's, inside "robots": [{
            (step if depth == 1 else arm)[m.group(1)] = m.group(2) is None
    assert depth == 0, "the documented row's brackets do not close"
    return step, arm


WITHOUT: dict[str, dict[str, Any]] = {"served": {"first": ...}, "refused": {"mode": "teleop"}}
"""What else an arm without an optional key changes to stay valid (``...``: dropped too):
``first`` is on a ``served``, mode ``refused`` says why in ``refused``."""


def full_row() -> dict[str, Any]:
    """A row with every key the writer can write: an arm with a human (refused, served,
    first, monitor, readings) and an arm waiting for one, faults, away, released, timing."""
    arms = [ArmStep("h/a", Mode.REFUSED, 1, 2, True, False, 0.25, 0.5, (3.0,),
                    refused="guard stop", served=4, first=(4, 1.5), monitor={"novelty": 0.5},
                    readings={"push_s": 1.25}),
            ArmStep("h/b", Mode.IDLE, None, None, False, False, 0.1, 0.2, (1.0,), waited=3)]
    images = np.zeros((2, IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
    return StepRecord(5, 0, arms, images, np.ones(2, bool), np.zeros((2, 2), np.float32),
                      faults={"h/c": "timeout"}, away=[0],
                      released=[{"robot": "h/a", "human": 0, "why": "away"}],
                      wall_time=1.5, duration_s=0.25).to_row()


def test_the_documented_step_schema_is_the_one_validate_step_checks() -> None:
    """The doc's keys are the validator's (``STEP_FIELDS``, ``ARM_FIELDS``), required as
    it requires them, and every key the writer writes is one of them: a key added to
    the writer, the validator or the doc alone fails here."""
    step, arm = documented_keys()
    assert step == STEP_FIELDS, "docs/ARCHITECTURE.md's row keys (\"?\": optional)"
    assert arm == ARM_FIELDS, "docs/ARCHITECTURE.md's arm keys (\"?\": optional)"
    row = full_row()
    validate_step(row)
    assert set(row) == set(STEP_FIELDS)
    assert {k for r in row["robots"] for k in r} == set(ARM_FIELDS)
    for key, required in STEP_FIELDS.items():  # the validator knows each key ...
        broken = row | {key: float("nan")}
        with pytest.raises(RecordError):
            validate_step(broken)
        missing = {k: v for k, v in row.items() if k != key}  # ... and requires it or not
        if required:
            with pytest.raises(RecordError):
                validate_step(missing)
        else:
            validate_step(missing)
    for key, required in ARM_FIELDS.items():
        i = next(i for i, r in enumerate(row["robots"]) if key in r)
        for value in (float("nan"), ...):
            arms = [dict(r) for r in row["robots"]]
            if value is ...:
                del arms[i][key]
                for other, then in WITHOUT.get(key, {}).items():
                    if then is ...:
                        del arms[i][other]
                    else:
                        arms[i][other] = then
            else:
                arms[i][key] = value
            if value is ... and not required:
                validate_step(row | {"robots": arms})
            else:
                with pytest.raises(RecordError):
                    validate_step(row | {"robots": arms})
