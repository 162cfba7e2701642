"""Arm angles for the twin's tests: the ``eax_a`` that makes the twin's arm take the joints
a driver planned.

Why: a YuMi robtarget's ``eax_a`` is ABB's arm angle (the shoulder-elbow-wrist angle,
``sim_twin/sew_angle.py``), not axis 7's value, and the twin now holds it as the robot
does. The pushes were planned with axis 7 fixed (+-130, testbed/lab/camera_model.py), and
a fixed arm angle cannot stand for that: along the table it leaves axis 7 tens of degrees
away, past its limit at some corners (docs/notes/rws.md, "What eax_a means on a YuMi").
A driver that wants its planned joints must send each target with the arm angle of those
joints. These helpers do that with the driver's own model (``drivers/yumi/irb14000_ik.py``,
axis 7 at the push's value) and the twin's arm angle, and build the programs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from abb_motion_program_exec import abb_motion_program_exec_client as mpe

from drivers.yumi.irb14000 import Arm
from drivers.yumi.irb14000_ik import solve_down
from sim_twin.sew_angle import arm_angle
from sim_twin.yumi_arms import DEFAULT_TOOL_MM, ArmModel, abb_to_chain, chain_to_abb
from sim_twin.yumi_geometry import REST_JOINTS_DEG

PLAN_AXIS7_DEG = {"left": 130.0, "right": -130.0}
"""Axis 7 in the driver's push plan (testbed/lab/camera_model.py PUSH_ARM_ANGLE_DEG)."""
DOWN = [0.0, 0.0, 1.0, 0.0]
"""The pusher pointing down (a half turn about y)."""


def plan(side: str, xyz: Sequence[float], current: Sequence[float] | None = None,
         tool_z_mm: float = DEFAULT_TOOL_MM) -> tuple[list[float], float]:
    """(chain joints, arm angle deg): the driver's model's joints holding the pusher's tip
    down at ``xyz`` with axis 7 at the plan's value, from ``current`` (chain; default: the
    rest), and their arm angle on the twin's model. Near a wrist singularity (which our
    RAPID's SingArea Wrist passes) the model's nearest joints serve: only their arm angle
    is used."""
    start = list(current) if current is not None else abb_to_chain(REST_JOINTS_DEG[side])
    s = solve_down(Arm(side), xyz, tool_z_mm, PLAN_AXIS7_DEG[side], current=start)
    pose = s.pose or s.near  # near a wrist singularity the joints still say the arm angle
    assert pose is not None, (side, xyz, s)
    q = list(pose.chain_deg)
    return q, arm_angle(ArmModel(side).pose(q))


AXIS7_STEP_DEG = 5.0
"""The step of :func:`plan_nearest`'s search for axis 7 away from the plan's value."""
AXIS7_SEARCH_DEG = 60.0
"""How far from the plan's value :func:`plan_nearest` looks (further is another
configuration, not the one the tests mean)."""
FAR_OUT_MM = 100.0
"""A target this far out of the model's reach is out of it at every axis 7."""
AXIS7_LIMIT_DEG = 168.5
"""Axis 7's range, +- (drivers/yumi/irb14000.py ``LIMITS_DEG``)."""


def plan_nearest(side: str, xyz: Sequence[float], current: Sequence[float] | None = None,
                 tool_z_mm: float = DEFAULT_TOOL_MM) -> tuple[list[float], float] | None:
    """:func:`plan`, or where the driver's model cannot hold the pusher down at ``xyz``
    with axis 7 at the plan's value, with axis 7 as near it as lets it (5-degree steps,
    up to 60 away, within axis 7's range): the configuration a test means by "a tool-down
    target" even where the fixed +-130 is not one (high over the box's far corners).
    None where none does: the target is out of the model's reach, and the twin answers
    it with its own code (50050, 50027) whatever arm angle it carries."""
    start = list(current) if current is not None else abb_to_chain(REST_JOINTS_DEG[side])
    home = PLAN_AXIS7_DEG[side]
    tries = [home] + [home + sign * k * AXIS7_STEP_DEG
                      for k in range(1, int(AXIS7_SEARCH_DEG / AXIS7_STEP_DEG) + 1)
                      for sign in (1.0, -1.0)]
    for axis7 in tries:
        if abs(axis7) > AXIS7_LIMIT_DEG:
            continue
        s = solve_down(Arm(side), xyz, tool_z_mm, axis7, current=start)
        if s.kind == "reach" and s.shortfall_mm > FAR_OUT_MM:
            return None
        pose = s.pose or s.near  # near a wrist singularity the joints still say the angle
        if pose is not None:
            q = list(pose.chain_deg)
            return q, arm_angle(ArmModel(side).pose(q))
    return None


def robtarget(xyz: Sequence[float], angle: float) -> Any:
    """A tool-down robtarget with the arm angle ``angle`` (ConfJ and ConfL are off in our
    RAPID: the confdata is not kept)."""
    return mpe.robtarget(list(xyz), DOWN, mpe.confdata(0, 0, 0, 4), [angle] + [9e9] * 5)


def jointtarget(chain_deg: Sequence[float]) -> Any:
    """The jointtarget of chain joints (axes 1-6, axis 7 in ``eax_a``)."""
    abb = chain_to_abb(chain_deg)
    return mpe.jointtarget(abb[:6], [abb[6]] + [9e9] * 5)


def program(moves: Sequence[tuple[Any, ...]], tool_z_mm: float = DEFAULT_TOOL_MM,
            v_tcp: float = 100.0) -> Any:
    """A program of stop points: ("A", chain joints) a MoveAbsJ, ("J" | "L", xyz, arm
    angle) a MoveJ or MoveL, with a straight tool ``tool_z_mm`` long, at ``v_tcp``."""
    mp = mpe.MotionProgram(tool=mpe.tooldata(True, mpe.pose([0, 0, tool_z_mm], [1, 0, 0, 0]),
                                             mpe.loaddata(0.1, [0, 0, 50], [1, 0, 0, 0],
                                                          0, 0, 0)))
    speed = mpe.speeddata(v_tcp, 100, 1000, 100)
    for kind, *args in moves:
        if kind == "A":
            mp.MoveAbsJ(jointtarget(args[0]), speed, mpe.fine)
        else:
            (mp.MoveJ if kind == "J" else mp.MoveL)(robtarget(args[0], args[1]), speed,
                                                     mpe.fine)
    return mp
