"""The twin controller's kinematics and motion supervision: each arm's joints along every
move, the targets it refuses, and the moment two arms (or an arm and the table) meet.

Why: the cell moves floating pushers; the robot moves 7-axis arms. Before a move runs,
the twin solves every arm's joints along its path (:mod:`sim_twin.yumi_ik`, the arms of
:mod:`sim_twin.yumi_arms`) and finds the first moment the controller would stop:

==============================  =====  ================================================
what                            code   the controller's title (IRC5 event log)
==============================  =====  ================================================
no joint angles reach a target  50050  Position outside reach
reachable only past a limit     50027  Joint Out of Range
MoveJ (ConfJ on): another conf  50080  Position not compatible
MoveL through a singularity     50026  Close to singularity
a link meets the other arm or   50204  Motion supervision
the table (the pusher's tip on
the table and cubes aside)
==============================  =====  ================================================

The codes and titles are the IRC5 operating manual's event messages as we know them;
docs/rws-checklist.md asks a lab to confirm each on its controller. A kinematic stop
stops the task at the moment its arm reaches the instruction it cannot do (the motion
before it runs); motion supervision stops every task when two shapes touch
(:data:`CONTACT_MM`): the real collision detection trips after contact, from the motor
torques, so the twin's arms stop where the bodies meet, never short of them.

The path model: a MoveL's TCP moves in a straight line, its joints follow by the
solution nearest the previous sample's (ConfL off: the closest configuration); a MoveJ's
joints move linearly from the start's to the target's (the pusher in the cell still
moves in a straight line: its path and the arm's differ a little between the ends, which
only the collision watch sees). With ConfJ off a MoveJ's end is taken in a configuration
the MoveLs after it can keep (the twin looks ahead); with SingArea Wrist (our RAPID) a
line's wrist axes turn evenly from its start's joints to its end's while axes 1, 2, 7 and
3 keep the tip on the line and the elbow at its arm angle (``ArmSupervisor._wrist_line``),
and targets are solved for the tool's axis alone (the round pusher's turn about it is
free). The arm angle is a robtarget's ``eax_a``: ABB's shoulder-elbow-wrist angle
(:mod:`sim_twin.sew_angle`), not axis 7's value; a line turns it evenly from the start's
to the target's (the short way round) and holds it exactly at every sample, axis 7
moving as it must; where the other joints cannot follow, the line stops with the
controller's code, never an eased arm angle. Not modelled: an arm against itself or the
body, blending in zones.

Over 450 lines, on purpose: its one job is to judge each arm's path as the
controller would (joint moves, lines with and without SingArea Wrist, limits,
singularities, zones along the joint path, contact), and the parts share one arm state
(``ArmSupervisor.joints``) and one sampling of the path (``_Track``); the solvers they
call live in :mod:`sim_twin.yumi_ik`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from sim_twin.rws.world_zones import ArmZone, ZoneBox, time_at
from sim_twin.sew_angle import angle_step, arm_angle
from sim_twin.yumi_arms import ArmModel, ArmPose, abb_to_chain, chain_to_abb, clearance
from sim_twin.yumi_arms import table_clearance as table_gap
from sim_twin.yumi_cell import Segment, Trajectory
from sim_twin.yumi_ik import (
    ARM_JOINTS,
    REACH_TOL_MM,
    SINGULAR_SIGMA,
    Solution,
    _descend,
    arm_sigma,
    configuration,
    manipulability,
    ranked,
    rotation_error,
    solve,
    tip_descend,
)

Mat = npt.NDArray[np.float64]
SAMPLE_MM: Final = 15.0
"""The path is checked at least every this many mm of TCP travel."""
CONTACT_MM: Final = 0.0
"""Motion supervision trips when two shapes come this close: 0, they touch. Why not a
margin: RobotWare's collision detection senses a collision from the motor torques, so it
trips only after contact; then "the robot will stop as quickly as possible. Then it will
move in the reverse direction to remove residual forces ... The robot remains in the
state motors on" (ABB, Application manual - Collision Detection, 3HAC18154-1, "What
happens at a collision"). Assumed about the real stop: the overshoot into the contact
(the braking distance, a few mm at the pushes' speeds: ABB publishes no figure for the
YuMi) and the back-off along the path cancel, leaving the arms at the point of contact,
which is where the twin leaves them; docs/rws-checklist.md ("The two grippers jogged")
has the lab measure the real stop."""
WRIST_SAMPLE_MM: Final = 5.0
"""A SingArea Wrist line is sampled at least every this many mm of TCP travel
(``ArmSupervisor._wrist_line``: a sample costs one small solve)."""
JUMP_DEG: Final = 25.0
"""A MoveL sample whose joints jump more than this from the previous one passed a
singularity (the closest solution flipped). With SingArea Wrist the wrist may turn fast
through one (axes 4 and 6 trade the tool's free turn): only the distance counts."""
FLANGE_DOWN: Final = np.diag([1.0, -1.0, -1.0])
"""The flange's rotation with the tool pointing down (the twin's only tool orientation)."""
AGREE_MM: Final = 2.0
"""The arm's tip and the cell's pusher this close: the arm's joints say where the flange
is (the pusher sags a little on its constraint under load)."""
JOINT_STEP_DEG: Final = 1.5
"""A joint move is sampled at least every this many degrees of its largest joint's
travel (at most about 25 mm of the tool's tip at full stretch), besides SAMPLE_MM."""
CONTINUE_ITERS: Final = 120
"""A line's sample that did not converge in the quick descent gets this many more
iterations from the same seed before the twin looks for the closest solution."""
SOLVED_KEPT: Final = 256
"""How many joint-move ends an arm's supervisor keeps (ArmSupervisor._solved)."""
LOOKAHEAD: Final = 4
"""How many of a ConfJ-off MoveJ's best solutions the twin tries for the MoveLs after it
(the controller's choice is among the few most dexterous)."""
ERRORS: Final = {
    "reach": (50050, "Position outside reach"),
    "limit": (50027, "Joint Out of Range"),
    "conf": (50080, "Position not compatible"),
    "singular": (50026, "Close to singularity"),
    "contact": (50204, "Motion supervision"),
}


@dataclass(frozen=True)
class ArmStop:
    """Where the controller stops: at ``t`` (s into the move), ``arm``'s task, why."""

    t: float
    arm: str
    reason: str
    detail: str

    @property
    def code(self) -> int:
        return ERRORS[self.reason][0]

    @property
    def title(self) -> str:
        return ERRORS[self.reason][1]

    @property
    def every_task(self) -> bool:
        return self.reason == "contact"


@dataclass
class _Track:
    """One arm's joint samples over a move: times (s) and chain angles (deg)."""

    t: list[float] = field(default_factory=list)
    q: list[list[float]] = field(default_factory=list)
    ends: list[float] = field(default_factory=list)
    """When each move that ran to its end ended (s)."""

    def at(self, t: float) -> list[float]:
        k = int(np.searchsorted(self.t, t))
        if k <= 0:
            return self.q[0]
        if k >= len(self.t):
            return self.q[-1]
        t0, t1 = self.t[k - 1], self.t[k]
        f = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return [a + f * (b - a) for a, b in zip(self.q[k - 1], self.q[k], strict=True)]


def flange_at(cell_xyz: Sequence[float], tool_mm: float, rot: npt.ArrayLike | None = None
              ) -> Mat:
    """The flange pose (4x4) that holds a cell TCP (the pusher's bottom, ``tool_mm``
    along the flange's z) with the flange's rotation ``rot`` (default: the tool down)."""
    f = np.eye(4)
    f[:3, :3] = FLANGE_DOWN if rot is None else np.asarray(rot, dtype=np.float64)
    f[:3, 3] = np.asarray(cell_xyz, dtype=np.float64)[:3] - f[:3, 2] * tool_mm
    return f


def turned(r0: Mat, r1: Mat, f: float) -> Mat:
    """The rotation ``f`` of the way from ``r0`` to ``r1`` about one fixed axis (a
    MoveL's orientation: interpolated evenly along the path, as the controller does)."""
    w = rotation_error(r0, r1) * f
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return r0.copy()
    k = w / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return (np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * kx @ kx) @ r0


class ArmSupervisor:
    """Each arm's joints and the checks of every move. ``sides``: arm -> "left"/"right";
    ``tool_mm``: the pusher's tip below the flange, along the flange's z (the gripper and
    the pusher); ``rest_joints``: arm -> its rest pose (ABB's order: axes 1-6, then 7),
    where the arms start."""

    def __init__(self, sides: Mapping[str, str], tool_mm: float,
                 rest_joints: Mapping[str, Sequence[float]]) -> None:
        self.models = {a: ArmModel(s) for a, s in sides.items()}
        self.tool_mm = float(tool_mm)
        self.rest = {a: abb_to_chain(rest_joints[a]) for a in sides}
        for arm, q in self.rest.items():
            over = self.models[arm].limit_violation(q)
            if over is not None:
                raise ValueError(f"arm {arm}: its rest joints put axis {over[0]} "
                                 f"{over[1]:.1f} deg past its limit")
        self.joints = {a: list(q) for a, q in self.rest.items()}
        self.closest: tuple[float, str] = (math.inf, "")
        """The smallest gap seen between the two arms over every move that ran (mm), and
        between which links (the rehearsal's figure; the twin logs it at exit)."""
        self.free_yaw = False
        """SingArea\\Wrist (our RAPID): the tool may turn about its own axis to keep the
        wrist away from its singularity, so a line is judged by the tool's axis alone."""
        self._solved: dict[tuple[object, ...], Solution] = {}
        """A joint move's end solved from the same joints to the same target before (the
        same arm, tool, orientation and configuration rule): the IK search is a pure
        function of those, and a lab's moves repeat (rest to the gate, every push and
        every calibration point). Oldest first, at most :data:`SOLVED_KEPT`."""

    def tip(self, arm: str, chain_deg: Sequence[float] | None = None
            ) -> tuple[float, float, float]:
        """The pusher's tip (the cell's TCP) for the arm's joints (default: its own)."""
        return self.models[arm].tip(self.joints[arm] if chain_deg is None else chain_deg,
                                    self.tool_mm)

    def flange_pose(self, arm: str, tip: Sequence[float]
                    ) -> tuple[tuple[float, float, float],
                               tuple[float, float, float, float]] | None:
        """The flange (position mm, quaternion wxyz) by the arm's joints when they hold the
        pusher's tip at ``tip`` (within :data:`AGREE_MM`), whatever the tool's direction
        (at rest it points forward and down); None when they do not (the lab moved the
        pusher): then the pusher itself says where the flange is."""
        if math.dist(self.tip(arm), tip) > AGREE_MM:
            return None
        f = self.models[arm].pose(self.joints[arm]).flange
        x, y, z = (float(v) for v in f[:3, 3])
        return (x, y, z), _quat(f[:3, :3])

    def arm_angle(self, arm: str, chain_deg: Sequence[float] | None = None) -> float:
        """The arm angle (deg, ``eax_a`` of a robtarget) of the arm's joints (default: its
        own): :func:`sim_twin.sew_angle.arm_angle`."""
        return arm_angle(self.models[arm].pose(self.joints[arm] if chain_deg is None
                                               else chain_deg))

    def rest_joints(self, arm: str) -> tuple[float, ...]:
        """The rest pose in ABB's joint order (axes 1-6, then 7)."""
        return tuple(chain_to_abb(self.rest[arm]))

    def abb_joints(self, arm: str) -> tuple[float, ...]:
        return tuple(chain_to_abb(self.joints[arm]))

    def robconf(self, arm: str) -> tuple[float, float, float, float]:
        c1, c4, c6 = configuration(self.joints[arm])
        return (float(c1), float(c4), float(c6), 0.0)

    def sync(self, arm: str, cell_xyz: Sequence[float]) -> None:
        """Make the arm's joints agree with its pusher when they do not (the lab's hand
        moved it): the joints nearest the arm's own that hold the pusher there, the tool
        turned as it is now, else pointing down. Never refuses: a pusher no joints can
        hold (the hand put it out of reach) leaves the joints where they were, and the
        next move is judged from them, as the controller judges from its own joints."""
        if math.dist(self.tip(arm), cell_xyz) < 0.5:
            return
        q, m = self.joints[arm], self.models[arm]
        now = m.pose(q).flange[:3, :3]
        for rot in (now, FLANGE_DOWN):
            s = solve(m, flange_at(cell_xyz, self.tool_mm, rot), self.arm_angle(arm), None,
                      current=q, free_yaw=self.free_yaw, seeds=[q])
            if s.pose is not None:
                self.joints[arm] = list(s.pose.chain_deg)
                return

    # --- a move --------------------------------------------------------------------------
    def check(self, trajs: Mapping[str, Trajectory],
              meta: Mapping[str, Sequence[Mapping[str, object]]]
              ) -> tuple[ArmStop | None, dict[str, _Track]]:
        """The first stop of a move (None: it runs to its end) and each arm's joints."""
        stops: list[ArmStop] = []
        tracks: dict[str, _Track] = {}
        for arm, traj in trajs.items():
            track, stop = self._arm(arm, traj, meta.get(arm, ()))
            tracks[arm] = track
            if stop is not None:
                stops.append(stop)
        horizon = min((s.t for s in stops), default=math.inf)
        contact = self._contact(tracks, horizon)
        if contact is not None:
            stops.append(contact)
        return (min(stops, key=lambda s: s.t) if stops else None), tracks

    def commit(self, tracks: Mapping[str, _Track], t: float) -> None:
        """The arms' joints at ``t`` into the move (its end, or where it stopped)."""
        for arm, track in tracks.items():
            if track.t:
                self.joints[arm] = list(track.at(t))

    def tool_point(self, arm: str, chain_deg: Sequence[float], trans: Sequence[float]
                   ) -> tuple[float, float, float]:
        """The TCP of a tool whose frame's translation is ``trans`` (the tool in use),
        for the arm's joints ``chain_deg``: the point the world zones watch."""
        f = self.models[arm].pose(chain_deg).flange
        x, y, z = (float(v) for v in f[:3, 3] + f[:3, :3] @ np.asarray(trans, dtype=float))
        return (x, y, z)

    def zone_entry(self, tracks: Mapping[str, _Track], zones: Mapping[str, ArmZone],
                   tools: Mapping[str, Sequence[float]]
                   ) -> tuple[float, str, ZoneBox, tuple[float, float, float]] | None:
        """The first moment an arm's TCP of the tool in use (``tools``: arm -> the
        tframe's translation) is inside one of its world zones along the path its joints
        really take (a joint move's TCP is the forward kinematics of interpolated joints,
        not a line): found at the first sample inside, then bisected back to the zone's
        face. Returns (time, arm, box, the TCP there) or None. A TCP already inside at
        the start stops at once, as ``WZLimSup`` refuses any motion inside the zone."""
        hits = []
        for arm, track in tracks.items():
            zone, trans = zones.get(arm), tools.get(arm)
            if zone is None or trans is None or not track.t:
                continue
            hit = self._track_entry(arm, track, zone, trans)
            if hit is not None:
                hits.append((hit[0], arm, hit[1], hit[2]))
        return min(hits, key=lambda h: h[0]) if hits else None

    def _track_entry(self, arm: str, track: _Track, zone: ArmZone, trans: Sequence[float]
                     ) -> tuple[float, ZoneBox, tuple[float, float, float]] | None:
        def at(t: float) -> tuple[float, float, float]:
            return self.tool_point(arm, track.at(t), trans)

        first = at(track.t[0])
        box = zone.inside(first)
        if box is not None:
            return track.t[0], box, first
        for k in range(1, len(track.t)):
            box = zone.inside(at(track.t[k]))
            if box is None:
                continue
            lo, hi = track.t[k - 1], track.t[k]
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if zone.inside(at(mid)) is not None else (mid, hi)
            return lo, zone.inside(at(hi)) or box, at(lo)
        return None

    def tip_path(self, arm: str, track: _Track, t0: float, t1: float
                 ) -> list[tuple[float, tuple[float, float, float]]]:
        """The pusher's tip (the cell's TCP) at the track's samples in ``(t0, t1]``, times
        from ``t0``: the path a joint move really gives the pusher, for the cell to follow."""
        return [(t - t0, self.tip(arm, q)) for t, q in zip(track.t, track.q, strict=True)
                if t0 < t <= t1 + 1e-9]

    def _arm(self, arm: str, traj: Trajectory, meta: Sequence[Mapping[str, object]]
             ) -> tuple[_Track, ArmStop | None]:
        q = list(self.joints[arm])
        track, t0 = _Track([0.0], [q]), 0.0
        segs = traj.segments
        for k, seg in enumerate(segs):
            info = meta[k] if k < len(meta) else {}
            # a robtarget without an arm angle (9E9) keeps the arm's own
            angle = float(info.get("arm_angle_deg", self.arm_angle(arm, q)))  # type: ignore[arg-type]
            if info.get("kind") in ("move_j", "rest"):
                lines = []
                for j in range(k + 1, len(segs)):
                    nxt = meta[j] if j < len(meta) else {}
                    if nxt.get("kind") != "move_l":
                        break
                    lines.append((segs[j], float(nxt.get("arm_angle_deg", angle)),  # type: ignore[arg-type]
                                  _rot(nxt)))
                stop = self._joint_move(arm, seg, info, angle, q, t0, track, lines)
            else:
                stop = self._linear_move(arm, seg, angle, q, t0, track, _rot(info))
            if stop is not None:
                return track, stop
            q = track.q[-1]
            t0 += seg.duration
            track.ends.append(t0)
        return track, None

    def _joint_move(self, arm: str, seg: Segment, info: Mapping[str, object], angle: float,
                    q: list[float], t0: float, track: _Track,
                    lines: Sequence[tuple[Segment, float]] = ()) -> ArmStop | None:
        """A MoveJ (or a move to a joint target): solve the end, then interpolate joints.
        ``lines``: the MoveLs that follow it (ConfJ off: the end is taken in a
        configuration they can be run in, when there is one)."""
        m = self.models[arm]
        target = info.get("joints_deg")
        if target is not None:
            end = abb_to_chain(target)  # type: ignore[arg-type]
        else:
            end_or = self._target(arm, seg.b, angle, info.get("conf"), q,
                                  bool(info.get("conf_on")), lines, _rot(info))
            if isinstance(end_or, ArmStop):
                return ArmStop(t0, arm, end_or.reason, end_or.detail)
            end = end_or
        over = m.limit_violation(end)
        if over is not None:
            return ArmStop(t0, arm, "limit", f"axis {over[0]} {over[1]:.1f} deg past its limit")
        n = max(1, math.ceil(seg.length / SAMPLE_MM),
                math.ceil(max(abs(b - a) for a, b in zip(q, end, strict=True)) / JOINT_STEP_DEG))
        for i in range(1, n + 1):
            f = i / n
            track.t.append(t0 + _time_of(seg, f))
            track.q.append([a + f * (b - a) for a, b in zip(q, end, strict=True)])
        return None

    def _target(self, arm: str, xyz: Sequence[float], angle: float, conf: object,
                current: list[float], conf_on: bool = True,
                lines: Sequence[tuple[Segment, float, Mat | None]] = (),
                rot: Mat | None = None) -> list[float] | ArmStop:
        """A joint move's end: in ``conf`` (ConfJ on, the most dexterous such solution),
        else (ConfJ off, "the closest configuration": a MoveJ "uses the least amount of
        axis rotation") the solution nearest the arm's joints, or, when the MoveLs that
        follow (``lines``) do not run from it, the most dexterous from which they do: the
        configuration a lab that taught its arm angle and rest pose well gets; the twin
        looks ahead for it. The target's orientation is held exactly (the round pusher
        is not let turn about its axis at a target: the controller reaches the
        robtarget's quaternion). The arm's present joints seed the search too (a target
        its own joints produced is found)."""
        flange = flange_at(xyz, self.tool_mm, rot)
        want = conf if conf_on else None
        key = (arm, tuple(float(v) for v in xyz), float(angle), repr(want), tuple(current),
               self.tool_mm, self.free_yaw, None if rot is None else rot.tobytes())
        s = self._solved.get(key)
        if s is None:
            s = solve(self.models[arm], flange, angle, want,  # type: ignore[arg-type]
                      current=None if conf_on else current, free_yaw=False,
                      seeds=[current], prefer=current)
            if len(self._solved) >= SOLVED_KEPT:
                del self._solved[next(iter(self._solved))]
            self._solved[key] = s
        if s.pose is not None and not conf_on and lines and \
                not self._lines_run(arm, lines, list(s.pose.chain_deg)):
            for cand in ranked(self.models[arm], flange, angle, False, LOOKAHEAD,
                               prefer=current):
                if self._lines_run(arm, lines, list(cand.chain_deg)):
                    return list(cand.chain_deg)
        if s.pose is None:
            return ArmStop(0.0, arm, s.reason or "reach", f"target {_xyz(xyz)}: {s.detail}")
        return list(s.pose.chain_deg)

    def _lines_run(self, arm: str, lines: Sequence[tuple[Segment, float, Mat | None]],
                   q: list[float]) -> bool:
        """Whether the MoveLs ``lines`` run from joints ``q`` without a stop."""
        scratch = _Track([0.0], [q])
        for seg, angle, rot in lines:
            if self._linear_move(arm, seg, angle, q, 0.0, scratch, rot) is not None:
                return False
            q = scratch.q[-1]
        return True

    def _linear_move(self, arm: str, seg: Segment, angle: float, q: list[float], t0: float,
                     track: _Track, rot: Mat | None = None) -> ArmStop | None:
        """A MoveL: the TCP on a straight line, the tool's orientation turned evenly from
        the arm's present one to the target's (``rot``, default down) along it (a MoveL
        from the rest pose turns the tool down as it goes; one to a target with the rest's
        orientation keeps it), the arm angle turned evenly from the arm's present one to
        ``angle`` (the target's ``eax_a``) and held at every sample, the joints the closest
        solution. With SingArea Wrist (our RAPID's), the wrist's axes are interpolated
        instead (:meth:`_wrist_line`)."""
        if self.free_yaw:
            stop = self._wrist_line(arm, seg, angle, q, t0, track, rot)
            if stop is not False:
                return stop
        m = self.models[arm]
        start_angle = self.arm_angle(arm, q)  # the arm angle turns with the line
        swing = angle_step(start_angle, angle)
        r0 = m.pose(q).flange[:3, :3]
        r1 = FLANGE_DOWN if rot is None else rot
        turn = math.degrees(float(np.linalg.norm(rotation_error(r0, r1))))
        # evenly in time: at most SAMPLE_MM apart, as the TCP never exceeds seg.speed
        n = max(1, math.ceil(seg.speed * seg.duration / SAMPLE_MM),
                math.ceil(abs(swing) / 5.0), math.ceil(turn / 3.0))
        a = np.asarray(seg.a)
        for i in range(1, n + 1):
            t = t0 + seg.duration * i / n
            xyz = np.asarray(seg.at(seg.duration * i / n))
            f = float(np.linalg.norm(xyz - a) / seg.length) if seg.length > 0 else i / n
            now = start_angle + f * swing
            flange = flange_at(xyz, self.tool_mm, turned(r0, r1, f))
            pose, res = _descend(m, flange, q, now, iters=40, free_yaw=self.free_yaw)
            if res > REACH_TOL_MM:  # slow to converge: longer, then the closest solution
                pose, res = self._continued(m, flange, q, now) or (pose, res)
            stop = self._sample_stop(arm, m, pose, res, q, t, xyz, flange, now,
                                     abs(swing) / n)
            if stop is not None:
                return stop
            q = list(pose.chain_deg)
            track.t.append(t)
            track.q.append(q)
        return None

    def _wrist_line(self, arm: str, seg: Segment, angle: float, q: list[float], t0: float,
                    track: _Track, rot: Mat | None = None) -> ArmStop | bool | None:
        """A MoveL with SingArea Wrist: the TCP on the straight line, axes 4, 5 and 6 turned
        evenly from the start's joints to the end's (the solution at the target closest to
        the start, ConfL Off) and the arm angle evenly from the start's to ``angle``, axes
        1, 2, 7 and 3 keeping the tip on the line and the elbow at that arm angle; the
        tool's orientation is exact at both ends and "allowed to differ somewhat" between
        them (ABB's words for Wrist). Why: with the pusher
        down the wrist passes near its singularity over parts of the table (axis 5 near
        0), where holding the orientation turns axis 4 fast; a string of such lines wound
        axis 4 past its limit (50027 on the rehearsal's pushes), which Wrist exists to
        prevent. None: the line runs; an ArmStop; False: no end solution within the
        limits, the line is judged sample by sample (:meth:`_linear_move`), which names
        where and why the arm cannot follow it."""
        if seg.length < 1.0:  # a turn on the spot (or nearly): judged sample by sample
            return False
        m = self.models[arm]
        r1 = FLANGE_DOWN if rot is None else rot
        end_flange = flange_at(seg.b, self.tool_mm, r1)
        # the end: the descent from the start's joints (the solution they continue to, the
        # closest but for a rare one), else the search's closest within the limits
        reach, res = _descend(m, end_flange, q, angle, free_yaw=False)
        if res <= REACH_TOL_MM and m.limit_violation(reach.chain_deg) is None:
            end = list(reach.chain_deg)
        else:
            flips = [[*q[:4], q[4] + d, -q[5], q[6] + d] for d in (180.0, -180.0)]
            s = solve(m, end_flange, angle, None, current=q, free_yaw=False, seeds=[q, *flips])
            if s.pose is None:
                return False
            end = list(s.pose.chain_deg)
        start_angle = self.arm_angle(arm, q)
        turn = angle_step(start_angle, angle)
        wrist = (4, 5, 6)  # chain indices of axes 4, 5, 6
        swing = max(max(abs(end[k] - q[k]) for k in wrist), abs(turn))
        # denser than a plain line's: between samples the joints are interpolated, and a
        # zone's entry is found on that path, which must stay near the line
        n = max(1, math.ceil(seg.speed * seg.duration / WRIST_SAMPLE_MM),
                math.ceil(swing / 2.0))
        a = np.asarray(seg.a)
        before = prev = list(q)
        for i in range(1, n + 1):
            t = t0 + seg.duration * i / n
            xyz = np.asarray(seg.at(seg.duration * i / n))
            f = float(np.linalg.norm(xyz - a) / seg.length) if seg.length > 0 else i / n
            seed = list(prev)
            for k in wrist:
                seed[k] = q[k] + f * (end[k] - q[k])
            for k in ARM_JOINTS:  # the arm's joints carried on as they went: a near seed
                seed[k] += prev[k] - before[k]
            pose, err = tip_descend(m, xyz, self.tool_mm, seed, start_angle + f * turn)
            if err > REACH_TOL_MM:
                return ArmStop(t, arm, "reach", f"at {_xyz(xyz)}: the arm cannot follow the "
                                                f"line ({err:.1f} mm off it)")
            over = m.limit_violation(pose.chain_deg)
            if over is not None:
                return ArmStop(t, arm, "limit", f"at {_xyz(xyz)}: axis {over[0]} "
                                                f"{over[1]:.1f} deg past its limit")
            jump = max(abs(pose.chain_deg[k] - prev[k]) for k in ARM_JOINTS)
            if jump > JUMP_DEG or arm_sigma(m, pose, self.tool_mm) < SINGULAR_SIGMA:
                return ArmStop(t, arm, "singular", f"at {_xyz(xyz)}: the linear path passes "
                                                   "an arm singularity")
            before, prev = prev, list(pose.chain_deg)
            track.t.append(t)
            track.q.append(prev)
        return None

    def _continued(self, m: ArmModel, flange: Mat, prev: list[float], angle: float
                   ) -> tuple[ArmPose, float] | None:
        """A line's next sample (arm angle ``angle``) when the quick descent from the
        previous sample's joints ``prev`` did not converge: a long one from them, else the
        solution closest to them if it is near (the arm follows the line); None when the
        arm cannot follow it."""
        pose, res = _descend(m, flange, prev, angle, iters=CONTINUE_ITERS,
                             free_yaw=self.free_yaw)
        if res <= REACH_TOL_MM:
            return pose, res
        s = solve(m, flange, angle, None, current=prev, free_yaw=self.free_yaw, seeds=[prev])
        if s.pose is None:
            return None
        # with SingArea Wrist the wrist's two turning axes (4 and 6, chain 4 and 6) may
        # spin through a wrist singularity; every other joint must stay near
        moved = [abs(x - y) for k, (x, y) in enumerate(zip(s.pose.chain_deg, prev, strict=True))
                 if not (self.free_yaw and k in (4, 6))]
        return (s.pose, 0.0) if max(moved) < JUMP_DEG else None

    def _sample_stop(self, arm: str, m: ArmModel, pose: ArmPose, res: float,
                     prev: list[float], t: float, xyz: Sequence[float], flange: Mat,
                     angle: float, turn: float) -> ArmStop | None:
        """Why a line's sample (arm angle ``angle``, ``turn`` deg of it since the last
        sample) stops the arm, or None."""
        if res > REACH_TOL_MM:  # the arm cannot follow the line from where it is
            s = solve(m, flange, angle, None, current=prev, free_yaw=self.free_yaw,
                      seeds=[prev])
            if s.pose is None:
                return ArmStop(t, arm, s.reason or "reach", f"at {_xyz(xyz)}: {s.detail}")
            over = m.limit_violation(pose.chain_deg)
            if over is not None:
                return ArmStop(t, arm, "limit", f"at {_xyz(xyz)}: axis {over[0]} "
                                                f"{over[1]:.1f} deg past its limit on the way")
            return ArmStop(t, arm, "singular", f"at {_xyz(xyz)}: the linear path leaves the "
                                               "arm's configuration")
        over = m.limit_violation(pose.chain_deg)
        if over is not None:
            return ArmStop(t, arm, "limit", f"at {_xyz(xyz)}: axis {over[0]} "
                                            f"{over[1]:.1f} deg past its limit")
        jump = max(abs(x - y) for x, y in zip(pose.chain_deg, prev, strict=True))
        flipped = jump > JUMP_DEG + 3.0 * turn and not self.free_yaw  # (Wrist: axes 4, 6 turn)
        if flipped or manipulability(m, pose, self.free_yaw) < SINGULAR_SIGMA:
            return ArmStop(t, arm, "singular", f"at {_xyz(xyz)}: the linear path passes "
                                               "a wrist or arm singularity")
        return None

    def _contact(self, tracks: Mapping[str, _Track], horizon: float) -> ArmStop | None:
        """The first moment (before ``horizon``) two shapes overlap (their gap below
        CONTACT_MM): the first sample that does, then bisected back to the moment they
        touch (within 0.1 mm of the path; the stop is that moment, the arms left at first
        contact). An arm that does not move is there too, where it stands."""
        tracks = {**{a: _Track([0.0], [list(q)]) for a, q in self.joints.items()}, **tracks}
        times = sorted({t for tr in tracks.values() for t in tr.t if t <= horizon})
        prev = 0.0
        for t in times:
            if self._gaps(tracks, t, note=True)[0] < CONTACT_MM:
                lo, hi = prev, t
                for _ in range(12):
                    mid = (lo + hi) / 2
                    lo, hi = (mid, hi) if self._gaps(tracks, mid)[0] >= CONTACT_MM else (lo, mid)
                _, arm, what = self._gaps(tracks, hi)
                return ArmStop(lo, arm, "contact", what)
            prev = t
        return None

    def _gaps(self, tracks: Mapping[str, _Track], t: float, note: bool = False
              ) -> tuple[float, str, str]:
        """The smallest gap at ``t`` (an arm to the table, the two arms), whose, and what;
        ``note``: keep the arms' gap in :attr:`closest` when it is the smallest yet."""
        arms = list(tracks)
        shapes = {a: self.models[a].capsules(self.models[a].pose(tracks[a].at(t)),
                                             self.tool_mm) for a in arms}
        best = (math.inf, arms[0], "")
        for a in arms:
            gap, k = table_gap(shapes[a])
            if gap < best[0]:
                best = (gap, a, f"arm {a}: link {k + 1} {max(gap, 0.0):.0f} mm from the table")
        if len(arms) == 2:
            gap, i, j = clearance(shapes[arms[0]], shapes[arms[1]])
            if note and gap < self.closest[0]:
                self.closest = (gap, f"{arms[0]} link {i + 1}, {arms[1]} link {j + 1}")
            if gap < best[0]:
                best = (gap, arms[0], f"arms {arms[0]} (link {i + 1}) and {arms[1]} "
                                      f"(link {j + 1}) {max(gap, 0.0):.0f} mm apart")
        return best


def _time_of(seg: Segment, f: float) -> float:
    """When (s into ``seg``) a joint move is ``f`` of the way: as the segment's own TCP
    speed profile covers that share of its length (the joints accelerate and brake with
    it, so the pusher following them arrives, not jolts to a stop at full speed)."""
    if f >= 1.0 or seg.length <= 0.0:
        return f * seg.duration
    return time_at(seg, f)


def _rot(info: Mapping[str, object]) -> Mat | None:
    """A waypoint's flange rotation (``rot``: 3x3 rows), None: the tool down."""
    r = info.get("rot")
    return None if r is None else np.asarray(r, dtype=np.float64).reshape(3, 3)


def _xyz(p: Sequence[float]) -> str:
    return "[" + ",".join(f"{float(v):.1f}" for v in p) + "]"


def _quat(r: Mat) -> tuple[float, float, float, float]:
    """A rotation matrix's unit quaternion (w, x, y, z), w >= 0."""
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = math.copysign(math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0,
                      r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0,
                      r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0,
                      r[1, 0] - r[0, 1])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    q = (w / n, x / n, y / n, z / n)
    if q[0] < 1e-6 and max(q[1:], key=abs) < 0.0:  # a half turn: one sign, not rounding's
        q = (-q[0], -q[1], -q[2], -q[3])
    return q
