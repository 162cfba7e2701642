"""Issue 35: with SingArea Wrist (our RAPID), a string of straight lines over the table
never winds a wrist axis past its limit.

Why: with the pusher pointing down the forearm stands upright somewhere over every table
box, at every arm angle that reaches it, so the wrist passes near its singularity (axis 5
near 0) where holding the tool down turns axis 4 fast. A twin that held the tool's axis
exact and let axis 4 alone follow it wound axis 4 round by half a turn and more over a
few lines and stopped them with 50027 ("axis 4 2.0 deg past its limit" within the first
programs of this walk): the rehearsal's calibration and pushes failed so. The twin now
interpolates the wrist's axes from each line's start to its end (the closest solution
within the limits), as ABB's Wrist lets the orientation differ between the ends
(``sim_twin/rws/arm_supervision.py``, ``ArmSupervisor._wrist_line``), so no line passes a
limit by winding; the tip still follows every line."""

from __future__ import annotations

import numpy as np
import pytest
from twin_rws import our_twin, program, run, stay

from drivers.yumi.paths import gate_xy
from sim_twin.yumi_arms import ArmModel
from sim_twin.yumi_geometry import workspace_mm
from testbed.lab.camera_model import push_box


@pytest.mark.parametrize("side", ["left", "right"])
def test_a_walk_of_random_lines_over_the_box_never_winds_a_joint_past_its_limit(
        side: str) -> None:
    rng = np.random.default_rng(3)
    box = push_box(workspace_mm(side))  # the shipped table box
    me, other = ("T_ROB_L", "T_ROB_R") if side == "left" else ("T_ROB_R", "T_ROB_L")
    model = ArmModel(side)
    with our_twin() as tw:
        assert run(tw.c, {me: program([("J", (*gate_xy(box), 100.0), 150)]),
                          other: stay()})[-1].title == "Testbed Motion Done"
        for k in range(12):  # 96 lines, never by rest (whose MoveAbsJ would unwind)
            moves = [("L", (float(rng.uniform(box[0], box[2])),
                            float(rng.uniform(box[1], box[3])), float(rng.choice([10, 80]))),
                      150) for _ in range(8)]
            got = run(tw.c, {me: program(moves), other: stay()})
            assert not [(e.code, e.desc) for e in got if e.msgtype == 3], (k, got)
            assert tw.tcps()[side] == pytest.approx(moves[-1][1], abs=1.0)
            assert model.limit_violation(tw.hook.arms.joints[side]) is None
