"""Issue 43's arm-angle measurements on the driver's IRB 14000 model (docs/notes/auto-day-one.md).

Why a script: the figures that decide how the driver should resolve the YuMi's redundancy
(which arm-angle reference, one arm angle held or axis 7 held) are measured here, so that
anyone can run them again after a change to the model or the reference.

``python scripts/arm_angle_scan.py reference``: for a grid over the left table box with the
pusher down and axis 7 held at 130 (the driver's joints), the angle between the
shoulder-to-wrist line and the body's up, and the one between that line and axis 1, and the
arm angle (reference as ``drivers/yumi/arm_angle.py`` has it).

``python scripts/arm_angle_scan.py hold``: for arm angles from -90 to 60 deg, how many of
51 points (5 x 5 over the shipped left box at z 10 and 80, and the gate) the left arm
reaches holding that arm angle with at least 10 deg to every joint limit and the smallest
singular value of the tip's and the arm angle's Jacobian at least 0.05.
"""

from __future__ import annotations

import sys

import numpy as np

from drivers.yumi.arm_angle import _points, _tip_jacobian, arm_angle_deg, solve_with_arm_angle
from drivers.yumi.irb14000_ik import _seeds
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
                pose = tool.solve((x, y, z)).pose
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
            first = tool.solve(p).pose
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


if __name__ == "__main__":
    {"reference": reference_table, "hold": hold_table}[sys.argv[1]]()
