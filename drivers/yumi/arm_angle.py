"""ABB's arm angle of an IRB 14000 arm in the driver's model: what a robtarget's ``eax_a`` is.

Why: a YuMi arm has seven axes, so a pose of the pusher leaves one freedom, the elbow's
swing about the line from the shoulder to the wrist. A robtarget fixes it with its
``extax.eax_a``, which on a YuMi is ABB's *arm angle*, not axis 7's value (a
jointtarget's ``eax_a`` is axis 7's): the shoulder-elbow-wrist (SEW) angle of A. J.
Elias and J. T. Wen, "Redundancy Parameterization of the ABB YuMi Robot Arm" (arXiv
2505.23111, 2025), validated there against RobotStudio, and the "new arm angle
definition" of the FlexPendant's event 50488 (docs/notes/rws.md, "What eax_a means on a
YuMi"). Along a line the controller turns the arm angle evenly from the start's to the
target's and holds it at every point: :func:`hold_tip` solves a line's sample so (a
SingArea Wrist line: the wrist's axes turned evenly, axes 1, 2, 7 and 3 holding the tip
and the arm angle) and :func:`solve_with_arm_angle` a robtarget's joints; the driver's
planner (``drivers/yumi/line_plan.py``) chooses each robtarget's arm angle with them,
and the layout check sweeps the lines so planned (``drivers/yumi/path_sweep.py``).

The definition, on this model's points: the shoulder is the point of axis 1 nearest axis
2 (they are 30 mm apart), the wrist the point of axis 6 nearest axis 5, and the elbow's
direction in the plane normal to the shoulder-to-wrist line is that line's direction
crossed with axis 3's (axis 3 is the elbow's hinge, normal to the arm's plane). The arm
angle is the signed turn, about the shoulder-to-wrist line, from the reference
direction's part normal to that line to the elbow's direction. Written for the driver
apart from the twin's (``sim_twin/sew_angle.py``: a closed form with an analytic
gradient; this one projects, and differentiates numerically) so that an error in one is
not hidden by the other; ``tests/drivers/test_yumi_kinematics.py`` holds the two within
0.1 deg and both against RobotStudio's published figures. numpy only (a robot host).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from drivers.yumi.irb14000 import Arm, Pose, arm
from drivers.yumi.irb14000_ik import ROT_WEIGHT_MM, rotation_error

__all__ = ["ARM_ANGLE_REFERENCE", "ARM_JOINTS", "Followed", "angle_step", "arm_angle_deg",
           "arm_angle_gradient", "held_sigma", "hold_tip", "solve_with_arm_angle"]

Mat = npt.NDArray[np.float64]

ARM_ANGLE_REFERENCE: Final = (0.0, 0.0, 1.0)
"""The controller's arm-angle reference direction in the arm's own base frame (its mount
on the body, z along axis 1): ASSUMED z, along axis 1, as in Elias and Wen's RobotStudio
figures for the single-arm YuMi in its own frame. It is a system parameter, *Arm-Angle
Reference Direction* (Controller > Configuration > Motion > Robot, one per arm), whose
value on the lab's YuMi is a day-one reading (docs/rws-checklist.md; docs/notes/rws.md):
another direction turns every arm angle the driver sends, and the controller would solve
its robtargets into other elbows than the ones planned. The twin assumes the same. Why
not the body's up: over the table the shoulder-to-wrist line comes within 8 deg of the
vertical (near (160, +-125) with the pusher down), where an arm angle measured from up
is ill-defined and turns by a hundred degrees across the box; it stays 50 to 88 deg from
axis 1 there (docs/notes/rws.md)."""
ARM_ANGLE_WEIGHT_MM: Final = 250.0
"""Millimetres of position error one radian of arm-angle error is worth in the solvers
(about the elbow's distance from the shoulder-to-wrist line: a radian of it moves the
elbow about that far)."""
POS_TOL_MM: Final = 0.05
ROT_TOL_RAD: Final = 1e-4
ANGLE_TOL_DEG: Final = 0.01
"""How closely the solvers hold the pose and the arm angle (the twin holds a line's arm
angle within 0.01 deg)."""
JUMP_DEG: Final = 20.0
"""A line's sample whose axes 1, 2, 7 or 3 turn more than this from the last sample's
(at most :data:`~drivers.yumi.wrist_line.LINE_STEP_MM` apart): the arm cannot follow the
line there (a singularity: its joints would have to jump), where the controller stops
the line (50026; the twin's ``sim_twin/rws/arm_supervision.py`` allows 25 between its
5 mm samples)."""
SINGULAR_SIGMA: Final = 0.005
"""The smallest singular value of the tip's and the arm angle's Jacobian over axes 1, 2,
7 and 3 (positions over ``REACH_SCALE_MM``, per radian) below which a line's sample is
"near a singularity": the elbow straight, the wrist over axis 1, or the arm angle's own
parameterization (the wrist on the shoulder's reference line), where the arm cannot hold
both the tip and the arm angle."""
REACH_SCALE_MM: Final = 559.0
_DELTA_RAD: Final = 1e-5
"""The joint step of the arm angle's numerical derivative (central differences)."""


def _nearest_point(p1: Mat, d1: Mat, p2: Mat, d2: Mat) -> Mat:
    """The point of the line through ``p1`` along ``d1`` nearest the line through ``p2``
    along ``d2`` (least squares on p1 + a d1 = p2 + b d2)."""
    ab = np.linalg.lstsq(np.stack([d1, -d2], axis=1), p2 - p1, rcond=None)[0]
    return p1 + ab[0] * d1


def _body_points() -> tuple[Mat, Mat]:
    """The shoulder in axis 1's frame and the wrist in axis 6's, homogeneous: fixed
    there (the shoulder lies on axis 1, the wrist on axis 6, each on the link that
    carries both lines), found once at joint zero (both arms share the chain)."""
    f = arm("left").pose([0.0] * 7).frames
    shoulder = _nearest_point(f[0][:3, 3], f[0][:3, 2], f[1][:3, 3], f[1][:3, 2])
    wrist = _nearest_point(f[6][:3, 3], f[6][:3, 2], f[5][:3, 3], f[5][:3, 2])
    return (np.linalg.solve(f[0], np.append(shoulder, 1.0)),
            np.linalg.solve(f[6], np.append(wrist, 1.0)))


_SHOULDER, _WRIST = _body_points()
_AXIS_3: Final = 3
"""Chain index of axis 3 (the chain is axes 1, 2, 7, 3, 4, 5, 6)."""


def _cross(a: Mat, b: Mat) -> Mat:
    """Row-wise cross products of (..., 3) arrays (``np.cross`` costs more than the
    arithmetic on three numbers)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _angles(s: Mat, w: Mat, h: Mat, r: Mat) -> Mat:
    """Arm angles (rad) of shoulders ``s``, wrists ``w`` and axis-3 directions ``h``
    (each (N, 3)) for the reference ``r``: the signed turn about the shoulder-to-wrist
    line from ``r``'s part normal to it to the elbow's direction (the line crossed with
    axis 3)."""
    e = w - s
    e = e / np.sqrt((e * e).sum(axis=1))[:, None]
    ref = r[None, :] - (e @ r)[:, None] * e
    elbow = _cross(e, h)
    sin = (_cross(ref, elbow) * e).sum(axis=1)
    cos = (ref * elbow).sum(axis=1)
    return np.arctan2(sin, cos)


def _points(pose: Pose) -> tuple[Mat, Mat, Mat]:
    f = pose.frames
    return (f[0] @ _SHOULDER)[:3], (f[6] @ _WRIST)[:3], f[_AXIS_3][:3, 2]


def _reference(pose: Pose, reference: Sequence[float]) -> Mat:
    """``reference`` (in the arm's own base frame, ``frames[0]``: the mount, before axis
    1 turns) in the body's base frame."""
    return pose.frames[0][:3, :3] @ np.asarray(reference, dtype=np.float64)


def arm_angle_deg(pose: Pose, reference: Sequence[float] = ARM_ANGLE_REFERENCE) -> float:
    """The arm angle (deg, in (-180, 180]) of ``pose``'s joints: the ``eax_a`` the
    controller takes and reports in a robtarget for them (``reference`` in the arm's own
    base frame)."""
    s, w, h = _points(pose)
    return math.degrees(float(_angles(s[None], w[None], h[None],
                                      _reference(pose, reference))[0]))


_TURN: Final = np.array([_DELTA_RAD, -_DELTA_RAD] * 7)
_COS, _SIN = np.cos(_TURN)[:, None], np.sin(_TURN)[:, None]
_JOINT: Final = np.repeat(np.arange(7), 2)


def arm_angle_gradient(pose: Pose, reference: Sequence[float] = ARM_ANGLE_REFERENCE
                       ) -> tuple[float, Mat]:
    """The arm angle (rad) and its derivative by each chain joint (7, rad per rad), by
    central differences: a turn of joint k by +-delta turns the wrist (and, before axis
    3, axis 3's direction) about joint k's axis (Rodrigues' formula); the shoulder lies
    on axis 1, before every joint."""
    s, w, h = _points(pose)
    r = _reference(pose, reference)
    o = pose.frames[_JOINT, :3, 3]  # (14, 3): each joint's axis, twice
    z = pose.frames[_JOINT, :3, 2]
    v = w[None, :] - o
    wk = o + v * _COS + _cross(z, v) * _SIN + z * (z * v).sum(axis=1)[:, None] * (1.0 - _COS)
    hk = np.broadcast_to(h, wk.shape).copy()
    before = _JOINT < _AXIS_3  # axis 3's direction turns with the joints before it only
    hb, zb = hk[before], z[before]
    hk[before] = hb * _COS[before] + _cross(zb, hb) * _SIN[before] + \
        zb * (zb * hb).sum(axis=1)[:, None] * (1.0 - _COS[before])
    psi = _angles(np.broadcast_to(s, (15, 3)), np.vstack([w[None], wk]),
                  np.vstack([h[None], hk]), r)
    diff = (psi[1::2] - psi[2::2] + math.pi) % (2.0 * math.pi) - math.pi
    return float(psi[0]), diff / (2.0 * _DELTA_RAD)


def angle_step(start_deg: float, end_deg: float) -> float:
    """The turn (deg) from one arm angle to another the short way round (the arm angle
    is an angle: from 170 to -170 is 20 degrees), as the controller turns it along a
    line (assumed, as the twin: docs/notes/rws.md)."""
    return (float(end_deg) - float(start_deg) + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class Followed:
    """One sample of a line solved for the tip and the arm angle: the pose reached, or
    why the controller could not go on there (``kind``: ``reach``, the joints cannot
    hold both; ``limit``; ``singular``)."""

    pose: Pose
    kind: str = ""
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.kind


ARM_JOINTS: Final = (0, 1, 2, 3)
"""Chain indices of axes 1, 2, 7 and 3: the joints that hold the tip and the arm angle
on a SingArea Wrist line (:func:`hold_tip`)."""


def _angle_of(pose: Pose) -> float:
    s, w, h = _points(pose)
    return float(_angles(s[None], w[None], h[None],
                         _reference(pose, ARM_ANGLE_REFERENCE))[0])


def _wrapped_rad(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _tip_error(pose: Pose, tool_z_mm: float, tip: Mat, psi_rad: float) -> Mat:
    """(4): the tip's error (mm) and the arm angle's (rad, weighted as mm)."""
    at = pose.flange[:3, 3] + pose.flange[:3, 2] * tool_z_mm
    return np.append(tip - at, _wrapped_rad(psi_rad - _angle_of(pose)) * ARM_ANGLE_WEIGHT_MM)


def _tip_jacobian(model: Arm, pose: Pose, tool_z_mm: float) -> tuple[Mat, Mat]:
    """The (4, 4) Jacobian of the tip and the arm angle over :data:`ARM_JOINTS` (per
    radian), weighted as :func:`_tip_error`, and scaled (positions over
    ``REACH_SCALE_MM``, the arm angle per radian: its smallest singular value says how
    near a singularity of the arm, or of the arm angle's parameterization)."""
    at = pose.flange[:3, 3] + pose.flange[:3, 2] * tool_z_mm
    j = model.jacobian(pose, at)[:3, list(ARM_JOINTS)]
    _, grad = arm_angle_gradient(pose)
    g = grad[list(ARM_JOINTS)]
    return np.vstack([j, g * ARM_ANGLE_WEIGHT_MM]), np.vstack([j / REACH_SCALE_MM, g])


def held_sigma(model: Arm, pose: Pose, tool_z_mm: float) -> float:
    """The smallest singular value of the tip's and the arm angle's Jacobian over
    :data:`ARM_JOINTS` (scaled as :func:`_tip_jacobian`): how far ``pose`` is from where
    the arm cannot hold both its tip and its arm angle (under :data:`SINGULAR_SIGMA`)."""
    return float(np.linalg.svd(_tip_jacobian(model, pose, tool_z_mm)[1],
                               compute_uv=False)[-1])


def hold_tip(model: Arm, tip: Sequence[float], tool_z_mm: float, arm_angle: float,
             seed: Sequence[float], previous: Sequence[float], iters: int = 40,
             sigma: float = SINGULAR_SIGMA) -> Followed:
    """A sample of a SingArea Wrist line: axes 1, 2, 7 and 3 that put the pusher's tip
    (``tool_z_mm`` along the flange's z) on ``tip`` (base frame, mm) with the arm angle
    ``arm_angle`` (deg), the wrist's axes (4, 5, 6) held at ``seed``'s, a damped least
    squares from ``seed`` (chain deg); or why the controller could not hold the line
    there: the joints do not converge (``reach``), a joint past its range (``limit``),
    the arm's joints turning more than :data:`JUMP_DEG` from ``previous`` (the last
    sample's) or the Jacobian's smallest singular value under ``sigma`` (``singular``)."""
    want, psi = np.asarray(tip, dtype=np.float64), math.radians(arm_angle)
    q = np.asarray(seed, dtype=np.float64).copy()
    pose = model.pose(q)
    e = _tip_error(pose, tool_z_mm, want, psi)
    cost, lam = float(e @ e), 1e-3
    free = list(ARM_JOINTS)
    for _ in range(iters):
        if _tip_converged(e):
            break
        j, _ = _tip_jacobian(model, pose, tool_z_mm)
        jtj = j.T @ j
        step = np.linalg.solve(jtj + lam * (np.diag(np.diag(jtj)) + 1e-6 * np.eye(4)),
                               j.T @ e)
        trial = q.copy()
        trial[free] += np.degrees(np.clip(step, -0.3, 0.3))
        tpose = model.pose(trial)
        te = _tip_error(tpose, tool_z_mm, want, psi)
        if float(te @ te) < cost:
            q, pose, e, cost, lam = trial, tpose, te, float(te @ te), max(lam / 10.0, 1e-9)
        else:
            lam *= 10.0
            if lam > 1e6:
                break
    if not _tip_converged(e):
        off = math.degrees(abs(float(e[3])) / ARM_ANGLE_WEIGHT_MM)
        return Followed(pose, "reach", f"the arm cannot hold the tip and the arm angle "
                                       f"{arm_angle:.1f} deg there ({np.linalg.norm(e[:3]):.1f}"
                                       f" mm, {off:.2f} deg off)")
    if (over := model.limit_excess(q)) is not None:
        return Followed(pose, "limit", f"axis {over[0]} past its limit by {over[1]:.1f} deg")
    jump = float(np.max(np.abs(q[free] - np.asarray(previous, dtype=np.float64)[free])))
    least = held_sigma(model, pose, tool_z_mm)
    if jump > JUMP_DEG or least < sigma:
        return Followed(pose, "singular", f"near a singularity (axes 1, 2, 7, 3 turn "
                                          f"{jump:.0f} deg in one sample, the smallest "
                                          f"singular value {least:.4f})")
    return Followed(pose)


def _tip_converged(e: Mat) -> bool:
    return bool(np.linalg.norm(e[:3]) < POS_TOL_MM
                and abs(e[3]) < math.radians(ANGLE_TOL_DEG) * ARM_ANGLE_WEIGHT_MM)


def _pose_error(pose: Pose, flange: Mat, psi_rad: float) -> Mat:
    """(7): the flange's position error (mm), its orientation's and the arm angle's
    (rad, weighted as mm)."""
    ep = flange[:3, 3] - pose.flange[:3, 3]
    er = rotation_error(pose.flange[:3, :3], flange[:3, :3])
    ea = _wrapped_rad(psi_rad - _angle_of(pose))
    return np.concatenate([ep, er * ROT_WEIGHT_MM, [ea * ARM_ANGLE_WEIGHT_MM]])


def solve_with_arm_angle(model: Arm, flange: Mat, arm_angle: float, seed: Sequence[float],
                         iters: int = 40) -> Pose | None:
    """The seven joints, from ``seed`` (chain deg), that put the flange at ``flange``
    (4x4, base frame mm) with the arm angle ``arm_angle`` (deg): what the controller
    solves a robtarget into (a Levenberg-Marquardt on the pose and the arm angle); None
    when the descent from ``seed`` does not get there (another seed may)."""
    want = math.radians(arm_angle)
    q = np.asarray(seed, dtype=np.float64).copy()
    pose = model.pose(q)
    e = _pose_error(pose, flange, want)
    cost, lam = float(e @ e), 1e-2
    for _ in range(iters):
        if _pose_converged(e):
            return pose
        jac = model.jacobian(pose, pose.flange[:3, 3])
        _, grad = arm_angle_gradient(pose)
        j = np.vstack([jac[:3], jac[3:] * ROT_WEIGHT_MM, grad * ARM_ANGLE_WEIGHT_MM])
        jtj = j.T @ j
        step = np.linalg.solve(jtj + lam * (np.diag(np.diag(jtj)) + 1e-6 * np.eye(7)),
                               j.T @ e)
        trial = q + np.degrees(np.clip(step, -0.4, 0.4))
        tpose = model.pose(trial)
        te = _pose_error(tpose, flange, want)
        if float(te @ te) < cost:
            q, pose, e, cost, lam = trial, tpose, te, float(te @ te), max(lam / 5.0, 1e-9)
        else:
            lam *= 8.0
            if lam > 1e8:
                break
    return pose if _pose_converged(e) else None


def _pose_converged(e: Mat) -> bool:
    return bool(np.linalg.norm(e[:3]) < POS_TOL_MM
                and np.linalg.norm(e[3:6]) < ROT_TOL_RAD * ROT_WEIGHT_MM
                and abs(e[6]) < math.radians(ANGLE_TOL_DEG) * ARM_ANGLE_WEIGHT_MM)
