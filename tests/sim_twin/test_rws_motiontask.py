"""A controller that omits ``motiontask`` in ``GET rw/rapid/tasks`` (abb_motion_program_exec
issue 4), played by the twin (``Irc5Controller(omit_motiontask=True)``, ``python -m
sim_twin.yumi_server --omit-motiontask``), and the driver's "stay" program.

With the field missing, abb_robot_client's ``get_tasks()`` reads every task as not a
motion task, so its ``start(tasks=["T_ROB_L"])`` deactivates nothing: ``T_ROB_R`` starts
too and our RAPID in it re-runs the file its RAM disk still holds (the hazard of issue 35:
the idle arm replays an old push). The driver closes it by uploading a program to both
tasks every time, the idle one a "stay" (one ``WaitTime 0``), which our RAPID accepts
without moving; like every file it carries the calibration's tool frame, which must be
``tool_pusher``'s. Driven by the UNCHANGED ABB client over HTTP on a real cell."""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Callable
from typing import Any

import pytest
from twin_rws import OurTwin, our_twin, program, run, since, stay, wait_stopped
from twin_rws import start as start_run

from sim_twin.rws.testbed_rapid import DONE, FAILED, TOOL_DIFFERS

RIGHT_OLD = [("J", (400, -200, 130), 500), ("L", (400, -200, 90), 100)]
"""The right arm's old program: up to 130 mm, then down to 90 mm (where it ends)."""
LEFT_NEW = [("J", (400, 200, 120), 500)]


def watcher(seen: list[float], holder: dict[str, Any]) -> Callable[[], None]:
    """An ``on_frame``: the right pusher's height at every sample of a motion."""
    return lambda: seen.append(holder["twin"].cell.tcp_xyz()["right"][2])


def first_both(t: OurTwin) -> None:
    """Both tasks run once (the right one leaves RIGHT_OLD on its RAM disk)."""
    got = run(t.c, {"T_ROB_L": program(LEFT_NEW), "T_ROB_R": program(RIGHT_OLD)})
    assert [(e.title, e.args[1]) for e in got] == [(DONE, "T_ROB_L"), (DONE, "T_ROB_R")]


def left_only(t: OurTwin, seen: list[float]) -> list[Any]:
    """The calibration's one-arm move as move_tcp did it: upload the left file, start
    ``tasks=["T_ROB_L"]`` through the client; what it wrote (``resetpp``'s left out)."""
    seen.clear()
    prev = start_run(t.c, {"T_ROB_L": program([("J", (380, 180, 120), 500)])}, seqno=2)
    wait_stopped(t.c)
    return [e for e in since(t.c, prev) if e.code != 10002]


@pytest.mark.parametrize("omit", [False, True])
def test_without_motiontask_a_one_arm_start_replays_the_other_arms_old_file(
        omit: bool) -> None:
    seen: list[float] = []
    holder: dict[str, Any] = {}
    with our_twin(omit_motiontask=omit, on_frame=watcher(seen, holder)) as t:
        holder["twin"] = t
        first_both(t)
        tasks = t.c.get_tasks()
        assert [tasks[n].motiontask for n in ("T_ROB_L", "T_ROB_R")] == [not omit] * 2
        raw = t.c._do_get("rw/rapid/tasks")["_embedded"]["_state"]
        assert all(("motiontask" in s) is not omit for s in raw)
        right_at = t.tcps()["right"]
        got = left_only(t, seen)
        done = [(e.args[1], e.args[2]) for e in got if e.title == DONE]
        if not omit:  # the client deactivated T_ROB_R: it stayed where it was
            assert done == [("T_ROB_L", "seqno 2")]
            assert not t.c.get_tasks()["T_ROB_R"].active
            assert max(seen) == pytest.approx(right_at[2], abs=0.5)
        else:  # both active, both started: the right arm replayed its old file
            assert done == [("T_ROB_L", "seqno 2"), ("T_ROB_R", "seqno 1")]
            assert t.c.get_tasks()["T_ROB_R"].active
            assert t.hook.last_run["T_ROB_R"].program.seqno == 1
            assert max(seen) == pytest.approx(130, abs=1.0)  # it went up and down again


def test_the_switch_is_on_the_lab_side_too() -> None:
    with our_twin() as t:
        req = urllib.request.Request(t.c.base_url + "/lab/controller",
                                     data=json.dumps({"omit_motiontask": True}).encode())
        with urllib.request.urlopen(req, timeout=20) as r:
            assert json.loads(r.read())["omit_motiontask"] is True
        assert not any(s.motiontask for s in t.c.get_tasks().values())


def test_a_stay_program_is_accepted_by_both_tasks_and_moves_nothing() -> None:
    with our_twin() as t:
        before = t.tcps()
        got = run(t.c, {"T_ROB_L": stay(), "T_ROB_R": stay()})
        assert [(e.code, e.title, e.args[1], e.args[3]) for e in got] == [
            (80003, DONE, "T_ROB_L", "commands 1"), (80003, DONE, "T_ROB_R", "commands 1")]
        assert t.tcps() == before
        assert [type(c).__name__ for c in t.hook.last_run["T_ROB_R"].program.commands] == [
            "WaitTime"]


def test_the_hazard_closed_a_stay_for_the_idle_arm_every_time() -> None:
    """What the driver does now: both tasks get a file; the idle one stays."""
    seen: list[float] = []
    holder: dict[str, Any] = {}
    with our_twin(omit_motiontask=True, on_frame=watcher(seen, holder)) as t:
        holder["twin"] = t
        first_both(t)
        right_at = t.tcps()["right"]
        seen.clear()
        got = run(t.c, {"T_ROB_L": program([("J", (380, 180, 120), 500)]),
                        "T_ROB_R": stay()}, seqno=2)
        assert [(e.args[1], e.args[2]) for e in got] == [("T_ROB_L", "seqno 2"),
                                                         ("T_ROB_R", "seqno 2")]
        assert max(seen) == pytest.approx(right_at[2], abs=0.5)
        assert t.tcps()["right"] == pytest.approx(right_at, abs=0.5)


def test_a_stay_with_the_flange_frame_is_refused_like_any_file() -> None:
    """The stay carries the calibration's tool frame: tool0 would be refused (an error
    entry the driver reports), so the driver must not send it."""
    with our_twin() as t:
        got = run(t.c, {"T_ROB_R": stay(tool_z_mm=0.0)})
        assert [(e.code, e.title, e.args[1]) for e in got] == [(80001, FAILED, TOOL_DIFFERS)]
