"""A throwaway OpenSSH server on loopback, for the SSH tests and the SSH benchmark.

Why a real sshd and not a paramiko server: the lab's path is OpenSSH on the robot host,
and its quirks (the user's shell runs the exec command, Nagle on the server side,
channel teardown when the server dies) are what the transport must survive. Recipe
(measured on these machines: docs/notes/rehearsal.md): ``sshd -D -e -f CONFIG`` with
its own host key, its own authorized_keys, no passwords, no PAM, ``StrictModes no``,
listening on 127.0.0.1 at a free port, as the current user. Debian package:
``openssh-server`` (it also brings ``openssh-client`` for ``ssh-keygen``); sshd needs
the folder ``/run/sshd``.

The server can be killed (``stop``), frozen (``freeze``/``thaw``, SIGSTOP: a dead peer
that never closes the TCP connection) and started again on the same port with the same
keys (``start``). ``stop`` also ends every process the server started (the agents), by
process id, so a test leaves nothing behind. A bastion is just another server (its
``log_level="DEBUG1"`` log shows each forwarded ``direct-tcpip`` connection);
``SshAgent`` is a real ``ssh-agent`` for keys that never touch the controller's disk.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

SSHD = shutil.which("sshd", path="/usr/sbin:/usr/bin:/sbin:/bin") or "/usr/sbin/sshd"


def sshd_available() -> bool:
    return Path(SSHD).is_file() and shutil.which("ssh-keygen") is not None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def keygen(path: Path, comment: str, passphrase: str = "") -> Path:
    """A new ed25519 key pair at ``path`` (and ``path.pub``) made by ``ssh-keygen``.

    A passphrase-protected key gets 2 bcrypt rounds instead of 16: the tests want a
    real encrypted OpenSSH key, not a slow one (16 rounds: ~0.3 s per decryption here)."""
    rounds = ["-a", "2"] if passphrase else []
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", passphrase, *rounds,
                    "-C", comment, "-f", str(path)], check=True, stdin=subprocess.DEVNULL)
    return path


def _children(pid: int) -> list[int]:
    """All descendants of ``pid`` (from /proc), deepest last."""
    parents: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat[stat.rindex(")") + 2:].split()[1])
        parents.setdefault(ppid, []).append(int(entry))
    out: list[int] = []
    stack = [pid]
    while stack:
        for c in parents.get(stack.pop(), []):
            out.append(c)
            stack.append(c)
    return out


@dataclass
class SshServer:
    """One sshd on 127.0.0.1; keys and config live in ``root``."""

    root: Path
    port: int = field(default_factory=free_port)
    user: str = field(default_factory=lambda: os.environ.get("USER") or _whoami())
    log_level: str = "ERROR"
    """sshd's ``LogLevel`` (its ``-e`` output goes to ``log``): ``DEBUG1`` shows each
    forwarded ``direct-tcpip`` connection, which a bastion test reads."""
    proc: subprocess.Popen[bytes] | None = None
    _known_pids: set[int] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        self.host_key = self.root / "ssh_host_ed25519_key"
        self.client_key = self.root / "client_ed25519"
        self.authorized_keys = self.root / "authorized_keys"
        self.known_hosts = self.root / "known_hosts"
        self.config = self.root / "sshd_config"
        self.log = self.root / "sshd.log"
        if not self.host_key.exists():
            keygen(self.host_key, "fleet-test-host")
            keygen(self.client_key, "fleet-test-client")
        shutil.copyfile(self.client_key.with_suffix(".pub"), self.authorized_keys)
        host_pub = self.host_key.with_suffix(".pub").read_text().split()
        self.known_hosts.write_text(f"[127.0.0.1]:{self.port} {host_pub[0]} {host_pub[1]}\n")
        self.config.write_text("\n".join([
            f"Port {self.port}", "ListenAddress 127.0.0.1", f"HostKey {self.host_key}",
            f"AuthorizedKeysFile {self.authorized_keys}", "PasswordAuthentication no",
            "KbdInteractiveAuthentication no", "PubkeyAuthentication yes", "UsePAM no",
            "StrictModes no", "PermitRootLogin prohibit-password", f"PidFile {self.root}/pid",
            "MaxStartups 100", "MaxSessions 50", "UseDNS no", "PrintMotd no",
            # SFTP as a Debian host's sshd has it (testbed deploy copies its wheel so)
            "Subsystem sftp internal-sftp",
            f"LogLevel {self.log_level}", "",
        ]))

    def authorize(self, public_key: Path) -> None:
        """Let the holder of ``public_key`` (a ``.pub`` file) log in too."""
        with open(self.authorized_keys, "a") as f:
            f.write(public_key.read_text().strip() + "\n")

    def known_hosts_line(self, hostname: str = "127.0.0.1") -> str:
        """This server's host key as a known_hosts line for ``hostname`` at its port."""
        kind, blob = self.host_key.with_suffix(".pub").read_text().split()[:2]
        return f"[{hostname}]:{self.port} {kind} {blob}\n"

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def start(self, timeout_s: float = 10.0) -> None:
        """Start (or restart) the server and wait until it answers with its banner."""
        if self.proc is not None and self.proc.poll() is None:
            return
        Path("/run/sshd").mkdir(parents=True, exist_ok=True)
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([SSHD, "-D", "-e", "-f", str(self.config)],
                                         stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                         start_new_session=True)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"sshd exited with {self.proc.returncode}: "
                                   f"{self.log.read_text(errors='replace')[-2000:]}")
            with contextlib.suppress(OSError), socket.create_connection(
                    ("127.0.0.1", self.port), timeout=1.0) as s:
                if s.recv(8).startswith(b"SSH-"):
                    return
            time.sleep(0.02)
        self.stop()
        raise RuntimeError(f"sshd did not answer on port {self.port} within {timeout_s} s")

    def pids(self) -> list[int]:
        """The server and everything it started (sessions, shells, agents)."""
        if self.proc is None:
            return []
        return [self.proc.pid, *_children(self.proc.pid)]

    def _signal_all(self, sig: signal.Signals) -> None:
        for pid in self.pids():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)

    def freeze(self) -> None:
        """SIGSTOP the server and its sessions: a peer that is dead but never says so."""
        self._signal_all(signal.SIGSTOP)

    def thaw(self) -> None:
        self._signal_all(signal.SIGCONT)

    def stop(self) -> None:
        """Kill the server, its sessions and the programs they run (by pid)."""
        if self.proc is None:
            return
        pids = self.pids()
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
                os.kill(pid, signal.SIGCONT)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(5.0)
        deadline = time.monotonic() + 5.0
        for pid in pids[1:]:  # not our children: wait until they are gone
            while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
                if _is_zombie(pid):
                    break
                time.sleep(0.01)
        self.proc = None

    def __enter__(self) -> SshServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


@dataclass
class SshAgent:
    """A real ``ssh-agent`` on a socket of its own, for the tests of agent-held keys.

    Why a real one: paramiko's ``Agent`` speaks the agent protocol over the socket
    named by ``SSH_AUTH_SOCK``, and the point is that a key the controller never reads
    from disk still logs in. ``ssh-agent -D -a SOCK`` stays in the foreground (its pid
    is ours to stop); ``add`` runs ``ssh-add`` against that socket only.
    """

    sock: Path
    proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout_s: float = 5.0) -> None:
        if len(str(self.sock)) > 100:  # sun_path holds 108 bytes
            raise ValueError(f"agent socket path too long for AF_UNIX: {self.sock}")
        self.sock.unlink(missing_ok=True)
        self.proc = subprocess.Popen(["ssh-agent", "-D", "-a", str(self.sock)],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + timeout_s
        while not self.sock.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"ssh-agent did not make its socket {self.sock}")
            time.sleep(0.01)

    def env(self) -> dict[str, str]:
        return {**os.environ, "SSH_AUTH_SOCK": str(self.sock)}

    def add(self, key: Path) -> None:
        """``ssh-add KEY`` (an unencrypted key: nothing to ask)."""
        subprocess.run(["ssh-add", "-q", str(key)], check=True, env=self.env(),
                       stdin=subprocess.DEVNULL, capture_output=True)

    def stop(self) -> None:
        if self.proc is None:
            return
        with contextlib.suppress(ProcessLookupError):
            self.proc.kill()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(5.0)
        self.proc = None
        self.sock.unlink(missing_ok=True)

    def __enter__(self) -> SshAgent:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _is_zombie(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat[stat.rindex(")") + 2] == "Z"


def _whoami() -> str:
    import pwd

    return pwd.getpwuid(os.getuid()).pw_name
