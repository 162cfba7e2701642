"""The read-only look ``testbed check`` and every trial's first check make (issue 43):
the YuMi backend's ``describe`` never moves an arm, it names an arm in the camera's view
with the fix; and an agent whose session only looked (hello, describe, frame) rests
nothing at bye, so a check that refused an arm where it is leaves it there."""

from __future__ import annotations

from pathlib import Path

from driver_fakes import RecordingBackend, frames_of, lockstep_serve, make_yumi, twin_picture

from drivers import agent
from drivers import wire as p
from drivers.yumi.backend import in_view_faults

HELLO = p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host="h")


def test_describe_names_an_arm_in_view_and_moves_nothing(tmp_path: Path) -> None:
    backend, ctrl = make_yumi(tmp_path, [twin_picture(0)])
    healthy = backend.describe()
    assert healthy["in_view"] == {} and in_view_faults(healthy) == []
    assert set(healthy["camera"]["crops"]) == {"left", "right"}  # judged: nothing in view
    ctrl.stuck.add("left")  # left over the table, as a stopped program or a jog leaves it
    info = backend.describe()
    assert ctrl.programs == []  # no program, before or now: the picture step would send one
    x, y, z = ctrl.in_view_xyz
    assert info["in_view"] == {"left": [x, y, z]}
    assert "crops" not in info["camera"] and info["camera"]["size"]  # the arm would be in them
    assert in_view_faults(info) == [
        f"arm left is in the camera's view at ({x:.0f}, {y:.0f}, {z:.0f}) mm: jog it to rest "
        f"on the FlexPendant, then check again"]
    backend.close()


def test_a_session_that_only_looked_rests_nothing_at_bye() -> None:
    looked = RecordingBackend()
    rc, out = lockstep_serve([HELLO, p.make_request("describe", 2), p.make_request("frame", 3),
                              p.make_request("bye", 4)], looked)
    assert rc == agent.EXIT_OK
    assert [f.type for f in frames_of(out)][-1] == "bye_ok"
    assert [c[0] for c in looked.calls] == ["frame", "close"]  # no rest: as it found them
    observed = RecordingBackend()  # an observation may move an arm (a YuMi's picture step)
    rc, _ = lockstep_serve([HELLO, p.make_request("observe", 2), p.make_request("bye", 3)],
                           observed)
    assert rc == agent.EXIT_OK
    assert [c[0] for c in observed.calls] == ["observe", "rest", "close"]
