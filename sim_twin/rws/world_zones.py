"""The stationary world zones our RAPID defines (``tb_zones`` in robot/rapid/TestbedMotion.mod),
as geometry the twin can supervise: boxes the TCP of ``tool_pusher`` must not enter.

Why it exists: on the robot, the zones are the controller's own supervision (RobotWare
option 608-1 World Zones, ``WZBoxDef \\Inside`` + ``WZLimSup \\Stat``): whatever program
runs, a TCP that reaches a zone stops every motion there with the controller's error.
The rehearsal must show that stop before a pusher meets a table edge or the other arm,
so the twin builds the SAME boxes from the same four numbers per arm (``tb_zone_lo``,
``tb_zone_hi``, ``tb_zone_z``, ``tb_floor_z`` in the task modules) and finds, for a
planned straight move, the first moment the TCP would be inside one.

The boxes, world frame (the frame of the cell's TCPs; RAPID's ``wobj0``), mm, each with
its sides parallel to the world axes as ``WZBoxDef`` makes them and every corner
coordinate distinct (the manual's rule for LowPoint/HighPoint; ``FAR`` keeps the outer
faces far beyond the YuMi's reach):

- ``tb_wz_floor``: everything below ``floor_z``, everywhere;
- ``tb_wz_xlo``, ``tb_wz_xhi``, ``tb_wz_ylo``, ``tb_wz_yhi``: the four slabs around the
  xy box ``[x0, x1] x [y0, y1]``, from below the floor up to ``zone_z``.

So below ``zone_z`` the TCP may only be inside the xy box, and never below the floor;
above ``zone_z`` it may go anywhere (travel, the rest pose). A box is OPEN: a TCP on a
face is not inside (a pusher held at the boundary can move away again).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

from sim_twin.yumi_geometry import workspace_mm

FAR = 5000.0
"""mm from the zone's faces to the boxes' outer faces (``TB_WZ_FAR`` in TestbedMotion.mod)."""
DEFAULT_MARGIN_MM = 25.0
"""The twin's default zone: the arm's workspace grown by this on every side; less than
half the 60 mm gap between the workspaces, so the two arms' zones never overlap."""
EPS_MM = 0.05
"""A point this close to a face counts as on it (not inside): the supervision's
resolution. A line that starts where a zone stopped the arm, on the zone's face, runs
along the face within the path's numerical error (the twin's SingArea Wrist lines
interpolate joints between samples a few mm apart)."""
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class ZoneBox:
    """One ``WZBoxDef \\Inside`` box: ``name`` (its wzstationary in the RAPID), corners."""

    name: str
    lo: Vec3
    hi: Vec3

    def contains(self, p: Sequence[float]) -> bool:
        """Strictly inside (a point on a face is outside)."""
        return all(self.lo[k] + EPS_MM < p[k] < self.hi[k] - EPS_MM for k in range(3))

    def entry(self, a: Sequence[float], b: Sequence[float]) -> float | None:
        """The first ``u`` in [0, 1) at which ``a + u (b - a)`` is inside, or None."""
        u_in, u_out = -math.inf, math.inf
        for k in range(3):
            lo, hi, d = self.lo[k] + EPS_MM, self.hi[k] - EPS_MM, b[k] - a[k]
            if abs(d) < 1e-12:
                if not lo < a[k] < hi:
                    return None
                continue
            t1, t2 = (lo - a[k]) / d, (hi - a[k]) / d
            u_in, u_out = max(u_in, min(t1, t2)), min(u_out, max(t1, t2))
        if u_in >= u_out or u_out <= 0.0 or u_in >= 1.0:
            return None
        return max(u_in, 0.0)

    def rapid(self) -> str:
        """As the RAPID writes it (for messages): ``[x,y,z] .. [x,y,z]``."""
        return f"[{_fmt(self.lo)}] .. [{_fmt(self.hi)}]"


def _fmt(p: Sequence[float]) -> str:
    return ",".join(f"{v:g}" for v in p)


@dataclass(frozen=True)
class ArmZone:
    """One task's zone constants: the xy box, ``zone_z`` and ``floor_z`` (mm, world)."""

    x0: float
    y0: float
    x1: float
    y1: float
    zone_z: float = 80.0
    floor_z: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.x0, self.y0, self.x1, self.y1, self.zone_z, self.floor_z)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("zone numbers must be finite")
        if not (self.x0 < self.x1 and self.y0 < self.y1):
            raise ValueError(f"zone box {self.box}: needs x0 < x1 and y0 < y1")
        if not self.floor_z < self.zone_z:
            raise ValueError(f"zone z {self.zone_z:g} mm must be above the floor "
                             f"{self.floor_z:g} mm")
        if max(abs(v) for v in vals) >= FAR:
            raise ValueError(f"zone numbers must lie within {FAR:g} mm of the origin")

    @property
    def box(self) -> tuple[float, float, float, float]:
        return (self.x0, self.y0, self.x1, self.y1)

    def boxes(self) -> tuple[ZoneBox, ...]:
        """The five forbidden boxes, in the order ``tb_zones`` defines them."""
        bottom = self.floor_z - FAR
        z = self.zone_z
        return (
            ZoneBox("tb_wz_floor", (-FAR, -FAR, bottom), (FAR, FAR, self.floor_z)),
            ZoneBox("tb_wz_xlo", (-FAR, -FAR, bottom), (self.x0, FAR, z)),
            ZoneBox("tb_wz_xhi", (self.x1, -FAR, bottom), (FAR, FAR, z)),
            ZoneBox("tb_wz_ylo", (self.x0, -FAR, bottom), (self.x1, self.y0, z)),
            ZoneBox("tb_wz_yhi", (self.x0, self.y1, bottom), (self.x1, FAR, z)),
        )

    def inside(self, p: Sequence[float]) -> ZoneBox | None:
        """The box ``p`` is inside, if any."""
        return next((b for b in self.boxes() if b.contains(p)), None)

    def entry(self, a: Sequence[float], b: Sequence[float]) -> tuple[float, ZoneBox] | None:
        """The first ``u`` along ``a -> b`` inside a box, and the box; None if none."""
        hits = [(u, box) for box in self.boxes() if (u := box.entry(a, b)) is not None]
        return min(hits, key=lambda h: h[0]) if hits else None


class Segment(Protocol):
    """A straight timed move (``sim_twin.yumi_cell.Segment``): the cell's TCP path."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]

    @property
    def length(self) -> float: ...

    @property
    def duration(self) -> float: ...

    def at(self, t: float) -> tuple[float, float, float]: ...


def time_at(seg: Segment, u: float) -> float:
    """The last time of ``seg`` before its point reaches fraction ``u`` of the way: a point
    on the near side of a face, so the stop point is never inside (bisection: the speed
    profile is a trapezoid, the distance travelled only grows)."""
    length, total = seg.length, seg.duration
    if u <= 0.0 or length <= 0.0 or total <= 0.0:
        return 0.0
    lo, hi = 0.0, total
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if math.dist(seg.at(mid), seg.a) < u * length:
            lo = mid
        else:
            hi = mid
    return lo


def first_entry(segments: Iterable[Segment], zone: ArmZone, offset: Sequence[float] = (0, 0, 0)
                ) -> tuple[float, ZoneBox] | None:
    """When (s from the start of ``segments``) the TCP (the cell point + ``offset``)
    first reaches a box of ``zone``, and which box; None if the path stays allowed."""
    t0 = 0.0
    for seg in segments:
        a = tuple(seg.a[k] + offset[k] for k in range(3))
        b = tuple(seg.b[k] + offset[k] for k in range(3))
        hit = zone.entry(a, b)
        if hit is not None:
            return t0 + time_at(seg, hit[0]), hit[1]
        t0 += seg.duration
    return None


def default_zone(side: str, *, zone_z: float = 80.0, floor_z: float = 0.0,
                 margin_mm: float = DEFAULT_MARGIN_MM) -> ArmZone:
    """The twin's default zone of an arm on ``side``: its workspace grown by ``margin_mm``."""
    x0, y0, x1, y1 = workspace_mm(side)
    return ArmZone(x0 - margin_mm, y0 - margin_mm, x1 + margin_mm, y1 + margin_mm,
                   zone_z, floor_z)


def parse_zone(text: str) -> tuple[str, tuple[float, float, float, float]]:
    """``ARM=x0,y0,x1,y1`` (the servers' ``--zone``) -> (arm, box); ``ValueError``."""
    arm, eq, rest = text.partition("=")
    try:
        nums = tuple(float(v) for v in rest.split(","))
    except ValueError:
        nums = ()
    if not eq or not arm.strip() or len(nums) != 4 or not all(map(math.isfinite, nums)):
        raise ValueError(f"--zone {text!r}: expected ARM=x0,y0,x1,y1 (mm)")
    return arm.strip(), nums  # type: ignore[return-value]
