"""The YuMi cell's layout against the arm's kinematics: one FAULT line per thing to fix.

Why: a table box whose far corner the arm cannot reach with the pusher down, a rest pose
under the world zone's ceiling (every move to rest stops on the zone), in the camera's
view (every picture is retaken) or against the other arm, and two arms whose paths meet,
all pass every check that reads numbers alone and stop the robot on day one. This module
puts the calibration's numbers through the arm's model (``drivers/yumi/irb14000.py``)
for ``testbed check`` (``drivers/yumi/check_report.py``) and ``testbed calibrate`` (the
plugin's ``layout_report``), and words what it finds in the style of the controller's
FAULT lines: what, the number, what to change.

Margins (mm): every corner :data:`~drivers.yumi.reach.REACH_MARGIN_MM` inside the
reach; the rest pose's pusher tip :data:`ZONE_MARGIN_MM` above ``tb_zone_z``; the two
arms' shapes :data:`ARM_GAP_MM` apart over both sweeps; every link and the gripper
:data:`TABLE_GAP_MM` above the table; the pusher's tip and the links
:data:`PATH_MARGIN_MM` (on a joint move :data:`JOINT_MARGIN_MM`) clear of the world
zones (below ``tb_zone_z`` outside the zone box, and below ``tb_floor_z``, as the
controller reports them) along every path the
driver commands (``drivers/yumi/paths.py``): rest by joints to the gate joints, straight
to above each corner of the table box at travel height, down to push height, and back
up, straight to the gate's point, by joints to the gate joints (the correction) and to
rest; and the correction from every solution of the gate's pose the lines may arrive in
(``drivers/yumi/gate.py``). A joint move is swept as the controller interpolates it
(every joint linearly, all together, between two known joint vectors), a straight move
as a line. The gate joints themselves must be in the file (``gate_joints_deg``) and put
the pusher's tip over the table box at clear height.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, is_dataclass
from typing import Any, Final

import numpy as np

from drivers.yumi.arm_shapes import Capsules, arm_capsules, min_distance, table_clearance
from drivers.yumi.gate import GATE_HOW, gate_problem, gate_solutions
from drivers.yumi.irb14000 import Pose
from drivers.yumi.path_sweep import Sample, Worst, ZoneSpec, joint_move, play, worst
from drivers.yumi.paths import DEFAULT_Z_CLEAR_MM, gate_xy, leave_rest, to_rest
from drivers.yumi.reach import (
    REACH_MARGIN_MM,
    ArmTool,
    CornerReach,
    box_corners,
    corner_reaches,
    default_arm_angle,
    side_of,
)
from drivers.yumi.yumi_controller import Waypoint

__all__ = ["ARM_GAP_MM", "JOINT_MARGIN_MM", "PATH_MARGIN_MM", "TABLE_GAP_MM",
           "ZONE_MARGIN_MM", "ArmLayout", "check_layout", "layout_of"]

ZONE_MARGIN_MM: Final = 20.0
ARM_GAP_MM: Final = 25.0
TABLE_GAP_MM: Final = 5.0
VIEW_MARGIN: Final = 0.02
"""A point this share of the frame outside its edge still counts as in view (as the
driver's retake rule, ``drivers/yumi/backend.py``)."""
PATH_MARGIN_MM: Final = 10.0
"""How close the tip or a link may come to a world zone along a commanded straight move
(a line the controller follows as programmed: the table box lies 25 mm inside the
shipped zone box)."""
JOINT_MARGIN_MM: Final = ZONE_MARGIN_MM
"""How close along a joint move (rest to the gate and back): a curve nobody programs,
whose model is a few mm off the robot, keeps the margin the clear height has over
``tb_zone_z`` (20 mm)."""


@dataclass(frozen=True)
class ArmLayout:
    """What the checks need of one arm (from its calibration and the controller)."""

    name: str
    tool: ArmTool
    table_box_mm: tuple[float, float, float, float]
    z_push_mm: float
    z_travel_mm: float
    rest_joints_deg: tuple[float, ...] | None = None
    homography: Any = None
    """pixel -> table mm (3x3) of the calibration, or None (not calibrated yet)."""
    frame_size: tuple[int, int] | None = None
    zone_z_mm: float | None = None
    """``tb_zone_z`` of the arm's task, as the controller reports it."""
    z_clear_mm: float = DEFAULT_Z_CLEAR_MM
    gate_xy_mm: tuple[float, float] | None = None
    zone_box_mm: tuple[float, float, float, float] | None = None
    """(x0, y0, x1, y1) of ``tb_zone_lo``/``tb_zone_hi``, as the controller reports them."""
    floor_z_mm: float | None = None
    gate_joints_deg: tuple[float, ...] | None = None
    """The calibration's gate joints (ABB's order), None: not measured yet."""

    @property
    def gate(self) -> tuple[float, float]:
        return gate_xy(self.table_box_mm, self.gate_xy_mm)

    @property
    def gate_xyz(self) -> tuple[float, float, float]:
        return (*self.gate, self.z_clear_mm)


def layout_of(name: str, cal: Mapping[str, Any], *, task: str | None = None,
              frame_size: Sequence[int] | None = None, zone_z_mm: float | None = None,
              zones: Mapping[str, Any] | None = None, tool_z_mm: float | None = None
              ) -> ArmLayout | None:
    """An arm's layout from its calibration file's keys; None when its side cannot be
    told (a task that is not an IRB 14000's, an arm not named left/right) or its tool is
    not known. ``tool_z_mm``: the controller's ``tool_pusher`` (used before the file's:
    the robot moves with the controller's); ``zones``: the task's zone constants as
    :func:`~drivers.yumi.controller_state.rapid_of_task` reads them."""
    side = side_of(name, task or cal.get("task"))
    tool_z = tool_z_mm if tool_z_mm is not None else cal.get("tool_z_mm")
    if side is None or "table_box_mm" not in cal or tool_z is None:
        return None
    tool = ArmTool(side, float(tool_z),
                   float(cal.get("arm_angle_deg", default_arm_angle(side))),
                   tuple(float(v) for v in cal.get("tool_quat_wxyz", (0, 0, 1, 0))))
    rest = cal.get("rest_joints_deg")
    z = dict(zones or {})
    lo, hi = z.get("tb_zone_lo"), z.get("tb_zone_hi")
    if zone_z_mm is None and z.get("tb_zone_z") is not None:
        zone_z_mm = float(z["tb_zone_z"])
    gate = cal.get("gate_xy_mm")
    gate_joints = cal.get("gate_joints_deg")
    return ArmLayout(name, tool, tuple(float(v) for v in cal["table_box_mm"]),  # type: ignore[arg-type]
                     float(cal.get("z_push_mm", 10.0)), float(cal.get("z_travel_mm", 80.0)),
                     None if rest is None else tuple(float(v) for v in rest),
                     cal.get("homography"),
                     None if frame_size is None else (int(frame_size[0]), int(frame_size[1])),
                     zone_z_mm, float(cal.get("z_clear_mm", DEFAULT_Z_CLEAR_MM)),
                     None if gate is None else (float(gate[0]), float(gate[1])),
                     None if lo is None or hi is None else (float(lo[0]), float(lo[1]),
                                                            float(hi[0]), float(hi[1])),
                     None if z.get("tb_floor_z") is None else float(z["tb_floor_z"]),
                     None if gate_joints is None else tuple(float(v) for v in gate_joints))


def _pt(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:.0f}" for v in p) + ")"


def reach_lines(lay: ArmLayout, reaches: Sequence[CornerReach]) -> tuple[list[str], list[str]]:
    """One report line with every corner's margin; a FAULT reason per corner short of it."""
    t = lay.tool
    how = (f"pusher down, tool_z_mm {t.tool_z_mm:g}, arm angle {t.arm_angle_deg:g} deg")
    figures = ", ".join(f"{_pt(c.tcp_mm)} {'-' if c.margin_mm is None else f'{c.margin_mm:.0f}'}"
                        for c in reaches)
    lines = [f"      {lay.name}: reach margin (mm) of the table box's corners at push "
             f"and travel height ({how}): {figures}"]
    faults = []
    for c in reaches:
        where = (f"arm {lay.name}: table box corner {_pt(c.tcp_mm)} mm "
                 f"({_height_name(lay, c.tcp_mm[2])} height)")
        if c.margin_mm is None:
            faults.append(f"{where} cannot be reached with the {how}: {c.solution.reason}; "
                          f"move the table box towards the shoulder or change the "
                          f"calibration's arm_angle_deg")
        elif c.margin_mm < REACH_MARGIN_MM:
            faults.append(f"{where} is only {c.margin_mm:.0f} mm inside the arm's reach "
                          f"(want {REACH_MARGIN_MM:g} mm) with the {how}; move the table box "
                          f"towards the shoulder")
    return lines, faults


def _height_name(lay: ArmLayout, z: float) -> str:
    return {lay.z_push_mm: "push", lay.z_travel_mm: "travel"}.get(z, "clear")


def rest_pose(lay: ArmLayout) -> Pose | None:
    return None if lay.rest_joints_deg is None else lay.tool.model.pose_abb(lay.rest_joints_deg)


def rest_faults(lay: ArmLayout, pose: Pose) -> list[str]:
    """The rest pose: within the joint limits, its pusher tip above ``tb_zone_z`` by the
    margin, clear of the table, out of the camera's view."""
    out: list[str] = []
    tip = pose.tcp(lay.tool.tool_z_mm)
    what = (f"arm {lay.name}: the rest pose (rest_joints_deg {list(lay.rest_joints_deg or ())}, "
            f"tool_z_mm {lay.tool.tool_z_mm:g})")
    if (over := lay.tool.model.limit_excess(pose.chain_deg)) is not None:
        out.append(f"{what} has axis {over[0]} past its limit by {over[1]:.1f} deg")
    if lay.zone_z_mm is not None and tip[2] < lay.zone_z_mm + ZONE_MARGIN_MM:
        out.append(f"{what} puts the pusher's tip at z {tip[2]:.0f} mm, below the world "
                   f"zone's tb_zone_z {lay.zone_z_mm:g} + {ZONE_MARGIN_MM:g} mm: every move "
                   f"to rest would stop on the zone; choose rest joints that hold the tip "
                   f"higher (robot/README.md)")
    low, part = table_clearance(arm_capsules(pose, lay.tool.tool_z_mm))
    if low < TABLE_GAP_MM:
        out.append(f"{what} puts its {part} {low:.0f} mm above the table (want "
                   f"{TABLE_GAP_MM:g} mm)")
    if (seen := in_view(lay, pose)) is not None:
        out.append(f"{what} is in the camera's view: its {seen}; every picture would be "
                   f"retaken; move the rest pose out of the view")
    return out


def in_view(lay: ArmLayout, pose: Pose) -> str | None:
    """Which of the pusher's tip and the flange the calibrated camera sees, or None.
    Each point is mapped at its (x, y) through the calibration's homography, which holds
    in the cube-top plane; a point higher up is seen further from the picture's centre
    by a downward camera, so "outside" here is outside for it too."""
    if lay.homography is None or lay.frame_size is None:
        return None
    h = np.asarray(lay.homography, dtype=np.float64)
    w, ht = lay.frame_size
    for name, p in (("pusher's tip", pose.tcp(lay.tool.tool_z_mm)),
                    ("flange", pose.flange[:3, 3])):
        u, v, s = np.linalg.solve(h, np.array([p[0], p[1], 1.0]))
        if s <= 0:
            continue
        u, v = u / s, v / s
        if -VIEW_MARGIN * w <= u <= (1 + VIEW_MARGIN) * w and \
                -VIEW_MARGIN * ht <= v <= (1 + VIEW_MARGIN) * ht:
            return f"{name} at ({p[0]:.0f}, {p[1]:.0f}, {p[2]:.0f}) mm is seen at pixel " \
                   f"({u:.0f}, {v:.0f}) of the {w}x{ht} frame"
    return None


def corner_programs(lay: ArmLayout, gate_joints: Sequence[float], speed: float = 100.0
                    ) -> list[tuple[str, list[Waypoint]]]:
    """The driver's program to each corner of the table box and back, as it writes a
    push's (``drivers/yumi/backend.py``, ``plan_push``): from rest by joints to the gate
    joints, straight to above the corner at travel height, down to push height, up,
    straight to the gate's point, by joints to the gate joints and to rest
    (``drivers/yumi/paths.py``)."""
    out = []
    for c in box_corners(lay.table_box_mm, lay.z_push_mm):
        xy = c[:2]
        out.append((f"to corner {_pt(xy)} and back: ", [
            *leave_rest(gate_joints, xy, lay.z_travel_mm, speed),
            Waypoint("move_l", (*xy, lay.z_push_mm), speed),
            Waypoint("move_l", (*xy, lay.z_travel_mm), speed),
            *to_rest(lay.gate, gate_joints, lay.z_clear_mm, speed)]))
    return out


def gate_faults(lay: ArmLayout) -> list[str]:
    """The gate joints: in the file, and at the gate (within the joint limits, the
    pusher's tip over the table box at clear height: ``drivers/yumi/gate.py``)."""
    if lay.gate_joints_deg is None:
        return [f"arm {lay.name}: its calibration has no 'gate_joints_deg' (the gate's "
                f"joints, the end of the joint move from rest): the driver moves the arm "
                f"nowhere; {GATE_HOW}"]
    why = gate_problem(lay.tool, lay.gate_joints_deg, lay.gate_xyz, lay.table_box_mm)
    return [] if why is None else [f"arm {lay.name}: {why}: every program would be "
                                   f"refused; {GATE_HOW}"]


def corrections(lay: ArmLayout, gate_chain: Sequence[float],
                arm_angles: Sequence[float] | None = None) -> list[Sample]:
    """The correction at the gate from every solution of the gate's pose within the joint
    limits at ``arm_angles`` (default the gate joints' own, the one the driver's lines
    back to the gate's point carry where they can: ``drivers/yumi/line_plan.py``;
    ``drivers/yumi/gate.py``) to the gate joints: whichever the controller's lines back
    to the gate's point arrive in. (A line back at another arm angle, where the gate's
    own cannot be held, ends where its plan says: its correction is swept with its
    program.)"""
    out: list[Sample] = []
    for k, q in enumerate(gate_solutions(lay.tool, lay.gate_xyz, gate_chain, arm_angles), 1):
        out += joint_move(lay.tool, q, gate_chain,
                          f"the correction at the gate from its pose's solution {k} "
                          f"({_pt(lay.tool.model.pose(q).abb_deg)} deg): joint move to "
                          f"the gate joints")
    return out


def path_checks(lay: ArmLayout, rest: Pose) -> tuple[list[str], list[str], list[Pose]]:
    """(report lines, FAULT reasons, sampled poses) of the driver's paths to every
    corner (:func:`corner_programs`) played through the model
    (``drivers/yumi/path_sweep.py``), and of the correction at the gate from every
    solution of its pose (:func:`corrections`): the tip and the links against the zones
    the controller reports (the joint moves :data:`JOINT_MARGIN_MM` clear, the straight
    ones :data:`PATH_MARGIN_MM`), the links above the table. Needs the gate joints
    (:func:`gate_faults` says when they are missing or wrong)."""
    assert lay.gate_joints_deg is not None
    zones = ZoneSpec(lay.zone_box_mm, lay.zone_z_mm, lay.floor_z_mm)
    faults: list[str] = []
    poses: list[Pose] = []
    least: dict[str, Worst] = {}  # each part of the paths (:data:`PARTS`) apart
    gate_chain = lay.tool.model.pose_abb(lay.gate_joints_deg).chain_deg
    runs = [(label, *play(lay.tool, rest.chain_deg, lay.rest_joints_deg, wps, label))
            for label, wps in corner_programs(lay, lay.gate_joints_deg)]
    runs.append(("the correction at the gate: ", corrections(lay, gate_chain), None))
    for label, samples, err in runs:
        poses += [smp.pose for smp in samples[::4]]
        if err is not None:
            faults.append(f"arm {lay.name}: the driver's path {label}cannot be made: {err}; "
                          f"move the gate (gate_xy_mm), lower z_clear_mm or shrink the "
                          f"table box")
            continue
        for part in PARTS:
            w = worst([smp for smp in samples if part_of(smp.leg) == part], lay.tool, zones)
            if w is not None and (part not in least or w.clearance < least[part].clearance):
                least[part] = w
        low = min((table_clearance(arm_capsules(smp.pose, lay.tool.tool_z_mm))
                   for smp in samples[::4]), default=None)
        if low is not None and low[0] < TABLE_GAP_MM:
            faults.append(f"arm {lay.name}: on the path {label}its {low[1]} comes {low[0]:.0f} "
                          f"mm above the table (want {TABLE_GAP_MM:g} mm)")
    g = lay.gate
    how = (f"rest by joints to the gate ({g[0]:.0f}, {g[1]:.0f}, {lay.z_clear_mm:g}), "
           f"straight to every corner at travel height and down, back the same way, the "
           f"correction at the gate from each of its pose's solutions")
    if not least or all(math.isinf(w.clearance) for w in least.values()):
        return [f"      {lay.name}: paths ({how}): the zones were not read, not swept"
                ], faults, poses
    lines = [f"      {lay.name}: paths ({how}): least clearance to the world zones: " + "; ".join(
        f"on {part} {least[part].clearance:.0f} mm, the {least[part].part} at "
        f"{_pt(least[part].point)} mm ({least[part].leg})" for part in PARTS if part in least)]
    for part in PARTS:
        if part not in least:
            continue
        w = least[part]
        want = PATH_MARGIN_MM if part == STRAIGHT else JOINT_MARGIN_MM
        if w.clearance < want:
            where = ("inside" if w.clearance < 0 else "from")
            faults.append(f"arm {lay.name}: on the driver's path {w.leg}, its {w.part} comes "
                          f"to {_pt(w.point)} mm, {abs(w.clearance):.0f} mm {where} a world "
                          f"zone (below tb_zone_z {lay.zone_z_mm:g} outside the zone box, or "
                          f"below the floor; want {want:g} mm clear): a zone stop; move the "
                          f"gate (gate_xy_mm) or change the rest joints")
    return lines, faults, poses


STRAIGHT: Final = "the straight moves"
PARTS: Final = ("the joint moves from rest", "the correction at the gate",
                "the joint moves back to rest", STRAIGHT)
"""The parts of the driver's paths whose least clearance is reported (and FAULTed) each
on its own: the way out, the correction, the way back and the straight legs."""


def part_of(leg: str) -> str:
    """Which of :data:`PARTS` a sample's leg is on (``drivers/yumi/path_sweep.py`` and
    :func:`corrections` name the legs)."""
    if "joint move" not in leg:
        return STRAIGHT
    if "correction" in leg:
        return PARTS[1]
    return PARTS[2] if "joint move to rest" in leg else PARTS[0]


def sweep(lay: ArmLayout, reaches: Sequence[CornerReach], paths: Sequence[Pose] = ()
          ) -> Capsules:
    """The arm's shapes over its work: every reachable corner's pose, the rest pose, and
    the poses along the driver's paths (:func:`path_checks`)."""
    poses = [c.solution.pose for c in reaches if c.solution.pose is not None]
    rest = rest_pose(lay)
    if rest is not None:
        poses = [rest, *poses]
    return Capsules.join([arm_capsules(p, lay.tool.tool_z_mm) for p in [*poses, *paths]])


def check_layout(arms: Sequence[ArmLayout]) -> tuple[list[str], list[str]]:
    """(report lines, FAULT reasons) of one YuMi's arms: each arm's reach, rest pose,
    table clearance and paths against the zones; with two arms, their rests and their
    sweeps apart.

    A pure function of the layouts, kept for the last few asked (:data:`KEPT_CHECKS`):
    a process asks it again of the same arms at every run's start (``testbed check``,
    a trial's preflight, each run of a protocol or a rehearsal) and at every arm's
    calibration, and one check costs seconds of inverse kinematics."""
    key = tuple(_key_of(lay) for lay in arms)
    kept = _KEPT.get(key)
    if kept is None:
        kept = _check_layout(arms)
        if len(_KEPT) >= KEPT_CHECKS:
            del _KEPT[next(iter(_KEPT))]
        _KEPT[key] = kept
    return list(kept[0]), list(kept[1])


KEPT_CHECKS: Final = 8
"""How many layouts' checks a process keeps (a lab's hosts: one YuMi each)."""
_KEPT: dict[tuple[object, ...], tuple[tuple[str, ...], tuple[str, ...]]] = {}


def _frozen(value: Any) -> Any:
    """``value`` made hashable with every digit kept (a homography's array or lists)."""
    if isinstance(value, np.ndarray):
        return _frozen(value.tolist())
    if is_dataclass(value) and not isinstance(value, type):
        return (type(value).__name__, _key_of(value))
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _key_of(lay: Any) -> tuple[object, ...]:
    """A dataclass's fields, each :func:`_frozen` (an arm's layout, its tool)."""
    return tuple((f.name, _frozen(getattr(lay, f.name))) for f in fields(lay))


def _check_layout(arms: Sequence[ArmLayout]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    lines: list[str] = []
    faults: list[str] = []
    sweeps: dict[str, Capsules] = {}
    rests: dict[str, Capsules] = {}
    for lay in arms:
        reaches = corner_reaches(lay.tool, lay.table_box_mm,  # clear height: at the gate
                                 (lay.z_push_mm, lay.z_travel_mm))  # only (the paths')
        got, bad = reach_lines(lay, reaches)
        lines += got
        faults += bad
        paths: list[Pose] = []
        if (rest := rest_pose(lay)) is not None:
            faults += rest_faults(lay, rest)
            rests[lay.name] = arm_capsules(rest, lay.tool.tool_z_mm)
            gate_bad = gate_faults(lay)
            faults += gate_bad
            if not gate_bad:
                got, bad, paths = path_checks(lay, rest)
                lines += got
                faults += bad
        sweeps[lay.name] = sweep(lay, reaches, paths)
    if len(arms) == 2:
        a, b = arms[0].name, arms[1].name
        got, bad = _apart(a, b, rests, sweeps)
        lines += got
        faults += bad
    return tuple(lines), tuple(faults)


def _apart(a: str, b: str, rests: Mapping[str, Capsules], sweeps: Mapping[str, Capsules]
           ) -> tuple[list[str], list[str]]:
    lines: list[str] = []
    faults: list[str] = []
    if a in rests and b in rests:
        gap, pa, pb = min_distance(rests[a], rests[b])
        lines.append(f"      {a}/{b}: rest poses {gap:.0f} mm apart ({pa} / {pb})")
        if gap < ARM_GAP_MM:
            faults.append(f"arms {a} and {b}: at rest their {pa} and {pb} are {gap:.0f} mm "
                          f"apart (want {ARM_GAP_MM:g} mm): choose rest joints clear of "
                          f"the other arm")
    gap, pa, pb = min_distance(sweeps[a], sweeps[b])
    lines.append(f"      {a}/{b}: swept volumes (rest, table box corners, the driver's paths "
                 f"to them) {gap:.0f} mm apart ({pa} / {pb})")
    if gap < ARM_GAP_MM:
        faults.append(f"arms {a} and {b}: on their way between rest and their table boxes "
                      f"their {pa} and {pb} come {gap:.0f} mm close (want {ARM_GAP_MM:g} mm): "
                      f"move the table boxes apart or the rest poses")
    return lines, faults
