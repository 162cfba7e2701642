"""Fixtures of the console tests: synthetic arm images and requests, a private Xvfb."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from console_helpers import RequestFactory, arm_image

from gui.xdo import Xvfb, tools_missing
from testbed.core.types import ArmObservation, HumanRequest, InterventionKind


@pytest.fixture
def make_request() -> RequestFactory:
    def make(
        robot: str = "cell0/left", human: int = 0, kind: str = "teleop", *,
        image: np.ndarray | None = None, goal: tuple[float, float] = (0.7, 0.7),
        served: int = 0, min_steps: int = 3, violating: bool | None = None,
    ) -> HumanRequest:
        k = InterventionKind(kind)
        obs = ArmObservation(
            robot, arm_image() if image is None else image,
            k is InterventionKind.RESET if violating is None else violating, goal,
        )
        return HumanRequest(robot, human, k, obs, served, min_steps, (0.0, 0.4, 0.1),
                            {"c": 0.0, "u": 0.4, "r": 0.1, "uncertainty": 0.4, "risk": 0.1})

    return make


@pytest.fixture(scope="module")
def xvfb() -> Iterator[Xvfb]:
    """A private X server for the module; DISPLAY of this process is left alone."""
    missing = tools_missing()
    if missing:
        pytest.fail(f"missing {', '.join(missing)}: apt-get install -y xvfb xauth xdotool "
                    "(scripts/setup.sh --dev does it)")
    server = Xvfb(set_env=False)
    server.start()
    yield server
    server.stop()
