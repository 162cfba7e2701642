"""Issue 43's arm-angle measurements on the driver's IRB 14000 model (docs/notes/auto-day-one.md).

Why a script: the figures that decide how the driver should resolve the YuMi's redundancy
(which arm-angle reference, one arm angle held or axis 7 held) are measured here, so that
anyone can run them again after a change to the model or the reference.

``python scripts/arm_angle_scan.py reference``: for a grid over the left table box with the
pusher down and axis 7 held at 130 (the joints the driver took before issue 43), the angle
between the
shoulder-to-wrist line and the body's up, and the one between that line and axis 1, and
the arm angle (reference as ``drivers/yumi/arm_angle.py`` has it).

``python scripts/arm_angle_scan.py hold``: for arm angles from -90 to 60 deg, how many of
51 points (5 x 5 over the shipped left box at z 10 and 80, and the gate) the left arm
reaches holding that arm angle with at least 10 deg to every joint limit and the smallest
singular value of the tip's and the arm angle's Jacobian at least 0.05.

``python scripts/arm_angle_scan.py programs SIDE PSI N``: the redundancy resolved by one
arm angle ``PSI`` held everywhere (what the driver does, ``drivers/yumi/reach.py``): the
gate solved at it by the driver's own ``ArmTool.solve``, then N push programs to random
points of the shipped table box (gate -> above the point at 80 mm -> down to 10 -> up ->
back to the gate), every line run in the driver's model at that arm angle with 3 deg to
every limit; how many run, the most a joint of axes 1, 2, 7, 3 turns on one leg, and how
far the way back ends from the gate joints (the correction joint move that would follow).
"""

from __future__ import annotations

import sys

import numpy as np

from drivers.yumi.arm_angle import _points, _tip_jacobian, arm_angle_deg, solve_with_arm_angle
from drivers.yumi.irb14000_ik import _seeds, solve_down
from drivers.yumi.reach import ArmTool
from drivers.yumi.wrist_line import _flange

PUSHER_MM = 184.2
ROOM_DEG, SIGMA = 10.0, 0.05


def reference_table() -> None:
    tool = ArmTool("left", PUSHER_MM, 130.0)
    print("x y z | deg from up | deg from axis 1 | arm angle")
    for x in (160, 310, 460):
        for y in (60, 125, 210, 300, 400):
            for z in (10, 90):
                pose = solve_down(tool.model, (x, y, z), PUSHER_MM, 130.0).pose
                if pose is None:
                    print(x, y, z, "no joints")
                    continue
                s, w, _ = _points(pose)
                e = (w - s) / np.linalg.norm(w - s)
                up = np.degrees(np.arccos(abs(e[2])))
                ax1 = np.degrees(np.arccos(abs(e @ pose.frames[0][:3, 2])))
                print(x, y, z, f"| {up:.1f} | {ax1:.1f} | {arm_angle_deg(pose):.1f}")


def hold_table() -> None:
    tool = ArmTool("left", PUSHER_MM, 130.0)
    m = tool.model
    pts = [(x, y, z) for x in (160, 235, 310, 385, 460) for y in (125, 200, 275, 350, 395)
           for z in (10, 80)] + [(310, 210, 100)]
    for psi in range(-90, 61, 10):
        good, missed = 0, []
        for p in pts:
            f = _flange(tool, p, tool.rotation)
            first = solve_down(m, p, PUSHER_MM, 130.0).pose
            seeds = ([first.chain_deg] if first is not None else []) + \
                [list(s) for s in _seeds(m, 130.0, None)[:6]]
            best = None
            for seed in seeds:
                got = solve_with_arm_angle(m, f, psi, seed, iters=60)
                if got is None or m.limit_excess(got.chain_deg) is not None:
                    continue
                room = m.limit_room(got.chain_deg)[1]
                sigma = float(np.linalg.svd(_tip_jacobian(m, got, PUSHER_MM)[1],
                                            compute_uv=False)[-1])
                score = min(room / ROOM_DEG, sigma / SIGMA)
                best = score if best is None else max(best, score)
            if best is not None and best >= 1.0:
                good += 1
            else:
                missed.append(p)
        print(f"arm angle {psi:4d}: {good} of {len(pts)}; missed {missed[:4]}")


def held_programs(side: str, psi: float, n: int) -> None:
    from drivers.yumi.paths import gate_xy
    from drivers.yumi.wrist_line import line_end, wrist_line
    from sim_twin.yumi_geometry import workspace_mm
    from testbed.lab.camera_model import push_box

    tool = ArmTool(side, PUSHER_MM, psi)
    box = push_box(workspace_mm(side))
    gate = (*gate_xy(box), 100.0)  # the shipped gate (drivers/yumi/paths.py)
    got = tool.solve(gate)
    assert got.pose is not None, f"the gate: {got.reason}"
    q0 = tuple(got.pose.chain_deg)
    room = tool.model.limit_room(q0)[1]
    print(f"gate joints {np.round(q0, 1)} ({room:.1f} deg to the nearest limit)")
    rng = np.random.default_rng(3)
    ran, travel, back, fails = 0, 0.0, 0.0, []
    for _ in range(n):
        x, y = float(rng.uniform(box[0], box[2])), float(rng.uniform(box[1], box[3]))
        q, err, leg = q0, None, 0.0
        for p in ((x, y, 80.0), (x, y, 10.0), (x, y, 80.0), gate):
            end = line_end(tool, q, p, psi)
            if end is None:
                err = f"no end at {p}"
                break
            samples, why = wrist_line(tool, q, end, psi, 3.0, 0.01)
            if why:
                err = f"{p}: {why}"
                break
            path = np.asarray([q, *samples])[:, :4]
            leg = max(leg, float(np.abs(np.diff(path, axis=0)).sum(axis=0).max()))
            q = tuple(samples[-1]) if samples else end
        if err:
            fails.append(((round(x), round(y)), err))
            continue
        ran += 1
        travel = max(travel, leg)
        back = max(back, max(abs(a - b) for a, b in zip(q, q0, strict=True)))
    print(f"{side} arm angle {psi:g}: {ran}/{n} programs run; the most a joint turns on one "
          f"leg {travel:.1f} deg; the way back ends {back:.2f} deg from the gate joints")
    for f in fails[:5]:
        print("  stops:", f)


if __name__ == "__main__":
    if sys.argv[1] == "programs":
        held_programs(sys.argv[2], float(sys.argv[3]), int(sys.argv[4]))
    else:
        {"reference": reference_table, "hold": hold_table}[sys.argv[1]]()
