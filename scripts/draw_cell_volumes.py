"""Draw the YuMi cell's volumes for docs/safety.md, "People in the cell": docs/cell-volumes.png.

Why a script: the swing volume (where the pusher's tip and the links go on the joint moves
between rest and the gate) is not a shape anyone can guess from the room; it comes from
the driver's own arm model and the paths it sends (drivers/yumi/paths.py), for the
shipped layout (the twin's workspaces, the shipped zones of robot/rapid/TestbedTask_L.mod
and _R.mod). A lab with another layout runs it with its own calibration files.

    .venv/bin/python scripts/draw_cell_volumes.py [--out docs/cell-volumes.png]
        [--calibration left=FILE --calibration right=FILE]

It prints the swing's extent (the farthest the tip and the links reach from the robot's
centre line, and their height there), the figures docs/safety.md quotes.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ZONES = {"left": ((125.0, 25.0), (495.0, 395.0)), "right": ((125.0, -395.0), (495.0, -25.0))}
"""The shipped zone boxes (tb_zone_lo, tb_zone_hi) of robot/rapid/TestbedTask_L.mod / _R.mod."""
ZONE_Z, CLEAR_Z = 80.0, 100.0
TABLE = (0.0, -480.0, 680.0, 480.0)
"""The hardware twin's table top (x0, y0, x1, y1) mm: sim_twin/yumi_geometry.py."""


def shipped_calibration(arm: str) -> dict[str, Any]:
    """The calibration a lab with the shipped layout writes (testbed/lab/camera_model.py)."""
    from drivers.yumi.gate import calibration_gate_joints
    from sim_twin.yumi_geometry import workspace_mm
    from testbed.lab.camera_model import arm_facts, push_box

    cal: dict[str, Any] = {"table_box_mm": push_box(workspace_mm(arm)), **arm_facts(arm)}
    cal["gate_joints_deg"] = calibration_gate_joints(arm, cal)
    return cal


def swing(arm: str, cal: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The tip's points and every link capsule's end points on the joint moves rest ->
    gate -> rest, as the layout check plays them (drivers/yumi/path_sweep.py)."""
    from drivers.yumi.arm_calibration import ArmCalibration
    from drivers.yumi.arm_shapes import arm_capsules
    from drivers.yumi.gate import arm_tool
    from drivers.yumi.path_sweep import joint_move

    c = ArmCalibration.from_dict({"homography": np.eye(3).tolist(), **cal}, arm)
    tool = arm_tool(arm, c)
    assert tool is not None and c.pose is not None
    rest = tool.model.pose_abb(c.pose.rest_joints_deg).chain_deg
    gate = tool.model.pose_abb(cal["gate_joints_deg"]).chain_deg
    samples = joint_move(tool, rest, gate, "out") + joint_move(tool, gate, rest, "back")
    tips = np.array([s.tip for s in samples])
    links = []
    for s in samples:
        caps = arm_capsules(s.pose, float(cal["tool_z_mm"]))
        links += [*caps.a, *caps.b]
    return tips, np.array(links)


def draw(out: Path, cals: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The figure (top view and side view) and the lines it prints."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig, (top, side) = plt.subplots(1, 2, figsize=(12, 6.5))
    t0, t1 = (TABLE[0], TABLE[1]), (TABLE[2] - TABLE[0], TABLE[3] - TABLE[1])
    top.add_patch(Rectangle(t0, *t1, fill=False, ec="0.4", lw=1, label="table"))
    lines = []
    for arm, cal in cals.items():
        tips, links = swing(arm, cal)
        colour = "tab:blue" if arm == "left" else "tab:orange"
        (zx0, zy0), (zx1, zy1) = ZONES[arm]
        top.add_patch(Rectangle((zx0, zy0), zx1 - zx0, zy1 - zy0, fill=False, ec=colour, ls="--",
                                label=f"{arm}: zone box (below z {ZONE_Z:g})"))
        bx0, by0, bx1, by1 = cal["table_box_mm"]
        top.add_patch(Rectangle((bx0, by0), bx1 - bx0, by1 - by0, color=colour, alpha=0.25,
                                label=f"{arm}: table box (collaborative workspace)"))
        top.scatter(links[:, 0], links[:, 1], s=2, color=colour, alpha=0.15)
        top.plot(tips[:, 0], tips[:, 1], color=colour, lw=2, label=f"{arm}: tip, rest <-> gate")
        side.scatter(links[:, 0], links[:, 2], s=2, color=colour, alpha=0.15)
        side.plot(tips[:, 0], tips[:, 2], color=colour, lw=2)
        far = int(np.argmax(np.abs(tips[:, 1])))
        lfar = int(np.argmax(np.abs(links[:, 1])))
        lines.append(f"{arm}: swing tip out to |y| {abs(tips[far, 1]):.0f} mm at z "
                     f"{tips[far, 2]:.0f}, x {tips[far, 0]:.0f}; links to |y| "
                     f"{abs(links[lfar, 1]):.0f} mm; tip x {tips[:, 0].min():.0f}.."
                     f"{tips[:, 0].max():.0f}, z {tips[:, 2].min():.0f}..{tips[:, 2].max():.0f}")
    side.axhline(ZONE_Z, color="0.3", ls="--", lw=1, label=f"tb_zone_z {ZONE_Z:g}")
    side.axhline(CLEAR_Z, color="0.3", ls=":", lw=1, label=f"clear height {CLEAR_Z:g}")
    side.axhline(0.0, color="0.4", lw=1, label="table top")
    top.set(title="Top view (world frame, mm): swing volume = the dots", xlabel="x (forward)",
            ylabel="y (left)", aspect="equal")
    side.set(title="Side view (x, z): the swing above the table", xlabel="x", ylabel="z")
    top.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    side.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="docs/cell-volumes.png")
    p.add_argument("--calibration", action="append", default=[], metavar="ARM=FILE")
    args = p.parse_args(argv)
    cals: dict[str, Mapping[str, Any]] = {a: shipped_calibration(a) for a in ("left", "right")}
    for item in args.calibration:
        arm, _, path = item.partition("=")
        cals[arm] = json.loads(Path(path).read_text())
    for line in draw(Path(args.out), cals):
        print(line)
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
