"""The YuMi's zones proof, rule for rule and line for line (docs/notes/tests.md, mutation
testing).

Why: drivers/yumi/zones_proof.py decides whether the driver may move the arm (the world
zones known active since the last restart), and what ``testbed check`` and a refused
start say. test_yumi_fail_closed_zones.py holds the rules on hand-made logs; a refusal
worded otherwise, an entry that names its task in the wrong place, a proof file of
another size or mode taken, or a check's line that names the wrong entry does not change
those. Here every expected line is written out from the module's rules (an entry is the
task's Zones Active entry when its code is 80003, its title or first argument is
"Testbed Zones Active" and its second argument is the task: robot/rapid/TestbedZones.sys)
and every record from its format. Pure: no twin, no sshd; logs are hand-made, newest
first.
"""

from __future__ import annotations

import json
import os
import stat
from datetime import datetime
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from event_log_entries import e, on, other, restart

from drivers.yumi.zones_proof import (
    MAX_PROOF_BYTES,
    PROOF_FORMAT,
    ZONES_ACTIVE,
    ZONES_COUNT,
    ProofFileError,
    ZonesProof,
    entry_key,
    entry_record,
    proof_path,
    read_proof_file,
    stamp,
    zones_active_count,
    zones_known,
    zones_known_problem,
    zones_refusal,
)

TASKS = ("T_ROB_L", "T_ROB_R")
SERIAL = "14000-500000"
FIX = ("restart the controller so tb_zones runs (the POWER_ON event routine) and writes its "
       "entries (robot/README.md, 'The zones')")


# -- one entry ----------------------------------------------------------------------------
def test_a_zones_active_entry_is_80003_titled_so_naming_the_task_second() -> None:
    assert zones_active_count(on(1, "T_ROB_L", 7), "T_ROB_L") == 7
    assert zones_active_count(on(1, "T_ROB_L", 12), "T_ROB_L") == 12
    assert zones_active_count(on(1, "T_ROB_L"), "T_ROB_R") is None
    assert zones_active_count(e(1, 80001, ZONES_ACTIVE, "T_ROB_L", "zones 5"), "T_ROB_L") \
        is None  # a refusal's code
    # the title alone, or the first argument alone, names it
    assert zones_active_count(e(1, 80003, "x", "T_ROB_L", "zones 4", title=ZONES_ACTIVE),
                              "T_ROB_L") == 4
    assert zones_active_count(e(1, 80003, ZONES_ACTIVE, "T_ROB_L", "zones 3", title="x"),
                              "T_ROB_L") == 3
    assert zones_active_count(e(1, 80003, "x", "T_ROB_L", "zones 3", title="y"),
                              "T_ROB_L") is None
    # the task must be the second argument, not a later one
    assert zones_active_count(e(1, 80003, ZONES_ACTIVE, "zones 5", "T_ROB_L"), "T_ROB_L") \
        is None
    # no count named: 0; the count anywhere in the arguments
    assert zones_active_count(e(1, 80003, ZONES_ACTIVE, "T_ROB_L", "now"), "T_ROB_L") == 0
    assert zones_active_count(e(1, 80003, ZONES_ACTIVE, "T_ROB_L", "at", "zones 6"),
                              "T_ROB_L") == 6
    # no arguments at all (the title alone): no task, not the task's entry
    bare = SimpleNamespace(seqnum=1, code=80003, title=ZONES_ACTIVE, args=None)
    assert zones_active_count(bare, "T_ROB_L") is None
    no_args = SimpleNamespace(seqnum=1, code=80003, title=ZONES_ACTIVE)
    assert zones_active_count(no_args, "T_ROB_L") is None


def test_an_entry_is_named_by_number_code_and_time_stamp() -> None:
    when = datetime(2026, 1, 2, 3, 4, 5)
    assert stamp(when) == "2026-01-02T03:04:05"
    assert stamp("12.01.26 10:00:00") == "12.01.26 10:00:00"
    assert stamp(None) == "None"
    entry = SimpleNamespace(seqnum="17", code="10045", tstamp=when)
    assert entry_key(entry) == (17, 10045, "2026-01-02T03:04:05")
    assert entry_key(SimpleNamespace(seqnum=3, code=80003)) == (3, 80003, "None")
    assert entry_record((17, 10045, "t")) == {"seqnum": 17, "code": 10045, "tstamp": "t"}


# -- testbed check's one read ------------------------------------------------------------
def test_the_check_reads_the_newest_restart_and_the_tasks_entry_after_it() -> None:
    log = [other(9), on(8, "T_ROB_R", 4), on(7, "T_ROB_L", 6), on(6, "T_ROB_L", 5),
           restart(5, 10046), on(4, "T_ROB_R"), restart(3)]
    assert zones_known(log, "T_ROB_L") == {"restart": 5, "restart_code": 10046,
                                           "active": 7, "zones": 6, "known": True}
    assert zones_known(log, "T_ROB_R") == {"restart": 5, "restart_code": 10046,
                                           "active": 8, "zones": 4, "known": True}
    # the entries before the newest restart do not count
    assert zones_known(log[4:], "T_ROB_L") == {"restart": 5, "restart_code": 10046,
                                               "active": None, "zones": None,
                                               "known": False}
    # no restart: the entries show nothing
    assert zones_known(log[:4], "T_ROB_L") == {"restart": None, "restart_code": None,
                                               "active": 7, "zones": 6, "known": False}
    assert zones_known([], "T_ROB_L") == {"restart": None, "restart_code": None,
                                          "active": None, "zones": None, "known": False}


def test_the_checks_lines_name_the_restart_entry_and_the_count() -> None:
    assert zones_known_problem("T_ROB_L", {"known": True, "zones": 5}) is None
    assert zones_known_problem("T_ROB_L", {"known": True, "zones": 7}, 7.0) is None
    assert zones_known_problem("T_ROB_L", {"known": True, "zones": 6}, 6) is None
    assert ZONES_COUNT == 5
    # known but no restart number: the line says the restart is missing
    assert zones_known_problem("T_ROB_L", {"known": True, "zones": 4}) == (
        "task T_ROB_L: the world zones are not known active: the event log holds no "
        "restart entry (cleared over RWS, or rolled over), so it cannot show them "
        f"written since the last restart; {FIX}")
    known = {"restart": 9, "restart_code": 10046, "active": 10, "zones": 4, "known": True}
    assert zones_known_problem("T_ROB_R", known, 6) == (
        f"task T_ROB_R: the world zones are not known active: the newest '{ZONES_ACTIVE}' "
        f"entry since the last restart (event log 10046, seq 9) says zones 4, not 6; {FIX}")
    assert zones_known_problem("T_ROB_R", {**known, "known": False, "zones": None}) == (
        f"task T_ROB_R: the world zones are not known active: no '{ZONES_ACTIVE}' entry "
        f"with zones 5 since the last restart (event log 10046, seq 9); {FIX}")
    assert zones_known_problem("T_ROB_R", {"restart": 9, "known": False}) == (
        f"task T_ROB_R: the world zones are not known active: no '{ZONES_ACTIVE}' entry "
        f"with zones 5 since the last restart (event log 10045, seq 9); {FIX}")
    assert zones_known_problem("T_ROB_L", {"restart": None, "known": False}) == (
        "task T_ROB_L: the world zones are not known active: the event log holds no "
        "restart entry (cleared over RWS, or rolled over), so it cannot show them "
        f"written since the last restart; {FIX}")
    # known but no count read: 0 zones, not enough even where 1 is asked
    assert zones_known_problem("T_ROB_L", {"restart": 1, "known": True, "zones": None}, 1) \
        == (f"task T_ROB_L: the world zones are not known active: the newest "
            f"'{ZONES_ACTIVE}' entry since the last restart (event log 10045, seq 1) says "
            f"zones None, not 1; {FIX}")
    assert zones_known_problem("T_ROB_L", {"restart": 1, "known": True, "zones": None}, 0) \
        is None


def test_a_refusal_names_the_first_task_the_log_does_not_prove() -> None:
    log = [on(4, "T_ROB_R", 3), on(3, "T_ROB_L"), restart(2)]
    assert zones_refusal(log, ["T_ROB_L"]) is None
    assert zones_refusal(log, TASKS) == (
        f"task T_ROB_R: the world zones are not known active: the newest '{ZONES_ACTIVE}' "
        f"entry since the last restart (event log 10045, seq 2) says zones 3, not 5; {FIX}")
    assert zones_refusal(log, TASKS, count=3) is None
    assert zones_refusal(log, ["T_ROB_L"], count=6) is not None
    assert zones_refusal([], []) is None


# -- the driver's proof across reads -----------------------------------------------------
def test_a_fresh_proof_knows_nothing_and_records_nothing() -> None:
    proof = ZonesProof(TASKS)
    assert proof.tasks == TASKS and proof.count == 5
    assert proof.state == {"T_ROB_L": "unknown", "T_ROB_R": "unknown"}
    assert proof.active == {"T_ROB_L": None, "T_ROB_R": None}
    assert proof.restart is None and proof.newest is None and proof.gap is False
    assert proof.resumed_from is None
    assert ZonesProof(TASKS, 3.0).count == 3  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^no read with an entry to record yet$"):
        proof.record(SERIAL)
    assert proof.save("/nonexistent/folder/x.json", SERIAL) is False


def test_the_refusals_of_a_read_word_what_the_log_lacks() -> None:
    proof = ZonesProof(TASKS)
    assert proof.read([other(2), other(1)]) == (
        "task T_ROB_L: the world zones are not known active since the last restart: the "
        f"event log shows no restart entry followed by a '{ZONES_ACTIVE}' entry (cleared "
        f"over RWS, or rolled over); {FIX}")
    assert proof.gap is False  # the first read: no gap, only nothing shown
    assert proof.newest == (2, 10002, "t2")
    assert proof.read([on(5, "T_ROB_L"), restart(4, 10046), other(3), other(2)]) == (
        "task T_ROB_R: the world zones are not known active since the last restart: a "
        f"restart (event log 10046, seq 4) with no '{ZONES_ACTIVE}' entry with zones 5 "
        f"after it; {FIX}")
    assert proof.state == {"T_ROB_L": "proved", "T_ROB_R": "restarted"}
    assert proof.restart == (4, 10046, "t4")
    assert proof.active == {"T_ROB_L": (5, 80003, "t5"), "T_ROB_R": None}
    # the restart rolled out of the next read: the line names no entry then
    assert proof.read([other(7), other(6), on(5, "T_ROB_L")]) == (
        "task T_ROB_R: the world zones are not known active since the last restart: a "
        f"restart with no '{ZONES_ACTIVE}' entry with zones 5 after it; {FIX}")
    assert proof.read([on(8, "T_ROB_R"), other(7), other(6)]) is None
    assert proof.state == {"T_ROB_L": "proved", "T_ROB_R": "proved"}
    # a gap: the words say so
    assert proof.read([other(20)]) == (
        "task T_ROB_L: the world zones are not known active since the last restart: the "
        "event log was cleared or rolled over past the entries this driver saw, and what "
        f"is left shows no restart entry followed by a '{ZONES_ACTIVE}' entry; {FIX}")
    assert proof.gap is True and proof.restart is None
    assert proof.state == {"T_ROB_L": "unknown", "T_ROB_R": "unknown"}
    # a read after it without a gap of its own still names it, until proved again
    assert proof.read([other(21), other(20)]) == proof.read([other(21), other(20)]) and \
        "rolled over past the entries this driver saw" in proof.read([other(21)])
    assert proof.gap is True
    assert proof.read([on(24, "T_ROB_R"), on(23, "T_ROB_L"), restart(22), other(21)]) is None
    assert proof.gap is False


def test_an_entry_with_too_few_zones_unproves_the_task_until_a_full_one() -> None:
    proof = ZonesProof(TASKS)
    log = [on(4, "T_ROB_R"), on(3, "T_ROB_L"), restart(2)]
    assert proof.read(log) is None
    log = [on(5, "T_ROB_L", 4), *log]  # a later entry naming fewer zones
    assert proof.read(log) is not None
    assert proof.state["T_ROB_L"] == "restarted" and proof.active["T_ROB_L"] is None
    assert proof.read([on(6, "T_ROB_L", 5), *log]) is None
    assert proof.active["T_ROB_L"] == (6, 80003, "t6")
    # a count of 3 takes 3
    three = ZonesProof(TASKS, 3)
    assert three.read([on(4, "T_ROB_R", 3), on(3, "T_ROB_L", 3), restart(2)]) is None
    # an entry before any restart proves nothing, however many zones it names
    fresh = ZonesProof(TASKS)
    assert fresh.read([on(2, "T_ROB_R"), on(1, "T_ROB_L")]) is not None
    assert fresh.state == {"T_ROB_L": "unknown", "T_ROB_R": "unknown"}


def test_a_read_keeps_only_what_came_after_the_newest_entry_seen() -> None:
    proof = ZonesProof(TASKS)
    log = [on(4, "T_ROB_R"), on(3, "T_ROB_L"), restart(2)]
    assert proof.read(log) is None
    # the same read again: nothing new, still proved
    assert proof.read(log) is None and proof.newest == (4, 80003, "t4")
    # an entry whose number is the newest's but of another time stamp: a gap
    twin = SimpleNamespace(seqnum=4, code=80003, title=ZONES_ACTIVE,
                           args=[ZONES_ACTIVE, "T_ROB_R", "zones 5"], tstamp="other")
    assert proof.read([twin, other(3)]) is not None and proof.gap is True


def test_a_recorded_entry_that_the_log_numbers_otherwise_is_a_gap() -> None:
    proof = ZonesProof(TASKS)
    log = [other(5), on(4, "T_ROB_R"), on(3, "T_ROB_L"), restart(2)]
    assert proof.read(log) is None
    # the newest entry is there, but seq 3 is now another entry: not the one recorded
    changed = [other(6), other(5), on(4, "T_ROB_R"), other(3), restart(2)]
    assert proof.read(changed) is not None and proof.gap is True
    proof = ZonesProof(TASKS)
    assert proof.read(log) is None
    # the recorded restart (seq 2) rolled out: what is left agrees, the proof holds
    assert proof.read([other(6), other(5), on(4, "T_ROB_R"), on(3, "T_ROB_L")]) is None
    assert proof.gap is False


# -- the record, from one agent to the next ----------------------------------------------
def proved(path: Path) -> tuple[ZonesProof, list[Any]]:
    proof, log = ZonesProof(TASKS), [other(5), on(4, "T_ROB_R"), on(3, "T_ROB_L"), restart(2)]
    assert proof.read(log) is None and proof.save(path, SERIAL) is True
    return proof, log


def test_the_record_holds_the_evidence_and_the_newest_entry(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    proved(path)
    data = json.loads(path.read_text())
    written = data.pop("written")
    assert datetime.fromisoformat(written).tzinfo is not None and len(written) == 25
    assert data == {
        "format": "fleet-testbed zones proof 1", "serial": SERIAL, "count": 5,
        "restart": {"seqnum": 2, "code": 10045, "tstamp": "t2"},
        "tasks": {"T_ROB_L": {"state": "proved",
                              "zones": {"seqnum": 3, "code": 80003, "tstamp": "t3"}},
                  "T_ROB_R": {"state": "proved",
                              "zones": {"seqnum": 4, "code": 80003, "tstamp": "t4"}}},
        "newest": {"seqnum": 5, "code": 10002, "tstamp": "t5"}}
    assert PROOF_FORMAT == "fleet-testbed zones proof 1"
    # sorted keys, one space of indent, a final newline
    text = path.read_text()
    assert text.startswith('{\n "count": 5,\n "format": ') and text.endswith("}\n")
    # before any restart: no evidence, recorded as such, and taken back
    first = ZonesProof(TASKS)
    assert first.read([other(1)]) is not None
    assert first.record(SERIAL)["restart"] is None
    assert first.record(SERIAL)["tasks"]["T_ROB_L"] == {"state": "unknown", "zones": None}
    first.save(path, SERIAL)
    again = ZonesProof(TASKS)
    assert again.load(path, SERIAL) is None and again.state["T_ROB_L"] == "unknown"
    assert again.newest == (1, 10002, "t1") and again.restart is None


def test_a_resumed_proof_takes_every_field_and_says_where_from(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    proof, _ = proved(path)
    fresh = ZonesProof(TASKS)
    assert fresh.load(path, SERIAL) is None
    assert fresh.state == proof.state and fresh.active == proof.active
    assert fresh.restart == (2, 10045, "t2") and fresh.newest == (5, 10002, "t5")
    assert fresh.resumed_from == str(path)
    # continued past a gap: the line names the record
    why = fresh.read([other(30)])
    assert why == ("task T_ROB_L: the world zones are not known active since the last "
                   "restart: the event log was cleared or rolled over past the newest entry "
                   f"the agent before this one recorded ({path}), and what is left shows no "
                   f"restart entry followed by a '{ZONES_ACTIVE}' entry; {FIX}")
    assert fresh.resumed_from is None  # only until the first read


def record_of(tmp_path: Path) -> dict[str, Any]:
    path = tmp_path / "p.json"
    proved(path)
    data = json.loads(path.read_text())
    assert isinstance(data, dict)
    return data


def refused(data: Any, serial: str = SERIAL, count: int = 5) -> str:
    proof = ZonesProof(TASKS, count)
    with pytest.raises(ProofFileError) as err:
        proof.resume(data, serial, "f")
    assert proof.state == {"T_ROB_L": "unknown", "T_ROB_R": "unknown"}  # nothing changed
    assert proof.newest is None and proof.resumed_from is None
    return str(err.value)


def test_a_record_is_refused_with_what_is_wrong(tmp_path: Path) -> None:
    good = record_of(tmp_path)
    assert refused([1, 2]) == "not a zones proof record (list)"
    assert refused({"format": PROOF_FORMAT}) == "not a zones proof record (['format'])"
    assert refused({**good, "format": "fleet-testbed zones proof 2"}) == (
        "format 'fleet-testbed zones proof 2', not 'fleet-testbed zones proof 1'")
    assert refused(good, "14000-1") == ("recorded for controller '14000-500000', not "
                                        "'14000-1'")
    assert refused({**good, "serial": ""}, "") == "recorded for controller '', not ''"
    assert refused(good, count=4) == "zones 5, not 4"
    assert refused({**good, "count": 5.0}) == "zones 5.0, not 5"
    assert refused({**good, "count": True}, count=1) == "zones True, not 1"
    assert refused({**good, "tasks": {"T_ROB_L": good["tasks"]["T_ROB_L"]}}).startswith(
        "tasks {'T_ROB_L': ")
    assert refused({**good, "tasks": []}) == "tasks [], not ['T_ROB_L', 'T_ROB_R']"
    assert refused({**good, "newest": None}) == "no newest entry or no time written"
    assert refused({**good, "written": 5}) == "no newest entry or no time written"
    assert refused({**good, "tasks": {**good["tasks"], "T_ROB_R": "proved"}}) == (
        "task T_ROB_R: 'proved'")
    assert refused({**good, "tasks": {**good["tasks"], "T_ROB_R": {"state": "proved"}}}) \
        == "task T_ROB_R: {'state': 'proved'}"
    no_zones = {**good, "tasks": {**good["tasks"], "T_ROB_R": {"state": "proved",
                                                               "zones": None}}}
    assert refused(no_zones) == ("task T_ROB_R: state 'proved' with restart {'code': 10045, "
                                 "'seqnum': 2, 'tstamp': 't2'} and zones None")
    odd = {**good, "tasks": {**good["tasks"], "T_ROB_L": {"state": "maybe", "zones": None}}}
    assert refused(odd).startswith("task T_ROB_L: state 'maybe' with restart ")
    waiting = {**good, "tasks": {**good["tasks"], "T_ROB_R": {"state": "restarted",
                                                              "zones": None}}}
    proof = ZonesProof(TASKS)
    proof.resume(waiting, SERIAL, "f")  # a restart with no zones entry yet: consistent
    assert proof.state["T_ROB_R"] == "restarted"
    unknown = {**good, "restart": None, "tasks": {t: {"state": "unknown", "zones": None}
                                                  for t in TASKS}}
    ZonesProof(TASKS).resume(unknown, SERIAL, "f")
    assert refused({**unknown, "tasks": {**unknown["tasks"], "T_ROB_L": {
        "state": "unknown", "zones": good["tasks"]["T_ROB_L"]["zones"]}}}).startswith(
        "task T_ROB_L: state 'unknown' with restart None and zones {")


@pytest.mark.parametrize(("entry", "ok"), [
    ({"seqnum": 0, "code": 10002, "tstamp": "t"}, True),
    ({"seqnum": 65535, "code": 10002, "tstamp": "t"}, True),
    ({"seqnum": 65536, "code": 10002, "tstamp": "t"}, False),
    ({"seqnum": -1, "code": 10002, "tstamp": "t"}, False),
    ({"seqnum": True, "code": 10002, "tstamp": "t"}, False),
    ({"seqnum": 5, "code": 10002.0, "tstamp": "t"}, False),
    ({"seqnum": 5, "code": 10002, "tstamp": 5}, False),
    ({"seqnum": 5, "code": 10002}, False),
    ({"seqnum": 5, "code": 10002, "tstamp": "t", "more": 1}, False),
    ([5, 10002, "t"], False),
])
def test_a_recorded_entry_is_a_number_in_range_a_code_and_a_time(
        tmp_path: Path, entry: Any, ok: bool) -> None:
    data = {**record_of(tmp_path), "newest": entry}
    proof = ZonesProof(TASKS)
    if ok:
        proof.resume(data, SERIAL, "f")
        assert proof.newest == (entry["seqnum"], 10002, "t")
    else:
        assert refused(data) == f"not an event log entry: {entry!r}"


def test_only_a_plain_small_file_of_this_user_that_no_one_else_may_write_is_read(
        tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    assert read_proof_file(path) is None
    proof = ZonesProof(TASKS)
    assert proof.load(path, SERIAL) == f"no zones proof file {path}"
    path.write_text('{"a": 1}')
    path.chmod(0o644)
    assert read_proof_file(path) == {"a": 1}
    for mode in (0o664, 0o646):
        path.chmod(mode)
        with pytest.raises(ProofFileError) as err:
            read_proof_file(path)
        assert str(err.value) == (f"not a plain file of uid {os.geteuid()} that only it may "
                                  f"write (uid {os.geteuid()}, mode "
                                  f"{'-rw-rw-r--' if mode == 0o664 else '-rw-r--rw-'}, "
                                  f"8 bytes)")
    path.chmod(0o601)  # others may run it, not write it: taken
    assert read_proof_file(path) == {"a": 1}
    path.chmod(0o600)
    path.write_text(" " * (MAX_PROOF_BYTES - 2) + "{}")
    assert MAX_PROOF_BYTES == 65536 and read_proof_file(path) == {}
    path.write_text(" " * (MAX_PROOF_BYTES - 1) + "{}")
    with pytest.raises(ProofFileError, match=r"65537 bytes\)$"):
        read_proof_file(path)
    folder = tmp_path / "d.json"
    folder.mkdir()
    # a folder: Python's open fails on it (an OSError), and the record is not used
    assert proof.load(folder, SERIAL).startswith(f"zones proof file {folder} not used: ")
    link = tmp_path / "l.json"
    link.symlink_to(path)
    with pytest.raises(ProofFileError, match=r"^cannot open it \("):
        read_proof_file(link)
    path.write_bytes(b"\xff{}")
    with pytest.raises(ProofFileError, match=r"^not JSON \("):
        read_proof_file(path)
    assert proof.load(path, SERIAL) is not None and proof.load(path, SERIAL).startswith(
        f"zones proof file {path} not used: not JSON (")


def test_the_record_lies_beside_the_robots_lock(tmp_path: Path) -> None:
    from drivers.hostlock import lock_path

    got = proof_path(tmp_path, SERIAL)
    assert got == lock_path(tmp_path, f"IRC5 {SERIAL}").with_suffix(".zones.json")
    assert got.name.startswith("IRC5_14000-500000-") and got.name.endswith(".zones.json")


def test_a_device_of_this_user_is_not_a_proof_file(tmp_path: Path) -> None:
    """A character device (/dev/null's numbers), this user's, mode 0600, that reads as
    empty: not a plain file, whatever it would read."""
    node = tmp_path / "dev.json"
    try:
        os.mknod(node, 0o600 | stat.S_IFCHR, os.makedev(1, 3))
    except (PermissionError, AttributeError):
        pytest.skip("no mknod here (not root)")
    with pytest.raises(ProofFileError, match=r"^not a plain file of uid "):
        read_proof_file(node)
