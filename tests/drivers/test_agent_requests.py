"""The agent's requests of protocol 2 through the real ``serve`` loop: reseed, frame,
move_tcp, save_calibration, per-arm refusals and errors, and backends that lack one."""

from __future__ import annotations

import numpy as np
from driver_fakes import RecordingBackend, frames_of, lockstep_serve

from drivers import agent
from drivers import wire as p
from drivers.backends.base import ArmOutcome, ArmView


def run(backend: RecordingBackend, *reqs: tuple[str, dict]) -> list[p.Frame]:
    data = [p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host="h")] + [
        p.make_request(t, i + 2, **f) for i, (t, f) in enumerate(reqs)]
    rc, out = lockstep_serve(data, backend)
    assert rc == agent.EXIT_OK
    frames = frames_of(out)
    assert frames[0].type == "hello_ok"
    return frames[1:]


def test_reseed_frame_move_tcp_save_calibration_reach_the_backend() -> None:
    b = RecordingBackend()
    f = run(b, ("reseed", {"seed": 9}), ("frame", {}),
            ("move_tcp", {"arm": "left", "xyz_mm": [400, 120, 10]}),
            ("save_calibration", {"arm": "right", "data": {"z_push_mm": 12.0}}))
    assert [x.type for x in f] == ["reseed_ok", "frame_ok", "move_tcp_ok",
                                   "save_calibration_ok"]
    assert np.array_equal(p.parse_frame_reply(f[1], "a"), b.frame())
    assert p.parse_move_tcp_reply(f[2], "a") == (400.0, 120.0, 10.25)
    assert p.parse_save_calibration_reply(f[3], "a") == "/calib/right.json"
    assert ("reseed", 9) in b.calls and ("move_tcp", ("left", (400.0, 120.0, 10.0))) in b.calls
    assert ("save_calibration", ("right", {"z_push_mm": 12.0})) in b.calls


def test_a_backend_without_a_capability_says_so_as_a_request_error() -> None:
    f = run(RecordingBackend(capable=False), ("reseed", {"seed": 1}), ("frame", {}),
            ("move_tcp", {"arm": "left", "xyz_mm": [1, 2, 3]}),
            ("save_calibration", {"arm": "left", "data": {}}), ("heartbeat", {}))
    for frame, what in zip(f, ["be reseeded", "take a full camera frame",
                               "move a TCP to a point", "save a calibration"], strict=False):
        h = frame.header
        assert frame.type == "error" and h["kind"] == "request" and not h["fatal"]
        assert h["message"].startswith(f"this backend (recording) cannot {what}")
    assert f[2].header["arm"] == "left"
    assert f[4].type == "heartbeat_ok"  # the agent keeps serving


def test_a_refused_move_names_the_arm() -> None:
    f = run(RecordingBackend(), ("move_tcp", {"arm": "right", "xyz_mm": [400, -120, -5]}))
    h = f[0].header
    assert f[0].type == "error" and h["kind"] == "request" and h["arm"] == "right"
    assert "below the table" in h["message"]


def test_per_arm_refusal_error_and_missing_view_travel_per_arm() -> None:
    b = RecordingBackend(push_outcomes={"left": ArmOutcome(False, False, refused="cube not found"),
                                        "right": ArmOutcome(False, False, error="IK failed")},
                         observe_errors={"right": "arm right is being calibrated"})
    f = run(b, ("push", {"faces": {"left": 0, "right": 1}}), ("observe", {}))
    out = p.parse_push_reply(f[0], ["left", "right"], "a")
    assert out["left"].refused == "cube not found" and out["right"].error == "IK failed"
    views = p.parse_observe_reply(f[1], ["left", "right"], "a")
    assert isinstance(views["left"], ArmView)
    assert views["right"] == p.ArmFailed("RuntimeError: arm right is being calibrated")
