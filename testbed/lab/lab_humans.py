"""The humans of a rehearsal: whoever helps, plus the lab around them.

Why it exists: on the real YuMi a scripted human has nothing to look at, and a hard
reset is done by a person's hands. On the hardware twin both come from the lab's side
channel (``testbed.lab.lab_client.LabClient``): a scripted human reads the table's
truth and pushes the expert's face, and the lab hand puts the cube back when a human
confirms a reset. ``ArmView`` maps the twin's pixels into each arm's canonical frame
exactly as the controller's config (crop, mirror) does, so the expert sees the table
the way the controller would.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from testbed.core.config import ConfigError
from testbed.core.humans import Humans
from testbed.core.types import HumanRequest, HumanResponse, InterventionKind
from testbed.core.wrappers import HumansWrapper
from testbed.experiments.fleet_config import FleetConfig

if TYPE_CHECKING:
    from testbed.lab.lab_client import LabClient

__all__ = ["ArmView", "TwinLabHumans", "arm_views"]

Truths = dict[str, dict[str, dict[str, Any]]]
"""One step's truth of each host asked so far: host -> arm -> the twin's answer."""


@dataclass(frozen=True, slots=True)
class ArmView:
    """How the controller's config maps one arm's camera pixels into its canonical frame."""

    host: str
    arm: str
    crop: tuple[int, int, int, int]
    mirror: bool

    def canonical(self, px: Sequence[float]) -> tuple[float, float]:
        x0, y0, x1, y1 = self.crop  # pixel centres at integers (OpenCV): edges at -0.5
        cx = (float(px[0]) + 0.5 - x0) / (x1 - x0)
        cy = (float(px[1]) + 0.5 - y0) / (y1 - y0)
        return (1.0 - cx if self.mirror else cx, cy)

    def canonical_yaw(self, yaw_px: float) -> float:
        return -yaw_px if self.mirror else yaw_px


def arm_views(cfg: FleetConfig, hosts: Collection[str] | None = None
              ) -> dict[str, ArmView]:
    """Every robot's crop and mirror, from the (rewritten) fleet config; with ``hosts``,
    those hosts' only (the twins with a side channel: a lab's robot whose agent plays
    it has no truth to map)."""
    out: dict[str, ArmView] = {}
    for h in cfg.hosts:
        if hosts is not None and h.name not in hosts:
            continue
        for a in h.arms:
            if a.crop is None:
                raise ConfigError(f"hosts[{h.name}].arms[{a.name}].crop: an arm whose twin "
                                  "the lab sees needs its crop box")
            out[f"{h.name}/{a.name}"] = ArmView(h.name, a.name, a.crop, a.mirror)
    return out


class TwinLabHumans(HumansWrapper):
    """The humans of a rehearsal: whoever helps (scripted or a person at the console),
    plus the lab around them.

    * Teleop: a scripted human looks at the table (the twin's truth, through the lab side
      channel) and pushes the expert's face, as a person looks at the real cube; a person
      at the console chooses for themselves. A robot without a view (its twin has no
      side channel) keeps its observation's expert action.
    * Hard reset: when the human confirms it (scripted: at the end of the t_R-th step;
      console: the confirm button), the lab hand puts the cube back near the centre of
      its workspace before the controller looks at the picture. The YuMi backend then
      believes the picture, as in the lab. A robot without a view resets itself.

    Every other call of the humans (``show``, ``presence``, ``close``) goes to the inner
    humans unchanged (``testbed.core.wrappers.HumansWrapper``).
    """

    def __init__(self, inner: Humans, labs: Mapping[str, LabClient],
                 views: Mapping[str, ArmView], *, expert: bool) -> None:
        super().__init__(inner)
        self.labs = dict(labs)
        self.views = dict(views)
        self.expert = expert
        self.lab_resets = 0

    def _expert_face(self, req: HumanRequest, truths: Truths) -> int:
        from sim_twin.supervisor import expert_face

        view = self.views[req.robot]
        if view.host not in truths:
            truths[view.host] = self.labs[view.host].truth()
        t = truths[view.host][view.arm]
        cube = view.canonical(t["cube_px"])
        return int(expert_face(cube, view.canonical_yaw(float(t["yaw_px"])),
                               req.observation.goal))

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        truths: Truths = {}
        asked: list[HumanRequest] = []
        for req in requests:
            if (self.expert and req.kind is InterventionKind.TELEOP
                    and req.robot in self.views):
                face = self._expert_face(req, truths)
                req = replace(req, observation=replace(req.observation, expert_action=face))
            asked.append(req)
        answers = self.humans.act(asked, t)
        for robot, answer in answers.items():
            if answer.reset_done and robot in self.views:
                view = self.views[robot]
                self.labs[view.host].reset(view.arm)
                self.lab_resets += 1
        return answers
