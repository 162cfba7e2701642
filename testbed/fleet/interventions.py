"""Which step of an intervention a human first acted on: the records' "first action".

Why: the per-human table says how long each human took from an assignment to their
first action (a teleop's first push, a hard reset's confirmation). The allocator knows
how long a human has been on an arm (``Allocator.served``: 0 on an intervention's first
step); this keeps, per arm, whether the current intervention has had its first action
yet, so the loop marks exactly one step of each intervention (the row's ``first``). A
resumed trial rebuilds it from its rows (:meth:`FirstActions.restore`), so an
intervention that spans the crash is not marked twice.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["FirstActions"]


class FirstActions:
    """Per arm: has the intervention in progress had its first action?"""

    def __init__(self) -> None:
        self._acted: dict[str, bool] = {}

    def first(self, robot: str, served: int, acted: bool) -> bool:
        """Step of ``robot``'s intervention ``served`` (0: it starts now); ``acted``: the
        human acted this step. True exactly once per intervention: at its first action."""
        if served == 0:
            self._acted[robot] = False
        if not acted or self._acted.get(robot, False):
            return False
        self._acted[robot] = True
        return True

    def restore(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Replay the rows of a resumed trial (their ``served`` and ``first`` fields)."""
        for row in rows:
            for r in row["robots"]:
                if r.get("served") is None:
                    continue
                self.first(r["robot"], int(r["served"]), r.get("first") is not None)
