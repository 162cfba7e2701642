"""HostFleet with local agents: the API, determinism, and faults that never stop a trial."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from driver_fakes import ExplodingBackend, ThreadAgentTransport, local_host, wait_until

import drivers.session
from drivers.backends.twin.twin_host import TwinHost
from drivers.build_id import matches
from drivers.host_fleet import HostFleet, derive_seed
from drivers.transport import LocalTransport, make_transport
from drivers.yumi.yumi_host import YumiHost
from testbed.core.host_config import HostConfig
from testbed.core.types import ArmObservation, Fault, PushResult


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def agent_pids(fleet: HostFleet) -> dict[str, int]:
    return {n: s.agent_pid for n, s in fleet.host_status().items() if s.agent_pid}


def test_twin_fleet_observes_executes_and_closes_cleanly() -> None:
    hosts = [local_host("cell0"), local_host("cell1")]
    with HostFleet(hosts, trial_seed=5) as fleet:
        assert fleet.robot_names == ["cell0/left", "cell0/right", "cell1/left", "cell1/right"]
        obs = fleet.observe()
        assert list(obs) == fleet.robot_names
        assert all(isinstance(o, ArmObservation) and o.image.shape == (64, 64, 3)
                   and o.expert_action is not None for o in obs.values())
        pushes = {r: o.expert_action for r, o in obs.items() if r != "cell1/right"}
        res = fleet.execute(pushes, ["cell1/right"])
        assert list(res) == fleet.robot_names
        for r, out in res.items():
            assert isinstance(out, PushResult)
            assert out.action == pushes.get(r)
        assert res["cell1/right"] == PushResult("cell1/right", None, False, False)
        waiting = fleet.execute({}, [])
        assert all(v == PushResult(r, None, False, False) for r, v in waiting.items())
        fleet.rest()
        pids = agent_pids(fleet)
        assert len(pids) == 2
        # what run.json ``hosts`` records: each host as its agent said at hello
        info = fleet.hosts_info()
        assert list(info) == ["cell0", "cell1"]
        for name, entry in info.items():
            assert entry == {"backend": "twin", "transport": "local",
                             "build": fleet.host_status()[name].build,
                             "arms": ["left", "right"]}
            assert matches(entry["build"])  # this checkout's build, as hello checked
    wait_until(lambda: not any(alive(pid) for pid in pids.values()), 10, "agents to exit")


def test_twin_seeds_are_deterministic_per_trial_and_host() -> None:
    assert derive_seed(7, 0) == derive_seed(7, 0)
    assert len({derive_seed(7, 0), derive_seed(7, 1), derive_seed(8, 0)}) == 3
    hosts = [local_host("a"), local_host("b"), local_host("c", seed=derive_seed(7, 0))]
    with HostFleet(hosts, trial_seed=7) as f1, HostFleet(hosts, trial_seed=7) as f2:
        o1, o2 = f1.observe(), f2.observe()
        for r in f1.robot_names:
            assert np.array_equal(o1[r].image, o2[r].image)  # type: ignore[union-attr]
        # Host c was given host a's derived seed: the same world.
        assert np.array_equal(o1["a/left"].image, o1["c/left"].image)  # type: ignore[union-attr]
        assert not np.array_equal(o1["a/left"].image, o1["b/left"].image)  # type: ignore[union-attr]


def test_execute_rejects_caller_bugs() -> None:
    fleet = HostFleet([local_host("cell0", physics=False)])
    try:
        with pytest.raises(ValueError, match="unknown robot"):
            fleet.execute({"cell9/left": 0}, [])
        with pytest.raises(ValueError, match="both pushed and reset"):
            fleet.execute({"cell0/left": 0}, ["cell0/left"])
        with pytest.raises(ValueError, match=r"face in 0\.\.3"):
            fleet.execute({"cell0/left": 4}, [])
        with pytest.raises(ValueError, match=r"face in 0\.\.3"):
            fleet.execute({"cell0/left": True}, [])
    finally:
        fleet.close()
    with pytest.raises(RuntimeError, match="closed"):
        fleet.observe()


def test_killed_agent_faults_its_host_only_and_comes_back() -> None:
    hosts = [local_host("cell0", physics=False), local_host("cell1", physics=False)]
    with HostFleet(hosts, reconnect_backoff_s=0.2) as fleet:
        victim = agent_pids(fleet)["cell0"]
        os.kill(victim, signal.SIGKILL)
        obs = fleet.observe()
        for r in ("cell0/left", "cell0/right"):
            assert isinstance(obs[r], Fault)
            assert "link closed" in obs[r].reason and "status -9" in obs[r].reason
        assert all(isinstance(obs[r], ArmObservation) for r in ("cell1/left", "cell1/right"))
        res = fleet.execute({r: 0 for r in fleet.robot_names}, [])
        assert isinstance(res["cell0/left"], Fault) and "unreachable" in res["cell0/left"].reason
        assert isinstance(res["cell1/left"], PushResult)
        wait_until(lambda: fleet.host_status()["cell0"].connected, 15, "cell0 to reconnect")
        assert agent_pids(fleet)["cell0"] != victim
        assert all(isinstance(o, ArmObservation) for o in fleet.observe().values())


def test_frozen_agent_is_a_deadline_fault_not_a_hang() -> None:
    hosts = [local_host("cell0", physics=False, deadline_s=0.5),
             local_host("cell1", physics=False)]
    with HostFleet(hosts, reconnect_backoff_s=0.2) as fleet:
        victim = agent_pids(fleet)["cell0"]
        os.kill(victim, signal.SIGSTOP)
        try:
            t0 = time.monotonic()
            obs = fleet.observe()
            assert time.monotonic() - t0 < 2.0
            assert isinstance(obs["cell0/left"], Fault)
            assert "deadline exceeded" in obs["cell0/left"].reason
            assert isinstance(obs["cell1/left"], ArmObservation)
            wait_until(lambda: fleet.host_status()["cell0"].connected, 15, "a new agent")
            assert isinstance(fleet.observe()["cell0/left"], ArmObservation)
        finally:
            os.kill(victim, signal.SIGCONT) if alive(victim) else None
        wait_until(lambda: not alive(victim), 10, "the frozen agent to be reaped")


def test_unstartable_agent_is_a_fault_with_the_reason() -> None:
    hosts = [local_host("cell0", physics=False, python="/nonexistent/python3"),
             # no camera: the backend cannot start (a config the loader refuses, built
             # unvalidated to reach the agent's own check)
             YumiHost.model_construct(name="yumi0", deadline_s=5.0)]
    with HostFleet(hosts, reconnect_backoff_s=5.0) as fleet:
        st = fleet.host_status()
        assert not st["cell0"].connected and "cannot start the agent" in str(st["cell0"].error)
        assert "needs --camera" in str(st["yumi0"].error)
        assert "build_yumi_backend" in str(st["yumi0"].traceback)
        obs = fleet.observe()
        assert isinstance(obs["yumi0/left"], Fault) and "needs --camera" in obs["yumi0/left"].reason
        assert "build_yumi_backend" in obs["yumi0/left"].traceback
        assert isinstance(obs["cell0/right"], Fault)


def test_backend_exception_faults_with_arm_and_traceback_and_keeps_the_link(
        monkeypatch: pytest.MonkeyPatch) -> None:
    def transport(host: HostConfig) -> ThreadAgentTransport | LocalTransport:
        if host.name == "bad":
            return ThreadAgentTransport(host, backend_factory=ExplodingBackend)
        return make_transport(host)  # type: ignore[return-value]

    monkeypatch.setattr(drivers.session, "make_transport", transport)
    with HostFleet([local_host("bad"), local_host("good", physics=False)]) as fleet:
        res = fleet.execute({"bad/right": 1, "good/right": 1}, [])
        f = res["bad/right"]
        assert isinstance(f, Fault) and "backend error on arm 'right'" in f.reason
        assert "gripper camera unplugged" in f.reason and "Traceback" in f.traceback
        assert isinstance(res["bad/left"], Fault)  # the host's call failed as a whole
        assert isinstance(res["good/right"], PushResult)
        assert fleet.host_status()["bad"].connected  # a clean refusal keeps the link
        assert isinstance(fleet.execute({"bad/left": 1}, [])["bad/left"], PushResult)


class InterruptingTransport(ThreadAgentTransport):
    interrupt = True

    def read(self, n: int, deadline: float) -> bytes:
        if InterruptingTransport.interrupt and self._sent > 1:
            InterruptingTransport.interrupt = False
            raise KeyboardInterrupt
        return super().read(n, deadline)


def test_ctrl_c_mid_call_propagates_and_the_host_recovers(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(drivers.session, "make_transport", InterruptingTransport)
    with HostFleet([local_host("h")], reconnect_backoff_s=0.1) as fleet:
        with pytest.raises(KeyboardInterrupt):
            fleet.observe()
        assert not fleet.host_status()["h"].connected  # the stream was mid-frame: dropped
        wait_until(lambda: fleet.host_status()["h"].connected, 10, "reconnect")
        assert isinstance(fleet.observe()["h/left"], ArmObservation)


def test_close_is_bounded_with_a_frozen_agent() -> None:
    fleet = HostFleet([local_host("cell0", physics=False, deadline_s=1.0)])
    fleet.start()
    victim = agent_pids(fleet)["cell0"]
    os.kill(victim, signal.SIGSTOP)
    t0 = time.monotonic()
    fleet.close()
    assert time.monotonic() - t0 < 9.0
    os.kill(victim, signal.SIGCONT) if alive(victim) else None
    wait_until(lambda: not alive(victim), 10, "the agent to be gone")


def test_a_fleet_dropped_without_close_still_stops_its_agents() -> None:
    import gc

    fleet = HostFleet([local_host("cell0", physics=False)])
    fleet.start()
    pid = agent_pids(fleet)["cell0"]
    del fleet
    gc.collect()
    wait_until(lambda: not alive(pid), 10, "the agent of a dropped fleet to exit")


def test_local_agent_uses_the_controllers_interpreter_unless_absolute() -> None:
    import sys

    assert LocalTransport.python_for(TwinHost(name="a")) == sys.executable
    assert LocalTransport.python_for(TwinHost(name="a", python="/opt/py")) == "/opt/py"


class DownTransport(ThreadAgentTransport):
    """A host whose link is gone while ``down`` (a cable out, its sshd stopped)."""

    down = False
    opened = 0

    def open(self, argv: list[str], timeout_s: float) -> None:
        DownTransport.opened += 1
        if DownTransport.down:
            raise ConnectionRefusedError("connection refused (the host's sshd is down)")
        super().open(argv, timeout_s)


def test_a_host_whose_link_is_back_reconnects_at_the_next_step_whatever_the_backoff(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(drivers.session, "make_transport", DownTransport)
    monkeypatch.setattr(DownTransport, "down", True)
    with HostFleet([local_host("h")], reconnect_backoff_s=30.0) as fleet:
        assert not fleet.host_status()["h"].connected  # refused: next attempt in 30 s
        tries = DownTransport.opened
        assert isinstance(fleet.observe()["h/left"], Fault)  # a step: retried at once...
        wait_until(lambda: DownTransport.opened > tries, 5, "the step's attempt")
        assert isinstance(fleet.observe()["h/left"], Fault)  # ...but at most once a second
        assert DownTransport.opened == tries + 1
        DownTransport.down = False  # the link is back
        time.sleep(drivers.session.STEP_RETRY_S)
        t0 = time.monotonic()
        fleet.observe()  # the next step retries, and its arms are back at once after
        wait_until(lambda: fleet.host_status()["h"].connected, 5, "the reconnect")
        assert time.monotonic() - t0 < 5.0  # not the 30 s backoff
        assert isinstance(fleet.observe()["h/left"], ArmObservation)
