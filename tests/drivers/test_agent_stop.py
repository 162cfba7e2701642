"""Protocol 3's control path, on a real agent process with an arm whose push lasts
seconds (``slow_arm.SlowArmBackend``): heartbeats answered during a push, ``stop``
mid-push, stdin closed mid-push, the watchdog when the controller falls silent, and a
``BackendError`` as one line without a traceback.

Latencies are measured between processes on ``time.monotonic()`` (one clock on Linux):
the test stamps what it sends and receives, the backend stamps what it does.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from driver_fakes import RecordingBackend, frames_of, local_host, lockstep_serve, wait_until
from slow_arm import EVENTS_ENV, PUSH_S_ENV, read_events

from drivers import agent
from drivers import wire as p
from drivers.backends.base import ArmOutcome
from drivers.errors import BackendError
from drivers.transport import agent_argv

pytestmark = pytest.mark.alone  # wall-clock bounds (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[2]
SLOW_ARM = Path(__file__).with_name("slow_arm.py")
FACES = {"left": 1, "right": 2}


class SlowAgent:
    """The real agent serving a SlowArmBackend, read frame by frame, every frame stamped."""

    def __init__(self, events: Path, push_s: float, *args: str) -> None:
        self.events = events
        env = dict(os.environ, PYTHONPATH=str(ROOT), **{EVENTS_ENV: str(events),
                                                        PUSH_S_ENV: str(push_s)})
        self.proc = subprocess.Popen(
            [sys.executable, str(SLOW_ARM), "--backend", "twin", "--host", "slow", *args],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
            env=env)
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()

        def read(n: int, deadline: float) -> bytes:
            if not select.select([fd], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise TimeoutError("the agent did not answer")
            return os.read(fd, n)

        self.reader = p.FrameReader(read, "agent")
        self.next_id = 1

    def send(self, mtype: str, **fields: Any) -> tuple[int, float]:
        """Write one request; its id and when it went."""
        assert self.proc.stdin is not None
        mid = self.next_id
        self.next_id += 1
        self.proc.stdin.write(p.make_request(mtype, mid, **fields))
        self.proc.stdin.flush()
        return mid, time.monotonic()

    def read(self, timeout_s: float = 10.0) -> tuple[p.Frame, float]:
        """The next frame and when it came."""
        frame = self.reader.read_frame(time.monotonic() + timeout_s)
        return frame, time.monotonic()

    def call(self, mtype: str, **fields: Any) -> p.Frame:
        mid, _ = self.send(mtype, **fields)
        frame, _ = self.read()
        assert frame.id == mid, frame.header
        return frame

    def hello(self) -> None:
        assert self.call("hello", version=p.PROTOCOL_VERSION, host="slow").type == "hello_ok"

    def event(self, name: str, timeout_s: float = 10.0) -> dict[str, Any]:
        """The first event ``name`` of this agent (waits for it)."""
        found: list[dict[str, Any]] = []

        def seen() -> bool:
            found[:] = [e for e in read_events(self.events, self.proc.pid)
                        if e["event"] == name]
            return bool(found)

        wait_until(seen, timeout_s, f"the backend's {name!r}", poll_s=0.005)
        return found[0]

    def names(self) -> list[str]:
        return [e["event"] for e in read_events(self.events, self.proc.pid)]

    def stderr(self) -> str:
        assert self.proc.stderr is not None
        return self.proc.stderr.read().decode()


@pytest.fixture
def slow_agent(tmp_path: Path) -> Iterator[Callable[..., SlowAgent]]:
    started: list[SlowAgent] = []

    def start(*args: str, push_s: float = 3.0) -> SlowAgent:
        a = SlowAgent(tmp_path / f"events{len(started)}.jsonl", push_s, *args)
        started.append(a)
        return a

    yield start
    for a in started:
        if a.proc.poll() is None:
            a.proc.kill()
        a.proc.wait(5)
        for f in (a.proc.stdin, a.proc.stdout, a.proc.stderr):
            if f is not None:
                f.close()


@pytest.mark.slow
def test_heartbeats_are_answered_at_once_during_a_push(
        slow_agent: Callable[..., SlowAgent]) -> None:
    """At the fleet's cadence (0.5 s) with its watchdog (heartbeat + 1 s): every reply
    within 0.2 s, while the agent reports the push in progress; the push runs to its end."""
    a = slow_agent("--watchdog", "1.5", push_s=3.0)
    a.hello()
    push_id, _ = a.send("push", faces=FACES)
    a.event("push_start")
    latencies: list[float] = []
    for _ in range(4):  # 2 s of the 3 s push
        time.sleep(0.5)
        mid, sent = a.send("heartbeat")
        frame, got = a.read()
        assert (frame.type, frame.id) == ("heartbeat_ok", mid), frame.header
        assert frame.header["busy"] == "push"
        latencies.append(got - sent)
    frame, _ = a.read()
    assert (frame.type, frame.id) == ("push_ok", push_id)  # not stopped: we kept talking
    assert max(latencies) < 0.2, latencies
    assert "stop" not in a.names()
    wait_until(lambda: a.call("heartbeat").header["busy"] is None, 2.0,
               "the worker idle")  # it marks itself idle just after its reply
    assert a.call("bye").type == "bye_ok"
    assert a.proc.wait(10) == agent.EXIT_OK
    print(f"heartbeat reply during a push: max {max(latencies) * 1e3:.1f} ms")


def test_stop_mid_push_stops_the_backend_at_once_and_the_agent_serves_on(
        slow_agent: Callable[..., SlowAgent]) -> None:
    a = slow_agent(push_s=20.0)
    a.hello()
    push_id, _ = a.send("push", faces=FACES)
    a.event("push_start")
    time.sleep(0.3)
    stop_id, t_stop = a.send("stop")
    replies = {}
    for _ in range(2):
        frame, got = a.read()
        replies[frame.id] = (frame, got)
    stop_ok, t_stop_ok = replies[stop_id]
    assert stop_ok.type == "stop_ok"
    stopped = a.event("stop")["t"] - t_stop
    assert stopped < 0.2 and t_stop_ok - t_stop < 0.2
    # The interrupted push gets its reply: the backend's BackendError, one line, no
    # traceback (an expected refusal).
    err, t_err = replies[push_id]
    assert err.type == "error" and err.header["kind"] == "backend" and not err.header["fatal"]
    assert err.header["message"].startswith("push stopped after")
    assert "\n" not in err.header["message"] and err.header["traceback"] == ""
    assert t_err - t_stop < 0.5
    # ... and the agent serves on.
    assert a.call("observe").type == "observe_ok"
    # the worker marks itself idle just after it sent that reply: a heartbeat in between
    # may still see "observe" (it raced there once under CI's load), so wait for idle
    wait_until(lambda: a.call("heartbeat").header["busy"] is None, 2.0, "the worker idle")
    assert a.call("bye").type == "bye_ok"
    assert a.proc.wait(10) == agent.EXIT_OK
    assert a.names()[-2:] == ["rest", "close"]
    print(f"stop frame -> backend.stop(): {stopped * 1e3:.1f} ms; -> push reply: "
          f"{(t_err - t_stop) * 1e3:.1f} ms")


def test_stdin_closed_mid_push_stops_and_exits_without_rest(
        slow_agent: Callable[..., SlowAgent]) -> None:
    a = slow_agent(push_s=20.0)
    a.hello()
    a.send("push", faces=FACES)
    a.event("push_start")
    assert a.proc.stdin is not None
    t_close = time.monotonic()
    a.proc.stdin.close()
    assert a.proc.wait(10) == agent.EXIT_OK
    t_exit = time.monotonic()
    stopped = a.event("stop")["t"] - t_close
    assert stopped < 1.0
    names = a.names()
    assert "rest" not in names and names[-1] == "close" and "push_stopped" in names
    text = a.stderr()
    assert "stopped the backend (the controller closed the stream) during push" in text
    assert "closing the backend without moving the arms" in text
    print(f"EOF -> backend.stop(): {stopped * 1e3:.1f} ms; -> exit: "
          f"{(t_exit - t_close) * 1e3:.1f} ms")


def test_watchdog_stops_the_push_when_the_controller_falls_silent(
        slow_agent: Callable[..., SlowAgent]) -> None:
    """The link stopped answering: the pipe stays open, nothing comes. Stop within
    S + 1 s of the last frame; the agent then serves on when the controller is back."""
    a = slow_agent("--watchdog", "1.0", push_s=20.0)
    a.hello()
    push_id, t_last = a.send("push", faces=FACES)
    stop = a.event("stop", timeout_s=5.0)
    silent = stop["t"] - t_last
    assert 1.0 <= silent <= 2.0, silent
    frame, _ = a.read()
    assert frame.id == push_id and frame.type == "error"
    assert "push stopped" in frame.header["message"]
    assert a.call("heartbeat").type == "heartbeat_ok"  # the controller is back
    assert a.call("bye").type == "bye_ok"
    assert a.proc.wait(10) == agent.EXIT_OK
    assert "watchdog: no frame from the controller for" in a.stderr()
    print(f"watchdog 1.0 s: stopped {silent * 1e3:.0f} ms after the last frame")


def test_idle_timeout_counts_only_while_no_request_runs(
        slow_agent: Callable[..., SlowAgent]) -> None:
    """A push longer than the idle timeout, with no heartbeat and no watchdog (a v2-like
    controller), runs to its end; the idle timeout starts after its reply."""
    a = slow_agent("--idle-timeout", "0.5", push_s=1.5)
    a.hello()
    a.send("push", faces=FACES)
    frame, t_reply = a.read()
    assert frame.type == "push_ok"
    assert a.proc.wait(10) == agent.EXIT_IDLE
    assert time.monotonic() - t_reply >= 0.4
    assert a.names() == ["push_start", "push_done", "close"]


# ------------------------------------------------------------------------- in-process
class RefusingBackend(RecordingBackend):
    """A push refused as a real controller refuses (BackendError), or failing as a bug."""

    def __init__(self, exc: Exception) -> None:
        super().__init__()
        self.exc = exc

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        raise self.exc


HELLO = p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host="h")


def serve(reqs: Sequence[bytes], backend: RecordingBackend) -> list[p.Frame]:
    rc, out = lockstep_serve([HELLO, *reqs], backend)
    assert rc == agent.EXIT_OK
    return frames_of(out)


def test_a_backend_error_is_one_line_without_traceback_other_errors_keep_theirs() -> None:
    refused = BackendError("the controller is in manual mode; switch it to auto")
    refused.arm = "left"  # type: ignore[attr-defined]
    push = p.make_request("push", 2, faces={"left": 0})
    err = serve([push], RefusingBackend(refused))[1].header
    assert err["kind"] == "backend" and err["arm"] == "left" and err["traceback"] == ""
    assert err["message"] == "the controller is in manual mode; switch it to auto"
    bug = serve([push], RefusingBackend(KeyError("cube")))[1].header
    assert bug["message"] == "KeyError: 'cube'" and "Traceback" in bug["traceback"]


def test_stop_is_answered_even_before_hello_and_heartbeat_is_not() -> None:
    backend = RecordingBackend()
    rc, out = lockstep_serve([p.make_request("stop", 7), p.make_request("heartbeat", 8),
                              HELLO, p.make_request("stop", 9)], backend)
    assert rc == agent.EXIT_OK
    frames = frames_of(out)
    assert [(f.type, f.id) for f in frames] == [("stop_ok", 7), ("error", 8),
                                                ("hello_ok", 1), ("stop_ok", 9)]
    assert "before hello" in frames[1].header["message"]
    assert backend.motions() == []  # a stop moves nothing


# ---------------------------------------------------------------------- the argv
def test_agent_argv_carries_the_watchdog_and_a_yumi_hosts_login_and_motion_limit() -> None:
    argv = agent_argv(local_host("t", heartbeat_s=2.0), seed=0, python="py",
                      idle_timeout_s=30)
    assert argv[argv.index("--watchdog") + 1] == "3"
    assert "--credentials-file" not in argv and "--motion-timeout" not in argv
    arm = SimpleNamespace(name="left", mirror=False, crop=None, calibration=None)
    yumi: Any = SimpleNamespace(backend="yumi", name="y", arms=[arm], heartbeat_s=0.5,
                                workdir=None, camera="0", controller_url="http://10.0.0.5",
                                credentials_file="/etc/yumi/login", motion_timeout_s=12.5)
    argv = agent_argv(yumi, seed=0, python="py", idle_timeout_s=30)
    assert argv[argv.index("--watchdog") + 1] == "1.5"
    assert argv[argv.index("--credentials-file") + 1] == "/etc/yumi/login"
    assert argv[argv.index("--motion-timeout") + 1] == "12.5"
    yumi.credentials_file = yumi.motion_timeout_s = None
    argv = agent_argv(yumi, seed=0, python="py", idle_timeout_s=30)
    assert "--credentials-file" not in argv and "--motion-timeout" not in argv


def test_login_and_motion_limit_reach_make_backend_only_when_given() -> None:
    base = ["--backend", "yumi", "--camera", "0", "--controller-url", "http://r"]
    kwargs = agent._backend_kwargs(agent.parse_args(base))
    assert isinstance(kwargs, dict)
    assert "credentials_file" not in kwargs and "motion_timeout_s" not in kwargs
    kwargs = agent._backend_kwargs(agent.parse_args(
        [*base, "--credentials-file", "/etc/yumi/login", "--motion-timeout", "12.5",
         "--watchdog", "3"]))
    assert isinstance(kwargs, dict)
    assert kwargs["credentials_file"] == "/etc/yumi/login" and kwargs["motion_timeout_s"] == 12.5
    assert agent._backend_kwargs(agent.parse_args([*base, "--mirror", "0"])) == (
        "--mirror needs one value per arm (2)")
