"""HostFleet, protocol 2: per-arm faults and refusals, reseed (byte-equal with a fresh
start), frame / move_tcp / save_calibration, per-host log files, --calibrate."""

from __future__ import annotations

import os
import re
import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from driver_fakes import RecordingBackend, ThreadAgentTransport, local_host, wait_until

import drivers.session
from drivers.backends.base import ArmOutcome
from drivers.host_fleet import HostCallError, HostFleet, derive_seed
from drivers.transport import make_transport
from testbed.core.host_config import HostConfig
from testbed.core.types import ArmObservation, Fault, PushResult


def with_backends(monkeypatch: pytest.MonkeyPatch,
                  factories: dict[str, Callable[[], RecordingBackend]]) -> None:
    """Hosts named in ``factories`` run the real agent loop in a thread on that backend."""
    def transport(host: HostConfig) -> object:
        if host.name in factories:
            return ThreadAgentTransport(host, backend_factory=factories[host.name])
        return make_transport(host)

    monkeypatch.setattr(drivers.session, "make_transport", transport)


def test_a_refused_arm_and_a_failed_arm_leave_their_siblings_alone(
        monkeypatch: pytest.MonkeyPatch) -> None:
    backend = RecordingBackend(
        push_outcomes={"left": ArmOutcome(False, False, refused="cube not found"),
                       "right": ArmOutcome(False, False, error="IK failed for the stroke")},
        observe_errors={"right": "arm right is being calibrated"})
    with_backends(monkeypatch, {"h": lambda: backend})
    with HostFleet([local_host("h"), local_host("g", physics=False)]) as fleet:
        res = fleet.execute({"h/left": 2, "h/right": 1, "g/left": 0}, [])
        assert res["h/left"] == PushResult("h/left", 2, False, False, "cube not found")
        f = res["h/right"]
        assert isinstance(f, Fault)
        assert f.reason == "agent on host h: arm 'right' failed: IK failed for the stroke"
        assert isinstance(res["g/left"], PushResult) and res["g/left"].refused is None
        obs = fleet.observe()
        assert isinstance(obs["h/left"], ArmObservation)
        assert isinstance(obs["h/right"], Fault) and "being calibrated" in obs["h/right"].reason
        assert fleet.host_status()["h"].connected  # per-arm trouble keeps the link


def test_frame_move_tcp_save_calibration_and_their_failures(
        monkeypatch: pytest.MonkeyPatch) -> None:
    good = RecordingBackend()
    with_backends(monkeypatch, {"h": lambda: good,
                                "old": lambda: RecordingBackend(capable=False)})
    with HostFleet([local_host("h"), local_host("old")]) as fleet:
        frame = fleet.frame("h")
        assert frame.shape == (48, 80, 3) and np.array_equal(frame, good.frame())
        assert fleet.move_tcp("h", "left", (400, 100, 10)) == (400.0, 100.0, 10.25)
        assert fleet.save_calibration("h", "right", {"z_push_mm": 12}) == "/calib/right.json"
        with pytest.raises(HostCallError, match=r"^move_tcp on host h failed: .*request error "
                                                r"on arm 'left': .*below the table") as ei:
            fleet.move_tcp("h", "left", (400, 100, -1))
        assert ei.value.host == "h" and "\n" not in str(ei.value)
        with pytest.raises(HostCallError, match=r"frame on host old failed: .*cannot take a full"):
            fleet.frame("old")
        with pytest.raises(HostCallError, match=r"reseed failed on host old: .*cannot be reseed"):
            fleet.reseed(4)
        with pytest.raises(ValueError, match="unknown host"):
            fleet.frame("nope")
        with pytest.raises(ValueError, match="has no arm 'elbow'"):
            fleet.move_tcp("h", "elbow", (0, 0, 0))
        with pytest.raises(ValueError, match="three finite numbers"):
            fleet.move_tcp("h", "left", (0, float("nan"), 0))
        assert fleet.host_status()["h"].connected and fleet.host_status()["old"].connected
        assert ("reseed", derive_seed(4, 0)) in good.calls


def steps(fleet: HostFleet, n: int) -> list[tuple[dict, dict]]:
    out = []
    for _ in range(n):
        obs = fleet.observe()
        pushes = {r: o.expert_action for r, o in obs.items()
                  if isinstance(o, ArmObservation) and o.expert_action is not None}
        out.append((obs, fleet.execute(pushes, [])))
    return out


def same(a: list[tuple[dict, dict]], b: list[tuple[dict, dict]]) -> bool:
    for (oa, ra), (ob, rb) in zip(a, b, strict=True):
        for r in oa:
            if not np.array_equal(oa[r].image, ob[r].image) or oa[r].goal != ob[r].goal:
                return False
        if ra != rb:
            return False
    return True


def test_reseed_after_pretraining_gives_the_same_trial_as_a_fresh_start() -> None:
    hosts = [local_host("cell0")]
    with HostFleet(hosts, trial_seed=3) as used, HostFleet(hosts, trial_seed=11) as fresh:
        steps(used, 3)  # "pretraining" on the trial's hosts
        used.reseed(11)
        a, b = steps(used, 4), steps(fresh, 4)
        assert same(a, b)  # byte-equal images, equal goals and outcomes
        # An agent started after the reseed (reconnect) already has the new seed.
        victim = used.host_status()["cell0"].agent_pid
        assert victim is not None
        os.kill(victim, signal.SIGKILL)
        used.observe()
        wait_until(lambda: used.host_status()["cell0"].connected, 20, "reconnect")
        pid = used.host_status()["cell0"].agent_pid
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
        assert argv[argv.index("--seed") + 1] == str(derive_seed(11, 0))


def test_twin_backend_reseed_is_byte_equal_to_a_new_backend() -> None:
    from drivers.backends.twin import TwinBackend

    with TwinBackend(5) as used, TwinBackend(9) as fresh:
        used.push({"left": 1, "right": 2})
        used.reseed(9)
        for _ in range(3):
            ou, of = used.observe(), fresh.observe()
            for arm in ("left", "right"):
                assert ou[arm].image.tobytes() == of[arm].image.tobytes()
                assert ou[arm].goal == of[arm].goal
            faces = {a: v.expert_action for a, v in of.items() if v.expert_action is not None}
            assert used.push(faces) == fresh.push(faces)


STAMP = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} (fleet|agent) \| ")


def test_per_host_logs_hold_agent_lines_and_drop_reconnect_events(tmp_path: Path) -> None:
    hosts = [local_host("cell0", physics=False), local_host("cell1", physics=False)]
    logs = tmp_path / "hosts"
    with HostFleet(hosts, trial_seed=1, reconnect_backoff_s=0.2, log_dir=logs) as fleet:
        steps(fleet, 3)
        victim = fleet.host_status()["cell0"].agent_pid
        assert victim is not None
        os.kill(victim, signal.SIGKILL)
        assert isinstance(fleet.observe()["cell0/left"], Fault)
        wait_until(lambda: fleet.host_status()["cell0"].connected, 20, "reconnect")
        steps(fleet, 2)
        second = fleet.host_status()["cell0"].agent_pid
    text = (logs / "cell0.log").read_text()
    lines = [ln for ln in text.splitlines() if not ln.startswith("    ")]
    assert lines and all(STAMP.match(ln) for ln in lines), text
    assert f"fleet | connected: agent pid {victim}, backend twin-canned" in text
    assert f"fleet | connected: agent pid {second}" in text
    assert "fleet | dropped the link (reconnecting in 0.2 s): link closed" in text
    assert "status -9" in text and "fleet | fault for left,right: link closed" in text
    assert text.count("fleet | starting the agent (attempt 1, local)") == 2
    # the agents' own stderr lines, with their timestamps, from both agents
    assert "agent | 20" in text
    assert f"agent[cell0] INFO agent pid {victim} for host cell0" in text
    assert f"agent[cell0] INFO agent pid {second} for host cell0" in text
    assert "agent[cell0] INFO bye: arms to rest, then exiting" in text
    assert "fleet | closed: bye answered; agent exit status 0" in text
    other = (logs / "cell1.log").read_text()
    assert "dropped" not in other and "agent[cell1] INFO bye" in other


def test_calibrating_arms_reach_the_agents_argv() -> None:
    hosts = [local_host("cell0"), local_host("cell1")]
    fleet = HostFleet(hosts, calibrating={"cell1": ["right"]})
    try:
        argv0, argv1 = (s.argv() for s in fleet._sessions)
        assert "--calibrate" not in argv0
        assert argv1[argv1.index("--calibrate") + 1] == "right"
    finally:
        fleet.close()
    with pytest.raises(ValueError, match="unknown arm"):
        HostFleet(hosts, calibrating={"cell1": ["elbow"]})
    with pytest.raises(ValueError, match="unknown host"):
        HostFleet(hosts, calibrating={"cell9": ["left"]})


def test_host_logs_rotate(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.hostlog

    monkeypatch.setattr(drivers.hostlog, "MAX_BYTES", 2000)
    log = drivers.hostlog.HostLog(tmp_path, "cell0")
    for i in range(400):
        log.agent_line(f"line {i:04d} " + "x" * 40)
    log.close()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["cell0.log", "cell0.log.1", "cell0.log.2", "cell0.log.3"]
    assert "line 0399" in (tmp_path / "cell0.log").read_text()
