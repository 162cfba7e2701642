"""Robot hosts as labs reach them: ssh config aliases, a bastion, ssh-agent and
passphrase keys, hashed known_hosts (issue 21, part 4).

Everything here is real: OpenSSH sshd processes on loopback (the bastion's log at
DEBUG1, so the forwarded ``direct-tcpip`` connection shows), a real ``ssh-agent``, keys
made by ``ssh-keygen``. The only seam is the passphrase prompt (``KEYRING.prompt``),
which a test answers as an operator would.
"""

from __future__ import annotations

import getpass
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from driver_fakes import ROOT, wait_until

from drivers.backends.twin.twin_host import TwinHost
from drivers.errors import HostKeyError, TransportError
from drivers.host_fleet import HostFleet
from drivers.ssh_setup import (
    KEYRING,
    BastionError,
    SshConfigError,
    resolve_route,
    terminal_prompt,
)
from drivers.testing.sshd import SshAgent, SshServer, free_port, keygen, sshd_available
from drivers.transport import SshTransport
from testbed.core.config import ConfigError
from testbed.core.types import ArmObservation, Fault
from testbed.experiments.fleet_config import parse_config

Servers = Callable[..., SshServer]


@pytest.fixture
def servers(tmp_path: Path) -> Iterator[Servers]:
    """Real sshds on loopback (``log_level`` passed on); all stopped at teardown."""
    if not sshd_available():
        pytest.skip("needs /usr/sbin/sshd and ssh-keygen (Debian: openssh-server)")
    started: list[SshServer] = []

    def make(name: str, **kw: Any) -> SshServer:
        s = SshServer(tmp_path / f"sshd-{name}", **kw)
        s.start()
        started.append(s)
        return s

    yield make
    for s in started:
        s.stop()


@pytest.fixture(autouse=True)
def hermetic_keys(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """No agent of the developer's, an empty key ring, and a prompt that records every
    question and answers nothing (a test that expects a question sets its own)."""
    monkeypatch.delenv("SSH_AUTH_SOCK", raising=False)
    asked: list[str] = []
    KEYRING.forget()
    saved = KEYRING.prompt
    KEYRING.prompt = lambda message: asked.append(message) or None
    yield asked
    KEYRING.prompt = saved
    KEYRING.forget()


@pytest.fixture
def agent() -> Iterator[SshAgent]:
    """A real ssh-agent on a short socket path (AF_UNIX paths hold 108 bytes)."""
    folder = Path(tempfile.mkdtemp(prefix="agent-"))
    a = SshAgent(folder / "sock")
    a.start()
    yield a
    a.stop()
    shutil.rmtree(folder, ignore_errors=True)


def alias_host(name: str, alias: str, ssh_config: Path, **kw: Any) -> TwinHost:
    kw.setdefault("deadline_s", 5.0)
    kw.setdefault("connect_timeout_s", 10.0)
    return TwinHost(name=name, transport="ssh", ssh_alias=alias, ssh_config=str(ssh_config),
                    python=sys.executable, workdir=str(ROOT), physics=False, **kw)


def explicit_host(name: str, server: SshServer, **kw: Any) -> TwinHost:
    """A host the way configs said it before aliases (address, port, user, files)."""
    fields: dict[str, Any] = {
        "address": "127.0.0.1", "port": server.port, "user": server.user,
        "key_file": str(server.client_key), "known_hosts": str(server.known_hosts),
        "deadline_s": 5.0, "connect_timeout_s": 10.0, **kw}
    return TwinHost(name=name, transport="ssh", python=sys.executable, workdir=str(ROOT),
                    physics=False, **{k: v for k, v in fields.items() if v is not None})


def run_remote(host: TwinHost, *argv: str, timeout_s: float = 10.0) -> str:
    """``argv`` on the host over the real SshTransport; its stdout."""
    t = SshTransport(host)
    t.open(list(argv), timeout_s)
    out = bytearray()
    deadline = time.monotonic() + timeout_s
    try:
        while chunk := t.read(65536, deadline):
            out += chunk
    finally:
        t.close()
    return out.decode()


def ssh_config(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def bastion_config(tmp_path: Path, jump: SshServer, cell: SshServer, known: Path) -> Path:
    return ssh_config(tmp_path / "ssh_config", f"""\
# the lab's ~/.ssh/config: the robot cell is reached through the bastion
Host jump
    HostName 127.0.0.1
    Port {jump.port}
    IdentityFile {jump.client_key}

Host cell-left
    HostName 127.0.0.1
    Port {cell.port}
    IdentityFile {cell.client_key}
    ProxyJump jump

Host *
    User {cell.user}
    UserKnownHostsFile {known}
""")


def one_step(fleet: HostFleet) -> dict[str, object]:
    obs = fleet.observe()
    pushes = {r: o.expert_action for r, o in obs.items()
              if isinstance(o, ArmObservation) and o.expert_action is not None}
    return {**obs, **{f"{r}#res": v for r, v in fleet.execute(pushes, []).items()}}


def kinds(step: dict[str, object]) -> set[str]:
    return {type(v).__name__ for v in step.values()}


# -- aliases -----------------------------------------------------------------------------
@pytest.mark.ssh
def test_alias_from_ssh_config_reaches_the_agent(servers: Servers, tmp_path: Path) -> None:
    cell = servers("cell")
    cfg = ssh_config(tmp_path / "ssh_config", f"""\
Host cell-left
    HostName 127.0.0.1
    Port {cell.port}
    User {cell.user}
    IdentityFile {cell.client_key}
    UserKnownHostsFile {cell.known_hosts}
""")
    host = alias_host("cell0", "cell-left", cfg)
    with HostFleet([host], trial_seed=1) as fleet:
        st = fleet.host_status()["cell0"]
        assert st.connected, st
        assert st.agent_pid in cell.pids()  # the agent runs under that sshd
        step = one_step(fleet)
        assert kinds(step) == {"ArmObservation", "PushResult"}
        fleet.rest()


@pytest.mark.ssh
def test_ssh_config_wins_and_the_host_config_fills_in(servers: Servers,
                                                     tmp_path: Path) -> None:
    cell = servers("cell")
    stranger = keygen(tmp_path / "stranger", "not-authorized")
    empty = tmp_path / "known_hosts_empty"
    empty.write_text("")
    cfg = ssh_config(tmp_path / "ssh_config", f"""\
Host says-all
    HostName 127.0.0.1
    Port {cell.port}
    User {cell.user}
    IdentityFile {cell.client_key}
    UserKnownHostsFile {cell.known_hosts}
Host says-little
    HostName 127.0.0.1
""")
    # Every field of the host config is wrong: the ssh config's values win.
    wrong = alias_host("cell0", "says-all", cfg, port=free_port(), user="nobody",
                       key_file=str(stranger), known_hosts=str(empty))
    assert run_remote(wrong, "/usr/bin/id", "-un").strip() == cell.user
    # What the ssh config leaves unsaid comes from the host config.
    filled = alias_host("cell0", "says-little", cfg, port=cell.port, user=cell.user,
                        key_file=str(cell.client_key), known_hosts=str(cell.known_hosts))
    target = resolve_route(filled).target
    assert (target.hostname, target.port, target.user) == ("127.0.0.1", cell.port, cell.user)
    assert target.identity_files == (str(cell.client_key),)
    assert run_remote(filled, "/usr/bin/id", "-un").strip() == cell.user
    # ... and then OpenSSH's defaults.
    bare = resolve_route(alias_host("cell0", "says-little", cfg)).target
    assert bare.port == 22 and bare.identity_files == ()
    assert bare.known_hosts == (os.path.expanduser("~/.ssh/known_hosts"),)


# -- the bastion ---------------------------------------------------------------------------
@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
@pytest.mark.ssh
def test_hop_through_a_bastion_then_the_bastion_goes_down(servers: Servers,
                                                         tmp_path: Path) -> None:
    jump, cell = servers("jump", log_level="DEBUG1"), servers("cell")
    known = tmp_path / "known_hosts"
    known.write_text(jump.known_hosts_line() + cell.known_hosts_line())
    host = alias_host("cell0", "cell-left", bastion_config(tmp_path, jump, cell, known),
                      connect_timeout_s=3.0)
    route = resolve_route(host)
    assert [(h.role, h.port, h.bastion) for h in route.hops] == [
        ("host cell0: bastion jump", jump.port, True), ("host cell0", cell.port, False)]
    direct = explicit_host("cell1", cell)  # a sibling reached without the bastion
    with HostFleet([host, direct], reconnect_backoff_s=0.2) as fleet:
        st = fleet.host_status()["cell0"]
        assert st.connected, st
        assert st.agent_pid in cell.pids() and st.agent_pid not in jump.pids()
        assert kinds(one_step(fleet)) == {"ArmObservation", "PushResult"}
        # The bastion's own log: the forwarded connection, to the cell's sshd.
        assert (f"server_request_direct_tcpip: originator 127.0.0.1 port 0, target "
                f"127.0.0.1 port {cell.port}") in jump.log_text()
        jump.stop()  # the bastion and every session through it
        t0 = time.monotonic()
        obs = fleet.observe()
        assert time.monotonic() - t0 < host.deadline_s + 1.0
        assert all(isinstance(obs[f"cell0/{arm}"], Fault) for arm in ("left", "right"))
        assert all(isinstance(obs[f"cell1/{arm}"], ArmObservation) for arm in ("left", "right"))
        wait_until(lambda: "bastion" in str(fleet.host_status()["cell0"].error), 10,
                   "a reconnect attempt against the dead bastion")
        reason = fleet.observe()["cell0/left"]
        assert isinstance(reason, Fault)
    assert "\n" not in reason.reason
    assert f"host cell0: bastion jump (127.0.0.1:{jump.port}) unreachable:" in reason.reason
    assert "Connection refused" in reason.reason


@pytest.mark.ssh
def test_host_down_behind_a_live_bastion_is_one_line(servers: Servers,
                                                     tmp_path: Path) -> None:
    jump, cell = servers("jump"), servers("cell")
    known = tmp_path / "known_hosts"
    known.write_text(jump.known_hosts_line() + cell.known_hosts_line())
    host = alias_host("cell0", "cell-left", bastion_config(tmp_path, jump, cell, known))
    cell.stop()
    with pytest.raises(BastionError) as err:
        run_remote(host, "/bin/true")
    line = str(err.value)
    assert "\n" not in line
    assert (f"host cell0: bastion jump (127.0.0.1:{jump.port}) could not open a tunnel to "
            f"127.0.0.1:{cell.port} for cell-left") in line


@pytest.mark.ssh
def test_unknown_bastion_key_is_refused(servers: Servers, tmp_path: Path) -> None:
    jump, cell = servers("jump", log_level="DEBUG1"), servers("cell")
    known = tmp_path / "known_hosts_cell_only"
    known.write_text(cell.known_hosts_line())  # the cell is known, the bastion is not
    host = alias_host("cell0", "cell-left", bastion_config(tmp_path, jump, cell, known))
    with pytest.raises(HostKeyError) as err:
        run_remote(host, "/bin/true")
    line = str(err.value)
    assert "\n" not in line
    assert line.startswith(f"host cell0: bastion jump: the SSH server at [127.0.0.1]:"
                           f"{jump.port} offered an unknown ssh-ed25519 host key (SHA256:")
    assert f"not in the known_hosts file {known}; refusing to connect" in line
    assert "direct-tcpip" not in jump.log_text()  # no tunnel was ever asked for


# -- keys ----------------------------------------------------------------------------------
@pytest.mark.ssh
def test_key_held_only_by_a_real_ssh_agent(servers: Servers, agent: SshAgent,
                                           tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    cell = servers("cell")
    key = keygen(tmp_path / "agent_only", "held-by-the-agent")
    cell.authorize(key.with_suffix(".pub"))
    agent.add(key)
    key.unlink()
    key.with_suffix(".pub").unlink()  # from now on only the agent has it
    host = explicit_host("cell0", cell, key_file=None)
    monkeypatch.setenv("SSH_AUTH_SOCK", str(agent.sock))
    assert run_remote(host, "/usr/bin/id", "-un").strip() == cell.user
    agent.stop()
    with pytest.raises(TransportError, match="no ssh-agent answers at SSH_AUTH_SOCK="):
        run_remote(host, "/bin/true")
    monkeypatch.delenv("SSH_AUTH_SOCK")
    with pytest.raises(TransportError) as err:
        run_remote(host, "/bin/true")
    assert str(err.value) == (f"host cell0: no key to log in to 127.0.0.1:{cell.port} as "
                              f"{cell.user!r}: no key_file or IdentityFile names one, and "
                              "SSH_AUTH_SOCK is not set (no ssh-agent)")


@pytest.mark.ssh
def test_the_agents_copy_of_a_named_key_spares_the_passphrase(
        servers: Servers, agent: SshAgent, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        hermetic_keys: list[str]) -> None:
    cell = servers("cell")
    key = keygen(tmp_path / "lab_key", "lab")
    cell.authorize(key.with_suffix(".pub"))
    agent.add(key)  # unlocked once by the operator (ssh-add)
    subprocess.run(["ssh-keygen", "-q", "-p", "-a", "2", "-P", "", "-N", "lab-pass",
                    "-f", str(key)], check=True, capture_output=True)  # now locked on disk
    host = explicit_host("cell0", cell, key_file=str(key))
    monkeypatch.setenv("SSH_AUTH_SOCK", str(agent.sock))
    assert run_remote(host, "/usr/bin/id", "-un").strip() == cell.user
    assert hermetic_keys == []  # nobody was asked: the agent signed
    monkeypatch.delenv("SSH_AUTH_SOCK")
    with pytest.raises(TransportError) as err:  # no agent, and the prompt answers nothing
        run_remote(host, "/bin/true")
    assert len(hermetic_keys) == 1 and str(key) in hermetic_keys[0]
    assert f"key {key} is passphrase-protected and no passphrase was given" in str(err.value)
    assert "key authentication as" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.ssh
def test_passphrase_asked_once_across_reconnects_and_never_written(
        servers: Servers, tmp_path: Path) -> None:
    cell = servers("cell")
    secret = f"correct horse {os.getpid()} battery"
    key = keygen(tmp_path / "locked_key", "lab", passphrase=secret)
    cell.authorize(key.with_suffix(".pub"))
    asked: list[str] = []
    KEYRING.prompt = lambda message: asked.append(message) or secret
    host = explicit_host("cell0", cell, key_file=str(key))
    with HostFleet([host], reconnect_backoff_s=0.2, log_dir=tmp_path / "hosts") as fleet:
        first = fleet.host_status()["cell0"].agent_pid
        assert first is not None, fleet.host_status()
        os.kill(first, signal.SIGKILL)
        assert isinstance(fleet.observe()["cell0/left"], Fault)  # dropped; reconnects
        wait_until(lambda: fleet.host_status()["cell0"].agent_pid not in (None, first), 20,
                   "the reconnected agent")
        assert kinds(one_step(fleet)) == {"ArmObservation", "PushResult"}
    assert len(asked) == 1 and f"Passphrase for key {key}" in asked[0]
    for f in tmp_path.rglob("*"):  # host logs, sshd logs, keys: the passphrase nowhere
        if f.is_file():
            assert secret.encode() not in f.read_bytes(), f


@pytest.mark.ssh
def test_wrong_passphrases_are_asked_three_times_then_not_again(
        servers: Servers, tmp_path: Path) -> None:
    cell = servers("cell")
    key = keygen(tmp_path / "locked_key", "lab", passphrase="the right one")
    cell.authorize(key.with_suffix(".pub"))
    asked: list[str] = []
    KEYRING.prompt = lambda message: asked.append(message) or "a wrong one"
    host = explicit_host("cell0", cell, key_file=str(key))
    for _ in range(2):
        with pytest.raises(TransportError) as err:
            run_remote(host, "/bin/true")
        assert f"key {key}: wrong passphrase 3 times" in str(err.value)
    assert len(asked) == 3 and asked[1].startswith("Wrong passphrase.")
    # Without a terminal (as under pytest, or a service) the real prompt asks nobody.
    KEYRING.forget()
    KEYRING.prompt = terminal_prompt
    with pytest.raises(TransportError, match=f"ssh-add {key}, or start from a terminal"):
        run_remote(host, "/bin/true")


# -- host keys ---------------------------------------------------------------------------
@pytest.mark.ssh
def test_hashed_known_hosts_entries_are_accepted(servers: Servers, tmp_path: Path) -> None:
    cell = servers("cell")
    hashed = tmp_path / "known_hosts_hashed"
    shutil.copyfile(cell.known_hosts, hashed)
    subprocess.run(["ssh-keygen", "-q", "-H", "-f", str(hashed)], check=True,
                   capture_output=True)
    text = hashed.read_text()
    assert text.startswith("|1|") and "127.0.0.1" not in text
    host = explicit_host("cell0", cell, known_hosts=str(hashed))
    assert run_remote(host, "/usr/bin/id", "-un").strip() == cell.user


# -- what the driver will not follow -------------------------------------------------------
@pytest.mark.parametrize(("line", "option"), [
    ("    ProxyCommand touch {mark}", "ProxyCommand"),
    ('Match exec "touch {mark}"', "Match exec"),
    ("Include {mark}", "Include"),
])
def test_local_commands_in_the_ssh_config_are_refused(tmp_path: Path, line: str,
                                                      option: str) -> None:
    mark = tmp_path / "ran"
    cfg = ssh_config(tmp_path / "ssh_config", "Host cell-left\n    HostName 127.0.0.1\n"
                     + line.format(mark=mark) + "\n")
    host = alias_host("cell0", "cell-left", cfg)
    with pytest.raises(SshConfigError) as err:
        SshTransport(host).open([sys.executable, "-c", "pass"], 5.0)
    text = str(err.value)
    assert isinstance(err.value, ConfigError) and isinstance(err.value, TransportError)
    assert "\n" not in text and text.startswith(f"host cell0: {option} in {cfg}")
    assert not mark.exists()  # nothing ran


def test_an_alias_the_ssh_config_does_not_know_is_one_line(tmp_path: Path) -> None:
    cfg = ssh_config(tmp_path / "ssh_config", "Host cell-left\n    HostName 127.0.0.1\n"
                     "Host *\n    User lab\n")
    with pytest.raises(SshConfigError) as err:
        resolve_route(alias_host("cell0", "cell-lfet", cfg))
    assert str(err.value) == (f"host cell0: ssh_alias 'cell-lfet' is not a Host of {cfg}; "
                              "fix the alias or add a Host block for it")


def test_proxy_command_of_another_host_does_not_matter(tmp_path: Path) -> None:
    cfg = ssh_config(tmp_path / "ssh_config", "Host elsewhere\n    ProxyCommand nc %h %p\n"
                     "Host cell-left\n    HostName 127.0.0.1\n")
    assert resolve_route(alias_host("cell0", "cell-left", cfg)).target.hostname == "127.0.0.1"


def test_proxy_jump_chains_as_openssh_and_loops_are_refused(tmp_path: Path) -> None:
    cfg = ssh_config(tmp_path / "ssh_config", """\
Host cell-left
    HostName 10.0.0.5
    ProxyJump ops@gate:2201,inner
Host gate
    HostName 192.0.2.1
    ProxyJump edge
Host inner
    HostName 10.0.0.1
    ProxyJump gate
Host edge
    HostName 198.51.100.7
Host loop-a
    ProxyJump loop-b
Host loop-b
    ProxyJump loop-a
""")
    route = resolve_route(alias_host("cell0", "cell-left", cfg, user="robot"))
    # gate by its own config (through edge), inner through gate (its ProxyJump unused)
    assert [(h.name, h.hostname, h.port, h.user) for h in route.hops] == [
        ("edge", "198.51.100.7", 22, getpass.getuser()),
        ("gate", "192.0.2.1", 2201, "ops"),
        ("inner", "10.0.0.1", 22, getpass.getuser()),
        ("cell-left", "10.0.0.5", 22, "robot")]
    assert all(h.bastion for h in route.hops[:-1]) and not route.target.bastion
    with pytest.raises(SshConfigError, match="a loop"):
        resolve_route(alias_host("cell0", "loop-a", cfg))


# -- the config fields -------------------------------------------------------------------
HOST = '[[hosts]]\nname = "cell0"\ntransport = "ssh"\npython = "/usr/bin/python3"\n'


def parse(text: str) -> Any:
    return parse_config(tomllib.loads(text)).hosts[0]


def test_alias_reads_the_default_ssh_config(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    with pytest.raises(ConfigError, match=r"hosts\[0\]\.ssh_config: no such file"):
        parse(HOST + 'ssh_alias = "cell-left"\n')
    (tmp_path / ".ssh").mkdir()
    (tmp_path / ".ssh" / "config").write_text("Host cell-left\n")
    h = parse(HOST + 'ssh_alias = "cell-left"\n')  # no user, key or known_hosts needed
    assert h.ssh_config == str(tmp_path / ".ssh" / "config")
    assert (h.user, h.key_file, h.known_hosts) == (None, None, None)


@pytest.mark.parametrize(("extra", "where"), [
    ('ssh_config = "/etc/hosts"\n', "hosts[0].ssh_alias: ssh_config is set but ssh_alias"),
    ('ssh_alias = "-oProxyCommand=x"\n', "hosts[0].ssh_alias"),
    ('ssh_alias = "a b"\n', "hosts[0].ssh_alias"),
    ('ssh_alias = "cell"\nssh_config = "/etc/hosts"\naddress = "10.0.0.5"\n',
     "hosts[0].address: address and ssh_alias both say where the host is"),
])
def test_alias_fields_refused_with_one_line(extra: str, where: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse(HOST + extra)
    assert where in str(err.value) and "\n" not in str(err.value)


def test_alias_needs_ssh_transport() -> None:
    with pytest.raises(ConfigError, match=r'hosts\[0\]\.ssh_alias: an ssh alias needs '
                                          r'transport = "ssh"'):
        parse('[[hosts]]\nname = "cell0"\nssh_alias = "cell"\nssh_config = "/etc/hosts"\n')


def test_explicit_hosts_keep_working_and_may_leave_the_key_to_the_agent(
        tmp_path: Path) -> None:
    known = tmp_path / "known_hosts"
    known.write_text("")
    base = HOST + f'address = "10.0.0.5"\nport = 2222\nuser = "lab"\nknown_hosts = "{known}"\n'
    h = parse(base)
    assert (h.address, h.port, h.user, h.key_file, h.ssh_alias, h.ssh_config) == (
        "10.0.0.5", 2222, "lab", None, None, None)
    hop = resolve_route(h).target
    assert (hop.hostname, hop.port, hop.user, hop.identity_files, hop.known_hosts) == (
        "10.0.0.5", 2222, "lab", (), (str(known),))
    with pytest.raises(ConfigError, match="ssh transport needs known_hosts"):
        parse(HOST + 'user = "lab"\n')
