"""The tool frame is the controller's (issue 35): our RAPID's ``tool_pusher`` (TASK PERS in
``TestbedTask_L`` / ``_R``) holds the pusher's measured frame, readable and writable over
RWS; a program file whose frame differs from it by more than 1 mm or 0.5 deg is refused
before any motion (80001 "Testbed Motion Failed", "Tool frame differs from tool_pusher",
both frames), and an accepted file moves, and is supervised, with the controller's frame,
never the file's. Driven by the UNCHANGED ABB client over HTTP against a real cell.

On the code before issue 35 every test here fails: ``tb_header`` set ``tool_pusher.tframe``
from each file, so a flange (0 mm) or 100 mm file ran, and moved, with its own frame."""

from __future__ import annotations

import math
import random

import pytest
from twin_rws import UNDER_SHOULDER_DEG, OurTwin, our_twin, program, run, tool

from sim_twin.rws import testbed_rapid
from sim_twin.rws.rapid_data import parse_value
from sim_twin.rws.testbed_rapid import DONE, FAILED, TOOL_DEG, TOOL_DIFFERS, TOOL_MM, angle_deg
from sim_twin.yumi_arms import DEFAULT_TOOL_MM

P = DEFAULT_TOOL_MM
"""The twin pusher's true length: tool_pusher's frame as a lab would measure it."""
SYMBOL = "T_ROB_L/TestbedTask_L"
"""``GET rw/rapid/symbol/data/RAPID/T_ROB_L/TestbedTask_L/tool_pusher`` (the client's path)."""
PATH = testbed_rapid.testbed_program_file("T_ROB_L")
"""The file the left task reads (named in its entries)."""
LOAD = "[0.272,[7.5,11.5,53.8],[1,0,0,0],0.0003,0.00032,0.00009]"
DOWN_AT = ("J", (400, 200, 120), 500)
"""A joint move of the left arm to a tool-down point above its box."""


def pusher(z: float) -> object:
    """tool_pusher with the frame ``z`` mm down the flange and the shipped load, parsed
    (how the controller prints 0.00009 is its own affair: 9E-05 on the twin)."""
    return parse_value(f"[TRUE,{frame(z)},{LOAD}]")


def read(t: OurTwin, symbol: str = SYMBOL) -> object:
    return parse_value(t.c.get_rapid_variable("tool_pusher", symbol))


def frame(z: float, rot: str = "1,0,0,0") -> str:
    return f"[[0,0,{z:g}],[{rot}]]"


def quat_z(deg: float) -> tuple[float, float, float, float]:
    """A rotation of ``deg`` about the tool's z axis."""
    h = math.radians(deg) / 2
    return (math.cos(h), 0.0, 0.0, math.sin(h))


def test_tool_pusher_is_served_in_rapid_syntax_per_task() -> None:
    with our_twin() as t:
        for task, mod in (("T_ROB_L", "TestbedTask_L"), ("T_ROB_R", "TestbedTask_R")):
            assert read(t, f"{task}/{mod}") == pusher(P)


@pytest.mark.parametrize("file_z", [0.0, 100.0, P + 1.2])
def test_a_file_with_another_frame_is_refused_and_nothing_moves(file_z: float) -> None:
    """0: a calibration without tool_z_mm sent the flange; 100: the old assumption."""
    if abs(file_z - P) <= TOOL_MM:
        pytest.skip("the twin's pusher is that long")
    with our_twin() as t:
        before = t.tcps()
        entries = run(t.c, {"T_ROB_L": program([DOWN_AT, ("L", (400, 200, 60), 100)],
                                               tool_z_mm=file_z)})
        assert [(e.code, e.msgtype, e.title) for e in entries] == [(80001, 3, FAILED)]
        assert entries[0].args == [FAILED, TOOL_DIFFERS, PATH,
                                   f"file {frame(file_z)}", f"tool_pusher {frame(P)}"]
        assert t.tcps() == before  # refused before any motion
        assert read(t) == pusher(P)


def test_the_limits_are_1_mm_and_half_a_degree() -> None:
    with our_twin() as t:
        ok = [tool(P + 0.9), tool(P, trans_xy=(0.6, -0.6)), tool(P, rot=quat_z(0.45)),
              tool(P, rot=[-q for q in quat_z(0.45)])]  # -q: the same orientation
        bad = [tool(P - 1.1), tool(P, trans_xy=(0.8, 0.8)), tool(P, rot=quat_z(0.55)),
               tool(P, robhold=False)]
        for seqno, td in enumerate(ok + bad, start=1):
            got = run(t.c, {"T_ROB_L": program([DOWN_AT], tooldata=td)}, seqno=seqno)
            want = [DONE] if td in ok else [FAILED]
            assert [e.title for e in got] == want, (td, got)
        rot = run(t.c, {"T_ROB_L": program([DOWN_AT], tooldata=tool(P, rot=quat_z(0.55)))},
                  seqno=9)
        assert rot[0].args[3] == f"file {frame(P, '1,0,0,0.0048')}"
        held = run(t.c, {"T_ROB_L": program([DOWN_AT], tooldata=tool(P, robhold=False))},
                   seqno=10)
        assert held[0].args[1:] == ["Stationary tool not supported",
                                    PATH, "tool robhold",
                                    "at byte 8"]


def test_an_accepted_file_moves_with_the_controllers_frame() -> None:
    """A file 0.8 mm short (inside the limit) runs with tool_pusher's frame: the pusher's
    tip goes to the target, not 0.8 mm below it; tool_pusher keeps its value."""
    with our_twin() as t:
        entries = run(t.c, {"T_ROB_L": program([DOWN_AT, ("L", (400, 200, 60), 100)],
                                               tool_z_mm=P - 0.8)})
        assert [e.title for e in entries] == [DONE]
        ran = t.hook.last_run["T_ROB_L"].program.tool
        assert ran.tframe.trans == pytest.approx((0, 0, P))  # the controller's, not the file's
        assert ran.tload.mass == pytest.approx(0.272)
        assert t.tcps()["left"] == pytest.approx((400, 200, 60), abs=0.3)  # not 59.2
        assert read(t) == pusher(P)


def test_a_lab_sets_tool_pusher_over_rws_and_the_motion_and_zones_use_it() -> None:
    """The lab's measurement says 20 mm shorter than the twin's real pusher: files with
    the old length are refused, files with the new one run with it, so the real tip goes
    20 mm below each target (the twin is faithful to a wrong measurement), and the zones
    watch that TCP; the value survives a restart and Reset RAPID (TASK PERS, system
    module). The lab writes and restarts as the person (the agent holds no such grant)."""
    with our_twin() as t:
        t.person.set_rapid_variable("tool_pusher", f"[TRUE,{frame(P - 20)},{LOAD}]",
                                    SYMBOL)
        assert read(t) == pusher(P - 20)
        old = run(t.c, {"T_ROB_L": program([DOWN_AT], tool_z_mm=P)})
        assert [e.args[1] for e in old] == [TOOL_DIFFERS]
        assert old[0].args[3:] == [f"file {frame(P)}", f"tool_pusher {frame(P - 20)}"]
        # the flange 20 mm lower than with the true length: the driver's plan for the line
        # down turns the arm angle across the shoulder's singularity (UNDER_SHOULDER_DEG)
        under = UNDER_SHOULDER_DEG["left"]
        new = run(t.c, {"T_ROB_L": program([(*DOWN_AT, under), ("L", (400, 200, 60), 100, under)],
                                           tool_z_mm=P - 20)}, seqno=2)
        assert [e.title for e in new] == [DONE]
        assert t.tcps()["left"] == pytest.approx((400, 200, 40), abs=0.3)
        tcp = t.c.get_robtarget("ROB_L", tool="tool_pusher").trans.tolist()
        assert tcp == pytest.approx([400, 200, 60], abs=0.3)
        assert t.hook._offsets["left"] == pytest.approx((0, 0, 20))  # what the zones watch
        for mode in ("restart", "pstart"):
            t.person._do_post("ctrl?action=restart", {"restart-mode": mode})
            assert read(t) == pusher(P - 20)
        with pytest.raises(Exception, match="tooldata"):  # the controller checks the type
            t.person.set_rapid_variable("tool_pusher", "[TRUE,[[0,0,1]]]", SYMBOL)


def test_angle_deg_is_the_angle_between_orientations() -> None:
    """The twin's ``tb_angle``: ``2 acos(|a.b|)`` (q and -q alike), exact near 0."""
    rng = random.Random(5)
    for _ in range(200):
        a = [rng.gauss(0, 1) for _ in range(4)]
        b = [rng.gauss(0, 1) for _ in range(4)]
        na, nb = math.hypot(*a), math.hypot(*b)
        dot = abs(sum(x * y for x, y in zip(a, b, strict=True))) / (na * nb)
        want = math.degrees(2 * math.acos(min(dot, 1.0)))
        assert angle_deg(a, b) == pytest.approx(want, abs=1e-6)
        assert angle_deg(a, [-v for v in a]) == pytest.approx(0.0, abs=1e-6)
    assert angle_deg((1, 0, 0, 0), quat_z(0.01)) == pytest.approx(0.01, rel=1e-6)
    assert angle_deg((1, 0, 0, 0), (2, 0, 0, 0)) == 0.0  # normalised first
    assert angle_deg((0, 0, 0, 0), (1, 0, 0, 0)) == 180.0
    assert TOOL_MM == 1.0 and TOOL_DEG == 0.5
