"""The controller's side of protocol 3 with a real agent over the local transport: the
heartbeat goes on while a fleet call holds the link, ``HostFleet.stop_motion`` stops a
push in flight, Ctrl-C mid-call sends the stop before the links are dropped, the
console's confirmed Stop stops the motion, and a late ``heartbeat_ok`` never passes for
(or breaks) a call's reply.

The agent is the real one serving ``slow_arm.SlowArmBackend`` (a push of seconds): the
argv that ``agent_argv`` builds runs ``tests/drivers/slow_arm.py`` instead of ``-m
drivers.agent``, everything else as built (``--watchdog`` included).
"""

from __future__ import annotations

import itertools
import os
import select
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from driver_fakes import local_host, ssh_host, wait_until
from slow_arm import EVENTS_ENV, PUSH_S_ENV, read_events

import drivers.session
from drivers import wire as p
from drivers.errors import DeadlineExceeded, ProtocolError
from drivers.host_fleet import HostFleet
from drivers.link import AgentLink
from drivers.testing.sshd import SshServer
from drivers.transport import Transport, agent_argv
from gui.console_core import OVERVIEW, ConsoleCore
from gui.keys import Command, KeyCommand
from testbed.core.types import Fault, PushResult
from testbed.core.wrappers import HostsWrapper, HumansWrapper

pytestmark = pytest.mark.alone  # wall-clock bounds (tests/conftest.py)

SLOW_ARM = Path(__file__).with_name("slow_arm.py")
PUSH = {"slow/left": 1, "slow/right": 2}


class Slow:
    """A one-host fleet whose agent serves a SlowArmBackend; its events file."""

    def __init__(self, events: Path) -> None:
        self.events = events
        self.fleet = HostFleet([local_host("slow", heartbeat_s=0.5, deadline_s=30.0)],
                               reconnect_backoff_s=0.2)
        self.fleet.start()
        assert self.fleet.host_status()["slow"].connected, self.fleet.host_status()

    @property
    def pid(self) -> int:
        pid = self.fleet.host_status()["slow"].agent_pid
        assert pid is not None
        return pid

    @property
    def link(self) -> AgentLink:
        link = self.fleet._sessions[0].link
        assert link is not None
        return link

    def event(self, name: str, pid: int, timeout_s: float = 10.0) -> dict[str, Any]:
        found: list[dict[str, Any]] = []

        def seen() -> bool:
            found[:] = [e for e in read_events(self.events, pid) if e["event"] == name]
            return bool(found)

        wait_until(seen, timeout_s, f"the backend's {name!r}", poll_s=0.005)
        return found[0]

    def names(self, pid: int) -> list[str]:
        return [e["event"] for e in read_events(self.events, pid)]

    def soon(self, pid: int, then: Any) -> threading.Thread:
        """Once the push has started (and 0.3 s more), ``then()`` in a thread."""
        def run() -> None:
            self.event("push_start", pid)
            time.sleep(0.3)
            then()

        t = threading.Thread(target=run, daemon=True)
        t.start()
        return t


def serve_slow_arms(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every agent the fleet starts runs slow_arm.py: agent_argv's argv, with
    ``-m drivers.agent`` swapped for that script."""
    real = agent_argv

    def argv(host: Any, **kw: Any) -> list[str]:
        words = real(host, **kw)
        i = words.index("-m")
        assert words[i + 1] == "drivers.agent"
        return [words[0], str(SLOW_ARM), *words[i + 2:]]

    monkeypatch.setattr(drivers.session, "agent_argv", argv)


@pytest.fixture
def slow(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[Any]:
    events = tmp_path / "events.jsonl"
    monkeypatch.setenv(EVENTS_ENV, str(events))
    serve_slow_arms(monkeypatch)
    made: list[Slow] = []

    def make(push_s: float) -> Slow:
        monkeypatch.setenv(PUSH_S_ENV, str(push_s))
        s = Slow(events)
        made.append(s)
        return s

    yield make
    for s in made:
        s.fleet.close()


def test_heartbeats_go_on_during_a_push_and_the_watchdog_stays_quiet(slow: Any) -> None:
    s = slow(3.0)
    argv = Path(f"/proc/{s.pid}/cmdline").read_bytes().decode().split("\0")
    assert argv[argv.index("--watchdog") + 1] == "1.5"  # heartbeat_s + 1
    link = s.link
    t0 = time.monotonic()
    res = s.fleet.execute(PUSH, [])
    took = time.monotonic() - t0
    assert all(isinstance(r, PushResult) for r in res.values()), res  # never stopped
    assert took >= 3.0 and "stop" not in s.names(s.pid)
    during = [(t, h) for t, h in link.skipped if h["type"] == "heartbeat_ok" and t >= t0]
    assert len(during) >= 4, during  # ~ every 0.5 s of the 3 s push
    assert all(h["busy"] == "push" for _, h in during)  # answered by the agent mid-push
    times = [t0] + [t for t, _ in during]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) < 1.0, gaps  # the watchdog (1.5 s) never goes hungry
    assert s.fleet.host_status()["slow"].connected
    print(f"{len(during)} heartbeats answered during a {took:.1f} s push; largest gap "
          f"{max(gaps) * 1e3:.0f} ms")


def test_stop_motion_stops_a_push_in_flight(slow: Any) -> None:
    s = slow(20.0)
    pid = s.pid
    called: dict[str, float] = {}
    reached: list[str] = []

    def stop() -> None:
        called["t"] = time.monotonic()
        reached.extend(s.fleet.stop_motion())
        called["took"] = time.monotonic() - called["t"]

    t = s.soon(pid, stop)
    res = s.fleet.execute(PUSH, [])
    t_back = time.monotonic()
    t.join(5)
    assert reached == ["slow"] and called["took"] < 0.6
    stopped = s.event("stop", pid)["t"] - called["t"]
    assert stopped < 1.0
    assert t_back - called["t"] < 1.0
    for r in PUSH:
        f = res[r]
        assert isinstance(f, Fault) and "push stopped after" in f.reason, f
    assert s.fleet.host_status()["slow"].connected and s.pid == pid  # a clean refusal
    assert all(not isinstance(o, Fault) for o in s.fleet.observe().values())
    print(f"stop_motion() -> backend.stop(): {stopped * 1e3:.1f} ms; -> execute returned: "
          f"{(t_back - called['t']) * 1e3:.1f} ms")


def test_ctrl_c_mid_call_sends_stop_before_dropping_the_link(slow: Any) -> None:
    """A real SIGINT (the trial's first Ctrl-C raises KeyboardInterrupt in the main
    thread, wherever it waits): the stop reaches the agent at once; then the link is
    dropped and the agent exits without rest."""
    s = slow(20.0)
    pid = s.pid
    in_call = threading.Event()
    fired: list[float] = []

    def interrupt() -> None:
        if in_call.is_set():
            fired.append(time.monotonic())
            os.kill(os.getpid(), signal.SIGINT)

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        t = s.soon(pid, interrupt)
        with pytest.raises(KeyboardInterrupt):
            in_call.set()
            try:
                s.fleet.execute(PUSH, [])
            finally:
                in_call.clear()
        t_raised = time.monotonic()
        t.join(5)
    finally:
        signal.signal(signal.SIGINT, old)
    assert fired
    stopped = s.event("stop", pid)["t"] - fired[0]
    assert stopped < 1.0
    wait_until(lambda: not Path(f"/proc/{pid}").exists() or
               Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] == "Z", 10,
               "the agent to exit")
    names = s.names(pid)
    assert "rest" not in names and names[-1] == "close"
    print(f"SIGINT -> backend.stop(): {stopped * 1e3:.1f} ms; -> KeyboardInterrupt out of "
          f"execute: {(t_raised - fired[0]) * 1e3:.1f} ms")


class QuietConsole(ConsoleCore):
    """The console logic with no surface at all (nothing drawn, nothing shown)."""

    def _has_surface(self, wid: int) -> bool:
        return False


def test_a_confirmed_console_stop_stops_the_motion_in_flight(slow: Any) -> None:
    from testbed.experiments.trial import _stop_motion_on_console_stop

    s = slow(20.0)
    pid = s.pid
    console = QuietConsole(1)
    # through a humans wrapper and a hosts wrapper, as a rehearsal builds them
    _stop_motion_on_console_stop(HumansWrapper(console), HostsWrapper(s.fleet))  # type: ignore[arg-type]
    confirmed: list[float] = []

    def press_stop() -> None:
        with console._cond:
            console._on_command(OVERVIEW, 0, KeyCommand(Command.STOP))
            confirmed.append(time.monotonic())
            console._on_command(OVERVIEW, 0, KeyCommand(Command.YES))

    t = s.soon(pid, press_stop)
    res = s.fleet.execute(PUSH, [])
    t.join(5)
    assert console.stop_requested
    stopped = s.event("stop", pid)["t"] - confirmed[0]
    assert stopped < 1.0
    assert isinstance(res["slow/left"], Fault) and "push stopped" in res["slow/left"].reason
    print(f"console Stop confirmed -> backend.stop(): {stopped * 1e3:.1f} ms")


@pytest.mark.slow
@pytest.mark.ssh
def test_over_ssh_heartbeats_go_on_during_a_push_and_stop_motion_stops_it(
        sshd_factory: Callable[[str], SshServer], monkeypatch: pytest.MonkeyPatch) -> None:
    """The lab's path: one SSH channel read by the call while the heartbeat and the stop
    write to it from other threads (the agent gets no environment over SSH: its push
    lasts the default 3 s and it writes no events)."""
    serve_slow_arms(monkeypatch)
    host = ssh_host("slow", sshd_factory("a"), heartbeat_s=0.5, deadline_s=30.0)
    with HostFleet([host], reconnect_backoff_s=0.2) as fleet:
        session = fleet._sessions[0]
        link = session.link
        assert link is not None
        t0 = time.monotonic()
        res = fleet.execute(PUSH, [])
        assert time.monotonic() - t0 >= 3.0
        assert all(isinstance(r, PushResult) for r in res.values()), res
        during = [h for t, h in link.skipped if h["type"] == "heartbeat_ok" and t >= t0]
        assert len(during) >= 4 and all(h["busy"] == "push" for h in during)
        timer = threading.Timer(0.5, fleet.stop_motion)
        timer.start()
        t1 = time.monotonic()
        res = fleet.execute(PUSH, [])
        took = time.monotonic() - t1
        timer.join()
        assert took < 1.5 and isinstance(res["slow/left"], Fault)
        assert "push stopped" in res["slow/left"].reason
        assert session.link is link  # the same channel all along
    print(f"over ssh: {len(during)} heartbeats during a 3 s push; stopped push returned "
          f"after {took * 1e3:.0f} ms (stop sent at 500 ms)")


# ---------------------------------------------------------------- the link, alone
class Scripted(Transport):
    """Replies from a script; writes into a pipe that a reader thread parses."""

    def __init__(self, replies: bytes = b"") -> None:
        super().__init__(local_host("h"))
        self._replies = bytearray(replies)
        self.r, self.w = os.pipe()

    def open(self, argv: list[str], timeout_s: float) -> None:
        pass

    def read(self, n: int, deadline: float) -> bytes:
        if not self._replies:
            raise DeadlineExceeded("nothing more")
        out = bytes(self._replies[:7])  # odd pieces: frames split across reads
        del self._replies[:7]
        return out

    def write(self, data: bytes, deadline: float) -> None:
        view = memoryview(data)
        while view:  # a few bytes at a time: a torn frame would show
            view = view[os.write(self.w, view[:5]):]

    def close(self) -> None:
        for fd in (self.r, self.w):
            os.close(fd)

    def exit_status(self) -> int | None:
        return None


def hb(mid: int) -> bytes:
    return p.encode_frame({"type": "heartbeat_ok", "id": mid, "uptime_s": 1.0, "busy": "push"})


def test_late_heartbeat_and_stop_replies_are_skipped_never_taken_for_the_reply() -> None:
    stream = b"".join([hb(5), p.encode_frame({"type": "stop_ok", "id": 6}),
                       p.encode_frame({"type": "rest_ok", "id": 3}), hb(7),
                       p.encode_frame({"type": "reset_ok", "id": 4, "results": {}}),
                       hb(8)])
    link = AgentLink(local_host("h"), Scripted(stream))
    deadline = time.monotonic() + 5
    assert link.receive("rest", 3, deadline).type == "rest_ok"
    assert [(h["type"], h["id"]) for _, h in link.skipped] == [("heartbeat_ok", 5),
                                                               ("stop_ok", 6)]
    assert link.receive("reset", 4, deadline).type == "reset_ok"
    assert [h["id"] for _, h in link.skipped] == [5, 6, 7]
    # the late one after the last reply waits for the next read, which skips it too
    with pytest.raises(DeadlineExceeded):
        link.receive("observe", 9, deadline)
    assert [h["id"] for _, h in link.skipped] == [5, 6, 7, 8]
    # a heartbeat_ok carrying the awaited id is no reply to that request
    bad = AgentLink(local_host("h"), Scripted(hb(3)))
    with pytest.raises(ProtocolError, match="got 'heartbeat_ok', expected 'push_ok'"):
        bad.receive("push", 3, deadline)


def test_frames_stay_whole_when_calls_and_write_only_frames_race() -> None:
    t = Scripted()
    link = AgentLink(local_host("h"), t)
    ids: list[int] = []

    def heartbeats() -> None:
        for _ in range(300):
            mid = link.send_only("heartbeat", time.monotonic() + 5)
            assert mid is not None
            ids.append(mid)

    def reader(got: list[p.Frame]) -> None:
        def read(n: int, deadline: float) -> bytes:
            if not select.select([t.r], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise DeadlineExceeded("done")
            return os.read(t.r, n)

        r = p.FrameReader(read, "controller")
        while len(got) < 600:
            got.append(r.read_frame(time.monotonic() + 5))

    got: list[p.Frame] = []
    threads = [threading.Thread(target=heartbeats), threading.Thread(target=reader,
                                                                    args=(got,))]
    for th in threads:
        th.start()
    for _ in range(300):
        ids.append(link.send("push", time.monotonic() + 5, faces={"left": 1}))
    for th in threads:
        th.join(10)
    assert len(got) == 600 and sorted(f.id for f in got) == sorted(ids) == list(range(1, 601))
    assert {f.type for f in got} == {"heartbeat", "push"}
    t.close()
