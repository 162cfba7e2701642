"""``testbed calibrate``'s box: a default from the arm's shipped layout, one frame's name.

Issue 44, "calibration that works the first time": a lab's first calibration file has the
rest pose and the tool but no ``table_box_mm``; ``testbed calibrate`` without ``--box``
then drives the arm in the backend's default table box for that arm (a YuMi's shipped
one, ``drivers/yumi/arm_calibration.py``), says which box it uses, and refuses a
``--box`` the host would refuse, in one line naming ``--box``. The box is in the robot's
world frame (wobj0), and ``--help`` and robot/README.md call it by the same words.
The run against the hardware twin (no ``table_box_mm``, no ``--box``, the file written
with the default box) is ``tests/testbed/test_calibrate.py``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from drivers.yumi.arm_calibration import SHIPPED_TABLE_BOX_MM, provisional_calibration
from drivers.yumi.gate import calibration_gate_joints
from drivers.yumi.reach import ArmTool, default_arm_angle
from sim_twin.yumi_geometry import workspace_mm
from testbed.cli import main
from testbed.core.backend_registry import backend
from testbed.core.config import ConfigError
from testbed.lab.calibrate import GRID_INSET_MM, TABLE_FRAME, CalibrateOptions, _safe_box
from testbed.lab.camera_model import arm_facts, push_box
from testbed.perception.homography import grid_points

ROOT = Path(__file__).resolve().parents[2]
YUMI = backend("yumi")


def _zone_box(side: str) -> tuple[float, float, float, float]:
    """``tb_zone_lo``/``tb_zone_hi`` (x, y) as the shipped task module sets them."""
    text = (ROOT / "robot" / "rapid" / f"TestbedTask_{side[0].upper()}.mod").read_text()
    lo, hi = (re.search(rf"CONST pos {n} := \[(-?\d+),(-?\d+),", text) for n in
              ("tb_zone_lo", "tb_zone_hi"))
    assert lo is not None and hi is not None
    return (float(lo[1]), float(lo[2]), float(hi[1]), float(hi[2]))


def test_the_default_box_is_each_arms_shipped_table_box_mirrored() -> None:
    left, right = YUMI.default_table_box("left"), YUMI.default_table_box("right")
    assert left == (150.0, 75.0, 470.0, 370.0)
    assert right == (left[0], -left[3], left[2], -left[1])  # mirrored in y
    for side in ("left", "right"):  # the twin's workspace, inner edge 75 mm off centre
        assert list(SHIPPED_TABLE_BOX_MM[side]) == push_box(workspace_mm(side))
        box, zone = SHIPPED_TABLE_BOX_MM[side], _zone_box(side)
        inside = min(box[0] - zone[0], box[1] - zone[1], zone[2] - box[2], zone[3] - box[3])
        assert inside >= 25.0, (side, box, zone)  # inside the controller's world zone
    # the side from the file's task first, then from the arm's name; none: no default
    assert YUMI.default_table_box("arm-b", {"task": "T_ROB_R"}) == right
    assert YUMI.default_table_box("arm-b", {"task": "T_ROB_L"}) == left
    assert YUMI.default_table_box("arm-b", None) is None
    assert backend("twin").default_table_box("left") is None


def test_the_agent_drives_an_arm_without_a_table_box_in_the_default_box(
        tmp_path: Path) -> None:
    """The host's side agrees with the command's: an arm being calibrated whose file has
    no table box is driven (and its gate placed) in the same default box."""
    for side in ("left", "right"):
        path = tmp_path / f"{side}.json"
        path.write_text('{"tool_z_mm": 184.2}')
        got = provisional_calibration(str(path), side).table_box_mm
        assert got == YUMI.default_table_box(side), side
    path = tmp_path / "b.json"
    path.write_text('{"tool_z_mm": 184.2, "task": "T_ROB_R"}')
    assert provisional_calibration(str(path), "arm-b").table_box_mm == SHIPPED_TABLE_BOX_MM[
        "right"]


def _shipped_file(side: str) -> dict[str, Any]:
    """What ``testbed calibrate`` writes over the default box with the shipped rest pose,
    tool and arm angle (the homography does not enter the layout's checks)."""
    cal = {"homography": [[0, 1, 0], [1, 0, 0], [0, 0, 1]],
           "table_box_mm": list(SHIPPED_TABLE_BOX_MM[side]), "z_push_mm": 10.0,
           "z_travel_mm": 80.0, **arm_facts(side),
           "task": "T_ROB_L" if side == "left" else "T_ROB_R"}
    return {**cal, "gate_joints_deg": calibration_gate_joints(side, cal)}


@pytest.mark.slow
def test_the_default_boxes_pass_the_layout_check_and_every_grid_point_solves() -> None:
    """What ``testbed calibrate`` reports after a fit (the YuMi's layout report, the
    shipped zones): no FAULT for the two default boxes together, and every point of the
    default 5x4 grid over each has a solution with the pusher down at the arm angle."""
    cals = {side: _shipped_file(side) for side in ("left", "right")}
    rapid = {}
    for side, c in cals.items():  # each task's zone as its shipped module sets it
        x0, y0, x1, y1 = _zone_box(side)
        rapid[c["task"]] = {"zones": {"tb_zone_lo": [x0, y0, 0], "tb_zone_hi": [x1, y1, 0],
                                      "tb_zone_z": 80, "tb_floor_z": 0}}
    info = {"controller": {"rapid": rapid}}
    lines, faults = YUMI.layout_report(None, cals, info)  # type: ignore[arg-type]
    assert faults == [], faults
    assert any("reach margin" in line for line in lines), lines
    for side in ("left", "right"):
        tool = ArmTool(side, 184.2, default_arm_angle(side))
        points = grid_points(SHIPPED_TABLE_BOX_MM[side], (5, 4), inset_mm=GRID_INSET_MM)
        assert len(points) == 20
        unsolved = [p for p in points if tool.solve((p[0], p[1], 10.0)).pose is None]
        assert unsolved == [], (side, unsolved)


def _opts(arm: str, box: tuple[float, float, float, float] | None = None) -> CalibrateOptions:
    return CalibrateOptions(host="yumi", arm=arm, box=box)


def test_without_box_the_default_is_used_and_named() -> None:
    default = YUMI.default_table_box("right")
    assert default is not None
    box, source = _safe_box(_opts("right"), {"rest_joints_deg": [0] * 7}, "cal/right.json",
                            default, "yumi")
    assert box == (150.0, -370.0, 470.0, -75.0)
    assert source == ("the yumi backend's default for arm right: cal/right.json has no "
                      "table_box_mm yet; --box for another inside it")
    box, source = _safe_box(_opts("right"), None, "cal/right.json", default, "yumi")
    assert box == default  # no file at all: the same
    # a file's own table box wins over the default
    box, source = _safe_box(_opts("right"), {"table_box_mm": [160, -300, 400, -100]},
                            "cal/right.json", default, "yumi")
    assert box == (160.0, -300.0, 400.0, -100.0)
    assert source == "cal/right.json's table_box_mm; --box for another inside it"
    # --box inside the default box: taken as given
    box, source = _safe_box(_opts("right", (200.0, -300.0, 400.0, -100.0)), None,
                            "cal/right.json", default, "yumi")
    assert (box, source) == ((200.0, -300.0, 400.0, -100.0), "--box")


def test_a_box_the_host_would_refuse_or_no_box_at_all_is_one_line_naming_box() -> None:
    default = YUMI.default_table_box("left")
    with pytest.raises(ConfigError) as info:  # the right arm's box given for the left
        _safe_box(_opts("left", (150.0, -370.0, 470.0, -75.0)), None, "cal/left.json",
                  default, "yumi")
    msg = str(info.value)
    assert msg == ("--box: (150.0, -370.0, 470.0, -75.0) leaves the table box (150.0, 75.0, "
                   "470.0, 370.0), the yumi backend's default for arm left (cal/left.json "
                   "has no table_box_mm), and the host refuses TCP points outside it; give a "
                   "box inside it or write table_box_mm into that file on the host first")
    with pytest.raises(ConfigError) as info:  # no file's box, no default
        _safe_box(_opts("arm-b"), None, "cal/b.json", None, "yumi")
    msg = str(info.value)
    assert msg.startswith("--box: required, the arm's calibration (cal/b.json) has no "
                          "table_box_mm and the yumi backend has no default box for arm "
                          "arm-b"), msg
    assert "\n" not in msg and TABLE_FRAME in msg


def _help(capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_help_and_robot_readme_name_the_boxs_frame_the_same_way(
        capsys: pytest.CaptureFixture[str]) -> None:
    """One frame, one name: ``--help``, robot/README.md ("Frames") and the calibration
    file's docstring say "the robot's world frame (wobj0)"; no doc says "robot base
    frame" for it (each arm's own base frame, at its shoulder, is another frame)."""
    assert TABLE_FRAME == "the robot's world frame (wobj0)"
    text = _help(capsys)
    assert f"--box x0,y0,x1,y1 safe box of TCP points, mm, in {TABLE_FRAME}" in text, text
    for side in ("left", "right"):  # the defaults --help shows are the driver's
        shown = ",".join(f"{v:g}" for v in SHIPPED_TABLE_BOX_MM[side])
        assert f"{side} {shown}" in text, (side, text)
    readme = " ".join((ROOT / "robot" / "README.md").read_text().split())
    assert f"everything is in {TABLE_FRAME}" in readme.replace("**", "")
    from drivers.yumi import arm_calibration

    assert TABLE_FRAME in " ".join(Path(arm_calibration.__file__).read_text().split())
    docs = [ROOT / "README.md", ROOT / "robot" / "README.md", *(ROOT / "docs").rglob("*.md")]
    said = [p.name for p in docs if "robot base frame" in " ".join(p.read_text().split())]
    assert said == [] and "base frame" not in text, said
