"""The agent's real YuMi controller client (``RwsYumiController``) against the RWS twin
serving a real ``YumiTwinCell`` with OUR RAPID's semantics (``TestbedRapid``): a two-arm
step uploads one file per task and moves BOTH arms to their own targets (the library's
naming put both programs in one file and the left arm ran the right's), a one-arm step
moves only that arm, and a refusal of our RAPID reaches the caller as one line naming the
event-log entry."""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.errors import BackendError
from drivers.yumi.credentials import FACTORY_LOGIN
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, RwsServer, serve
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.motion_exec import CellMotion
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_arms import rest_tip
from sim_twin.yumi_cell import YumiTwinCell

PUSHER_MM = 184.2
"""The shipped pusher (the twin's and tool_pusher's)."""
REST_TIP = {side: rest_tip(side, PUSHER_MM) for side in ("left", "right")}
"""Where the twin's arms rest the pusher's tip (their rest joints, the pusher)."""
LEFT, RIGHT = (400.0, 200.0, 60.0), (420.0, -180.0, 40.0)
Made = tuple[RwsYumiController, Irc5Controller, YumiTwinCell, CellMotion, threading.Lock]


@pytest.fixture
def yumi() -> Iterator[Callable[..., Made]]:
    made: list[tuple[RwsServer, YumiTwinCell, RwsYumiController]] = []

    def make(hook: type[CellMotion] = TestbedRapid) -> Made:
        cell = YumiTwinCell(3, realtime=0.0)
        lock = threading.Lock()
        motion = hook(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
        ctrl = Irc5Controller(units=YUMI_UNITS, poses=motion.poses, on_start=motion)
        if isinstance(motion, TestbedRapid):  # our modules loaded: tool_pusher, the zones
            TestbedInstall(ctrl, motion)
        server = serve(ctrl)
        poses = {u.arm: ArmPose(u.task, u.name, tuple(motion.poses.joints(u)),
                                tool_z_mm=PUSHER_MM) for u in YUMI_UNITS}
        client = RwsYumiController(server.url, poses, http_timeout_s=20.0,
                                   motion_timeout_s=60.0, login=FACTORY_LOGIN)
        made.append((server, cell, client))
        return client, ctrl, cell, motion, lock

    yield make
    for server, cell, client in made:
        client.close()
        server.stop()
        cell.close()


def tcps(cell: YumiTwinCell, lock: threading.Lock) -> dict[str, tuple[float, float, float]]:
    with lock:
        return cell.tcp_xyz()


def to(xyz: tuple[float, float, float]) -> list[Waypoint]:
    above = (xyz[0], xyz[1], xyz[2] + 40.0)
    return [Waypoint("move_j", above, 150.0, fine=False), Waypoint("move_l", xyz, 150.0)]


def test_a_two_arm_step_moves_each_arm_to_its_own_target(yumi: Any) -> None:
    client, ctrl, cell, motion, lock = yumi()
    client.execute({"left": to(LEFT), "right": to(RIGHT)})
    assert sorted(f["_title"] for f in ctrl.files.listdir("$TEMP")) == [
        "testbed_T_ROB_L.bin", "testbed_T_ROB_R.bin"]  # two files: no clash
    assert {t: tp.path for t, tp in motion.last_run.items()} == {
        "T_ROB_L": "RAMDISK:/testbed_T_ROB_L.bin", "T_ROB_R": "RAMDISK:/testbed_T_ROB_R.bin"}
    got = tcps(cell, lock)
    assert got["left"] == pytest.approx(LEFT, abs=1.0)
    assert got["right"] == pytest.approx(RIGHT, abs=1.0)
    # read with tool_pusher, whose tframe each program set: the pusher's tip, not the flange
    assert client.tcp_xyz()["left"] == pytest.approx(LEFT, abs=1.0)
    done = [e for e in ctrl.elog.entries() if e.title == "Testbed Motion Done"]
    assert sorted(e.args[1] for e in done) == ["T_ROB_L", "T_ROB_R"]
    assert {e.args[2] for e in done} == {"seqno 1"}
    client.execute({"left": [Waypoint("rest", None, 150.0)],  # the next step: seqno 2
                    "right": [Waypoint("rest", None, 150.0)]})
    got = tcps(cell, lock)
    assert got["left"] == pytest.approx(REST_TIP["left"], abs=1.0)
    assert got["right"] == pytest.approx(REST_TIP["right"], abs=1.0)


def test_a_one_arm_step_moves_only_that_arm(yumi: Any) -> None:
    client, ctrl, cell, motion, lock = yumi()
    before = tcps(cell, lock)
    client.execute({"right": to(RIGHT)})
    # both tasks get a file and run it (issue 35: no stale program ever): the idle left
    # one a "stay" (a single WaitTime), which moves nothing
    assert sorted(motion.last_run) == ["T_ROB_L", "T_ROB_R"]
    assert [type(c).__name__ for c in motion.last_run["T_ROB_L"].program.commands] == [
        "WaitTime"]
    got = tcps(cell, lock)
    assert got["right"] == pytest.approx(RIGHT, abs=1.0)
    assert got["left"] == before["left"]
    assert ctrl.task("T_ROB_L").active is True  # activated by the driver, then resetpp


def test_a_malformed_program_is_one_line_naming_the_entry(
        yumi: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    client, _, cell, _, lock = yumi()
    before = tcps(cell, lock)
    plain = client.program

    class Garbled:  # the first command's opcode (float 1 + header) made 99
        def __init__(self, mp: Any) -> None:
            self.mp = mp

        def get_program_bytes(self, seqno: int | None = None) -> bytes:
            data = self.mp.get_program_bytes(seqno)
            i = 4 * (1 + 19 + 25 + 11 + 9 + 1 + 1 + 1)
            return data[:i] + struct.pack("<f", 99.0) + data[i + 4:]

    monkeypatch.setattr(client, "program", lambda arm, wps: Garbled(plain(arm, wps)))
    with pytest.raises(BackendError) as info:
        client.execute({"left": to(LEFT)})
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("YuMi controller: event log 80001 'Testbed Motion Failed': ")
    assert "Invalid motion program command; RAMDISK:/testbed_T_ROB_L.bin; unknown opcode 99" \
        in msg
    assert tcps(cell, lock) == before


def test_a_target_below_the_table_is_refused_before_any_motion(yumi: Any) -> None:
    client, _, cell, _, lock = yumi()
    before = tcps(cell, lock)
    with pytest.raises(BackendError, match=r"^YuMi controller: event log 80001 'Testbed "
                                           r"Motion Failed': Target below the table; "
                                           r"RAMDISK:/testbed_T_ROB_R.bin; MoveL cmd_num 2: "
                                           r"z -5 mm"):
        client.execute({"left": to(LEFT), "right": to((400.0, -200.0, -5.0))})
    got = tcps(cell, lock)
    assert got["right"] == before["right"]  # refused in full: not even the MoveJ
    assert got["left"] == pytest.approx(LEFT, abs=1.0)  # an independent task: it ran


def test_a_controller_without_our_rapid_is_named(yumi: Any) -> None:
    """Issue 43: the library's RAPID (no TestbedMotion) is refused BEFORE anything is
    uploaded or started (it used to be named only after its run failed); and our RAPID
    that ends without its Done entry is named after the run."""
    client, ctrl, *_ = yumi(hook=CellMotion)  # the library's RAPID: it reads another file
    newest = ctrl.elog.newest
    with pytest.raises(BackendError, match=r"task T_ROB_L: TestbedMotion/TB_RAPID_VERSION "
                                           r"cannot be read: .*the motion was not started"):
        client.execute({"left": to(LEFT)})
    assert ctrl.files.listdir("$TEMP") == [] and ctrl.elog.newest == newest  # nothing sent
    client, ctrl, *_ = yumi()
    ctrl.on_start = None  # RAPID that ends at once and writes nothing
    with pytest.raises(BackendError, match=r"task\(s\) T_ROB_L, T_ROB_R ended without the "
                                           r"event log entry "
                                           r"'Testbed Motion Done' for program 1: is the "
                                           r"testbed RAPID \(robot/rapid/\) loaded"):
        client.execute({"left": to(LEFT)})


# -- the pusher, not the flange: lift first; world zones -----------------------------------
def backend_on(client: RwsYumiController, motion: CellMotion, tmp_path: Path, *,
               table_box: tuple[float, float, float, float] | None = None) -> Any:
    """A ``YumiBackend`` on the real client (a video file for a camera: no pictures are
    taken here). Its calibration: the pusher's length as ``tool_z_mm``, the twin's rest."""
    from driver_fakes import twin_picture, write_video

    from drivers.cameras.camera import VideoCaptureCamera
    from drivers.yumi.arm_calibration import ArmCalibration
    from drivers.yumi.backend import ArmSetup, YumiBackend
    from sim_twin.yumi_geometry import workspace_mm

    setups = []
    for u in YUMI_UNITS:
        cal = {"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
               "table_box_mm": list(table_box or workspace_mm(motion.cell.sides[u.arm])),
               "z_push_mm": 12.0, "z_travel_mm": 80.0, "max_speed_mm_s": 150.0,
               "push_speed_mm_s": 100.0, "tool_z_mm": PUSHER_MM,
               "rest_joints_deg": list(motion.poses.joints(u))}
        setups.append(ArmSetup(u.arm, (0, 0, 64, 64), u.arm == "right",
                               ArmCalibration.from_dict(cal, u.arm)))
    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    return YumiBackend(setups, VideoCaptureCamera(str(video)), client)


def test_move_tcp_and_rest_lift_the_pusher_first_when_it_is_low(yumi: Any,
                                                                 tmp_path: Path) -> None:
    client, _, cell, motion, lock = yumi()
    backend = backend_on(client, motion, tmp_path)
    low = (400.0, 200.0, 15.0)
    assert backend.move_tcp("left", low) == pytest.approx(low, abs=1.0)
    # The pusher is 15 mm over the table, its flange 199 mm: only a read with the pusher's
    # tool sees that it is low. The rest move goes straight up to travel height first
    # (retracing the way down), straight to the gate, then MoveAbsJ (drivers/yumi/paths.py).
    gate = backend._arms["left"].calibration.gate_xy
    backend.rest()
    cmds = motion.last_run["T_ROB_L"].program.commands
    assert [type(c).__name__ for c in cmds] == ["MoveL", "MoveL", "MoveAbsJ"]
    assert list(cmds[0].to_point.trans) == pytest.approx([400.0, 200.0, 80.0], abs=0.05)
    assert list(cmds[1].to_point.trans) == pytest.approx([*gate, 100.0], abs=1e-3)
    assert tcps(cell, lock)["left"] == pytest.approx(REST_TIP["left"], abs=1.0)
    backend.move_tcp("left", low)
    backend.move_tcp("left", (300.0, 100.0, 20.0))  # from low to another point: up first,
    cmds = motion.last_run["T_ROB_L"].program.commands  # then by rest (it unwinds axes 4, 6)
    assert [type(c).__name__ for c in cmds] == ["MoveL", "MoveL", "MoveAbsJ", "MoveJ",
                                                "MoveL", "MoveL"]
    assert list(cmds[0].to_point.trans) == pytest.approx([400.0, 200.0, 80.0], abs=0.05)
    assert list(cmds[1].to_point.trans) == pytest.approx([*gate, 100.0], abs=1e-3)
    assert list(cmds[3].to_point.trans) == pytest.approx([*gate, 100.0], abs=1e-3)
    assert tcps(cell, lock)["left"] == pytest.approx((300.0, 100.0, 20.0), abs=1.0)
    backend.rest()
    backend.move_tcp("left", (300.0, 100.0, 90.0))  # from rest: by joints to the gate
    cmds = motion.last_run["T_ROB_L"].program.commands
    assert [type(c).__name__ for c in cmds] == ["MoveJ", "MoveL", "MoveL"]
    assert list(cmds[0].to_point.trans) == pytest.approx([*gate, 100.0], abs=1e-3)
    backend.close()


@pytest.mark.slow
def test_a_calibration_grid_over_the_shipped_box_reaches_every_point(yumi: Any,
                                                                     tmp_path: Path) -> None:
    """Issue 35: ``testbed calibrate``'s 5x4 grid over the right arm's shipped box, as the
    rehearsal runs it. With the pusher down the wrist passes near its singularity over
    part of the box (axis 5 near 0, axis 4 turning fast); a way back from a point that was
    not the way out (up to clear height, then across to the gate) wound axis 4 round and
    the twin stopped the grid's 17th point with 50027 ("axis 4 0.1 deg past its limit")
    on the way back from the 16th. Back the way it came, every point is reached."""
    from sim_twin.yumi_geometry import workspace_mm
    from testbed.lab.calibrate import GRID_INSET_MM
    from testbed.lab.camera_model import push_box
    from testbed.perception.homography import grid_points

    client, _, _, motion, _ = yumi()
    box = tuple(push_box(workspace_mm(motion.cell.sides["right"])))
    backend = backend_on(client, motion, tmp_path, table_box=box)  # type: ignore[arg-type]
    points = grid_points(box, (5, 4), inset_mm=GRID_INSET_MM)  # type: ignore[arg-type]
    for x, y in points:
        got = backend.move_tcp("right", (x, y, 10.0))
        assert got == pytest.approx((x, y, 10.0), abs=1.0)
    cmds = motion.last_run["T_ROB_R"].program.commands  # the way back: up to travel height
    assert list(cmds[0].to_point.trans) == pytest.approx([*points[-2], 80.0], abs=0.05)
    backend.close()


def test_a_push_past_the_world_zone_is_stopped_by_the_controller(yumi: Any,
                                                                  tmp_path: Path) -> None:
    client, ctrl, cell, motion, lock = yumi()
    zone = motion.zones["left"]  # the twin's default: the workspace grown by 25 mm
    y = (zone.y0 + zone.y1) / 2
    start, past = (zone.x1 - 60.0, y, 12.0), (zone.x1 + 40.0, y, 12.0)
    stroke = [Waypoint("move_j", (start[0], y, 80.0), 150.0, fine=False),
              Waypoint("move_l", start, 100.0), Waypoint("move_l", past, 50.0)]
    with pytest.raises(BackendError) as info:
        client.execute({"left": stroke, "right": to(RIGHT)})
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert msg.startswith("YuMi controller: event log 50000 'World zone reached': Task "
                          "T_ROB_L: the TCP of tool_pusher reached the stationary world "
                          "zone tb_wz_xhi"), msg
    got = tcps(cell, lock)
    assert got["left"][0] == pytest.approx(zone.x1, abs=0.5)  # stopped on the zone's face
    assert got["left"][2] == pytest.approx(12.0, abs=0.5)
    assert not any(e.title == "Testbed Motion Done" for e in ctrl.elog.entries())
    # A task stopped by the zone stays stopped for the driver until a person has looked:
    # the next motion is refused, naming the entry, until the program pointer is reset.
    with pytest.raises(BackendError, match=r"stopped by a RAPID error \(event log 50000 "
                                           r"'World zone reached'.*PP to Main"):
        client.execute({"left": to(LEFT)})
    ctrl.resetpp()  # the FlexPendant's "PP to Main"
    # The same through the backend: a table box wider than the zone lets a point past it
    # be asked for; the controller stops the arm where the zone begins, and says so: the
    # pusher travels above the zone's height and comes down past its face, so it stops
    # on the zone's top, over the point.
    backend = backend_on(client, motion, tmp_path, table_box=(
        zone.x0, zone.y0, zone.x1 + 80.0, zone.y1))
    with pytest.raises(BackendError, match=r"^YuMi controller: event log 50000 'World zone "
                                           r"reached'"):
        backend.move_tcp("left", (zone.x1 + 40.0, y, 20.0))
    got = tcps(cell, lock)["left"]
    assert (got[0], got[2]) == pytest.approx((zone.x1 + 40.0, zone.zone_z), abs=0.5)
    backend.close()


# -- what the agent says of its controller at hello (run.json ``hosts``) -------------------
def test_controller_info_is_what_the_controller_says_and_never_the_login(
        tmp_path: Path) -> None:
    from drivers.yumi.rws_controller import controller_identity, controller_info
    from sim_twin.rws import serve
    from sim_twin.rws.irc5 import Identity

    ident = Identity(ctrl_id="14000-512345", rwversion="6.15.02.00", name="YUMI_LAB")
    server = serve(Irc5Controller(identity=ident), users={"lab": "s3cret-pw"})
    login = tmp_path / "rws.login"
    login.write_text("lab:s3cret-pw\n")
    login.chmod(0o600)
    try:
        info = controller_info(server.url, str(login))
        assert info == {"serial": "14000-512345", "robotware": "6.15.02.00",
                        "system": "YUMI_LAB"}
        assert controller_identity(server.url, str(login)) == "IRC5 14000-512345"
        login.write_text("lab:wrong\n")  # refused: nothing is known, nothing is guessed
        assert controller_info(server.url, str(login)) is None
    finally:
        server.stop()
    assert controller_info(server.url, None, timeout_s=0.5) is None  # unreachable
