"""The host agent as a real process: frames only on stdout, clear errors, clean exits."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from driver_fakes import ExplodingBackend, frames_of, lockstep_serve

from drivers import agent
from drivers import wire as p
from drivers.backends.base import ArmView

ROOT = Path(__file__).resolve().parents[2]


class Agent:
    """``python -m drivers.agent`` with pipes, read frame by frame with deadlines."""

    def __init__(self, *args: str) -> None:
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen([sys.executable, "-m", "drivers.agent", *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, cwd=ROOT, env=env)
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()

        def read(n: int, deadline: float) -> bytes:
            if not select.select([fd], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise TimeoutError("agent did not answer")
            return os.read(fd, n)

        self.reader = p.FrameReader(read, "agent")
        self.next_id = 1

    def send_raw(self, data: bytes) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(data)
        self.proc.stdin.flush()

    def call(self, mtype: str, **fields: object) -> p.Frame:
        mid = self.next_id
        self.next_id += 1
        self.send_raw(p.make_request(mtype, mid, **fields))
        frame = self.reader.read_frame(time.monotonic() + 30)
        assert frame.id in (mid, 0)
        return frame

    def finish(self, timeout: float = 10) -> tuple[int, bytes, bytes]:
        out, err = self.proc.communicate(timeout=timeout)
        return self.proc.returncode, out, err


@pytest.fixture
def run_agent() -> Iterator[type[Agent]]:
    started: list[Agent] = []

    class Tracked(Agent):
        def __init__(self, *args: str) -> None:
            super().__init__(*args)
            started.append(self)

    yield Tracked
    for a in started:
        if a.proc.poll() is None:
            a.proc.kill()
            a.proc.wait(5)


def test_twin_agent_serves_a_session_and_keeps_stdout_for_frames(run_agent: type[Agent]
                                                                 ) -> None:
    a = run_agent("--backend", "twin", "--host", "cell7", "--seed", "3")
    hello = a.call("hello", version=p.PROTOCOL_VERSION, host="cell7")
    info = p.parse_hello_reply(p.check_reply(hello, "hello_ok", 1, "agent"), "agent")
    assert info.backend == "twin" and info.arms == ("left", "right")
    assert info.mirror == (False, True) and info.pid == a.proc.pid
    views = p.parse_observe_reply(a.call("observe"), info.arms, "agent")
    assert all(v.image.shape == (64, 64, 3) and v.image.any() for v in views.values())
    faces = {arm: v.expert_action for arm, v in views.items() if v.expert_action is not None}
    pushed = p.parse_push_reply(a.call("push", faces=faces), list(faces), "agent")
    assert set(pushed) == set(faces)
    assert p.parse_reset_reply(a.call("reset", arms=["left"]), ["left"], "agent") == {
        "left": True}
    assert a.call("rest").type == "rest_ok"
    assert a.call("heartbeat").header["uptime_s"] >= 0
    assert a.call("bye").type == "bye_ok"
    rc, out, err = a.finish()
    assert rc == 0 and out == b""  # every stdout byte was a frame, read above
    assert b"pybullet build time" in err  # pybullet's print went to stderr


def test_version_mismatch_is_refused(run_agent: type[Agent]) -> None:
    a = run_agent("--backend", "twin", "--no-physics")
    f = a.call("hello", version=p.PROTOCOL_VERSION + 1, host="h")
    assert f.type == "error" and f.header["kind"] == "version" and f.header["fatal"]
    assert "update the project on the host" in f.header["message"]
    assert a.finish()[0] == agent.EXIT_VERSION


def test_backend_that_cannot_start_reports_why_at_hello(run_agent: type[Agent]) -> None:
    a = run_agent("--backend", "yumi", "--host", "yumi1")
    f = a.call("hello", version=p.PROTOCOL_VERSION, host="yumi1")
    assert f.type == "error" and f.header["kind"] == "startup"
    assert "needs --camera" in f.header["message"]
    assert "Traceback" in f.header["traceback"] and "build_yumi_backend" in f.header["traceback"]
    assert a.finish()[0] == agent.EXIT_STARTUP


def test_requests_before_hello_are_refused_not_fatal(run_agent: type[Agent]) -> None:
    a = run_agent("--backend", "twin", "--no-physics")
    f = a.call("observe")
    assert f.type == "error" and "before hello" in f.header["message"]
    assert a.call("hello", version=p.PROTOCOL_VERSION, host="h").type == "hello_ok"
    assert a.call("bye").type == "bye_ok"
    assert a.finish()[0] == 0


@pytest.mark.parametrize("garbage", [
    b"GET / HTTP/1.1\r\n\r\n",
    p.make_request("observe", 9)[:10],
    p.PREFIX.pack(p.MAGIC, 10**7, 0, 0),
])
def test_a_broken_frame_gets_a_fatal_error_frame_and_exit_3(run_agent: type[Agent],
                                                            garbage: bytes) -> None:
    a = run_agent("--backend", "twin", "--no-physics")
    assert a.call("hello", version=p.PROTOCOL_VERSION, host="h").type == "hello_ok"
    a.send_raw(garbage)
    assert a.proc.stdin is not None
    a.proc.stdin.close()
    f = a.reader.read_frame(time.monotonic() + 10)
    assert f.type == "error" and f.header["kind"] == "protocol" and f.header["fatal"]
    assert f.header["message"].startswith(("malformed frame", "truncated frame"))
    rc, out, _ = a.proc.wait(10), a.proc.stdout.read(), None  # type: ignore[union-attr]
    assert rc == agent.EXIT_PROTOCOL and out == b""


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_agent_exits_after_idle_timeout_without_moving(run_agent: type[Agent]) -> None:
    a = run_agent("--backend", "twin", "--no-physics", "--idle-timeout", "0.5")
    assert a.call("hello", version=p.PROTOCOL_VERSION, host="h").type == "hello_ok"
    t0 = time.monotonic()
    assert a.proc.wait(10) == agent.EXIT_IDLE
    assert time.monotonic() - t0 < 5


def test_backend_exception_is_an_error_frame_with_arm_and_traceback() -> None:
    backend = ExplodingBackend()
    reqs = [p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host="h"),
            p.make_request("push", 2, faces={"right": 1}),
            p.make_request("push", 3, faces={"left": 1}),
            p.make_request("push", 4, faces={"left": 9})]
    rc, out = lockstep_serve(reqs, backend)
    assert rc == 0
    frames = frames_of(out)
    assert [f.type for f in frames] == ["hello_ok", "error", "push_ok", "error"]
    err = frames[1].header
    assert err["kind"] == "backend" and err["arm"] == "right" and not err["fatal"]
    assert "gripper camera unplugged" in err["message"] and "in push" in err["traceback"]
    assert frames[3].header["kind"] == "protocol"  # face 9 never reaches the backend
    assert backend.rested == 0  # EOF: an orphaned agent never moves the arms


def test_claim_stdout_sends_prints_to_stderr() -> None:
    code = ("import os, sys; from drivers.agent import claim_stdout; fd = claim_stdout(); "
            "print('stray'); os.write(1, b'c-level'); os.write(fd, b'FRAME')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=30)
    assert r.stdout == b"FRAME"
    assert b"stray" in r.stderr and b"c-level" in r.stderr


def test_image_survives_the_agent_unchanged() -> None:
    img = np.random.default_rng(1).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    data = p.make_observe_reply(1, {"left": ArmView(img, False, (0.5, 0.5))})
    f = p.FrameReader(lambda n, d: data, "a").read_frame(1e18)
    assert np.array_equal(p.parse_observe_reply(f, ["left"], "a")["left"].image, img)
