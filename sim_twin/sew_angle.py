"""ABB's arm angle of a YuMi arm: what a robtarget's ``extax.eax_a`` holds.

Why: a YuMi arm has seven axes, so a TCP pose leaves one freedom, the elbow's swing about
the line from the shoulder to the wrist. A robtarget fixes it with its arm angle, in
``eax_a``; a jointtarget's ``eax_a`` is axis 7's own value, a different number. The arm
angle is the shoulder-elbow-wrist (SEW) angle: the turn, about the shoulder-to-wrist line,
of axis 3's direction (the elbow) from the plane that line makes with the controller's
arm-angle reference direction. Its definition is Elias and Wen's, "Redundancy
Parameterization of the ABB YuMi Robot Arm" (arXiv 2505.23111, 2025), validated there
against RobotStudio; their RobotStudio figures (rpiRobotics/yumi-ik,
``unit_tests/compare_to_robotstudio.m``) hold for this module within 0.3 deg at 8 of 10
poses (tests/sim_twin/test_yumi_arms.py). The FlexPendant's event 50488 ("the new arm
angle definition", the system parameter *Arm-Angle definition*, topic Motion, type Robot)
says the same from the controller's side. docs/notes/rws.md, "What eax_a means on a YuMi".

The points, on this project's model (``sim_twin.yumi_arms``): the shoulder is the point of
axis 1 nearest axis 2, the wrist the point of axis 6 nearest axis 5, the elbow direction
axis 3's. The reference direction is a controller setting (*Arm-Angle Reference
Direction*, topic Motion, type Robot) whose value on the lab's YuMi is not known here:
:data:`ARM_ANGLE_REFERENCE` assumes z of the arm's own base frame (along axis 1);
docs/rws-checklist.md has the lab read it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from sim_twin.yumi_arms import _OFFSETS, ArmPose

Mat = npt.NDArray[np.float64]

ARM_ANGLE_REFERENCE: Final = (0.0, 0.0, 1.0)
"""The controller's arm-angle reference direction in the arm's own base frame (its mount,
z along axis 1): assumed z, as in the RobotStudio figures for the single-arm YuMi in its
own frame. A day-one reading (docs/rws-checklist.md); every arm angle the twin solves or
reports follows it."""


def _nearest_on(pa: Mat, da: Mat, pb: Mat, db: Mat) -> Mat:
    """The point of line a (through ``pa`` along ``da``) nearest line b."""
    w0 = pa - pb
    a, b, c = float(da @ da), float(da @ db), float(db @ db)
    d, e = float(da @ w0), float(db @ w0)
    return pa + ((b * e - c * d) / (a * c - b * b)) * da


def _local_points() -> tuple[Mat, Mat]:
    """The shoulder in joint 1's frame and the wrist in axis 6's joint frame (both fixed
    there: the shoulder lies on axis 1, the wrist on axis 6), homogeneous."""
    frames = [np.eye(4)]
    for off in _OFFSETS[:-1]:
        frames.append(frames[-1] @ off)  # joint zero: each frame its offset from the last
    axis = [(f[:3, 3], f[:3, 2]) for f in frames]
    shoulder = _nearest_on(*axis[0], *axis[1])
    wrist = np.linalg.solve(frames[6], np.append(_nearest_on(*axis[6], *axis[5]), 1.0))
    return np.append(shoulder, 1.0), wrist


_SHOULDER, _WRIST = _local_points()
_SHOULDER_L, _WRIST_L = _SHOULDER.tolist(), _WRIST.tolist()
_ELBOW_JOINT: Final = 3
"""Chain index of axis 3, whose direction is the elbow's."""


def _cross(a: Mat, b: Mat) -> Mat:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def arm_angle_batch(frames: npt.ArrayLike, reference: npt.ArrayLike = ARM_ANGLE_REFERENCE
                    ) -> tuple[Mat, Mat]:
    """Arm angles (N,: rad) of joint frames (N, 8, 4, 4, ``ArmModel.frames_batch``) and
    their gradients (N, 7: rad per rad of each chain joint), the inverse kinematics'
    extra row (``reference`` in the arm's own base frame, ``frames[:, 0]``, fixed as the
    joints turn): psi = atan2(-(e x (e x r)).h, -(e x r).h), e the unit shoulder-to-wrist
    vector, r the reference direction, h axis 3's direction."""
    f = np.asarray(frames, dtype=np.float64)
    if f.shape[0] == 1:  # one pose (the solvers' every iteration): plain floats
        return _arm_angle_one(f[0], f[0, 0, :3, :3] @ np.asarray(reference, dtype=np.float64))
    r = f[:, 0, :3, :3] @ np.asarray(reference, dtype=np.float64)  # the mount's frame
    s = (f[:, 0] @ _SHOULDER)[:, :3]
    w = (f[:, 6] @ _WRIST)[:, :3]
    h = f[:, _ELBOW_JOINT, :3, 2]
    d = w - s
    length = np.linalg.norm(d, axis=1)
    e = d / length[:, None]
    a = _cross(e, r)
    b = _cross(e, a)
    x = -np.einsum("ni,ni->n", a, h)
    y = -np.einsum("ni,ni->n", b, h)
    z, o = f[:, :7, :3, 2], f[:, :7, :3, 3]
    dw = _cross(z, w[:, None, :] - o)  # (N, 7, 3): the wrist's motion per joint
    dh = _cross(z, np.broadcast_to(h[:, None, :], z.shape))
    dh[:, _ELBOW_JOINT:] = 0.0  # axis 3's direction moves with the joints before it only
    de = (dw - e[:, None, :] * np.einsum("nki,ni->nk", dw, e)[:, :, None]) / \
        length[:, None, None]
    # d(a.h) = (de x r).h + a.dh = de.(r x h) + a.dh; d(b.h) = (de x a + e x (de x r)).h
    # + b.dh = de.(a x h + r x (h x e)) + b.dh: 3-vectors per pose, not per joint
    rh = _cross(r, h)
    ah = _cross(a, h) + _cross(r, _cross(h, e))
    dx = -(np.einsum("nki,ni->nk", de, rh) + np.einsum("ni,nki->nk", a, dh))
    dy = -(np.einsum("nki,ni->nk", de, ah) + np.einsum("ni,nki->nk", b, dh))
    n2 = np.maximum(x * x + y * y, 1e-300)
    return np.arctan2(y, x), (x[:, None] * dy - y[:, None] * dx) / n2[:, None]


def _arm_angle_one(f: Mat, r: Mat) -> tuple[Mat, Mat]:
    """:func:`arm_angle_batch` of one pose's frames (8, 4, 4), the same formulas on plain
    floats: the inverse kinematics asks it of one pose at every iteration, where numpy's
    call overhead on 3-vectors was most of a line's supervision (py-spy of a rehearsal's
    calibration); ``tests/sim_twin/test_sew_angle_paths.py`` holds the two paths together."""
    def cross(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
        return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0])

    def dot(a: Sequence[float], b: Sequence[float]) -> float:
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    fr = f.tolist()
    sh, wr = _SHOULDER_L, _WRIST_L
    s = [sum(fr[0][i][j] * sh[j] for j in range(4)) for i in range(3)]
    w = [sum(fr[6][i][j] * wr[j] for j in range(4)) for i in range(3)]
    h = [fr[_ELBOW_JOINT][i][2] for i in range(3)]
    rr = r.tolist()
    d = [w[i] - s[i] for i in range(3)]
    length = math.sqrt(dot(d, d))
    e = [x / length for x in d]
    a = cross(e, rr)
    b = cross(e, a)
    x, y = -dot(a, h), -dot(b, h)
    dx, dy = [], []
    for k in range(7):
        z = [fr[k][i][2] for i in range(3)]
        o = [fr[k][i][3] for i in range(3)]
        dw = cross(z, [w[i] - o[i] for i in range(3)])
        dh = cross(z, h) if k < _ELBOW_JOINT else (0.0, 0.0, 0.0)
        we = dot(dw, e)
        de = [(dw[i] - e[i] * we) / length for i in range(3)]
        da = cross(de, rr)
        db1, db2 = cross(de, a), cross(e, da)
        db = [db1[i] + db2[i] for i in range(3)]
        dx.append(-(dot(da, h) + dot(a, dh)))
        dy.append(-(dot(db, h) + dot(b, dh)))
    n2 = max(x * x + y * y, 1e-300)
    grad = [(x * dy[k] - y * dx[k]) / n2 for k in range(7)]
    return np.array([math.atan2(y, x)]), np.array([grad])


def arm_angle(pose: ArmPose, reference: npt.ArrayLike = ARM_ANGLE_REFERENCE) -> float:
    """The pose's arm angle, degrees in (-180, 180]: the ``eax_a`` the controller reports
    in a robtarget for these joints."""
    psi, _ = arm_angle_batch(pose.frames[None], reference)
    return math.degrees(float(psi[0]))


def angle_step(start_deg: float, end_deg: float) -> float:
    """The turn (deg) from one arm angle to another the short way round (an angle, not a
    joint: 170 to -170 is 20 degrees)."""
    return (end_deg - start_deg + 180.0) % 360.0 - 180.0
