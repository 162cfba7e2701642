"""A FAKE ABB YuMi controller client, for the tests of the YuMi backend.

Why here and not next to the real clients: it is a test helper (it records programs and
moves the TCPs instantly), so it lives with the other helpers of ``drivers.testing`` and
no production module carries it. It implements
:class:`~drivers.yumi.yumi_controller.YumiControllerClient`, the seam the real client
(:class:`~drivers.yumi.rws_controller.RwsYumiController`, for a lab's controller and
the hardware twin alike) implements.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from drivers.errors import BackendError
from drivers.yumi.yumi_controller import Waypoint


@dataclass
class FakeYumiController:
    """A FAKE IRB 14000 controller for tests: records programs, moves TCPs instantly.

    ``park_in_view(arm, reads)`` makes the next ``reads`` TCP reads report the arm over
    the table (until it is sent to rest), so the backend's "take the picture again" path
    can be tested; an arm in ``stuck`` stays in view whatever it is told.

    Joints (the driver judges where an arm is from them): ``rest_joints`` at rest, a
    joint target's after an ``abs_j``, and after a straight move (or parked in view)
    what ``solve(arm, xyz)`` gives (a test's inverse kinematics: the driver's model), or
    the joints the arm had (None: the fake has no kinematics). ``place(arm, xyz,
    joints)`` puts an arm anywhere, as a person's jog does.
    """

    rest_xyz: dict[str, tuple[float, float, float]]
    in_view_xyz: tuple[float, float, float] = (0.0, 0.0, 50.0)
    stuck: set[str] = field(default_factory=set)
    programs: list[dict[str, list[Waypoint]]] = field(default_factory=list)
    closed: bool = False
    stops: int = 0
    rest_joints: dict[str, tuple[float, ...]] = field(default_factory=dict)
    solve: Callable[[str, Sequence[float]], Sequence[float] | None] | None = None
    _tcp: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    _joints: dict[str, tuple[float, ...]] = field(default_factory=dict)
    _in_view_reads: dict[str, int] = field(default_factory=dict)
    _parked: set[str] = field(default_factory=set)
    """The arms the latest TCP read reported in view: their joints read as there."""

    def __post_init__(self) -> None:
        self._tcp = dict(self.rest_xyz)
        self._joints = {a: tuple(self.rest_joints.get(a, (0.0,) * 7)) for a in self.rest_xyz}

    def place(self, arm: str, xyz: Sequence[float], joints: Sequence[float]) -> None:
        """The arm at ``xyz`` with ``joints``, as a person jogged it."""
        self._tcp[arm] = (float(xyz[0]), float(xyz[1]), float(xyz[2]))
        self._joints[arm] = tuple(float(v) for v in joints)

    def _solved(self, arm: str, xyz: Sequence[float]) -> tuple[float, ...]:
        got = self.solve(arm, xyz) if self.solve is not None else None
        return self._joints[arm] if got is None else tuple(float(v) for v in got)

    def park_in_view(self, arm: str, reads: int = 1) -> None:
        self._in_view_reads[arm] = reads

    def execute(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        if self.closed:
            raise BackendError("fake controller is closed")
        unknown = set(programs) - set(self.rest_xyz)
        if unknown:
            raise BackendError(f"fake controller has no arm(s) {sorted(unknown)}")
        self.programs.append({a: list(w) for a, w in programs.items()})
        for arm, wps in programs.items():
            for w in wps:
                if w.speed_mm_s <= 0:
                    raise BackendError(f"arm {arm}: non-positive speed {w.speed_mm_s}")
                if w.kind == "rest":
                    self._tcp[arm] = self.rest_xyz[arm]
                    self._joints[arm] = tuple(self.rest_joints.get(arm, (0.0,) * 7))
                    self._in_view_reads.pop(arm, None)
                elif w.kind == "abs_j" and w.joints_deg is not None:
                    self._joints[arm] = tuple(w.joints_deg)
                elif w.xyz_mm is not None:
                    self._tcp[arm] = w.xyz_mm
                    self._joints[arm] = self._solved(arm, w.xyz_mm)

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        out = dict(self._tcp)
        for arm, n in list(self._in_view_reads.items()):
            if n > 0:
                out[arm] = self.in_view_xyz
                self._in_view_reads[arm] = n - 1
        for arm in self.stuck:
            out[arm] = self.in_view_xyz
        self._parked = {a for a, xyz in out.items() if xyz == self.in_view_xyz
                        and self._tcp.get(a) != self.in_view_xyz}
        return out

    def joints(self) -> dict[str, tuple[float, ...]]:
        out = dict(self._joints)
        for arm in self._parked:  # as the latest TCP read put them
            out[arm] = self._solved(arm, self.in_view_xyz)
        return out

    def stop(self) -> None:
        self.stops += 1

    def describe(self) -> dict[str, object]:
        return {"fake": True, "arms": sorted(self.rest_xyz)}

    def close(self) -> None:
        self.closed = True
