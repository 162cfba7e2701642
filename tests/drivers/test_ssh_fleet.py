"""The lab path against a REAL OpenSSH server on loopback (fixtures start and stop it).

Two hosts, each behind its own sshd, so one can die while the other goes on.
"""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from driver_fakes import ROOT, ssh_host, wait_until

from drivers.backends.twin.twin_host import TwinHost
from drivers.host_fleet import HostFleet
from drivers.testing.sshd import SshServer
from drivers.transport import SshTransport, agent_argv
from testbed.core.types import ArmObservation, Fault, PushResult

pytestmark = pytest.mark.ssh

SshdFactory = Callable[[str], SshServer]


def steps(fleet: HostFleet, n: int) -> list[dict[str, object]]:
    out = []
    for _ in range(n):
        obs = fleet.observe()
        pushes = {r: o.expert_action for r, o in obs.items()
                  if isinstance(o, ArmObservation) and o.expert_action is not None}
        out.append({**obs, **{f"{r}#res": v for r, v in fleet.execute(pushes, []).items()}})
    return out


def kinds(step: dict[str, object], host: str) -> set[str]:
    return {type(v).__name__ for k, v in step.items() if k.startswith(host + "/")}


def test_twin_trial_steps_over_ssh(sshd_factory: SshdFactory) -> None:
    a, b = sshd_factory("a"), sshd_factory("b")
    hosts = [ssh_host("cell0", a), ssh_host("cell1", b)]
    with HostFleet(hosts, trial_seed=1) as fleet:
        st = fleet.host_status()
        assert all(s.connected and s.backend == "twin" for s in st.values()), st
        agent_pid = st["cell0"].agent_pid
        assert agent_pid in a.pids()  # the agent really runs under that sshd
        cmdline = Path(f"/proc/{agent_pid}/cmdline").read_bytes().split(b"\0")
        assert cmdline[0].decode() == sys.executable  # the venv's absolute interpreter
        for step in steps(fleet, 8):
            assert kinds(step, "cell0") == kinds(step, "cell1") == {
                "ArmObservation", "PushResult"}
        fleet.rest()


def test_agent_killed_mid_trial_faults_that_host_and_it_comes_back(
        sshd_factory: SshdFactory, tmp_path: Path) -> None:
    a, b = sshd_factory("a"), sshd_factory("b")
    hosts = [ssh_host("cell0", a, physics=False), ssh_host("cell1", b, physics=False)]
    with HostFleet(hosts, reconnect_backoff_s=0.2, log_dir=tmp_path / "hosts") as fleet:
        steps(fleet, 2)
        victim = fleet.host_status()["cell0"].agent_pid
        assert victim is not None
        os.kill(victim, signal.SIGKILL)
        obs = fleet.observe()
        assert isinstance(obs["cell0/left"], Fault) and "link closed" in obs["cell0/left"].reason
        assert all(isinstance(obs[f"cell1/{arm}"], ArmObservation) for arm in ("left", "right"))
        wait_until(lambda: fleet.host_status()["cell0"].connected, 20, "cell0 back")
        second = fleet.host_status()["cell0"].agent_pid
        assert second != victim
        assert kinds(steps(fleet, 1)[0], "cell0") == {"ArmObservation", "PushResult"}
    # The host log over SSH: the agents' stderr lines (channel stderr) and our events.
    log = (tmp_path / "hosts" / "cell0.log").read_text()
    assert f"agent[cell0] INFO agent pid {victim} for host cell0" in log
    assert f"agent[cell0] INFO agent pid {second} for host cell0" in log
    assert "fleet | dropped the link" in log and "(attempt 1, ssh)" in log
    assert "agent[cell0] INFO bye: arms to rest" in log


def test_sshd_stopped_mid_trial_then_restarted(sshd_factory: SshdFactory) -> None:
    a, b = sshd_factory("a"), sshd_factory("b")
    hosts = [ssh_host("cell0", a, physics=False, connect_timeout_s=3.0),
             ssh_host("cell1", b, physics=False)]
    with HostFleet(hosts, reconnect_backoff_s=0.2) as fleet:
        steps(fleet, 2)
        a.stop()  # the host's sshd and every session it held, agents included
        down = steps(fleet, 5)
        for step in down:
            assert kinds(step, "cell0") == {"Fault"}
            assert kinds(step, "cell1") == {"ArmObservation", "PushResult"}
        assert "unreachable" in str(down[-1]["cell0/left"])
        a.start()  # same port, same keys
        wait_until(lambda: fleet.host_status()["cell0"].connected, 30, "cell0 back")
        assert kinds(steps(fleet, 1)[0], "cell0") == {"ArmObservation", "PushResult"}


def test_frozen_sshd_is_caught_by_deadline_and_heartbeat(sshd_factory: SshdFactory) -> None:
    """SIGSTOP: the peer is dead but the TCP connection stays open (no FIN, no RST):
    only the per-call deadline and the application heartbeat can notice."""
    a, b = sshd_factory("a"), sshd_factory("b")
    hosts = [ssh_host("cell0", a, physics=False, deadline_s=0.6, heartbeat_s=0.3,
                      connect_timeout_s=2.0),
             ssh_host("cell1", b, physics=False)]
    with HostFleet(hosts, reconnect_backoff_s=0.2) as fleet:
        steps(fleet, 1)
        a.freeze()
        t0 = time.monotonic()
        obs = fleet.observe()
        assert time.monotonic() - t0 < 3.0
        assert isinstance(obs["cell0/left"], Fault)
        assert "deadline exceeded" in obs["cell0/left"].reason
        assert isinstance(obs["cell1/left"], ArmObservation)
        a.thaw()
        wait_until(lambda: fleet.host_status()["cell0"].connected, 30, "cell0 back")
        assert isinstance(fleet.observe()["cell0/left"], ArmObservation)
        # Now with no call at all: the heartbeat alone notices the next freeze.
        a.freeze()
        wait_until(lambda: not fleet.host_status()["cell0"].connected, 10,
                   "the heartbeat to drop the frozen host")
        assert "deadline exceeded" in str(fleet.host_status()["cell0"].error)
        a.thaw()


def _host_key_line(server: SshServer, path: Path) -> str:
    key = path.with_suffix(".pub").read_text().split()
    return f"[127.0.0.1]:{server.port} {key[0]} {key[1]}\n"


def test_unknown_host_key_is_refused_with_a_clear_message(sshd_factory: SshdFactory,
                                                          tmp_path: Path) -> None:
    a = sshd_factory("a")
    empty = tmp_path / "known_hosts_without_it"
    empty.write_text("# nothing for this server\n")
    host = ssh_host("cell0", a, physics=False).model_copy(update={"known_hosts": str(empty)})
    with HostFleet([host]) as fleet:
        err = str(fleet.host_status()["cell0"].error)
        obs = fleet.observe()
    assert "host cell0" in err and "unknown ssh-ed25519 host key" in err
    assert f"not in the known_hosts file {empty}" in err and "refusing to connect" in err
    assert "SHA256:" in err
    assert isinstance(obs["cell0/left"], Fault) and "refusing to connect" in obs[
        "cell0/left"].reason
    assert not any(b"drivers.agent" in Path(f"/proc/{pid}/cmdline").read_bytes()
                   for pid in a.pids()[1:] if Path(f"/proc/{pid}").exists())


def test_changed_host_key_is_refused(sshd_factory: SshdFactory, tmp_path: Path) -> None:
    a = sshd_factory("a")
    other = tmp_path / "other_key"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(other)],
                   check=True)
    wrong = tmp_path / "known_hosts_wrong"
    wrong.write_text(_host_key_line(a, other))
    host = ssh_host("cell0", a, physics=False).model_copy(update={"known_hosts": str(wrong)})
    with HostFleet([host]) as fleet:
        err = str(fleet.host_status()["cell0"].error)
    assert "does NOT match the entry in" in err and str(wrong) in err


def test_key_auth_only(sshd_factory: SshdFactory, tmp_path: Path) -> None:
    a = sshd_factory("a")
    stranger = tmp_path / "stranger"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(stranger)],
                   check=True)
    host = ssh_host("cell0", a, physics=False).model_copy(update={"key_file": str(stranger)})
    with HostFleet([host]) as fleet:
        err = str(fleet.host_status()["cell0"].error)
    assert "key authentication as" in err and str(stranger) in err


def test_config_values_are_never_shell_code(sshd_factory: SshdFactory, tmp_path: Path) -> None:
    a = sshd_factory("a")
    token = f"pwned-{os.getpid()}-{time.monotonic_ns()}"
    evil = tmp_path / f"checkout with space;touch {token};$(touch {token})`touch {token}`'\""
    evil.symlink_to(ROOT, target_is_directory=True)
    host = ssh_host("cell0", a, physics=False).model_copy(update={"workdir": str(evil)})
    cmd = SshTransport.remote_command(host, agent_argv(host, seed=0, python=host.python,
                                                       idle_timeout_s=30))
    assert shlex.split(cmd)[:2] == ["env", f"PYTHONPATH={evil}"]
    with HostFleet([host]) as fleet:
        assert fleet.host_status()["cell0"].connected, fleet.host_status()
        assert isinstance(fleet.execute({"cell0/left": 1}, [])["cell0/left"], PushResult)
    for where in (Path.home(), tmp_path, ROOT, Path.cwd()):
        assert not (where / token).exists()


def test_ssh_config_validation_requires_absolute_python() -> None:
    with pytest.raises(ValueError, match="absolute interpreter path"):
        TwinHost(name="h", transport="ssh", user="u", key_file="k", known_hosts="kh")
