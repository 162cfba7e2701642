"""Twin backends: a PyBullet cell (``sim_twin.TwinCell``) served like a robot host.

Why a backend and not a direct call: twin mode must exercise exactly the path the lab
uses (agent, frames, transport, worker), so a twin host is a process speaking the same
protocol; only this adapter differs. ``sim_twin`` is imported lazily, inside the agent
process, after the agent has claimed its stdout (pybullet prints to fd 1 at import).

:class:`CannedTwinBackend` is the agent's ``--no-physics`` mode: fixed images (PNG
encoded once) and seeded outcomes with no simulation at all, so the SSH benchmark
measures the controller and the wire, not PyBullet.

Neither has a ``stop`` of its own (``HostBackend.stop`` does nothing): a twin push is
one PyBullet call that simulates the stroke faster than real time and returns its
outcome, and stopping it midway from another thread is neither cheap (PyBullet is not
thread-safe) nor wanted (a trial's records are byte-equal per seed).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.backends.base import ArmOutcome, ArmView, HostBackend
from testbed.core.types import IMAGE_SIZE


class _TwinArms(HostBackend):
    """The arms of a twin cell, as its agent was started with them (both twins)."""

    def __init__(self, arms: Sequence[str], mirror: Sequence[bool]) -> None:
        self._arms = tuple(arms)
        self._mirror = tuple(bool(m) for m in mirror)

    @property
    def arm_names(self) -> tuple[str, ...]:
        return self._arms

    @property
    def mirror(self) -> tuple[bool, ...]:
        return self._mirror


class TwinBackend(_TwinArms):
    """One ``sim_twin.TwinCell`` (its arms share one simulated camera)."""

    kind = "twin"

    def __init__(self, seed: int, arms: Sequence[str] = ("left", "right"),
                 mirror: Sequence[bool] = (False, True), *,
                 cell_factory: Callable[..., Any] | None = None) -> None:
        if cell_factory is None:
            from sim_twin.cell import TwinCell  # pybullet only in the agent

            cell_factory = TwinCell
        super().__init__(arms, mirror)
        self._factory = cell_factory
        self._cell = self._new_cell(seed)
        self._pushed_since_rest = False
        self._closed = False
        self._ready: dict[str, ArmView] | None = None  # prepare()'s views, until used

    def _new_cell(self, seed: int) -> Any:
        return self._factory(seed=seed, arms=self._arms, mirror=self._mirror,
                             image_size=IMAGE_SIZE)

    def reseed(self, seed: int) -> None:
        """A new cell from ``seed``, exactly as a newly started agent would build it (so
        pretraining on a host, then reseeding, gives the trial a fresh start)."""
        self._ready = None
        old, self._cell = self._cell, self._new_cell(seed)
        self._pushed_since_rest = False
        old.close()

    def prepare(self) -> None:
        """Render and read the next views now (after a push or reset, while the controller
        waits for the other hosts, trains and logs); ``observe`` returns them unless the
        world changes first. The same calls in the same order as ``observe`` makes: the
        twin's observation never touches the physics, so the records are unchanged."""
        self._ready = None
        self._ready = self._views()

    def observe(self) -> dict[str, ArmView]:
        if self._ready is not None:
            views, self._ready = self._ready, None
            return views
        return self._views()

    def _views(self) -> dict[str, ArmView]:
        if self._pushed_since_rest:
            # Never a picture with a pusher in view: rest first (cheap in the twin).
            self._cell.rest()
            self._pushed_since_rest = False
        images = self._cell.observe()
        views: dict[str, ArmView] = {}
        for arm in self._arms:
            st = self._cell.arm_state(arm)
            violating = bool(st.violating)
            expert = None if violating else int(self._cell.expert_action(arm))
            views[arm] = ArmView(np.ascontiguousarray(images[arm], dtype=np.uint8), violating,
                                 (float(st.goal_xy[0]), float(st.goal_xy[1])), expert)
        return views

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        faces = self.check_faces(faces)
        self._ready = None
        outcomes = self._cell.push(faces)
        self._pushed_since_rest = True
        return {arm: ArmOutcome(bool(outcomes[arm].success), bool(outcomes[arm].violation))
                for arm in faces}

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        done: dict[str, bool] = {}
        self._ready = None
        for arm in self.check_arms(arms):
            self._cell.hard_reset(arm)
            done[arm] = not bool(self._cell.arm_state(arm).violating)
        return done

    def rest(self) -> None:
        self._ready = None
        self._cell.rest()
        self._pushed_since_rest = False

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._cell.close()


def canned_image(arm_index: int, cube_xy: tuple[float, float], goal_xy: tuple[float, float]
                 ) -> npt.NDArray[np.uint8]:
    """A twin-like 64x64 frame: grey table, orange cube, green goal disc (flat colours,
    as the twin renders them, so the bytes on the wire are the twin's)."""
    import cv2

    img = np.full((IMAGE_SIZE, IMAGE_SIZE, 3), (158, 158, 153), np.uint8)
    img[:, : 2 + arm_index] = (150, 150, 146)  # a table edge; each arm's image differs
    c = (int(cube_xy[0] * IMAGE_SIZE), int(cube_xy[1] * IMAGE_SIZE))
    cv2.rectangle(img, (c[0] - 4, c[1] - 4), (c[0] + 4, c[1] + 4), (235, 77, 15), -1)
    g = (int(goal_xy[0] * IMAGE_SIZE), int(goal_xy[1] * IMAGE_SIZE))
    cv2.circle(img, g, 3, (40, 200, 40), -1)
    return img


class CannedTwinBackend(_TwinArms):
    """No physics: fixed images and seeded outcomes (``--no-physics``, benchmarks)."""

    kind = "twin-canned"

    def __init__(self, seed: int, arms: Sequence[str] = ("left", "right"),
                 mirror: Sequence[bool] = (False, True)) -> None:
        from drivers.wire import encode_image

        super().__init__(arms, mirror)
        self.reseed(seed)
        self._views: dict[str, ArmView] = {}
        self._goal = (0.7, 0.3)
        for i, arm in enumerate(self._arms):
            img = canned_image(i, (0.5, 0.5), self._goal)
            self._views[arm] = ArmView(img, False, self._goal, 0, encode_image(img))

    def reseed(self, seed: int) -> None:
        """Outcomes from ``seed`` again, every arm free (as a new agent)."""
        self._rng = np.random.default_rng(seed)
        self._violating = dict.fromkeys(self._arms, False)

    def observe(self) -> dict[str, ArmView]:
        return {a: ArmView(v.image, self._violating[a], v.goal,
                           None if self._violating[a] else v.expert_action, v.png)
                for a, v in self._views.items()}

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        faces = self.check_faces(faces)
        out: dict[str, ArmOutcome] = {}
        for arm in faces:
            if self._violating[arm]:
                out[arm] = ArmOutcome(False, False)
                continue
            r = float(self._rng.random())
            violation = r < 0.01
            self._violating[arm] = violation
            out[arm] = ArmOutcome(success=0.01 <= r < 0.06, violation=violation)
        return out

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        arms = self.check_arms(arms)
        for arm in arms:
            self._violating[arm] = False
        return dict.fromkeys(arms, True)

    def rest(self) -> None:
        pass

    def close(self) -> None:
        pass

