"""The operator's wait for a push (``deadline_s``) against the controller's speed ratio.

Why: at 10 % a push takes ten times as long; the driver scales its motion timeout by the
ratio, the operator side does not know the ratio, so ``testbed check`` and the trial's
gate FAULT a host whose ``deadline_s`` would cut such a push off
(drivers/yumi/yumi_plugin.py ``deadline_faults``; docs/rws-checklist.md, "Timeouts at 10 %").
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from drivers.yumi.yumi_plugin import deadline_faults


def _info(ratio: float | None) -> dict[str, object]:
    return {"controller": {"state": {"speedratio": ratio}}}


def test_a_deadline_shorter_than_the_scaled_motion_timeout_is_a_fault() -> None:
    host = SimpleNamespace(motion_timeout_s=15.0, deadline_s=20.0)
    (fault,) = deadline_faults(host, _info(10.0))  # type: ignore[arg-type]
    assert "speed ratio is 10 %" in fault
    assert "up to 150 s" in fault and "deadline_s 20 s" in fault
    assert "set deadline_s above 150" in fault


@pytest.mark.parametrize(("ratio", "deadline"), [(100.0, 20.0), (10.0, 151.0), (None, 20.0),
                                                 (80.0, 19.0)])
def test_no_fault_at_full_speed_or_with_a_deadline_long_enough(ratio: float | None,
                                                               deadline: float) -> None:
    host = SimpleNamespace(motion_timeout_s=15.0, deadline_s=deadline)
    assert deadline_faults(host, _info(ratio)) == []  # type: ignore[arg-type]


def test_the_boundary_is_the_scaled_timeout_itself() -> None:
    host = SimpleNamespace(motion_timeout_s=15.0, deadline_s=30.0)
    assert deadline_faults(host, _info(50.0))  # type: ignore[arg-type]  # needs > 30
    host.deadline_s = 30.5
    assert deadline_faults(host, _info(50.0)) == []  # type: ignore[arg-type]
