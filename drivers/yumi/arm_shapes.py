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
    overlap), mm, and which two shapes.

    Exactly the minimum over every pair, without measuring every pair: two whole sweeps
    are thousands of capsules each (tens of millions of pairs, seconds of ``testbed
    check`` per host). Each capsule lies inside a sphere about its middle, so
    ``|centre - centre| - reach - reach`` is a lower bound of a pair's gap. The pairs of
    lowest bound, measured, give a gap to beat; every pair whose bound is not above it
    is measured, in the all-pairs order, so the answer is the pair ``argmin`` over all
    pairs would give."""
    m = len(other.r)
    c1, c2 = (one.a + one.b) / 2, (other.a + other.b) / 2
    h1 = np.linalg.norm(one.b - one.a, axis=1) / 2 + one.r
    h2 = np.linalg.norm(other.b - other.a, axis=1) / 2 + other.r
    sq = (np.einsum("ij,ij->i", c1, c1)[:, None] + np.einsum("ij,ij->i", c2, c2)[None]
          - 2 * c1 @ c2.T)
    bound = (np.sqrt(np.maximum(sq, 0.0)) - h1[:, None] - h2[None]).ravel()
    bound -= 1e-6 * (1.0 + np.abs(bound))  # the sum's rounding may not lift a bound

    def gaps_of(k: npt.NDArray[np.intp]) -> Mat:
        i, j = k // m, k % m
        return segment_distances(one.a[i], one.b[i], other.a[j], other.b[j]) - one.r[i] \
            - other.r[j]

    few = min(64, bound.size)  # the pairs of lowest bound give a gap to beat
    ceiling = float(gaps_of(np.argpartition(bound, few - 1)[:few]).min())
    k = np.flatnonzero(bound <= ceiling)  # every pair that may be as close, in order
    gaps = gaps_of(k)
    first = int(k[int(np.argmin(gaps))])
    return float(gaps.min()), one.names[first // m], other.names[first % m]


def table_clearance(shapes: Capsules, table_z_mm: float = 0.0) -> tuple[float, str]:
    """The lowest point of any shape but the pusher above the table top, mm, and which."""
    body = shapes.without_tool()
    low = np.minimum(body.a[:, 2], body.b[:, 2]) - body.r - table_z_mm
    k = int(np.argmin(low))
    return float(low[k]), body.names[k]
