"""Simple collision shapes of an IRB 14000 arm with its gripper and pusher, and clearances.

Why capsules: two arms meet, or an arm meets the table, long before any mesh detail
matters; a capsule per link (a segment between two joint origins, with a radius that
covers the casing) answers "how far apart" with one segment-to-segment distance, and a
whole swept path's worth of them in one numpy pass (``drivers/yumi/layout_check.py``
compares every pose of one arm's sweep with every pose of the other's).

The radii are ours, not ABB's: envelopes of the casings of the IRB 14000 as drawn in
ABB's product specification (the shoulder about 100 mm across, the elbow 90, the wrist
70), rounded up to 5 mm. The gripper's housing reaches 83.7 mm past the flange, where the
public description of the IRB 14000 (OrebroUniversity/yumi, ``yumi_description``:
``gripper_l_joint`` at 83.7 mm from the gripper's base, which sits on the flange) starts
its fingers; below it the fingers holding the pusher, and the pusher to its tip (the
TCP), are one slim capsule.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from drivers.yumi.irb14000 import Pose

__all__ = ["LINK_RADII_MM", "Capsules", "arm_capsules", "min_distance", "table_clearance"]

Mat = npt.NDArray[np.float64]
LINK_RADII_MM: Final = (50.0, 45.0, 45.0, 40.0, 35.0, 35.0, 35.0)
"""The capsule after each chain joint: axis 1 -> 2, 2 -> 7, 7 -> 3, 3 -> 4, 4 -> 5, 5 -> 6,
6 -> flange."""
GRIPPER_HOUSING_MM: Final = 83.7
"""The gripper's housing from the flange to where its fingers start."""
GRIPPER_RADIUS_MM: Final = 35.0
PUSHER_RADIUS_MM: Final = 15.0
"""The fingers around the pusher, and the pusher (12 mm radius in the twin,
``sim_twin/yumi_geometry.py``)."""
SHAPE_NAMES: Final = ("shoulder", "upper arm", "upper arm (axis 7)", "elbow", "forearm",
                      "wrist", "wrist (axis 6)", "gripper", "pusher")


class Capsules:
    """A set of capsules: ``a`` and ``b`` (n, 3) segment ends, ``r`` (n,) radii, and what
    each is (``names``)."""

    def __init__(self, a: Mat, b: Mat, r: Mat, names: list[str]) -> None:
        self.a, self.b, self.r, self.names = a, b, r, names

    @classmethod
    def join(cls, parts: list[Capsules]) -> Capsules:
        return cls(np.concatenate([p.a for p in parts]), np.concatenate([p.b for p in parts]),
                   np.concatenate([p.r for p in parts]), [n for p in parts for n in p.names])

    def without_tool(self) -> Capsules:
        """The shapes but the pusher (its tip pushes cubes on the table by design)."""
        keep = [i for i, n in enumerate(self.names) if n != "pusher"]
        return Capsules(self.a[keep], self.b[keep], self.r[keep],
                        [self.names[i] for i in keep])


def arm_capsules(pose: Pose, tool_z_mm: float) -> Capsules:
    """The arm's links, the gripper's housing and the pusher down to the TCP."""
    pts = pose.frames[:, :3, 3]
    down = pose.flange[:3, 2]
    housing = min(GRIPPER_HOUSING_MM, max(tool_z_mm, 0.0))
    g_end = pts[7] + down * housing
    tip = pts[7] + down * max(tool_z_mm, housing)
    a = np.vstack([pts[:7], pts[7:8], g_end[None]])
    b = np.vstack([pts[1:8], g_end[None], tip[None]])
    r = np.array([*LINK_RADII_MM, GRIPPER_RADIUS_MM, PUSHER_RADIUS_MM])
    return Capsules(a, b, r, list(SHAPE_NAMES))


def segment_distances(a0: Mat, a1: Mat, b0: Mat, b1: Mat) -> Mat:
    """The smallest distance between segments a0-a1 and b0-b1, pairwise over the
    leading axis (arrays (n, 3)), clamped to the segments' ends."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    den = a * e - b * b
    safe_a, safe_e = np.maximum(a, 1e-12), np.maximum(e, 1e-12)
    s = np.where(den > 1e-9, np.clip((b * f - c * e) / np.maximum(den, 1e-12), 0, 1), 0.0)
    t = (b * s + f) / safe_e
    s = np.where(t < 0, np.clip(-c / safe_a, 0, 1), np.where(t > 1, np.clip((b - c) / safe_a,
                                                                            0, 1), s))
    t = np.clip(t, 0, 1)
    gap = (a0 + d1 * s[:, None]) - (b0 + d2 * t[:, None])
    return np.linalg.norm(gap, axis=1)


def min_distance(one: Capsules, other: Capsules) -> tuple[float, str, str]:
    """The smallest gap between any shape of ``one`` and any of ``other`` (negative: they
    overlap), mm, and which two shapes."""
    n, m = len(one.r), len(other.r)
    i, j = np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
    gaps = segment_distances(one.a[i], one.b[i], other.a[j], other.b[j]) - one.r[i] \
        - other.r[j]
    k = int(np.argmin(gaps))
    return float(gaps[k]), one.names[i[k]], other.names[j[k]]


def table_clearance(shapes: Capsules, table_z_mm: float = 0.0) -> tuple[float, str]:
    """The lowest point of any shape but the pusher above the table top, mm, and which."""
    body = shapes.without_tool()
    low = np.minimum(body.a[:, 2], body.b[:, 2]) - body.r - table_z_mm
    k = int(np.argmin(low))
    return float(low[k]), body.names[k]
