"""One YuMi arm's calibration file: what it holds, how it is checked, how it is written.

Why its own module: the file is the contract between ``testbed calibrate`` (which
writes it), the backend (which plans every push from it, ``backend.py``), ``testbed
check`` and the layout's checks (which read its heights, tool and rest pose,
``layout_check.py``). The homography joins the policy's image to the table in
millimetres; the safety envelope (the table box every waypoint is clipped into, the
speed cap, the push, travel and clear heights), the pusher's length and the rest pose
come with it. A file that would move the arm somewhere unsafe (no tool length, a gate
off the table, a clear height below travel) is refused on load, naming the arm and the
key.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.errors import BackendError
from drivers.yumi.paths import DEFAULT_Z_CLEAR_MM, gate_xy
from drivers.yumi.reach import ARM_ANGLE_MAX_DEG, default_arm_angle, side_of
from drivers.yumi.yumi_controller import ArmPose

__all__ = ["CALIBRATION_BOX_MM", "KNOWN_KEYS", "SHIPPED_TABLE_BOX_MM", "TOOL_HOW",
           "ArmCalibration", "default_table_box", "layout_keys", "provisional_calibration",
           "tool_of", "write_atomic"]

SHIPPED_TABLE_BOX_MM: dict[str, tuple[float, float, float, float]] = {
    "left": (150.0, 75.0, 470.0, 370.0), "right": (150.0, -370.0, 470.0, -75.0)}
"""Each arm's table box (x0, y0, x1, y1) when its calibration file has none: the shipped
layout's, in the robot's world frame (wobj0), mm; left and right mirror each other in y.
Why these: the hardware twin's workspaces (x 150 to 470, |y| 50 to 370:
``sim_twin/yumi_geometry.py``) with the inner edge held 75 mm from the body's centre line
(``testbed/lab/camera_model.py``, ``INNER_EDGE_MM``: two arms at their inner far corners
keep 29 mm apart), at least 25 mm inside the shipped world zone boxes (``tb_zone_lo``,
``tb_zone_hi`` of ``robot/rapid/TestbedTask_L.mod``, ``_R.mod``). With the 184.2 mm
pusher every corner is reached and every path of the layout check is clear
(``tests/drivers/test_yumi_paths_zones.py``), and every point of ``testbed calibrate``'s
5x4 grid over it is reached on the twin (``tests/drivers/test_yumi_rws_twin.py``). So a
lab's first ``testbed calibrate`` needs no ``--box`` (it prints the box it drives in), and
an arm being calibrated has its gate where the shipped layout has it."""

CALIBRATION_BOX_MM = (-1000.0, -1000.0, 1000.0, 1000.0)
"""Table box of an arm being calibrated whose file has none and whose side (left, right)
cannot be told: wide on purpose; the calibration command supplies the safe box it drives
in (``move_tcp`` refuses outside)."""


def default_table_box(arm: str, task: str | None = None
                      ) -> tuple[float, float, float, float] | None:
    """:data:`SHIPPED_TABLE_BOX_MM` of ``arm``'s side (from its task ``T_ROB_L``/``_R``,
    else its name ``left``/``right``); None when the side cannot be told."""
    side = side_of(arm, task)
    return None if side is None else SHIPPED_TABLE_BOX_MM[side]

KNOWN_KEYS = frozenset({
    "homography", "table_box_mm", "z_push_mm", "z_travel_mm", "z_clear_mm", "gate_xy_mm",
    "max_speed_mm_s", "push_speed_mm_s", "start_offset", "stroke", "task", "mechunit",
    "rest_joints_deg", "gate_joints_deg", "tool_quat_wxyz", "robconf", "arm_angle_deg",
    "tool_z_mm"})
TOOL_HOW = ("measure the pusher on the robot with the FlexPendant's 4-point TCP method and "
            "write its z (mm, flange to tip; the shipped pusher: 184.2) as tool_z_mm, the "
            "same value as tool_pusher's tframe in TestbedTask_L/_R (robot/README.md, "
            "'The tool frame')")
"""How a lab gets ``tool_z_mm``: said wherever it is missing."""

log = logging.getLogger(__name__)


def _tool_z(d: Mapping[str, Any], bad: Any) -> float:
    """The file's ``tool_z_mm``: required (never a silent flange: world zones guard the
    TCP of the tool in use, so a wrong tool moves every zone by the difference)."""
    if "tool_z_mm" not in d:
        raise bad(f"has no 'tool_z_mm' (the pusher's length): {TOOL_HOW}")
    try:
        z = float(d["tool_z_mm"])
    except (TypeError, ValueError):
        raise bad(f"'tool_z_mm' must be a number, got {d['tool_z_mm']!r}") from None
    if not (math.isfinite(z) and 0 < z <= 500):
        raise bad(f"'tool_z_mm' must be the pusher's length, 0 < tool_z_mm <= 500 mm, got "
                  f"{z:g}: {TOOL_HOW}")
    return z


def _joints(d: Mapping[str, Any], key: str, bad: Any) -> tuple[float, ...] | None:
    """The file's ``key`` (7 finite angles, axis 7 last), None when not given."""
    if key not in d:
        return None
    try:
        joints = tuple(float(v) for v in d[key])
    except (TypeError, ValueError):
        raise bad(f"'{key}' must be 7 numbers (axes 1-6, then axis 7)") from None
    if len(joints) != 7 or not all(math.isfinite(v) for v in joints):
        raise bad(f"'{key}' needs 7 angles (axis 7 last), got {list(joints)}")
    return joints


def _gate(d: Mapping[str, Any], box: Sequence[float], bad: Any) -> tuple[float, float] | None:
    """The file's ``gate_xy_mm``, which must lie in the table box (None: not given)."""
    if "gate_xy_mm" not in d:
        return None
    try:
        gx, gy = (float(v) for v in d["gate_xy_mm"])
    except (TypeError, ValueError):
        raise bad("'gate_xy_mm' must be 2 numbers (x, y) mm") from None
    if not (box[0] <= gx <= box[2] and box[1] <= gy <= box[3]):
        raise bad(f"'gate_xy_mm' ({gx:g}, {gy:g}) must lie in the table box {tuple(box)}")
    return (gx, gy)


@dataclass(frozen=True, slots=True)
class ArmCalibration:
    """One arm's calibration file (JSON), validated on load."""

    homography: npt.NDArray[np.float64]
    """3x3: camera pixel (u, v, 1) -> table point (x, y, w), mm, in the robot's world frame
    (wobj0): every target the driver sends is in it (robot/README.md, "Frames")."""
    table_box_mm: tuple[float, float, float, float]
    """(x_min, y_min, x_max, y_max): every waypoint's (x, y) is clipped into it."""
    z_push_mm: float = 10.0
    z_travel_mm: float = 80.0
    max_speed_mm_s: float = 150.0
    push_speed_mm_s: float = 50.0
    start_offset: float = 8.0 / 64.0
    """Push start, canonical units outside the chosen face (as the twin)."""
    stroke: float = 0.15
    """Push stroke length, canonical units past the start (cube moves ~ stroke - offset)."""
    pose: ArmPose | None = None
    tool_z_mm: float = 0.0
    """The pusher's length, flange to tip (mm): the frame every program file carries,
    which our RAPID compares with the controller's ``tool_pusher`` (robot/README.md, "The
    tool frame"). Required in a file: :meth:`from_dict` refuses one without it."""
    z_clear_mm: float = DEFAULT_Z_CLEAR_MM
    """Clear height (mm): every joint move to or from rest ends or starts at the arm's
    gate at this height; every other move is straight, over the table box
    (``drivers/yumi/paths.py``)."""
    gate_xy_mm: tuple[float, float] | None = None
    """The gate's (x, y) when the file gives one (else its default, ``drivers/yumi/paths.py``)."""
    gate_joints_deg: tuple[float, ...] | None = None
    """The gate as a measured joint target (7 angles, ABB's order: axes 1-6, then 7), the
    end of the joint move from rest (``drivers/yumi/paths.py``). A file may lack it (an
    arm not calibrated since issue 43, or being calibrated): it loads, and the driver
    refuses to move the arm away from rest until ``testbed calibrate`` has written it
    (``drivers/yumi/gate.py``)."""

    @classmethod
    def load(cls, path: str | Path, arm: str) -> ArmCalibration:
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise BackendError(f"arm {arm}: cannot read calibration {p}: {exc}") from None
        return cls.from_dict(d, arm, str(p))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], arm: str, source: str = "calibration"
                  ) -> ArmCalibration:
        def bad(msg: str) -> BackendError:
            return BackendError(f"arm {arm}: {source}: {msg}")

        try:
            h = np.asarray(d["homography"], dtype=np.float64)
            box = tuple(float(v) for v in d["table_box_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise bad(f"needs 'homography' (3x3) and 'table_box_mm' (4 numbers): {exc}") from None
        if h.shape != (3, 3) or not np.all(np.isfinite(h)) or abs(np.linalg.det(h)) < 1e-12:
            raise bad("'homography' must be an invertible 3x3 matrix")
        if len(box) != 4 or box[0] >= box[2] or box[1] >= box[3]:
            raise bad("'table_box_mm' must be (x_min, y_min, x_max, y_max)")
        if extra := set(d) - KNOWN_KEYS:
            raise bad(f"unknown key(s) {sorted(extra)}")
        tool_z = _tool_z(d, bad)
        nums = {k: float(d[k]) for k in ("z_push_mm", "z_travel_mm", "max_speed_mm_s",
                                         "push_speed_mm_s", "start_offset", "stroke",
                                         "z_clear_mm") if k in d}
        gate = _gate(d, box, bad)
        gate_joints = _joints(d, "gate_joints_deg", bad)
        cal = cls(h, box, **nums, tool_z_mm=tool_z, gate_xy_mm=gate)  # type: ignore[arg-type]
        if not 0 < cal.push_speed_mm_s <= cal.max_speed_mm_s <= 1000:
            raise bad("need 0 < push_speed_mm_s <= max_speed_mm_s <= 1000")
        if cal.z_push_mm >= cal.z_travel_mm:
            raise bad("z_push_mm must be below z_travel_mm")
        if not cal.z_clear_mm >= cal.z_travel_mm:
            raise bad(f"z_clear_mm ({cal.z_clear_mm:g}) must be at or above z_travel_mm "
                      f"({cal.z_travel_mm:g}): the clear height is where the joint moves "
                      f"to and from rest end (drivers/yumi/paths.py)")
        angle = _arm_angle(d, arm, bad)
        pose = None
        if (joints := _joints(d, "rest_joints_deg", bad)) is not None:
            side = "L" if arm.startswith("l") else "R"
            pose = ArmPose(task=str(d.get("task", f"T_ROB_{side}")),
                           mechunit=str(d.get("mechunit", f"ROB_{side}")),
                           rest_joints_deg=joints,
                           tool_quat_wxyz=tuple(d.get("tool_quat_wxyz", (0, 0, 1, 0))),
                           robconf=tuple(d.get("robconf", (0, 0, 0, 4))),
                           arm_angle_deg=angle,
                           tool_z_mm=tool_z)
        return cls(h, box, **nums, pose=pose, tool_z_mm=tool_z,  # type: ignore[arg-type]
                   gate_xy_mm=gate, gate_joints_deg=gate_joints)

    @property
    def gate_xy(self) -> tuple[float, float]:
        """The arm's gate (``drivers/yumi/paths.py``)."""
        return gate_xy(self.table_box_mm, self.gate_xy_mm)

    @property
    def gate_xyz(self) -> tuple[float, float, float]:
        """The gate's point: its (x, y) at clear height."""
        return (*self.gate_xy, self.z_clear_mm)

    def pixel_to_table(self, u: float, v: float) -> tuple[float, float]:
        x, y, w = self.homography @ np.array([u, v, 1.0])
        return (float(x / w), float(y / w))

    def table_to_pixel(self, x: float, y: float) -> tuple[float, float]:
        u, v, w = np.linalg.solve(self.homography, np.array([x, y, 1.0]))
        return (float(u / w), float(v / w))


def _arm_angle(d: Mapping[str, Any], arm: str, bad: Any) -> float:
    """The calibration's ``arm_angle_deg`` (default :func:`default_arm_angle`), refused
    when not a number or past :data:`ARM_ANGLE_MAX_DEG`."""
    try:
        angle = float(d.get("arm_angle_deg", default_arm_angle(arm)))
    except (TypeError, ValueError):
        raise bad("'arm_angle_deg' must be a number (deg)") from None
    if not math.isfinite(angle) or abs(angle) > ARM_ANGLE_MAX_DEG:
        raise bad(f"'arm_angle_deg' is {angle:g}: ABB's arm angle, at most "
                  f"{ARM_ANGLE_MAX_DEG:g} deg either way; an older calibration held axis 7's "
                  f"value there (+-130): set it to {default_arm_angle(arm):g} or remove it "
                  f"(docs/notes/auto-day-one.md)")
    return angle


def layout_keys(cal: ArmCalibration) -> dict[str, Any]:
    """What the layout's checks read of a calibration (``drivers/yumi/layout_check.py``):
    the table box, the heights, the tool, the arm angle, the rest and gate joints, the
    homography."""
    out: dict[str, Any] = {"table_box_mm": list(cal.table_box_mm), "z_push_mm": cal.z_push_mm,
                           "z_travel_mm": cal.z_travel_mm, "z_clear_mm": cal.z_clear_mm,
                           "gate_xy_mm": list(cal.gate_xy), "tool_z_mm": cal.tool_z_mm,
                           "homography": cal.homography.tolist()}
    if cal.pose is not None:
        out.update(rest_joints_deg=list(cal.pose.rest_joints_deg),
                   arm_angle_deg=cal.pose.arm_angle_deg,
                   tool_quat_wxyz=list(cal.pose.tool_quat_wxyz))
    if cal.gate_joints_deg is not None:
        out["gate_joints_deg"] = list(cal.gate_joints_deg)
    return out


def write_atomic(path: Path, text: str) -> None:
    """Temp file in the same folder, fsync, ``os.replace``, fsync the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fchmod(f.fileno(), mode)
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # the rename itself durable (not on every FS)
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def provisional_calibration(path: str, arm: str, tool_z_mm: float | None = None
                            ) -> ArmCalibration:
    """An arm being calibrated: the file's speeds, heights, table box, tool and rest pose
    when it has them, an identity homography (unused: pictures are off in calibration
    mode) and, without a table box in the file, the arm's :func:`default_table_box` (the
    box ``testbed calibrate`` then drives in by default; its gate is the shipped one), or
    the wide :data:`CALIBRATION_BOX_MM` for an arm whose side cannot be told.
    Without ``tool_z_mm`` in the file, ``tool_z_mm`` (the controller's ``tool_pusher``,
    :func:`~drivers.yumi.rws_controller.controller_tools`) is the tool; without either,
    a BackendError (never the flange)."""
    p = Path(path)
    d: dict[str, Any] = {}
    if p.exists():
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise BackendError(f"arm {arm}: cannot read calibration {p}: {exc}") from None
        if not isinstance(d, dict):
            raise BackendError(f"arm {arm}: calibration {p} is not a JSON object")
    d = {**d, "homography": np.eye(3).tolist()}
    task = d.get("task")
    d.setdefault("table_box_mm", list(default_table_box(arm, task if isinstance(task, str)
                                                        else None) or CALIBRATION_BOX_MM))
    if tool_z_mm is not None:
        d.setdefault("tool_z_mm", float(tool_z_mm))
    return ArmCalibration.from_dict(d, arm, str(p))


def tool_of(path: str, arm: str, url: str, credentials_file: str | None) -> float | None:
    """For an arm being calibrated whose file has no ``tool_z_mm``: the z of the
    controller's ``tool_pusher`` in the arm's task (None when the file has it)."""
    from drivers.yumi.rws_controller import controller_tools

    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        d = {}
    if not isinstance(d, dict) or "tool_z_mm" in d:
        return None
    task = str(d.get("task", f"T_ROB_{'L' if arm.startswith('l') else 'R'}"))
    frame = controller_tools(url, [task], credentials_file).get(task)
    if frame is None:
        raise BackendError(f"arm {arm}: calibration {path} has no 'tool_z_mm' and the "
                           f"controller's tool_pusher of {task} cannot be read: {TOOL_HOW}")
    log.info("arm %s: tool_z_mm %g from the controller's tool_pusher (%s)", arm,
             frame["trans"][2], task)
    return float(frame["trans"][2])
