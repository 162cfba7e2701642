"""Issue 35, the safety case's lost link (docs/safety.md): a program the controller has
started runs to its end when the PC that started it vanishes mid-motion.

Why: nothing on the PC can stop a motion once its link to the controller is gone, so the
safety case rests on the program being bounded and running to its end (the pusher back
at rest), never on the PC. A twin that stopped, or froze, a program when its RWS client
went away would hide what the robot does (docs/rws-checklist.md asks a lab to confirm
it on day one). The client here is ABB's unchanged one; its connections are closed while
the arm is moving, and a second client, as a person at another PC, reads the outcome."""

from __future__ import annotations

import pytest
from twin_rws import client, newest, our_twin, program, since, start, stay, wait_stopped

from sim_twin.rws.testbed_rapid import DONE
from sim_twin.yumi_arms import rest_tip


def test_a_started_program_runs_to_its_end_when_its_client_vanishes() -> None:
    with our_twin() as tw:
        prev = newest(tw.c)
        target = (330.0, -250.0, 80.0)
        start(tw.c, {"T_ROB_R": program([("J", (310.0, -250.0, 100.0), 150),
                                         ("L", target, 20), ("L", (310.0, -250.0, 100.0), 20),
                                         ("R", "right", 150)]),
                     "T_ROB_L": stay()})
        assert tw.c.get_execution_state().ctrlexecstate == "running"
        tw.c._session.close()  # the PC is gone: its connections closed, no more requests
        other = client(tw.c.base_url)
        assert other.get_execution_state().ctrlexecstate == "running"  # mid-motion
        wait_stopped(other, timeout_s=60.0)
        titles = [e.title for e in since(other, prev) if e.code != 10002]
        assert DONE in titles, titles  # the program ran to its end, no error entry
        assert not [e for e in since(other, prev) if e.msgtype == 3]
        assert tw.tcps()["right"] == pytest.approx(rest_tip("right"), abs=1.0)
