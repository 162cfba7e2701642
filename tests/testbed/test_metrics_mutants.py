"""The metrics' edges that scripts/mutation.sh found untested (docs/notes/tests.md).

Why: every figure of a run (summary.json, the curves, ROHE) comes from
testbed/records/metrics.py; a mutation run showed changes to it that no test noticed: the
curves' integer type, a reset counted per arm-step when an arm that is not in reset
follows it in the same step, ROHE with one robot, and the ROHE curve with no robot.
"""

from __future__ import annotations

import numpy as np
from test_records import LOG, robot

from testbed.records.metrics import cumulative, rohe, summarize


def test_the_count_curves_are_integers() -> None:
    """Counts stay int64 (a float curve prints 3.0 successes in the report's tables)."""
    curves = cumulative(LOG, num_humans=2)
    for k in ("t", "successes", "hard_resets", "idle_time", "human_actions"):
        assert curves[k].dtype == np.int64, k
    assert curves["rohe"].dtype == np.float64


def test_every_arm_in_reset_counts_even_when_an_arm_not_in_reset_follows() -> None:
    rows = [{"t": 0, "robots": [robot("h/a", "reset", 0), robot("h/b", "reset", 1),
                                robot("h/c", "autonomous", action=1)]},
            {"t": 1, "robots": [robot("h/a", "reset", 0), robot("h/b", "autonomous",
                                                                 action=0)]}]
    s = summarize(rows, "cur", num_humans=2)
    assert (s["reset_steps"], s["human_actions"], s["idle_time"]) == (3, 3, 3)


def test_rohe_with_one_robot_is_the_formula_not_zero() -> None:
    assert rohe(6, 2, num_humans=1, num_robots=1) == 2.0
    one = [{"t": 0, "robots": [robot("h/a", "autonomous", action=1, success=True)]},
           {"t": 1, "robots": [robot("h/a", "teleop", 0, action=2, success=True)]}]
    np.testing.assert_array_equal(cumulative(one, num_humans=3)["rohe"], [3.0, 3.0])


def test_the_rohe_curve_with_no_robot_is_zeros_of_the_steps_length() -> None:
    curves = cumulative(LOG, num_humans=2, num_robots=0)
    np.testing.assert_array_equal(curves["rohe"], [0.0, 0.0, 0.0, 0.0])
    assert curves["rohe"].shape == (4,)


def test_the_rohe_curve_of_an_empty_log_is_empty() -> None:
    curves = cumulative([], num_humans=2)
    assert curves["rohe"].shape == (0,)
    assert curves["t"].shape == (0,)
