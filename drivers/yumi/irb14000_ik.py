"""Inverse kinematics of an IRB 14000 arm for a pusher pointing down, axis 7 held.

Why numerical, and why this way: the driver picks the joints of each robtarget it sends
(the TCP's position, the tool's orientation) with axis 7 held at the calibration's
``arm_angle_deg``: the configuration it always chose. The robtarget itself carries ABB's
arm angle (``eax_a``: the elbow plane's angle, not axis 7's value; docs/notes/rws.md),
the one of the joints picked here or of a line the arm can run to them
(``drivers/yumi/arm_angle.py``, ``drivers/yumi/line_plan.py``). With axis 7 held, six
joints remain for a six-number pose: a damped least squares (Levenberg-Marquardt) on the
flange's pose converges in a few iterations from a seed in the arm's working family
(elbow out and down, wrist over the table), with more seeds when the first fails. What
the robot would refuse is told precisely: out of reach by N mm, axis k past its limit by
N deg, near a singularity.

The orientation counts ``ROT_WEIGHT_MM`` mm per radian, so an unreachable target leaves
the tool nearly down and the position short: the shortfall is "out of reach by N mm".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from drivers.yumi.irb14000 import Arm, Pose

__all__ = ["DOWN", "Solution", "quat_matrix", "smallest_sigma", "solve_down", "solve_pose"]

Mat = npt.NDArray[np.float64]
ROT_WEIGHT_MM: Final = 1000.0
"""Millimetres of position error one radian of orientation error is worth."""
POS_TOL_MM: Final = 0.05
ROT_TOL_RAD: Final = 1e-4
SINGULAR_SIGMA: Final = 0.03
"""The smallest singular value of the six free joints' Jacobian (positions over
``REACH_SCALE_MM``, per radian) below which a pose is "near a singularity"."""
REACH_SCALE_MM: Final = 559.0
"""ABB's reach of the IRB 14000 (product specification): the Jacobian's length unit."""
_FREE: Final = [0, 1, 3, 4, 5, 6]
"""Chain indices solved for; index 2 is axis 7, held at the value asked for."""


def quat_matrix(wxyz: Sequence[float]) -> Mat:
    """The rotation of a unit quaternion (w, x, y, z), as a robtarget's ``rot``."""
    w, x, y, z = (float(v) for v in wxyz)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if n < 1e-9:
        raise ValueError(f"a tool orientation needs a non-zero quaternion, got {wxyz}")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


DOWN: Final = quat_matrix((0.0, 0.0, 1.0, 0.0))
"""The tool pointing straight down (z to -z), its x to -x: the driver's default
``tool_quat_wxyz`` (0, 0, 1, 0)."""


@dataclass(frozen=True)
class Solution:
    """A solved target (``pose``), or why there is none: ``kind`` is ``reach``,
    ``limit`` or ``singular`` and ``reason`` says it in words with the number."""

    pose: Pose | None
    kind: str = ""
    reason: str = ""
    shortfall_mm: float = 0.0
    """How far the closest reachable point is from the target (``reach``)."""
    near: Pose | None = None
    """``singular``: the solution nearest the arm's joints (the first seed's, the arm's
    own joints when given: a line goes on without a jump). The controller moves there
    (SingArea Wrist, ConfJ off: ``drivers/yumi/backend.py``'s ``refuse_unreachable``
    leaves such a target to it), so a path sweep goes on through it."""

    @property
    def ok(self) -> bool:
        return self.pose is not None


def rotation_error(current: Mat, target: Mat) -> Mat:
    """The rotation vector (rad, base frame) that turns ``current`` into ``target``."""
    r = target @ current.T
    cos = max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0))
    angle = math.acos(cos)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    n = float(np.linalg.norm(axis))
    if angle < 1e-9:
        return np.zeros(3)
    if n < 1e-9:  # a half turn: the axis from the symmetric part
        w, v = np.linalg.eigh((r + r.T) / 2.0)
        return v[:, int(np.argmax(w))] * angle
    return axis / n * angle


def _errors(pose: Pose, target: Mat) -> tuple[Mat, Mat]:
    return (target[:3, 3] - pose.flange[:3, 3],
            rotation_error(pose.flange[:3, :3], target[:3, :3]))


def descend(model: Arm, target: Mat, seed: Sequence[float], iters: int = 60
            ) -> tuple[Pose, float, float]:
    """Levenberg-Marquardt from ``seed`` (chain deg; index 2 stays): the pose reached, its
    position error (mm) and orientation error (rad)."""
    q = np.array(seed, dtype=np.float64)
    pose = model.pose(q)
    ep, er = _errors(pose, target)
    cost = float(ep @ ep + (er @ er) * ROT_WEIGHT_MM ** 2)
    lam = 1e-2
    for _ in range(iters):
        if np.linalg.norm(ep) < POS_TOL_MM and np.linalg.norm(er) < ROT_TOL_RAD:
            break
        j = model.jacobian(pose, pose.flange[:3, 3])[:, _FREE]
        j[3:] *= ROT_WEIGHT_MM
        j[:, :] *= math.pi / 180.0  # per degree
        e = np.concatenate([ep, er * ROT_WEIGHT_MM])
        jtj = j.T @ j
        step = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj) + 1e-9), j.T @ e)
        trial = q.copy()
        trial[_FREE] += np.clip(step, -25.0, 25.0)
        tpose = model.pose(trial)
        tp, tr = _errors(tpose, target)
        tcost = float(tp @ tp + (tr @ tr) * ROT_WEIGHT_MM ** 2)
        if tcost < cost:
            q, pose, ep, er, cost, lam = trial, tpose, tp, tr, tcost, max(lam / 5.0, 1e-7)
        else:
            lam *= 8.0
            if lam > 1e8:
                break
    return pose, float(np.linalg.norm(ep)), float(np.linalg.norm(er))


def wrapped(model: Arm, chain_deg: Sequence[float]) -> list[float]:
    """The same joints with each brought into its range by whole turns where it can be."""
    out = []
    for k, q in enumerate(chain_deg):
        q = (q + 180.0) % 360.0 - 180.0
        for turn in (0.0, 360.0, -360.0):
            if model.lower[k] <= q + turn <= model.upper[k]:
                q += turn
                break
        out.append(q)
    return out


def smallest_sigma(model: Arm, pose: Pose) -> float:
    """The smallest singular value of the six free joints' Jacobian at the flange, with
    lengths over the arm's reach (0: singular: some direction cannot be moved in)."""
    j = model.jacobian(pose, pose.flange[:3, 3])[:, _FREE]
    j[:3] /= REACH_SCALE_MM
    return float(np.linalg.svd(j, compute_uv=False)[-1])


SEEDS: Final = (
    (-70.0, -63.0, 0.0, 7.0, 109.0, 76.0, 140.0),
    (-90.0, -90.0, 0.0, 20.0, 90.0, 60.0, 120.0),
    (-50.0, -40.0, 0.0, -20.0, 120.0, 90.0, 160.0),
    (-120.0, -80.0, 0.0, -50.0, 170.0, 75.0, -150.0),
    (30.0, 35.0, 0.0, 0.0, 90.0, 10.0, 100.0),
    (-140.0, -120.0, 0.0, 10.0, 0.0, -80.0, 40.0),
)
"""Chain seeds (axis 7 replaced by the value held): the elbow out and down with
the wrist over the table, in a few of its variants; the left arm's, mirrored for the
right (axes 1, 7, 4 and 6 change sign)."""
_MIRROR: Final = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0])


def _seeds(model: Arm, arm_angle_deg: float, current: Sequence[float] | None
           ) -> list[list[float]]:
    out = [list(current)] if current is not None else []
    for s in SEEDS:
        v = np.array(s) * (_MIRROR if model.side == "right" else 1.0)
        out.append(list(v))
    for s in out:
        s[2] = arm_angle_deg
    return out


def solve_pose(model: Arm, flange: Mat, arm_angle_deg: float,
               current: Sequence[float] | None = None) -> Solution:
    """The joints that put the flange at ``flange`` (4x4, base frame mm) with axis 7 at
    ``arm_angle_deg`` (axis 7's value, not ABB's arm angle: the name is the calibration
    key's); or why the robot would refuse it (see :class:`Solution`)."""
    best_miss = math.inf
    over: tuple[int, float] | None = None
    singular: tuple[Pose, float] | None = None
    near: Pose | None = None
    for seed in _seeds(model, arm_angle_deg, current):
        pose, ep, er = descend(model, flange, seed)
        if ep > 0.5 or er > 1e-3:
            best_miss = min(best_miss, ep + er * ROT_WEIGHT_MM)
            continue
        q = wrapped(model, pose.chain_deg)
        excess = model.limit_excess(q)
        if excess is not None:
            over = excess if over is None or excess[1] < over[1] else over
            continue
        pose = model.pose(q)
        sigma = smallest_sigma(model, pose)
        if sigma < SINGULAR_SIGMA:
            near = near or pose  # the first: from ``current`` when given (a line goes on)
            singular = singular if singular is not None and singular[1] > sigma else (pose,
                                                                                     sigma)
            continue
        return Solution(pose)
    if singular is not None:
        return Solution(None, "singular", f"near a singularity (the arm's smallest "
                        f"singular value {singular[1]:.3f}, under {SINGULAR_SIGMA:g})",
                        near=near)
    if over is not None:
        return Solution(None, "limit", f"axis {over[0]} past its limit by {over[1]:.1f} deg")
    return Solution(None, "reach", f"out of reach by {best_miss:.0f} mm",
                    shortfall_mm=best_miss)


def solve_down(model: Arm, tcp_mm: Sequence[float], tool_z_mm: float,
               arm_angle_deg: float, tool: Mat = DOWN,
               current: Sequence[float] | None = None) -> Solution:
    """The joints that put the TCP (``tool_z_mm`` along the flange's z) at ``tcp_mm``
    with the tool's orientation ``tool`` (default: pointing straight down)."""
    target = np.eye(4)
    target[:3, :3] = tool
    target[:3, 3] = np.asarray(tcp_mm, dtype=np.float64) - tool[:, 2] * tool_z_mm
    return solve_pose(model, target, arm_angle_deg, current)
