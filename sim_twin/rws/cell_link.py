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
from collections.abc import Mapping
from typing import Protocol

from sim_twin.rws.mechunits import TOOL_DOWN, MechUnit, Quat, StaticPoses, Vec3


class TcpSource(Protocol):
    """What the link needs of a cell: ``YumiTwinCell.tcp_xyz``."""

    def tcp_xyz(self) -> Mapping[str, tuple[float, float, float]]: ...


class CellPoses(StaticPoses):
    """Flanges from the cell's TCPs; joints and configuration as :class:`StaticPoses`."""

    def __init__(self, cell: TcpSource, lock: threading.Lock | threading.RLock,
                 units: tuple[MechUnit, ...], pusher_length_mm: float = 0.0) -> None:
        super().__init__(units)
        self.cell, self.cell_lock = cell, lock
        self.pusher_length_mm = float(pusher_length_mm)

    def flange(self, unit: MechUnit) -> tuple[Vec3, Quat]:
        with self.cell_lock:
            x, y, z = self.cell.tcp_xyz()[unit.arm]
        return (float(x), float(y), float(z) + self.pusher_length_mm), TOOL_DOWN
