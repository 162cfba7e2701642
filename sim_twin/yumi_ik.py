"""Inverse kinematics of a twin YuMi arm, as its controller solves a robtarget.

Why: a robtarget is a TCP pose, a configuration (``confdata``: the quadrants of axes 1, 4
and 6) and, on a YuMi, the arm angle (``extax.eax_a``: ABB's shoulder-elbow-wrist angle,
:mod:`sim_twin.sew_angle`; not axis 7's value, which a jointtarget's ``eax_a`` holds).
The controller finds the seven joint angles that put the tool there with the elbow at
that arm angle, in that configuration, and refuses a target it cannot reach, past a joint
limit, or reachable only in another configuration. The twin does the same here, so the
rehearsal refuses what the robot would: the arm angle is held exactly, never eased.

The solver: all seven joints by damped least squares on the flange pose (position mm,
orientation weighted ``ROT_WEIGHT_MM`` mm per radian) and the arm angle (weighted
``ARM_ANGLE_WEIGHT_MM`` mm per radian), from the arm's current joints and from seeds in
the commanded configuration's quadrants.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from sim_twin.sew_angle import arm_angle_batch
from sim_twin.yumi_arms import CHAIN_AXES, ArmModel, ArmPose

Mat = npt.NDArray[np.float64]
ROT_WEIGHT_MM: Final = 200.0
POS_TOL_MM: Final = 0.01
ROT_TOL_RAD: Final = 1e-4
REACH_TOL_MM: Final = 0.5
"""A best residual above this is "out of reach"."""
ARM_ANGLE_WEIGHT_MM: Final = 200.0
"""The arm angle's error counts this many mm per radian in a residual (as the tool's
orientation does): 0.5 mm of residual is 0.14 deg of arm angle."""
ARM_ANGLE_TOL_RAD: Final = 1e-4
"""A solution holds the arm angle within this (0.006 deg)."""
SINGULAR_SIGMA: Final = 0.005
"""The smallest singular value of the scaled Jacobian (per radian, positions over the
arm's reach of 560 mm) below which a pose is "close to singularity": about a tenth of a
degree of axis 5 from a wrist singularity without SingArea\\Wrist. The controller slows
a line near one and stops it (50026) only this close, or when the line passes through
(the joints flip: ``arm_supervision.JUMP_DEG``)."""
TIE: Final = 1e-6
"""Two solutions whose scores (dexterity, or the largest joint difference in degrees)
differ by less are equally good to :func:`_pick`: rounding, not the arm."""
ALL: Final = (0, 1, 2, 3, 4, 5, 6)
"""Chain indices of the seven joints, all solved for against the pose and the arm angle."""


@dataclass(frozen=True)
class Solution:
    """A solved target: its chain angles (deg) and pose; or why there is none."""

    pose: ArmPose | None
    reason: str | None = None
    """None, or ``reach``, ``limit``, ``conf`` (see :func:`solve`)."""
    detail: str = ""


def quadrant(angle_deg: float) -> int:
    """ABB's ``confdata`` quadrant of a joint angle: 0 for [0, 90), -1 for [-90, 0) ..."""
    return math.floor(angle_deg / 90.0 + 1e-9)


def rotation_error(current: Mat, target: Mat) -> Mat:
    """The rotation vector (rad, base frame) that turns ``current`` into ``target``."""
    r = target @ current.T
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0)))
    if angle < 1e-9:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    n = np.linalg.norm(axis)
    if n < 1e-9:  # a half turn: the axis from the symmetric part
        w, v = np.linalg.eigh((r + r.T) / 2.0)
        axis = v[:, int(np.argmax(w))]
        return axis * angle
    return axis / n * angle


def _cross(a: Mat, b: Mat) -> Mat:
    """Row-wise cross products of (..., 3) arrays (np.cross is slow on small arrays)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _orientation_batch(rot: Mat, flange: Mat, free_yaw: bool) -> tuple[Mat, Mat | None]:
    """For flange rotations ``rot`` (N, 3, 3): the orientation errors (N, 3; rad, base
    frame) towards ``flange``'s, and with ``free_yaw`` (SingArea\\Wrist, a pusher round
    about its own axis) the matrices (N, 3, 3) that keep only what tilts the tool's axis
    (None: all of an angular velocity matters)."""
    if free_yaw:
        z, want = rot[:, :, 2], flange[:3, 2]
        tilt = _cross(z, np.broadcast_to(want, z.shape))
        s = np.linalg.norm(tilt, axis=1)
        angle = np.arctan2(s, z @ want)
        err = np.where((s > 1e-12)[:, None], tilt / np.maximum(s, 1e-300)[:, None]
                       * angle[:, None], 0.0)
        return err, np.eye(3) - z[:, :, None] * z[:, None, :]
    r = flange[:3, :3] @ np.swapaxes(rot, 1, 2)
    angle = np.arccos(np.clip((np.trace(r, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    axis = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                     r[:, 1, 0] - r[:, 0, 1]], axis=1)
    n = np.linalg.norm(axis, axis=1)
    err = np.where((n >= 1e-9)[:, None], axis / np.maximum(n, 1e-300)[:, None]
                   * angle[:, None], 0.0)
    for i in np.flatnonzero((n < 1e-9) & (angle > 1e-9)):  # a half turn: rare, exact
        err[i] = rotation_error(rot[i], flange[:3, :3])
    return err, None


def _errors(frames: Mat, flange: Mat, free_yaw: bool) -> tuple[Mat, Mat, Mat | None]:
    """Position (N, 3, mm) and orientation (N, 3, rad) errors of flange frames (N, 4, 4),
    and the orientation's keep matrices (see :func:`_orientation_batch`)."""
    ep = flange[:3, 3] - frames[:, :3, 3]
    er, keep = _orientation_batch(frames[:, :3, :3], flange, free_yaw)
    return ep, er, keep


def _angle_error(frames: Mat, want_rad: float) -> tuple[Mat, Mat]:
    """The arm angle's error (N,: rad, the short way round) of joint frames (N, 8, 4, 4)
    towards ``want_rad``, and its gradient (N, 7)."""
    psi, grad = arm_angle_batch(frames)
    return (want_rad - psi + math.pi) % (2.0 * math.pi) - math.pi, grad


def descend_batch(model: ArmModel, flange: Mat, seeds: npt.ArrayLike, arm_angle_deg: float,
                  iters: int = 80, free_yaw: bool = False) -> tuple[Mat, Mat]:
    """Damped least squares from every seed (N, 7 chain deg) at once, all seven joints
    moving, towards the flange pose and the arm angle ``arm_angle_deg``: the angles
    reached (N, 7) and their residuals (N,: mm, the orientation and the arm angle
    weighted ``ROT_WEIGHT_MM`` and ``ARM_ANGLE_WEIGHT_MM`` per radian). Each seed keeps
    its own damping and stops once within the tolerances: the same descent as one seed
    at a time, a broad search costing one pass instead of one per seed."""
    want = math.radians(arm_angle_deg)
    q = np.array(seeds, dtype=np.float64).reshape(-1, 7)
    n = q.shape[0]
    lam = np.ones(n)
    frames = model.frames_batch(q)
    ep, er, keep = _errors(frames[:, 7], flange, free_yaw)
    ea, grad = _angle_error(frames, want)

    def residual(ep: Mat, er: Mat, ea: Mat) -> Mat:
        return np.linalg.norm(ep, axis=1) + np.linalg.norm(er, axis=1) * ROT_WEIGHT_MM + \
            np.abs(ea) * ARM_ANGLE_WEIGHT_MM

    res = residual(ep, er, ea)
    for _ in range(iters):
        live = (np.linalg.norm(ep, axis=1) >= POS_TOL_MM) | \
            (np.linalg.norm(er, axis=1) >= ROT_TOL_RAD) | (np.abs(ea) >= ARM_ANGLE_TOL_RAD)
        if not live.any():
            break
        z, o = frames[:, :7, :3, 2], frames[:, :7, :3, 3]
        p = frames[:, 7, :3, 3]
        jp = _cross(z, p[:, None, :] - o)  # (N, 7, 3)
        rot_rows = np.swapaxes(z, 1, 2) if keep is None else keep @ np.swapaxes(z, 1, 2)
        j = np.concatenate([np.swapaxes(jp, 1, 2), rot_rows * ROT_WEIGHT_MM,
                            grad[:, None, :] * ARM_ANGLE_WEIGHT_MM], axis=1)  # (N, 7, 7)
        e = np.concatenate([ep, er * ROT_WEIGHT_MM, ea[:, None] * ARM_ANGLE_WEIGHT_MM], axis=1)
        a = j @ np.swapaxes(j, 1, 2) + (lam * lam)[:, None, None] * np.eye(7)
        x = np.linalg.solve(a, e[:, :, None])[:, :, 0]
        step = (np.swapaxes(j, 1, 2) @ x[:, :, None])[:, :, 0]
        trial = q + np.degrees(np.clip(step, -0.3, 0.3))
        tframes = model.frames_batch(trial)
        tep, ter, tkeep = _errors(tframes[:, 7], flange, free_yaw)
        tea, tgrad = _angle_error(tframes, want)
        tres = residual(tep, ter, tea)
        ok = live & (tres < res)
        q[ok], frames[ok], ep[ok], er[ok], res[ok] = trial[ok], tframes[ok], tep[ok], \
            ter[ok], tres[ok]
        ea[ok], grad[ok] = tea[ok], tgrad[ok]
        if keep is not None and tkeep is not None:
            keep[ok] = tkeep[ok]
        lam = np.where(ok, np.maximum(lam * 0.5, 1e-3),
                       np.where(live, np.minimum(lam * 4.0, 1e6), lam))
    return q, res


def _descend(model: ArmModel, flange: Mat, seed: Sequence[float], arm_angle_deg: float,
             iters: int = 80, free_yaw: bool = False) -> tuple[ArmPose, float]:
    """:func:`descend_batch` from one seed: the pose and its residual (mm)."""
    q, res = descend_batch(model, flange, [seed], arm_angle_deg, iters, free_yaw)
    return model.pose(q[0]), float(res[0])


def _seeds(current: Sequence[float] | None, conf: Sequence[float], arm_angle: float
           ) -> list[list[float]]:
    """The arm's current joints, then elbow and wrist variants in the quadrants of
    ``conf`` (axis 1, 4 and 6 in the middle of theirs; axis 7 starting at the arm angle's
    value, a guess the descent corrects)."""
    c1, c4, c6 = ((c + 0.5) * 90.0 for c in conf[:3])
    out = [list(current)] if current is not None else []
    out += [[c1, q2, arm_angle, q3, c4, q5, c6] for q2 in (-130.0, -80.0)
            for q3 in (-60.0, 20.0) for q5 in (40.0, 100.0)]
    return out


BROAD: Final = tuple((q1, q2, q3, q4, q5) for q1 in (-120.0, -45.0, 45.0, 120.0)
                     for q2 in (-140.0, -90.0, -40.0) for q3 in (-90.0, -30.0, 40.0)
                     for q4 in (-90.0, 90.0) for q5 in (30.0, 100.0))
"""Seeds over the whole joint space (axes 1, 2, 3, 4, 5; axis 6 at 0, axis 7 at the arm
angle's value), for a target the seeds near the commanded configuration do not solve."""


def _broad(arm_angle_deg: float) -> list[tuple[float, ...]]:
    return [(q1, q2, arm_angle_deg, q3, q4, q5, 0.0) for q1, q2, q3, q4, q5 in BROAD]


def solutions(model: ArmModel, flange: Mat, arm_angle_deg: float,
              seeds: Sequence[Sequence[float]], free_yaw: bool = False
              ) -> tuple[list[ArmPose], float]:
    """Every seed's solution within ``REACH_TOL_MM`` that holds the arm angle (angles
    brought into range by whole turns where they can be), and the best residual (mm)."""
    if not len(seeds):
        return [], math.inf
    start = np.array([list(s) for s in seeds], dtype=np.float64)
    q, res = descend_batch(model, flange, start, arm_angle_deg, free_yaw=free_yaw)
    found: list[ArmPose] = []
    for k in np.flatnonzero(res <= REACH_TOL_MM):
        found += _turns(model, _wrapped(model, model.pose(q[k])))
    return found, float(res.min())


def _turns(model: ArmModel, pose: ArmPose) -> list[ArmPose]:
    """The pose and its twins a whole turn away on the axes whose range exceeds a turn
    (4 and 6: +-290 and +-229 deg) that stay in range: the same flange, another margin
    to the limits (the controller picks by its configuration, the twin by the margin)."""
    out = [pose]
    for k in range(7):
        if model.upper[k] - model.lower[k] <= 360.0:
            continue
        for p in list(out):
            for turn in (-360.0, 360.0):
                q = list(p.chain_deg)
                q[k] += turn
                if model.lower[k] <= q[k] <= model.upper[k]:
                    out.append(model.pose(q))
    return out


def _flipped(found: Sequence[ArmPose]) -> list[list[float]]:
    """Seeds for the wrist's other solutions of poses found: axes 4 and 6 a half turn
    round, axis 5 mirrored (exact for a spherical wrist; the IRB 14000's wrist offsets
    make it a near seed), so a configuration the seeds near the arm missed is found."""
    out: list[list[float]] = []
    for p in found[:4]:
        q = list(p.chain_deg)
        for d4, d6 in ((180.0, 180.0), (-180.0, -180.0), (180.0, -180.0), (-180.0, 180.0)):
            out.append([q[0], q[1], q[2], q[3], q[4] + d4, -q[5], q[6] + d6])
    return out


def solve(model: ArmModel, flange: Mat, arm_angle_deg: float, conf: Sequence[float] | None,
          current: Sequence[float] | None = None, free_yaw: bool = False,
          seeds: Sequence[Sequence[float]] = (),
          prefer: Sequence[float] | None = None) -> Solution:
    """The joints that put the flange at ``flange`` (4x4, base frame mm) with the arm
    angle ``arm_angle_deg`` (:mod:`sim_twin.sew_angle`), in the configuration ``conf``
    (cf1, cf4, cf6[, cfx]; None: any, the closest to ``current``, else the most
    dexterous). ``free_yaw``: the tool's turn about its own axis is free
    (SingArea\\Wrist with a round tool).

    Refused, as the controller refuses: ``reach`` (no joint angles put the flange there:
    the residual in mm), ``limit`` (only past a joint limit: which axis, by how much),
    ``conf`` (only in another configuration than ``conf``: the quadrants found).

    ``seeds``: more starting joints (chain order), tried first without ranking by them:
    the arm's present joints, so that a pose its own forward kinematics produced (the
    rest pose, a stop mid-way) is always found, however far from the generic seeds.
    ``prefer``: among solutions equally good (see :func:`_pick`), the one closest to these
    joints (the arm's present ones: no wrist turned a whole turn for nothing)."""
    short = model.reach_shortfall(flange[:3, 3])
    if short > REACH_TOL_MM:  # past the arm's length: no search needed
        return Solution(None, "reach", f"{short:.1f} mm short")
    want = None if conf is None else tuple(int(c) for c in conf[:3])
    near = [list(x) for x in seeds] + _seeds(current, conf if conf is not None else (0, 0, 0),
                                             arm_angle_deg)
    found, best = solutions(model, flange, arm_angle_deg, near, free_yaw)
    hit = _pick(model, found, want, current, free_yaw, prefer)
    if hit is None and found and want is not None:  # the wrist's other solutions
        more, _ = solutions(model, flange, arm_angle_deg, _flipped(found), free_yaw)
        found = found + more
        hit = _pick(model, found, want, current, free_yaw, prefer)
    if hit is None:
        more, best2 = solutions(model, flange, arm_angle_deg, _broad(arm_angle_deg), free_yaw)
        found, best = found + more, min(best, best2)
        hit = _pick(model, found, want, current, free_yaw, prefer)
    if hit is not None:
        return Solution(hit)
    if not found:
        return Solution(None, "reach", f"{best:.1f} mm short")
    inside = [p for p in found if model.limit_violation(p.chain_deg) is None]
    if not inside:
        axis, over = min((model.limit_violation(p.chain_deg) or (0, 0.0) for p in found),
                         key=lambda v: v[1])
        return Solution(None, "limit", f"axis {axis} {over:.1f} deg past its limit")
    got = sorted({configuration(p.chain_deg) for p in inside})
    return Solution(None, "conf", f"reachable with cf1, cf4, cf6 in {[list(c) for c in got]}"
                                  f", not {list(want or ())}")


def ranked(model: ArmModel, flange: Mat, arm_angle_deg: float, free_yaw: bool = False,
           most: int = 8, prefer: Sequence[float] | None = None) -> list[ArmPose]:
    """The distinct solutions within the limits, best first (as :func:`_pick` ranks them
    without a current pose, ties to the closest to ``prefer``): the candidates of a
    ConfJ-off joint move."""
    found, _ = solutions(model, flange, arm_angle_deg, _broad(arm_angle_deg), free_yaw)
    out: list[ArmPose] = []
    pool = [p for p in found if model.limit_violation(p.chain_deg) is None]
    while pool and len(out) < most:
        best = _pick(model, pool, None, None, free_yaw, prefer)
        assert best is not None
        out.append(best)
        pool = [p for p in pool if np.abs(np.subtract(p.chain_deg, best.chain_deg)).max() > 1.0]
    return out


def _pick(model: ArmModel, found: Sequence[ArmPose], want: tuple[int, ...] | None,
          current: Sequence[float] | None, free_yaw: bool = False,
          prefer: Sequence[float] | None = None) -> ArmPose | None:
    """The solution within the limits (in the configuration ``want``) the controller
    would take: clear of singularities first, then the closest to ``current`` (without
    one, the most dexterous, counting a joint within 30 deg of its limit against it: a
    line that starts there soon runs out of travel).

    Solutions that score the same (within :data:`TIE`: one pose with a wrist a whole
    turn apart has the same dexterity) go to the closest to ``prefer`` (else to
    ``current``, else to the joints' zero): never to whichever rounding favoured, which
    differs between CPUs (a MoveJ that turned axis 4 by 360 deg on one machine only)."""
    ok = [p for p in found if model.limit_violation(p.chain_deg) is None
          and (want is None or configuration(p.chain_deg) == want)]
    if not ok:
        return None

    def cost(p: ArmPose) -> tuple[bool, float]:
        dex = manipulability(model, p, free_yaw)
        margin = float(np.min(np.minimum(np.subtract(p.chain_deg, model.lower),
                                         np.subtract(model.upper, p.chain_deg))))
        near = -dex * min(1.0, margin / 30.0) if current is None else float(
            np.abs(np.subtract(p.chain_deg, current)).max())
        return dex < 3 * SINGULAR_SIGMA, near

    costs = [cost(p) for p in ok]
    best = min(costs)
    tied = [p for p, c in zip(ok, costs, strict=True)
            if c[0] == best[0] and c[1] <= best[1] + TIE]
    ref = np.zeros(7) if prefer is None and current is None else \
        np.asarray(prefer if prefer is not None else current, dtype=np.float64)
    return min(tied, key=lambda p: float(np.abs(np.subtract(p.chain_deg, ref)).max()))


def _wrapped(model: ArmModel, pose: ArmPose) -> ArmPose:
    """The same pose with each angle brought into its range by whole turns when it can."""
    q = list(pose.chain_deg)
    for k in range(7):
        for turn in (0.0, -360.0, 360.0):
            if model.lower[k] <= q[k] + turn <= model.upper[k]:
                q[k] += turn
                break
    return model.pose(q) if q != list(pose.chain_deg) else pose


def configuration(chain_deg: Sequence[float]) -> tuple[int, int, int]:
    """(cf1, cf4, cf6) of a chain angle vector."""
    by_axis = dict(zip(CHAIN_AXES, chain_deg, strict=True))
    return quadrant(by_axis[1]), quadrant(by_axis[4]), quadrant(by_axis[6])


def manipulability(model: ArmModel, pose: ArmPose, free_yaw: bool = False) -> float:
    """The smallest singular value of the seven joints' Jacobian at the flange with the
    arm angle's row below it (positions over the arm's reach; 0: singular, the arm or
    the arm angle's parameterization: the controller cannot hold both); with
    ``free_yaw`` of the rows that matter (the tool's turn about its own axis left out: a
    wrist singularity, axes 4 and 6 in line, costs nothing there)."""
    j = model.jacobian(pose, pose.flange[:3, 3])
    j[:3] /= 560.0
    if free_yaw:
        z = pose.flange[:3, 2]
        e1 = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        j = np.vstack([j[:3], np.cross(z, e1) @ j[3:], e1 @ j[3:]])
    _, grad = arm_angle_batch(pose.frames[None])
    return float(np.linalg.svd(np.vstack([j, grad]), compute_uv=False)[-1])


ARM_JOINTS: Final = (0, 1, 2, 3)
"""Chain indices of axes 1, 2, 7 and 3: the arm's joints, which hold the tip on a SingArea
Wrist line and the arm angle (``sim_twin.rws.arm_supervision``)."""


def tip_descend(model: ArmModel, tip: npt.ArrayLike, tool_mm: float, seed: Sequence[float],
                arm_angle_deg: float, iters: int = 60) -> tuple[ArmPose, float]:
    """Axes 1, 2, 7 and 3 (:data:`ARM_JOINTS`) that put the pusher's tip (``tool_mm``
    along the flange's z) on ``tip`` (base frame, mm) at the arm angle
    ``arm_angle_deg``, the wrist's axes held at ``seed``'s; and the residual (mm, the
    arm angle weighted ``ARM_ANGLE_WEIGHT_MM`` per radian). SingArea Wrist's line
    (``sim_twin.rws.arm_supervision``): the wrist's axes are interpolated, the arm's
    four keep the tip on the path and the elbow at its arm angle."""
    free = list(ARM_JOINTS)
    q = np.array(seed, dtype=np.float64)
    want, angle = np.asarray(tip, dtype=np.float64), math.radians(arm_angle_deg)
    pose = model.pose(q)

    def at(p: ArmPose) -> Mat:
        return p.flange[:3, 3] + p.flange[:3, 2] * tool_mm

    def error(p: ArmPose) -> tuple[Mat, Mat]:
        ea, grad = _angle_error(p.frames[None], angle)
        return np.append(want - at(p), ea[0] * ARM_ANGLE_WEIGHT_MM), grad[0]

    e, grad = error(pose)
    err = float(np.linalg.norm(e))
    lam = 1.0
    for _ in range(iters):
        if np.linalg.norm(e[:3]) < POS_TOL_MM and \
                abs(e[3]) < ARM_ANGLE_TOL_RAD * ARM_ANGLE_WEIGHT_MM:
            break
        j = np.vstack([model.jacobian(pose, at(pose))[:3], grad * ARM_ANGLE_WEIGHT_MM])[:, free]
        step = j.T @ np.linalg.solve(j @ j.T + lam * lam * np.eye(4), e)
        trial = q.copy()
        trial[free] += np.degrees(np.clip(step, -0.3, 0.3))
        tpose = model.pose(trial)
        te, tgrad = error(tpose)
        terr = float(np.linalg.norm(te))
        if terr < err:
            q, pose, e, grad, err = trial, tpose, te, tgrad, terr
            lam = max(lam * 0.5, 1e-3)
        else:
            lam = min(lam * 4.0, 1e6)
    return pose, err


def arm_sigma(model: ArmModel, pose: ArmPose, tool_mm: float) -> float:
    """The smallest singular value of the tip's position Jacobian over axes 1, 2, 7 and
    3 with the arm angle's row below it (positions over the arm's reach of 560 mm, per
    radian): 0 where the arm (not the wrist) cannot hold both the tip and the arm angle,
    the elbow straight, the wrist over axis 1, or the arm angle's own singularity."""
    tip = pose.flange[:3, 3] + pose.flange[:3, 2] * tool_mm
    _, grad = arm_angle_batch(pose.frames[None])
    j = np.vstack([model.jacobian(pose, tip)[:3] / 560.0, grad])[:, list(ARM_JOINTS)]
    return float(np.linalg.svd(j, compute_uv=False)[-1])
