"""A FAKE ABB YuMi controller client, for the tests of the YuMi backend.

Why here and not next to the real clients: it is a test helper (it records programs and
moves the TCPs instantly), so it lives with the other helpers of ``drivers.testing`` and
no production module carries it. It implements
:class:`~drivers.yumi.yumi_controller.YumiControllerClient`, the seam the real client
(:class:`~drivers.yumi.rws_controller.RwsYumiController`, for a lab's controller and
the hardware twin alike) implements.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from drivers.errors import BackendError
from drivers.yumi.yumi_controller import Waypoint


@dataclass
class FakeYumiController:
    """A FAKE IRB 14000 controller for tests: records programs, moves TCPs instantly.

    ``park_in_view(arm, reads)`` makes the next ``reads`` TCP reads report the arm over
    the table (until it is sent to rest), so the backend's "take the picture again" path
    can be tested; an arm in ``stuck`` stays in view whatever it is told.
    """

    rest_xyz: dict[str, tuple[float, float, float]]
    in_view_xyz: tuple[float, float, float] = (0.0, 0.0, 50.0)
    stuck: set[str] = field(default_factory=set)
    programs: list[dict[str, list[Waypoint]]] = field(default_factory=list)
    closed: bool = False
    stops: int = 0
    _tcp: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    _in_view_reads: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._tcp = dict(self.rest_xyz)

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
                    self._in_view_reads.pop(arm, None)
                elif w.xyz_mm is not None:
                    self._tcp[arm] = w.xyz_mm

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        out = dict(self._tcp)
        for arm, n in list(self._in_view_reads.items()):
            if n > 0:
                out[arm] = self.in_view_xyz
                self._in_view_reads[arm] = n - 1
        for arm in self.stuck:
            out[arm] = self.in_view_xyz
        return out

    def stop(self) -> None:
        self.stops += 1

    def describe(self) -> dict[str, object]:
        return {"fake": True, "arms": sorted(self.rest_xyz)}

    def close(self) -> None:
        self.closed = True
