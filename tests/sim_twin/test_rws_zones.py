"""The stationary world zones of OUR RAPID (``tb_zones``) as the twin plays them, driven by
the UNCHANGED ABB client over HTTP against a real YumiTwinCell: a push planned past the
zone box stops every arm when the pusher reaches the box's face (the truth there, the
controller's error in the event log, no ``Done``), a target below the floor is refused
(in another work object too) and a joint path that dips below it stops at the floor,
travel above ``tb_zone_z`` outside the box is allowed,
the arm moves away from the face again, and the zone constants read over RWS as the
task modules declare them."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from twin_rws import client, program, run

from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import (
    DONE,
    RAPID_VERSION,
    TOOL_DIFFERS,
    WORLD_ZONE_CODE,
    WORLD_ZONE_TITLE,
    TestbedRapid,
)
from sim_twin.rws.world_zones import EPS_MM, ArmZone, default_zone, first_entry
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, rest_tip
from sim_twin.yumi_cell import Segment, YumiTwinCell

REST_TIP = {side: rest_tip(side) for side in ("left", "right")}
HELD = {"left": -40.0, "right": 40.0}
"""The arm angle the driver holds for each arm (drivers/yumi/reach.py ``ARM_ANGLE_DEG``)."""
"""Where the twin's arms rest the pusher's tip (their rest joints, its 184.2 mm tool)."""

Made = tuple[Any, Irc5Controller, YumiTwinCell, threading.Lock]


@pytest.fixture
def twin() -> Iterator[Callable[..., Made]]:
    made: list[tuple[RwsServer, YumiTwinCell]] = []

    def make(floor_z: float = 0.0, zones: dict[str, ArmZone] | None = None) -> Made:
        cell = YumiTwinCell(3)
        lock = threading.Lock()
        hook = TestbedRapid(cell, lock, YUMI_UNITS, floor_z_mm=floor_z, zones=zones)
        ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses)
        install = TestbedInstall(ctrl, hook)
        server = RwsServer(RwsService(ctrl, program=install)).start_thread()
        made.append((server, cell))
        return client(server.url), ctrl, cell, lock

    yield make
    for server, cell in made:
        server.stop()
        cell.close()


def tcps(cell: YumiTwinCell, lock: threading.Lock) -> dict[str, tuple[float, float, float]]:
    with lock:
        return cell.tcp_xyz()


def test_the_zone_geometry() -> None:
    z = ArmZone(200, 0, 600, 400, zone_z=80, floor_z=0)
    assert z.inside((400, 200, 10)) is None and z.inside((400, 200, -1)).name == "tb_wz_floor"
    assert z.inside((400, 450, 10)).name == "tb_wz_yhi" and z.inside((400, 450, 90)) is None
    assert z.inside((400, 400, 10)) is None  # on a face: not inside
    seg = Segment((400.0, 300.0, 10.0), (400.0, 500.0, 10.0), 100.0)
    t, box = first_entry([seg], z)
    # entered at the face, to the supervision's resolution (a point within EPS_MM of a
    # face counts as on it)
    assert box.name == "tb_wz_yhi" and seg.at(t)[1] == pytest.approx(400.0 + EPS_MM, abs=1e-6)
    assert z.inside(seg.at(t)) is None  # the stop point counts as on the face, not inside
    assert first_entry([Segment((100.0, 450.0, 150.0), (400.0, 200.0, 80.0), 500.0)], z) is None
    for bad in ((600, 0, 200, 400), (200, 0, 600, 400, 0, 0)):
        with pytest.raises(ValueError):
            ArmZone(*bad)  # type: ignore[arg-type]
    left = default_zone("left")
    assert (left.x0, left.y0, left.x1, left.y1) == (125, 25, 495, 395)


def test_a_push_past_the_zone_box_stops_every_arm_at_its_face(twin: Any) -> None:
    c, _, cell, lock = twin()
    box = default_zone("left")  # y up to 395 below 80 mm
    right_to = (310.0, -210.0, 100.0)
    entries = run(c, {
        "T_ROB_L": program([("J", (400, 300, 100), 500, HELD["left"]),
                            ("L", (400, 300, 10), 200, HELD["left"]),
                            ("L", (400, 460, 10), 100, HELD["left"])]),  # (down from 100)
        "T_ROB_R": program([("J", right_to, 50, HELD["right"])])})  # slow: on its way
    assert [(e.code, e.msgtype, e.title) for e in entries] == [
        (WORLD_ZONE_CODE, 3, WORLD_ZONE_TITLE)]  # the controller's error; no Done at all
    e = entries[0]
    assert e.args[:2] == ["T_ROB_L", "tb_wz_yhi"] and "tb_wz_yhi" in e.desc
    at = [float(v) for v in e.args[2:5]]  # the TCP of tool_pusher where it stopped
    assert at[1] == pytest.approx(box.y1, abs=0.1)  # on the face, as the joints put it
    assert at == pytest.approx([400.0, box.y1, 10.0], abs=0.2)
    assert c.get_execution_state().ctrlexecstate == "stopped"
    assert c.get_tasks()["T_ROB_L"].excstate == "stopped"
    got = tcps(cell, lock)
    assert got["left"] == pytest.approx((400.0, box.y1, 10.0), abs=1.0)  # held at the face
    tip = c.get_robtarget("ROB_L", tool="tool_pusher").trans.tolist()
    assert tip == pytest.approx(list(got["left"]), abs=0.5)
    start, now = REST_TIP["right"], got["right"]  # the other arm stopped too, mid-way
    assert math.dist(start, now) > 10.0 and math.dist(now, right_to) > 10.0
    # the arm moves away from the face (up, out of the zone's height) and on
    back = run(c, {"T_ROB_L": program([("L", (400, got["left"][1], 100), 100),
                                       ("J", (310, 210, 100), 500)])}, seqno=2)
    assert [en.title for en in back] == [DONE]
    assert tcps(cell, lock)["left"] == pytest.approx((310, 210, 100), abs=1.0)


def test_a_shifted_work_object_is_refused_and_the_floor_zone_stops_a_dip(twin: Any) -> None:
    """A target below the floor is refused before any motion, in wobj0 and (since issue
    43, our RAPID's version 5) in a work object 15 mm down, which used to pass the file's
    check: every work object but wobj0's frames is refused. The floor zone still stops
    what no file check sees: a joint move between two targets 2 mm above the floor whose
    path dips below it stops on the floor."""
    c, _, cell, lock = twin(floor_z=30.0)
    low = mpe.wobjdata(False, True, "", mpe.pose([0, 0, -15], [1, 0, 0, 0]),
                       mpe.pose([0, 0, 0], [1, 0, 0, 0]))
    before = tcps(cell, lock)["left"]
    plain = run(c, {"T_ROB_L": program([("L", (400, 200, 20), 100)])})  # 20 < 30 in wobj0
    assert [(e.code, e.args[1]) for e in plain] == [(80001, "Target below the table")]
    assert tcps(cell, lock)["left"] == before  # refused by our RAPID before any motion
    shifted = run(c, {"T_ROB_L": program([("J", (400, 200, 100), 150),
                                          ("L", (400, 200, 40), 100)], wobj=low)}, seqno=2)
    assert [(e.code, e.args[1], e.args[3]) for e in shifted] == [
        (80001, "Work object not supported", "uframe [[0,0,-15],[1,0,0,0]]")]
    assert tcps(cell, lock)["left"] == before
    under = HELD["left"]  # one arm angle for all three, as the driver holds it
    dips = run(c, {"T_ROB_L": program([("J", (400, 210, 100), 150, under),
                                       ("L", (400, 210, 32), 100, under),
                                       ("J", (250, 210, 32), 150, under)])}, seqno=3)
    assert [(e.code, e.args[1]) for e in dips] == [(WORLD_ZONE_CODE, "tb_wz_floor")]
    assert tcps(cell, lock)["left"][2] == pytest.approx(30, abs=1.0)


def test_travel_above_the_zone_height_outside_the_box_is_allowed(twin: Any) -> None:
    c, _, cell, lock = twin()
    entries = run(c, {"T_ROB_L": program([("J", (150, 450, 120), 500),  # y 450: past the box
                                          ("L", (500, 430, 81), 300)])})  # (as far as it reaches)
    assert [e.title for e in entries] == [DONE]
    assert tcps(cell, lock)["left"] == pytest.approx((500, 430, 81), abs=1.0)


def test_the_zone_constants_read_over_rws_as_the_modules_declare_them(twin: Any) -> None:
    zones = {"left": ArmZone(250, 40, 550, 330, zone_z=70, floor_z=2)}
    c, _, _, _ = twin(floor_z=2.0, zones=zones)
    read = {n: c.get_rapid_variable(n, "T_ROB_L/TestbedTask_L")
            for n in ("tb_zone_lo", "tb_zone_hi", "tb_zone_z", "tb_floor_z", "tb_name")}
    assert read == {"tb_zone_lo": "[250,40,0]", "tb_zone_hi": "[550,330,0]",
                    "tb_zone_z": "70", "tb_floor_z": "2", "tb_name": '"testbed_T_ROB_L.bin"'}
    assert c.get_rapid_variable("tb_zone_lo", "T_ROB_R/TestbedTask_R") == "[125,-395,0]"
    assert c.get_rapid_variable("TB_RAPID_VERSION", "T_ROB_R/TestbedMotion") == str(
        RAPID_VERSION)
    assert c.get_rapid_variable("tb_wz_floor", "T_ROB_L/TestbedZones") != "[0]"
    assert c.get_rapid_variable("tb_zones_n", "T_ROB_L/TestbedZones") == "5"  # all active
    with pytest.raises(Exception, match="is a CONST"):  # the controller refuses a write
        c.set_rapid_variable("tb_zone_z", "500", "T_ROB_L/TestbedTask_L")
    refused = run(c, {"T_ROB_L": program([("J", (400, 200, 100), 500)], tool_z_mm=12.5)})
    assert [e.args[1] for e in refused] == [TOOL_DIFFERS]
    assert c.get_rapid_variable("tool_pusher", "T_ROB_L/TestbedTask_L").startswith(
        f"[TRUE,[[0,0,{DEFAULT_TOOL_MM:g}],[1,0,0,0]],[0.272,")  # the controller's, kept
