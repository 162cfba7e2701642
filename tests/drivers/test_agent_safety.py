"""The agent's safety rules: one agent per robot (a real lock, two real processes), and an
orphaned agent never moves an arm (rest only on request or bye)."""

from __future__ import annotations

import json
import os
import pwd
import select
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from driver_fakes import RecordingBackend, frames_of, lockstep_serve, wait_until

from drivers import agent
from drivers import wire as p
from drivers.agent.agent_cli import _robot_identity, parse_args
from drivers.errors import DeadlineExceeded
from drivers.hostlock import lock_path, normalise_url

ME = pwd.getpwuid(os.geteuid()).pw_name

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------ orphaned agents, in-process
def serve_script(reqs: list[bytes], backend: RecordingBackend, *,
                 tail: Callable[[], bytes] = lambda: b"",
                 write: Callable[[bytes], None] | None = None) -> tuple[int, list[bytes]]:
    """Serve ``reqs`` in lockstep (each after the reply to the one before), then
    whatever ``tail`` gives (b"" = EOF)."""
    return lockstep_serve(reqs, backend, tail=tail, write=write)


HELLO = p.make_request("hello", 1, version=p.PROTOCOL_VERSION, host="h")
PUSH = p.make_request("push", 2, faces={"left": 1, "right": 2})


def idle(*_: object) -> bytes:
    raise DeadlineExceeded("no frame from the controller in time")


def broken_pipe_after(n: int) -> Callable[[bytes], None]:
    count = [0]

    def write(data: bytes) -> None:
        count[0] += 1
        if count[0] > n:
            raise BrokenPipeError("the controller is gone")

    return write


@pytest.mark.parametrize(("case", "rc"), [
    ("eof", agent.EXIT_OK), ("idle", agent.EXIT_IDLE), ("broken frame", agent.EXIT_PROTOCOL),
    ("truncated frame", agent.EXIT_PROTOCOL), ("broken pipe", agent.EXIT_LINK)])
def test_an_agent_whose_controller_vanished_sends_no_motion(case: str, rc: int) -> None:
    backend = RecordingBackend()
    reqs = [HELLO, PUSH]
    kw: dict[str, object] = {}
    if case == "idle":
        kw["tail"] = idle
    elif case == "broken frame":
        reqs.append(b"GET / HTTP/1.1\r\n\r\n")
    elif case == "truncated frame":
        reqs.append(p.make_request("rest", 3)[:12])
    elif case == "broken pipe":  # hello_ok is written, the push reply is not
        reqs.append(p.make_request("rest", 3))
        kw["write"] = broken_pipe_after(1)
    got, _ = serve_script(reqs, backend, **kw)  # type: ignore[arg-type]
    assert got == rc
    # The push was asked for; after it, nothing moves (the rest request of the
    # broken-pipe case is never run: the push reply could not be written).
    assert backend.calls == [("push", {"left": 1, "right": 2}), ("close", None)]


def test_rest_only_when_asked_and_at_bye_before_bye_ok() -> None:
    backend = RecordingBackend()
    seen_at_bye: list[list[tuple[str, object]]] = []
    out: list[bytes] = []

    def write(data: bytes) -> None:
        out.append(data)
        if frames_of([data])[0].type == "bye_ok":
            seen_at_bye.append(list(backend.calls))

    reqs = [HELLO, p.make_request("rest", 2), PUSH, p.make_request("bye", 4)]
    rc, _ = serve_script(reqs, backend, write=write)
    assert rc == agent.EXIT_OK
    assert [f.type for f in frames_of(out)] == ["hello_ok", "rest_ok", "push_ok", "bye_ok"]
    assert [c[0] for c in backend.calls] == ["rest", "push", "rest", "close"]
    assert seen_at_bye[0][-1] == ("rest", None)  # at rest before the controller hears bye_ok


def test_a_real_orphaned_twin_agent_exits_without_moving() -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "drivers.agent", "--backend", "twin",
                             "--no-physics", "--host", "orphan"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT, env=env)
    try:
        out, err = proc.communicate(HELLO + PUSH, timeout=30)  # then EOF: controller gone
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == agent.EXIT_OK
    frames = p.FrameReader(lambda n, d, b=[out]: b.pop() if b else b"", "agent")
    assert frames.read_frame(1e18).type == "hello_ok"
    # The push came with the EOF: it may have run (its reply unwritten: nobody reads
    # it) or not; nothing runs after it, nothing rests.
    text = err.decode()
    assert "closed the stream; closing the backend without moving the arms" in text
    assert "bye" not in text
    assert " agent[orphan] INFO " in text and text[:4].isdigit()  # timestamped lines


# ------------------------------------------------------------------ the per-robot lock
class LiveAgent:
    """A real agent process, read frame by frame."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        full_env = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))
        self.proc = subprocess.Popen([sys.executable, "-m", "drivers.agent", *args],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, cwd=ROOT, env=full_env)
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()

        def read(n: int, deadline: float) -> bytes:
            if not select.select([fd], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise TimeoutError("agent did not answer")
            return os.read(fd, n)

        self.reader = p.FrameReader(read, "agent")

    def call(self, mtype: str, mid: int, **fields: object) -> p.Frame:
        assert self.proc.stdin is not None
        self.proc.stdin.write(p.make_request(mtype, mid, **fields))
        self.proc.stdin.flush()
        return self.reader.read_frame(time.monotonic() + 30)

    def hello(self) -> p.Frame:
        return self.call("hello", 1, version=p.PROTOCOL_VERSION, host="h")


@pytest.fixture
def agents() -> Iterator[Callable[..., LiveAgent]]:
    started: list[LiveAgent] = []

    def start(*args: str, env: dict[str, str] | None = None) -> LiveAgent:
        a = LiveAgent(list(args), env)
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


def test_a_second_agent_for_the_same_robot_is_refused_naming_the_holder(
        tmp_path: Path, agents: Callable[..., LiveAgent]) -> None:
    locks = str(tmp_path / "locks")
    first = agents("--backend", "twin", "--no-physics", "--host", "yumi-a", "--lock-id",
                   "cell-7", "--lock-dir", locks,
                   env={"SSH_CONNECTION": "127.0.0.1 51514 127.0.0.1 22"})
    assert first.hello().type == "hello_ok"
    # The second would build a PHYSICS twin (pybullet prints at import): it must not.
    second = agents("--backend", "twin", "--host", "yumi-b", "--lock-id", "cell-7",
                    "--lock-dir", locks)
    f = second.hello()
    assert f.type == "error" and f.header["kind"] == "startup" and f.header["fatal"]
    msg = f.header["message"]
    assert msg.startswith(f"robot cell-7 is held by agent pid {first.proc.pid} of user {ME} "
                          f"on host yumi-a since ")
    assert "from 127.0.0.1 51514" in msg and "lock file" in msg
    assert second.proc.wait(10) == agent.EXIT_STARTUP
    assert second.proc.stderr is not None
    assert b"pybullet build time" not in second.proc.stderr.read()  # never built
    holder = json.loads(lock_path(locks, "cell-7").read_text())
    assert holder["pid"] == first.proc.pid and holder["host"] == "yumi-a"
    # The holder says bye: the lock is free for the next agent.
    assert first.call("bye", 2).type == "bye_ok" and first.proc.wait(10) == 0
    third = agents("--backend", "twin", "--no-physics", "--lock-id", "cell-7",
                   "--lock-dir", locks)
    assert third.hello().type == "hello_ok"


def test_yumi_agents_lock_the_normalised_controller_url(
        tmp_path: Path, agents: Callable[..., LiveAgent]) -> None:
    locks = str(tmp_path / "locks")
    path = lock_path(locks, "twin+http://127.0.0.1:4101")
    # No camera: this backend cannot start, but the agent holds the lock until it exits.
    first = agents("--backend", "yumi", "--host", "yumi-a", "--lock-dir", locks,
                   "--controller-url", "twin+http://127.0.0.1:4101")
    wait_until(lambda: path.exists() and str(first.proc.pid) in path.read_text(), 20,
               "the first agent to take the lock")
    second = agents("--backend", "yumi", "--host", "yumi-b", "--lock-dir", locks,
                    "--controller-url", "TWIN+HTTP://127.0.0.1:4101/", "--camera", "0")
    f = second.hello()
    assert f.type == "error" and f.header["kind"] == "startup"
    assert (f"robot twin+http://127.0.0.1:4101 is held by agent pid {first.proc.pid} of "
            f"user {ME} on host yumi-a") in f.header["message"]
    # Twin agents without --lock-id share nothing: both start.
    t1 = agents("--backend", "twin", "--no-physics", "--lock-dir", locks)
    t2 = agents("--backend", "twin", "--no-physics", "--lock-dir", locks)
    assert t1.hello().type == t2.hello().type == "hello_ok"


def test_lock_identity_and_url_normalisation() -> None:
    assert normalise_url("TWIN+HTTP://LocalHost:4101/") == "twin+http://localhost:4101"
    assert normalise_url("http://10.0.0.5") == normalise_url("http://10.0.0.5:80/")
    assert normalise_url("https://robot/rws") == "https://robot:443/rws"
    twin = ["--backend", "twin"]
    assert _robot_identity(parse_args(twin), None) is None  # a twin owns its own cell
    assert _robot_identity(parse_args([*twin, "--lock-id", "x"]), None) == "x"
    yumi = parse_args(["--backend", "yumi", "--controller-url", "http://R:80"])
    assert _robot_identity(yumi, None) == "http://r:80"  # the controller could not say
    assert _robot_identity(yumi, {"serial": "14000-501234"}) == "IRC5 14000-501234"
    assert lock_path("/d", "a/b").parent == Path("/d") and "/" not in lock_path("/d", "a/b").name
