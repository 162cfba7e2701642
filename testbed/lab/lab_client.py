"""The lab's side channel to one hardware twin: what a person in the lab has.

Why a module of its own: the twin's ``/lab/*`` endpoints (the table's truth, the lab
hand, the true camera model, the faults a person causes and clears) are read by the
lab's humans, the truth recorder, the calibration's scoring and the fault drills, none
of which needs to start a twin; ``testbed.lab.hardware_twin`` starts them and hands out
one :class:`LabClient` per twin that declares a side channel
(``HardwareTwin.lab_port``). The controller's decisions never read it.
"""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["LabClient", "LabError"]


class LabError(RuntimeError):
    """The hardware twin's lab side channel failed (the twin process is gone?)."""


class LabClient:
    """The lab's side channel to one hardware twin: truth, the lab hand, the camera model.

    This is what a person in the lab has that the controller does not: eyes on the real
    table and hands to put a cube back. The controller's decisions never read it.
    """

    def __init__(self, base_url: str, timeout_s: float = 15.0) -> None:
        self.base_url = base_url.rstrip("/")
        self.timeout_s = timeout_s

    def _call(self, path: str, body: Mapping[str, Any] | None = None) -> dict[str, Any]:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(f"{self.base_url}{path}", data=data,
                                     headers={"Content-Type": "application/json"},
                                     method="GET" if body is None else "POST")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
                out: dict[str, Any] = json.loads(resp.read())
                return out
        except urllib.error.HTTPError as exc:
            detail = exc.read().decode("utf-8", "replace")[:300]
            raise LabError(f"hardware twin {self.base_url}{path}: HTTP {exc.code}: "
                           f"{detail}") from None
        except (OSError, ValueError) as exc:
            raise LabError(f"hardware twin {self.base_url}{path}: {exc}") from None

    def truth(self) -> dict[str, dict[str, Any]]:
        arms: dict[str, dict[str, Any]] = self._call("/lab/truth")["arms"]
        return arms

    def reset(self, arm: str) -> None:
        self._call("/lab/reset", {"arm": arm})

    def place(self, arm: str, xy_mm: Sequence[float], yaw: float = 0.0) -> None:
        """A person puts the cube somewhere (fault drills, tests)."""
        self._call("/lab/place", {"arm": arm, "xy_mm": [float(v) for v in xy_mm], "yaw": yaw})

    def jog(self, arm: str, xyz_mm: Sequence[float]) -> list[float]:
        """A person jogs the arm's TCP to a point on the FlexPendant (tests: an arm left
        in the camera's view); where its TCP is then (mm)."""
        out: list[float] = self._call("/lab/jog", {"arm": arm, "xyz_mm": [float(v) for v
                                                                          in xyz_mm]})["tcp_mm"]
        return out

    def camera(self) -> dict[str, Any]:
        return self._call("/lab/camera")

    def tcp(self) -> dict[str, list[float]]:
        """Where each pusher is now, also mid-motion (the twin's latest motion sample)."""
        out: dict[str, list[float]] = self._call("/lab/tcp")["tcp_mm"]
        return out

    def fault(self, kind: str, arm: str | None = None) -> dict[str, Any]:
        """Something goes wrong in the cell (``sim_twin.lab_faults``): a guard stop, the
        motors off, a RAPID error or a zone stop in ``arm``'s task, a frozen camera."""
        return self._call("/lab/fault", {"kind": kind, **({"arm": arm} if arm else {})})

    def clear(self, kind: str) -> dict[str, Any]:
        """A person clears ``kind`` as in the lab; ``actions``: what they did."""
        return self._call("/lab/clear", {"kind": kind})

    def healthy(self) -> bool:
        try:
            return bool(self._call("/lab/health").get("ok"))
        except LabError:
            return False
