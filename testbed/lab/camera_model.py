"""Calibrations judged against the hardware twin's TRUE camera model.

Why it exists: on a real robot nobody knows how good a calibration is beyond its own
reprojection error; on the twin the camera's pinhole, lens distortion and pose are
known (``/lab/camera``). So a rehearsal can say what a fitted homography really gets
wrong (``true_model_error``), tests and benchmarks can have a perfect calibration
without driving the arm (``true_calibration``), and a rehearsal can write the file a
lab writes by hand before its first calibration (``starting_calibration``: the safe box
and the rest pose, no homography yet). All three project the cube-top plane through the
true camera (``project_plane``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from testbed.lab.hardware_twin import HardwareTwinLab

REST_JOINTS_DEG = {"left": (40.0, -90.0, 30.0, 0.0, 40.0, 0.0, 135.0),
                   "right": (-40.0, -90.0, 30.0, 0.0, 40.0, 0.0, -135.0)}
"""The twin's rest joints (``sim_twin/yumi_geometry.py``'s ``REST_JOINTS_DEG``, whose
docstring gives the figures: the lab's rooms import no twin at import time, so the
numbers are here too; a test keeps them equal): ABB's folded arm and wrist (axes 3-7 as
ABB's home ``[0,-130,30,0,40,0]``, axis 7 +135 left, -135 right) with axis 1 swung back
40 deg and axis 2 raised to -90. ABB's home itself cannot be the rest with the 184.2 mm
pusher: its tip hangs at about (149, +-141, 115) mm, over the workspaces' near edge, in
the camera's view (the driver's retake rule would retake for ever). This rest holds the
tip at about (-117, +-276, 268) mm, outside the camera's view, the links over 330 mm
above the table, the arms apart, no joint within 33 deg of its limit."""
PUSH_ARM_ANGLE_DEG = -40.0
"""The left arm's arm angle (ABB's, the reference along axis 1) for its pushes (the
right's: minus it), the driver's own default (``drivers/yumi/reach.py``
``ARM_ANGLE_DEG``; a test keeps them equal): held at every target, each straight line
keeps it and the way back retraces the way out (docs/notes/auto-day-one.md)."""
DEFAULT_TOOL_Z_MM = 184.2
"""The pusher's tip below the flange when the twin does not say (its default, the
project's one pusher length: ABB's servo-gripper finger TCP at 114.2 mm plus the rod's
70 mm beyond the fingers; robot/README.md)."""

INNER_EDGE_MM = 75.0
"""Where the shipped table boxes stop on the side of the body's centre line (|y|, mm): the
workspaces begin at 50, but with the 184.2 mm pusher two arms pushing at their boxes'
inner far corners at once meet: the project's model puts the forearms 22 mm INTO each
other at (470, +-50) (``testbed check``: a FAULT), the twin stops them with 50204 ("2 mm
apart"); at 75 the model keeps them 29 mm apart (``drivers/yumi/layout_check.py`` wants
25). A cube in the inner 25 mm is still seen and reached from the outside; a push that
would start nearer the centre line is clipped into the box, as at every other edge."""

__all__ = [
    "INNER_EDGE_MM",
    "REST_JOINTS_DEG",
    "arm_facts",
    "project_plane",
    "push_box",
    "starting_calibration",
    "true_calibration",
    "true_model_error",
]


def project_plane(cam: Mapping[str, Any], box_mm: Sequence[float], plane_z_mm: float,
                  n: int) -> tuple[Any, Any]:
    """An n x n grid of the box at height ``plane_z_mm`` (mm, (n*n, 3)) and where the
    twin's TRUE camera (pinhole, distortion, pose from ``/lab/camera``) sees it ((n*n, 2))."""
    import cv2
    import numpy as np

    xs = np.linspace(box_mm[0], box_mm[2], n)
    ys = np.linspace(box_mm[1], box_mm[3], n)
    pts = np.array([(x, y, plane_z_mm) for x in xs for y in ys], dtype=np.float64)
    rvec, _ = cv2.Rodrigues(np.asarray(cam["R"], dtype=np.float64))
    px, _ = cv2.projectPoints(pts, rvec, np.asarray(cam["t"], dtype=np.float64),
                              np.asarray(cam["K"], dtype=np.float64),
                              np.asarray(cam["dist"], dtype=np.float64))
    return pts, px.reshape(-1, 2)


def true_calibration(cam: Mapping[str, Any], arm: str, plane_z_mm: float = 40.0,
                     n: int = 9) -> dict[str, Any]:
    """The arm's calibration file as a perfect ``testbed calibrate`` would write it: the
    homography fitted to the twin's TRUE projection of the cube-top plane over the arm's
    workspace, and the gate joints (the driver's model's for the gate: drivers/yumi/gate.py;
    a rehearsal's calibration measures them on the twin). For tests and benchmarks that need a
    calibrated twin quickly; a rehearsal calibrates with ``testbed calibrate`` itself."""
    import cv2

    from drivers.yumi.gate import calibration_gate_joints

    box = [float(v) for v in cam["workspaces_mm"][arm]]
    pts, px = project_plane(cam, box, plane_z_mm, n)
    h, _ = cv2.findHomography(px, pts[:, :2])
    side = "L" if arm.startswith("l") else "R"
    cal = {"homography": h.tolist(), "table_box_mm": push_box(box), **arm_facts(arm, cam),
           "task": f"T_ROB_{side}", "mechunit": f"ROB_{side}"}
    return {**cal, "gate_joints_deg": calibration_gate_joints(arm, cal)}


def push_box(workspace_mm: Sequence[float]) -> list[float]:
    """The table box a lab writes for an arm of the twin: its workspace (x0, y0, x1, y1)
    with the edge nearer the centre line held :data:`INNER_EDGE_MM` from it."""
    x0, y0, x1, y1 = (float(v) for v in workspace_mm)
    if y0 >= 0:  # a left arm's workspace: the inner edge is y0
        return [x0, max(y0, INNER_EDGE_MM), x1, y1]
    return [x0, y0, x1, min(y1, -INNER_EDGE_MM)]


def arm_facts(arm: str, cam: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What a lab measures on its arm and writes into the calibration before the first
    fit: the rest joints (jogged and read off the jointtarget), the pushes' arm angle and
    the tool's length (the twin's, from its ``/lab/camera`` when given)."""
    cam = cam or {}
    side = "left" if arm.startswith("l") else "right"
    rest = cam.get("rest_joints_deg", {}).get(arm) or REST_JOINTS_DEG[side]
    return {"rest_joints_deg": [float(v) for v in rest],
            "arm_angle_deg": PUSH_ARM_ANGLE_DEG if side == "left" else -PUSH_ARM_ANGLE_DEG,
            "tool_z_mm": float(cam.get("tool_z_mm", DEFAULT_TOOL_Z_MM))}


def true_model_error(cam: Mapping[str, Any], homography: Any, box_mm: Sequence[float],
                     plane_z_mm: float = 40.0, n: int = 9) -> dict[str, float]:
    """A fitted pixel -> table homography against the twin's TRUE camera model (pinhole,
    distortion, pose), over an n x n grid of the box in the cube-top plane: the error a
    calibrated arm makes in pixels (where it thinks a table point is seen) and in
    millimetres (where it thinks a seen point is on the table)."""
    import cv2
    import numpy as np

    pts, px = project_plane(cam, box_mm, plane_z_mm, n)
    h = np.asarray(homography, dtype=np.float64)
    mm = cv2.perspectiveTransform(px.reshape(-1, 1, 2), h).reshape(-1, 2)
    back = cv2.perspectiveTransform(pts[:, None, :2].copy(), np.linalg.inv(h)).reshape(-1, 2)
    err_mm = np.linalg.norm(mm - pts[:, :2], axis=1)
    err_px = np.linalg.norm(back - px, axis=1)
    return {"median_px": float(np.median(err_px)), "max_px": float(err_px.max()),
            "median_mm": float(np.median(err_mm)), "max_mm": float(err_mm.max())}


def starting_calibration(lab: HardwareTwinLab, host: str, arm: str) -> Path:
    """The file a lab writes by hand before its first calibration: the arm's safe table
    box and its rest pose (here, the twin's), no homography yet. An existing file is
    left as it is (a rehearsal run again keeps its calibrations)."""
    cam = lab.hosts[host].lab.camera()
    path = lab.calibration_path(host, arm)
    if path.exists():
        return path
    from testbed.core.atomic import atomic_write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    start = true_calibration(cam, arm)
    del start["homography"]  # what a person knows before calibrating: box and rest pose
    del start["gate_joints_deg"]  # testbed calibrate measures them at the gate
    atomic_write_json(path, start)
    return path
