"""Zones known active after every restart (issue 35), as the twin plays the controller and
our RAPID: every restart ("restart") and "Reset RAPID" ("pstart") writes 10045 "System
restarted" first; the POWER_ON event routine ``tb_zones`` then writes, per task, the info
entry "Testbed Zones Active" (80003: the task, ``zones 5``, the time). TASK PERS survive
restarts, so a restart whose event routine is not configured (a lab removed it) leaves
``tb_zones_n`` reading 5 and the zones OFF: only the missing entry newer than the 10045
tells. Driven by the UNCHANGED ABB client over HTTP.

On the code before issue 35 these fail: no restart entry and no zones entry were written."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from typing import Any

from twin_rws import OurTwin, our_twin

from sim_twin.rws.irc5 import RESTARTED
from sim_twin.rws.testbed_install import ZONES_ACTIVE, ZONES_MODULE

TASKS = ("T_ROB_L", "T_ROB_R")


def restart(t: OurTwin, mode: str) -> None:
    """``POST ctrl?action=restart`` as a lab's curl line does."""
    t.c._do_post("ctrl?action=restart", {"restart-mode": mode})


def lab(t: OurTwin, body: dict[str, Any]) -> Any:
    """The twin's side channel (``POST /lab/controller``)."""
    url = t.c.base_url + "/lab/controller"
    req = urllib.request.Request(url, data=json.dumps(body).encode())
    with urllib.request.urlopen(req, timeout=20) as r:
        return json.loads(r.read())


def pers(t: OurTwin, task: str) -> tuple[str, str]:
    """(tb_zones_n, tb_zones_at) as a lab reads them over RWS."""
    return (t.c.get_rapid_variable("tb_zones_n", f"{task}/{ZONES_MODULE}"),
            t.c.get_rapid_variable("tb_zones_at", f"{task}/{ZONES_MODULE}"))


def active_since_restart(t: OurTwin) -> dict[str, list[Any]]:
    """What testbed check reads: per task, the "Testbed Zones Active" entries newer (a
    higher seqnum) than the newest 10045."""
    log = t.c.read_event_log()
    restarts = [e.seqnum for e in log if e.code == RESTARTED[0]]
    newest = max(restarts) if restarts else -1
    return {task: [e for e in log if e.code == 80003 and e.title == ZONES_ACTIVE
                   and e.args[:1] == [ZONES_ACTIVE] and e.args[1] == task
                   and e.seqnum > newest] for task in TASKS}


def test_the_install_writes_one_zones_active_entry_per_task() -> None:
    with our_twin() as t:
        got = active_since_restart(t)
        for task in TASKS:
            assert len(got[task]) == 1
            e = got[task][0]
            assert (e.msgtype, e.args[2]) == (1, "zones 5")
            assert e.args[3] == pers(t, task)[1].strip('"')  # the time tb_zones_at holds


def test_a_restart_and_reset_rapid_write_10045_then_the_zones_entries() -> None:
    with our_twin() as t:
        for mode, name in (("restart", "Restart"), ("pstart", "Reset RAPID")):
            before = t.c.read_event_log()[0].seqnum
            restart(t, mode)
            log = [e for e in reversed(t.c.read_event_log()) if e.seqnum > before]
            assert (log[0].code, log[0].msgtype, log[0].title) == (10045, 1, "System restarted")
            assert name in log[0].desc and log[0].args == [name]
            got = active_since_restart(t)
            assert {task: len(got[task]) for task in TASKS} == {"T_ROB_L": 1, "T_ROB_R": 1}
            assert t.install.zones_active == {"left": True, "right": True}
            assert lab(t, {})["rapid"]["event_routines"] is True


def test_a_restart_without_the_event_routine_keeps_the_pers_but_writes_no_entry() -> None:
    """The state testbed check must catch: tb_zones_n reads 5, the zones are off."""
    with our_twin() as t:
        old = {task: pers(t, task) for task in TASKS}
        assert all(n == "5" for n, _ in old.values())
        state = lab(t, {"event_routines": False})  # the lab removed the configuration
        assert state["rapid"]["event_routines"] is False
        for mode in ("restart", "pstart"):
            restart(t, mode)
            assert {task: pers(t, task) for task in TASKS} == old  # TASK PERS: kept
            assert active_since_restart(t) == {"T_ROB_L": [], "T_ROB_R": []}
            assert t.install.zones_active == {"left": False, "right": False}  # the truth
            log = t.c.read_event_log()
            after = log[:next(i for i, e in enumerate(log) if e.code == 10045)]
            assert {e.code for e in after} <= {10010}  # motors off at most: no routine ran
        lab(t, {"event_routines": True})
        restart(t, "restart")
        assert {task: len(v) for task, v in active_since_restart(t).items()} == {
            "T_ROB_L": 1, "T_ROB_R": 1}
        assert t.install.zones_active == {"left": True, "right": True}
        assert all(pers(t, task)[0] == "5" for task in TASKS)


def test_the_lab_side_refuses_a_malformed_flag() -> None:
    with our_twin() as t:
        for body in ({"event_routines": "no"}, {"omit_motiontask": 1}):
            try:
                lab(t, body)
            except urllib.error.HTTPError as exc:
                assert exc.code == 400
            else:
                raise AssertionError(f"{body} was accepted")
        assert t.install.event_routines and not t.ctrl.omit_motiontask


def test_the_install_restart_writes_10045_before_the_zones_entries() -> None:
    """The restart after the install is a restart: its entry first (the driver and
    testbed check need a restart entry AND the zones entries after it, issue 43)."""
    with our_twin() as t:
        codes = [e.code for e in reversed(t.c.read_event_log())]
        first = codes.index(10045)
        assert codes[first + 1:].count(80003) == 2 and 80003 not in codes[:first]


def test_the_event_log_clears_over_rws_and_rolls_over() -> None:
    """As the RWS manual has it (Application manual 3HAC050973-001, "Clear elog
    messages"): ``POST rw/elog?action=clearall`` clears every domain, ``POST
    rw/elog/{domain}?action=clear`` one; a domain keeps a bounded number of entries, the
    oldest rolling out, the numbers going on."""
    with our_twin() as t:
        assert [e.code for e in t.c.read_event_log() if e.code == 10045] == [10045]
        t.c._do_post("rw/elog/1?action=clear", {})  # the operational domain: 1xxxx
        assert {e.code // 10000 for e in t.c.read_event_log()} == {8}  # ErrWrite's left
        t.c._do_post("rw/elog?action=clearall", {})
        assert t.c.read_event_log() == []
        for bad in ("rw/elog?action=clear", "rw/elog/0?action=clearall"):
            try:
                t.c._do_post(bad, {})
            except Exception as exc:  # the client raises on the 400
                assert "400" in str(exc) or "action" in str(exc), exc
            else:
                raise AssertionError(f"{bad} was accepted")
        t.ctrl.elog.capacity = 2
        before = t.ctrl.elog.newest or 0
        for _ in range(3):
            restart(t, "restart")  # 10045 (motors off once), two zones entries
        log = t.c.read_event_log()
        assert [e.code for e in log] == [80003, 80003]  # the restart's entry rolled out
        assert log[-1].seqnum >= before + 8  # the numbers went on
