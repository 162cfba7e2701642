"""Every move at most as fast as its speeddata allows, joint moves included: the twin's
reading of how the controller times a move.

Why: speeddata has no per-axis speed. A move takes as long as its slowest component
needs: the TCP at ``v_tcp`` (at most VelSet's Max), the tool's reorientation at
``v_ori``, the rotational external axis (the YuMi's axis 7, the arm angle) at ``v_reax``
(Technical reference manual - RAPID Instructions, Functions and Data types, speeddata).
The twin's arm supervision times a move along the straight chord between its ends at
the chord speed; the TCP of a joint move follows the joints' curve, which is longer than
the chord, and a move whose ends coincide (the arm angle or the tool turned on the spot)
took no time at all. So a file within every cap could move an arm faster than the caps,
on the twin, where the controller would not (issue 43: the caps are the cell's).

How (:func:`within_speeds`): the arms' check gives each move's joint samples; a move's
geometry (the joints as a function of the share of the way, ``f``) does not depend on its
timing, so the largest rate per unit of ``f`` of each component (the tool's TCP for a
joint move, the flange's turn and axis 7 for every move) says how fast the move may run:
its chord speed is lowered to ``cap * chord / rate`` for the component that needs it
most (a move on the spot is given a duration instead), and the arms check the slower
moves again. A MoveL's TCP is the cell's straight line at the chord speed, already
within ``v_tcp``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from sim_twin.constants import TIME_STEP_S
from sim_twin.rws.arm_supervision import ArmStop, ArmSupervisor
from sim_twin.yumi_cell import PathSegment, Segment, Trajectory

Waypoint = dict[str, Any]
Programs = Mapping[str, Sequence[Waypoint]]
ON_THE_SPOT_MM = 1e-6
"""A move whose chord is shorter than this has no chord speed to lower: it gets a time."""
NOMINAL_S = 1.0
"""The duration a move on the spot is sampled over in the first check. It keeps at
least one physics step (:data:`~sim_twin.constants.TIME_STEP_S`) when nothing turns: a
move of no duration put its joint samples at the previous move's end time, whose
path then ran back in time (the cell refused it: "path times must increase")."""
MARGIN = 0.995
"""The slowed speed is this share of the bound, for the small changes of a MoveL's
samples (their count follows the speed) between the two checks."""
AXIS_7 = 2
"""The arm angle's index in the chain's joint order (sim_twin.yumi_arms)."""
JOINT_KINDS = ("move_j", "rest")


def _turn_deg(r0: np.ndarray, r1: np.ndarray) -> float:
    """The angle (deg) of the rotation from ``r0`` to ``r1``."""
    c = (float(np.trace(r0.T @ r1)) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _fraction(seg: Segment | PathSegment, t: float) -> float:
    """How far along its chord ``seg`` is ``t`` s into it (0..1); a move on the spot
    (a timed path) is linear in time."""
    if seg.length < ON_THE_SPOT_MM:
        return min(1.0, t / seg.duration) if seg.duration > 0.0 else 1.0
    return min(1.0, math.dist(seg.a, seg.at(t)) / seg.length)


def _rates(arms: ArmSupervisor, arm: str, tool: Sequence[float], seg: Segment | PathSegment,
           samples: Sequence[tuple[float, Sequence[float]]], joint: bool
           ) -> dict[str, float]:
    """The largest rate per unit of ``f`` (mm, deg) of the TCP of the tool in use (joint
    moves only), the flange's turn and axis 7 over ``samples`` ((t from the move's start,
    chain joints), the first at the move's start)."""
    model = arms.models[arm]
    out = {"tcp": 0.0, "ori": 0.0, "reax": 0.0}
    prev_f, prev_q = 0.0, samples[0][1]
    prev_r = model.pose(prev_q).flange[:3, :3]
    prev_p = arms.tool_point(arm, prev_q, tool)
    for t, q in samples[1:]:
        f = _fraction(seg, t)
        r = model.pose(q).flange[:3, :3]
        p = arms.tool_point(arm, q, tool)
        df = f - prev_f
        if df > 1e-12:
            moved = {"tcp": math.dist(p, prev_p) if joint else 0.0,
                     "ori": _turn_deg(prev_r, r), "reax": abs(q[AXIS_7] - prev_q[AXIS_7])}
            for k, d in moved.items():
                out[k] = max(out[k], d / df)
        prev_f, prev_q, prev_r, prev_p = f, q, r, p
    return out


def _caps(wp: Waypoint) -> dict[str, float]:
    """The waypoint's bounds: ``speed_mm_s`` (the TCP's, VelSet and the speed ratio
    applied), ``v_ori_deg_s``, ``v_reax_deg_s`` (absent or not above 0: no bound)."""
    caps = {"tcp": float(wp["speed_mm_s"]), "ori": float(wp.get("v_ori_deg_s", 0.0)),
            "reax": float(wp.get("v_reax_deg_s", 0.0))}
    return {k: v for k, v in caps.items() if v > 0.0}


def _on_the_spot(programs: Programs, trajs: Mapping[str, Trajectory]
                 ) -> dict[str, list[Waypoint]] | None:
    """Every move on the spot given :data:`NOMINAL_S` (a timed path to its end), so that
    the arms' check samples its turn over time; None when there is none."""
    out, changed = {}, False
    for arm, wps in programs.items():
        new = []
        for wp, seg in zip(wps, trajs[arm].segments, strict=False):
            if seg.length < ON_THE_SPOT_MM and "path" not in wp:
                wp = {**wp, "path": [(NOMINAL_S, list(seg.b))]}
                changed = True
            new.append(wp)
        out[arm] = new + list(wps[len(new):])
    return out if changed else None


def _slowed(programs: Programs, trajs: Mapping[str, Trajectory], tracks: Mapping[str, Any],
            arms: ArmSupervisor, tools: Mapping[str, Sequence[float]]
            ) -> dict[str, list[Waypoint]] | None:
    """The programs with every move that would exceed a bound slowed to it (a move on
    the spot: timed to it, one physics step when nothing turns); None if none would."""
    out, changed = {}, False
    for arm, wps in programs.items():
        track, segs = tracks.get(arm), trajs[arm].segments
        new = list(wps)
        if track is None or not track.t:
            out[arm] = new
            continue
        ends = [0.0, *track.ends]
        i = 0
        for k, (wp, seg) in enumerate(zip(wps, segs, strict=False)):
            t0 = ends[k] if k < len(ends) else math.inf
            t1 = ends[k + 1] if k + 1 < len(ends) else math.inf
            if t0 == math.inf:
                break
            while i + 1 < len(track.t) and track.t[i + 1] <= t0 + 1e-12:
                i += 1
            samples = [(0.0, track.q[i])]
            j = i + 1
            while j < len(track.t) and track.t[j] <= t1 + 1e-9:
                samples.append((track.t[j] - t0, track.q[j]))
                j += 1
            caps = _caps(wp)
            if len(samples) < 2 or not caps:
                continue
            rates = _rates(arms, arm, tools.get(arm, (0.0, 0.0, arms.tool_mm)), seg, samples,
                           wp.get("kind") in JOINT_KINDS)
            need = {c: rates[c] for c in caps if rates[c] > 0.0}
            if seg.length < ON_THE_SPOT_MM:
                duration = max((r / caps[c] for c, r in need.items()), default=0.0) / MARGIN
                timed = {**wp, "path": [(max(duration, TIME_STEP_S), list(seg.b))]}
                changed = changed or timed != wp
                new[k] = timed
                continue
            bound = min((caps[c] * seg.length / r for c, r in need.items()), default=math.inf)
            if bound < float(wp["speed_mm_s"]):
                new[k] = {**wp, "speed_mm_s": bound * MARGIN}
                changed = True
        out[arm] = new
    return out if changed else None


def within_speeds(programs: Programs, trajs: Mapping[str, Trajectory],
                  plan: Callable[[Programs], dict[str, Trajectory]], arms: ArmSupervisor,
                  tools: Mapping[str, Sequence[float]]
                  ) -> tuple[Programs, dict[str, Trajectory], ArmStop | None, dict[str, Any]]:
    """The arms' check of ``programs`` (planned as ``trajs``; ``plan`` plans others),
    each move first slowed to its speeddata's bounds (the module's docstring): the
    programs, their trajectories, the first stop and the tracks, as the motion runs."""
    trajs = dict(trajs)
    timed = _on_the_spot(programs, trajs)
    if timed is not None:
        programs, trajs = timed, plan(timed)
    stop, tracks = arms.check(trajs, programs)
    slow = _slowed(programs, trajs, tracks, arms, tools)
    if slow is not None:
        programs, trajs = slow, plan(slow)
        stop, tracks = arms.check(trajs, programs)
    return programs, trajs, stop, tracks
