"""The RWS twin's arms read from a :class:`~sim_twin.yumi_cell.YumiTwinCell`.

Why it exists: on the hardware twin, the position RWS reports must be the cell's pusher,
not a number of its own. The cell knows each arm's TCP (the bottom of the pusher); the
controller reports the flange for ``tool0``, so the flange here is the TCP moved up by
the pusher's length along the tool's z (the tool points down). A client that reads with
``tool0`` sees the flange; with a ``tooldata`` whose ``tframe`` is ``[0, 0, length]`` it
sees the pusher's tip, as on the robot.

The cell is not thread-safe: every read takes the lock the cell's server holds around it.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from typing import Protocol

from sim_twin.rws.mechunits import TOOL_DOWN, MechUnit, Quat, StaticPoses, Vec3


class ArmJoints(Protocol):
    """What the link reads of the twin's arms (``ArmSupervisor``): joints, ABB's order."""

    def abb_joints(self, arm: str) -> tuple[float, ...]: ...

    def robconf(self, arm: str) -> tuple[float, float, float, float]: ...

    def flange_pose(self, arm: str, tip: Sequence[float]) -> tuple[Vec3, Quat] | None:
        """The flange by the arm's joints when they hold the pusher's tip at ``tip``
        (None: the arm is on its way, the joints not yet known)."""


class TcpSource(Protocol):
    """What the link needs of a cell: ``YumiTwinCell.tcp_xyz``."""

    def tcp_xyz(self) -> Mapping[str, tuple[float, float, float]]: ...


class CellPoses(StaticPoses):
    """Flanges from the cell's TCPs; joints and configuration from the twin's arms when
    it has them (``arms``), else as :class:`StaticPoses`."""

    def __init__(self, cell: TcpSource, lock: threading.Lock | threading.RLock,
                 units: tuple[MechUnit, ...], pusher_length_mm: float = 0.0,
                 arms: ArmJoints | None = None) -> None:
        super().__init__(units)
        self.cell, self.cell_lock = cell, lock
        self.pusher_length_mm = float(pusher_length_mm)
        self.arms = arms

    def joints(self, unit: MechUnit) -> tuple[float, ...]:
        if self.arms is None:
            return super().joints(unit)
        with self.cell_lock:
            return self.arms.abb_joints(unit.arm)

    def robconf(self, unit: MechUnit) -> tuple[float, float, float, float]:
        if self.arms is None:
            return super().robconf(unit)
        with self.cell_lock:
            return self.arms.robconf(unit.arm)

    def flange(self, unit: MechUnit) -> tuple[Vec3, Quat]:
        with self.cell_lock:
            x, y, z = self.cell.tcp_xyz()[unit.arm]
            pose = None if self.arms is None else self.arms.flange_pose(unit.arm, (x, y, z))
        if pose is not None:  # at rest the tool points sideways: the arm's own pose
            return pose
        return (float(x), float(y), float(z) + self.pusher_length_mm), TOOL_DOWN
