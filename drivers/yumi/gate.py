"""The arm's gate, a measured joint target: its joints from the model, the checks of a
calibration's ``gate_joints_deg``, and every solution of the gate's pose.

Why a module of its own: the gate is where the only joint moves of a program begin and
end (``drivers/yumi/paths.py``). Its joints come from the calibration file
(``gate_joints_deg``, written by ``testbed calibrate`` as the controller reports them at
the gate), and three places must agree on them: the driver, which refuses to move an
arm whose file has none or whose joints are not at the gate (``backend.py``); ``testbed
calibrate``, which measures them (``backend.py``'s ``_measure_gate``); the tests and
the twin's exact calibrations, which take the model's (:func:`model_gate_joints`,
:func:`calibration_gate_joints`); ``testbed check``, which sweeps the joint moves between rest
and them, and the *correction* at the gate from every solution of the gate's pose at the
arm angles the driver's lines back to it carry (:func:`gate_solutions`: whichever the
controller's lines may arrive in; ``layout_check.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from drivers.yumi.arm_angle import angle_step, arm_angle_deg, solve_with_arm_angle
from drivers.yumi.irb14000 import abb_to_chain
from drivers.yumi.irb14000_ik import _seeds, wrapped
from drivers.yumi.reach import ArmTool, default_arm_angle, side_of

if TYPE_CHECKING:
    from drivers.yumi.arm_calibration import ArmCalibration

__all__ = ["GATE_ANGLE_DEG", "GATE_HOW", "GATE_MATCH_MM", "arm_tool", "calibration_gate_joints",
           "gate_problem", "gate_solutions", "model_gate_joints"]

GATE_ANGLE_DEG: Final = 1.0
"""How far the arm angle of ``gate_joints_deg`` (the driver's model) may be from the
calibration's ``arm_angle_deg``, the angle the gate's robtarget was sent with."""
GATE_MATCH_MM: Final = 10.0
"""How far the pusher's tip at ``gate_joints_deg`` (the model's forward kinematics) may
lie from the gate's point at clear height. The joints ``testbed calibrate`` measures
put the robot's tip there by the robot's own kinematics, and the model's a few mm off
(its numbers are the published description's; docs/rws-checklist.md asks for the
difference on day one); 10 mm is half the joint moves' margin to the zones
(``layout_check.JOINT_MARGIN_MM``), and the correction at the gate absorbs it."""
GATE_HOW = ("run testbed calibrate: it drives the arm to its gate (by joints from rest) and "
            "writes the joints the controller reports there as gate_joints_deg (axes 1-6, "
            "then 7; robot/README.md)")
"""How a lab gets ``gate_joints_deg``: said wherever they are missing or wrong."""
SAME_DEG: Final = 1.0
"""Two solutions whose joints all agree within this many degrees are one."""
TURNS: Final = (0.0, 360.0, -360.0)


def arm_tool(arm: str, cal: ArmCalibration) -> ArmTool | None:
    """The arm's model and tool as its programs hold the pusher (the calibration's tool,
    arm angle and orientation); None: not an IRB 14000 arm the model can tell, or no
    rest pose in the file."""
    side = side_of(arm, cal.pose.task if cal.pose else None)
    if side is None or cal.pose is None:
        return None
    angle = cal.pose.arm_angle_deg
    return ArmTool(side, cal.tool_z_mm, default_arm_angle(side) if angle is None else angle,
                   tuple(float(v) for v in cal.pose.tool_quat_wxyz))


def _tip(tool: ArmTool, chain: Sequence[float]) -> tuple[float, float, float]:
    t = tool.model.pose(chain).tcp(tool.tool_z_mm)
    return (float(t[0]), float(t[1]), float(t[2]))


def model_gate_joints(tool: ArmTool, gate_xyz: Sequence[float], rest_abb: Sequence[float]
                      ) -> tuple[float, ...] | str:
    """The joints (ABB's order) the model solves for the pusher at ``gate_xyz`` (tool as
    ``tool`` holds it, axis 7 at its arm angle), seeded from the rest pose: the gate
    joints on an arm the model matches (the twin's exact calibrations, the tests'); or
    why there are none (out of reach, past a limit, near a singularity: the model's
    words). A lab's come from its robot (``testbed calibrate`` measures them)."""
    sol = tool.solve(gate_xyz, tool.model.pose_abb(rest_abb).chain_deg)
    if sol.pose is None:
        x, y, z = (float(v) for v in gate_xyz)
        return f"the gate ({x:.0f}, {y:.0f}, {z:.0f}) mm: {sol.reason}"
    return tuple(float(v) for v in sol.pose.abb_deg)


def gate_problem(tool: ArmTool, gate_abb: Sequence[float], gate_xyz: Sequence[float],
                 box: Sequence[float]) -> str | None:
    """Why ``gate_abb`` is not the arm's gate, or None: past a joint limit, the pusher's
    tip there (the model) not over the table box ``box`` within :data:`GATE_MATCH_MM` of
    the gate's point ``gate_xyz`` (at clear height), or the elbow there not at the arm
    angle the tool holds within :data:`GATE_ANGLE_DEG`. Why the angle: ``testbed
    calibrate`` measures the gate joints where the controller put the arm for a robtarget
    sent with that arm angle; a controller whose *Arm-Angle Reference Direction* is not
    the driver's (axis 1, ``drivers/yumi/arm_angle.py``) puts the elbow elsewhere, and so
    would every robtarget the driver sends. Then the check FAULTs and the driver refuses
    every program (fail closed) instead of running paths nobody swept."""
    chain = abb_to_chain(gate_abb)
    shown = "[" + ", ".join(f"{v:g}" for v in gate_abb) + "]"
    if (over := tool.model.limit_excess(chain)) is not None:
        return f"gate_joints_deg {shown} have axis {over[0]} past its limit by {over[1]:.1f} deg"
    tip = _tip(tool, chain)
    x0, y0, x1, y1 = (float(v) for v in box)
    off = math.dist(tip, gate_xyz)
    if x0 <= tip[0] <= x1 and y0 <= tip[1] <= y1 and off <= GATE_MATCH_MM:
        angle = arm_angle_deg(tool.model.pose(chain))
        if abs(angle_step(tool.arm_angle_deg, angle)) <= GATE_ANGLE_DEG:
            return None
        return (f"gate_joints_deg {shown} hold the elbow at arm angle {angle:.1f} deg (the "
                f"driver's model, its reference along axis 1), not the calibration's "
                f"arm_angle_deg {tool.arm_angle_deg:g}: the controller's Arm-Angle Reference "
                f"Direction differs from the driver's (docs/rws-checklist.md, \"A robtarget's "
                f"eaxa is ABB's arm angle\"), or the arm angle changed since the gate was "
                f"measured")
    gx, gy, gz = (float(v) for v in gate_xyz)
    return (f"gate_joints_deg {shown} put the pusher's tip at ({tip[0]:.0f}, {tip[1]:.0f}, "
            f"{tip[2]:.0f}) mm (the model), {off:.0f} mm from the gate ({gx:.0f}, {gy:.0f}, "
            f"{gz:.0f}) over the table box at clear height (want {GATE_MATCH_MM:g} mm)")


def gate_solutions(tool: ArmTool, gate_xyz: Sequence[float], gate_chain: Sequence[float],
                   arm_angles: Sequence[float] | None = None) -> list[list[float]]:
    """Every solution (chain order) of the gate's pose within the joint limits at each of
    ``arm_angles`` (default: the gate joints' own): the pusher at ``gate_xyz`` held as
    ``tool`` holds it, the elbow at that arm angle (``drivers/yumi/arm_angle.py``). A
    line back to the gate's point ends in one of them (the robtarget's ``eax_a``, ConfL
    Off: whichever the path leads to), so the correction to the gate joints starts from
    one of them. Found from the gate's own joints, their wrist turned over (axes 4 and 6
    half a turn, axis 5 mirrored), the inverse kinematics' seeds, and each solution's
    axes 4 and 6 turned by whole turns within range."""
    m = tool.model
    target = np.eye(4)
    target[:3, :3] = tool.rotation
    target[:3, 3] = np.asarray(gate_xyz, dtype=np.float64) - tool.rotation[:, 2] * tool.tool_z_mm
    g = [float(v) for v in gate_chain]
    seeds = [g, *([g[0], g[1], g[2], g[3], g[4] + d4, -g[5], g[6] + d6]
                  for d4 in (180.0, -180.0) for d6 in (180.0, -180.0)),
             *_seeds(m, g[2], None)]
    angles = [arm_angle_deg(m.pose(g))] if arm_angles is None else list(arm_angles)
    found: list[list[float]] = []
    for angle in angles:
        for seed in seeds:
            pose = solve_with_arm_angle(m, target, angle, seed)
            if pose is None:
                continue
            q = wrapped(m, pose.chain_deg)
            q4, q6 = ((q[4] + 180.0) % 360.0 - 180.0, (q[6] + 180.0) % 360.0 - 180.0)
            for t4 in TURNS:
                for t6 in TURNS:
                    cand = [*q[:4], q4 + t4, q[5], q6 + t6]
                    if m.limit_excess(cand) is None and all(
                            max(abs(a - b) for a, b in zip(cand, f, strict=True)) > SAME_DEG
                            for f in found):
                        found.append(cand)
    return found


def calibration_gate_joints(arm: str, cal: Mapping[str, Any]) -> list[float]:
    """The gate joints a calibration file's keys give on an arm the model matches (the
    twin's): :func:`model_gate_joints` of its gate, tool, arm angle and rest joints, what
    ``testbed calibrate`` reads back there. For the twin's exact calibrations and the
    tests' files; ValueError when the file's arm cannot be told or the model finds none."""
    from drivers.yumi.arm_calibration import ArmCalibration

    c = ArmCalibration.from_dict({"homography": np.eye(3).tolist(), **cal}, arm)
    tool = arm_tool(arm, c)
    if tool is None or c.pose is None:
        raise ValueError(f"arm {arm}: not an IRB 14000 arm with rest joints")
    got = model_gate_joints(tool, c.gate_xyz, c.pose.rest_joints_deg)
    if isinstance(got, str):
        raise ValueError(f"arm {arm}: {got}")
    return [round(v, 4) for v in got]
