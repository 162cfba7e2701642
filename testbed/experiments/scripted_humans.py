"""The twin's scripted humans: ground-truth teleop and timed hard resets.

Why in ``experiments``: they are how a twin trial, protocol or sweep rehearses its
operators (the paper's simulated experts); the fleet loop sees them only through the
``testbed.core.humans.Humans`` contract.
"""

from __future__ import annotations

from collections.abc import Sequence

from testbed.core.types import FleetStatus, HumanRequest, HumanResponse, InterventionKind

__all__ = ["ScriptedHumans"]


class ScriptedHumans:
    """Ground-truth teleop and timed hard resets, for twin mode.

    Teleop pushes the host's expert action (``ArmObservation.expert_action``, which only
    a twin host reports). A hard reset is done at the end of the ``t_R``-th step it was
    served (docs/ARCHITECTURE.md, "The timestep"), i.e. when ``served + 1 >= min_steps``.
    """

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        out: dict[str, HumanResponse] = {}
        for req in requests:
            if req.kind is InterventionKind.TELEOP:
                action = req.observation.expert_action
                if action is None:
                    raise RuntimeError(
                        f"{req.robot}: scripted humans need a twin host (no expert action); "
                        "use --humans gui with physical arms"
                    )
                out[req.robot] = HumanResponse(req.robot, action=int(action))
            else:
                done = req.served + 1 >= req.min_steps
                out[req.robot] = HumanResponse(req.robot, reset_done=done)
        return out

    def show(self, t: int, status: FleetStatus) -> None:
        return None

    def close(self) -> None:
        return None
