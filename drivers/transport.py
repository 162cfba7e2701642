"""Byte pipes to a host agent: a local subprocess or one SSH exec channel (paramiko).

Why two transports with one interface: the agent speaks the same frames either way, so
twin mode needs no SSH server, and the tests can still run the lab path against a real
OpenSSH on loopback. A transport only moves bytes with deadlines; framing and meaning
live in ``drivers.wire`` and ``drivers.link``.

Rules kept here (the security rules; docs/notes/drivers.md, "SSH"):

* The agent's command line is a fixed argv built by :func:`agent_argv`; over SSH every
  word is quoted with ``shlex.quote`` (the remote side always runs a shell), so no config
  value is ever interpolated into a shell string; no local shell is ever started.
* SSH: host key checked against the host's configured known_hosts file only; an unknown
  key is refused (a ``RejectPolicy``) with a message naming the host and the file; key
  auth only (no passwords, no ssh-agent, no ~/.ssh key search); TCP_NODELAY on the
  socket (Nagle + delayed ACK stall small frames by ~40 ms).
* Reads and writes take an absolute deadline (``time.monotonic()``); nothing blocks
  past it. ``close`` is bounded too.
"""

from __future__ import annotations

import contextlib
import os
import select
import shlex
import socket
import subprocess
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

from drivers.errors import DeadlineExceeded, HostKeyError, LinkClosed, TransportError
from testbed.core.config import HostConfig

PROJECT_ROOT = Path(__file__).resolve().parent.parent
STDERR_KEEP = 8192
STDERR_LINE_MAX = 16384


def agent_argv(host: HostConfig, *, seed: int, python: str, idle_timeout_s: float,
               calibrating: Collection[str] = ()) -> list[str]:
    """The agent's argv for ``host`` (no shell words; quoting is the transport's job).

    Backend-specific fields are read with ``getattr``: a twin host's config has no
    camera, a YuMi host's no physics. ``calibrating``: arms started in calibration mode
    (``--calibrate ARM``). The watchdog is one second past the heartbeat period: the
    session heartbeats every ``heartbeat_s`` during a call too, so a longer silence
    while a motion runs means the link stopped answering."""
    argv = [python, "-m", "drivers.agent", "--backend", host.backend, "--host", host.name,
            "--arms", ",".join(a.name for a in host.arms),
            "--mirror", ",".join("1" if a.mirror else "0" for a in host.arms),
            "--seed", str(seed), "--idle-timeout", f"{idle_timeout_s:g}",
            "--watchdog", f"{host.heartbeat_s + 1:g}"]
    if host.backend == "twin" and not getattr(host, "physics", True):
        argv.append("--no-physics")
    if host.backend == "yumi":
        if (camera := getattr(host, "camera", None)) is not None:
            argv += ["--camera", str(camera)]
        if (url := getattr(host, "controller_url", None)) is not None:
            argv += ["--controller-url", str(url)]
        if (creds := getattr(host, "credentials_file", None)) is not None:
            argv += ["--credentials-file", str(creds)]
        if (limit := getattr(host, "motion_timeout_s", None)) is not None:
            argv += ["--motion-timeout", f"{limit:g}"]
        if (locks := getattr(host, "lock_dir", None)) is not None:
            argv += ["--lock-dir", str(locks)]
        for a in host.arms:
            if (crop := getattr(a, "crop", None)) is not None:
                argv += ["--crop", f"{a.name}=" + ",".join(str(v) for v in crop)]
            if (cal := getattr(a, "calibration", None)) is not None:
                argv += ["--calibration", f"{a.name}={cal}"]
    for arm in calibrating:
        argv += ["--calibrate", arm]
    if host.workdir is not None:
        argv += ["--chdir", host.workdir]
    return argv


class Transport(ABC):
    """A byte stream to one agent process, with deadlines."""

    def __init__(self, host: HostConfig) -> None:
        self.host = host
        self._stderr = bytearray()
        self._reads = 0
        self._partial = bytearray()
        self.on_stderr_line: Callable[[str], None] | None = None
        """Called with every complete line the agent writes to stderr (the host log);
        lines arrive when stderr is drained: every 32nd read, at EOF and at close."""

    @property
    def peer(self) -> str:
        return f"agent on host {self.host.name}"

    @abstractmethod
    def open(self, argv: list[str], timeout_s: float) -> None:
        """Start the agent; TransportError/HostKeyError if that is impossible."""

    @abstractmethod
    def read(self, n: int, deadline: float) -> bytes:
        """Up to ``n`` bytes (at least one), ``b""`` at EOF; DeadlineExceeded past it."""

    @abstractmethod
    def write(self, data: bytes, deadline: float) -> None:
        """All of ``data``; LinkClosed if the peer is gone, DeadlineExceeded past it."""

    @abstractmethod
    def close(self) -> None:
        """Stop the agent and release everything; bounded time, never raises."""

    @abstractmethod
    def exit_status(self) -> int | None:
        """The agent's exit status, if it has exited."""

    def _due_drain(self) -> bool:
        """Drain the agent's stderr every 32nd read: often enough that it never fills a
        pipe or an SSH window, rarely enough to cost nothing per frame."""
        self._reads += 1
        return self._reads % 32 == 0

    def _keep_stderr(self, data: bytes) -> None:
        self._stderr += data
        if len(self._stderr) > STDERR_KEEP:
            del self._stderr[:-STDERR_KEEP]
        if self.on_stderr_line is None or not data:
            return
        self._partial += data
        if b"\n" not in data and len(self._partial) <= STDERR_LINE_MAX:
            return
        *lines, rest = self._partial.split(b"\n")
        self._partial = bytearray(rest)
        if len(self._partial) > STDERR_LINE_MAX:  # a runaway line: pass it on in pieces
            lines.append(bytes(self._partial))
            self._partial.clear()
        for line in lines:
            self._emit(line)

    def _emit(self, line: bytes) -> None:
        cb = self.on_stderr_line
        if cb is None:
            return
        with contextlib.suppress(Exception):  # a log sink must never break the link
            cb(line.decode("utf-8", "replace").rstrip("\r"))

    def flush_stderr_lines(self) -> None:
        """Pass on a last line that had no newline (the agent has exited)."""
        if self._partial:
            line, self._partial = bytes(self._partial), bytearray()
            self._emit(line)

    def stderr_tail(self) -> str:
        return self._stderr.decode("utf-8", "replace").strip()

    def diagnostics(self) -> str:
        """What the agent left behind: exit status and the end of its stderr."""
        status = self.exit_status()
        parts = [] if status is None else [f"agent exited with status {status}"]
        if tail := self.stderr_tail():
            parts.append("agent stderr (last lines):\n" + "\n".join(tail.splitlines()[-20:]))
        return "\n".join(parts)


class LocalTransport(Transport):
    """The agent as a child process on this machine, frames over its stdin/stdout."""

    def __init__(self, host: HostConfig) -> None:
        super().__init__(host)
        self._proc: subprocess.Popen[bytes] | None = None
        self._closed = False

    @staticmethod
    def python_for(host: HostConfig) -> str:
        """A local agent runs with the controller's own interpreter unless the config
        names an absolute one (the default ``python3`` may be another install)."""
        return host.python if host.python.startswith("/") else sys.executable

    def open(self, argv: list[str], timeout_s: float) -> None:
        workdir = self.host.workdir or str(PROJECT_ROOT)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (workdir, env.get("PYTHONPATH", "")) if p)
        try:
            # New session: a Ctrl-C at the terminal must not kill the agent before the
            # controller has sent its arms to rest.
            self._proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, cwd=workdir, env=env,
                                          bufsize=0, start_new_session=True)
        except OSError as exc:
            raise TransportError(f"host {self.host.name}: cannot start the agent "
                                 f"{argv[0]!r}: {exc}") from None
        assert self._proc.stdin and self._proc.stdout and self._proc.stderr
        os.set_blocking(self._proc.stdin.fileno(), False)
        os.set_blocking(self._proc.stderr.fileno(), False)

    def _drain_stderr(self) -> None:
        if self._proc is None or self._proc.stderr is None:
            return
        with contextlib.suppress(BlockingIOError, OSError, ValueError):
            while chunk := os.read(self._proc.stderr.fileno(), 65536):
                self._keep_stderr(chunk)

    def read(self, n: int, deadline: float) -> bytes:
        assert self._proc is not None and self._proc.stdout is not None
        fd = self._proc.stdout.fileno()
        if self._due_drain():
            self._drain_stderr()
        while True:
            # Past the deadline, bytes that are already there still count: the fleet
            # reads hosts one after the other, and a fast host must not pay for a slow one.
            timeout = max(deadline - time.monotonic(), 0.0)
            ready, _, _ = select.select([fd], [], [], timeout)
            if ready:
                data = os.read(fd, n)
                if not data:
                    self._drain_stderr()
                return data
            if timeout == 0.0:
                raise DeadlineExceeded(f"{self.peer}: no reply within the deadline")

    def write(self, data: bytes, deadline: float) -> None:
        assert self._proc is not None and self._proc.stdin is not None
        fd = self._proc.stdin.fileno()
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(fd, view):]
            except BlockingIOError:
                pass
            except (BrokenPipeError, ConnectionError, OSError) as exc:
                raise LinkClosed(f"{self.peer} is gone ({exc.__class__.__name__})") from None
            if view:
                timeout = deadline - time.monotonic()
                if timeout <= 0:
                    raise DeadlineExceeded(f"{self.peer}: does not read its input")
                select.select([], [fd], [], timeout)

    def exit_status(self) -> int | None:
        return None if self._proc is None else self._proc.poll()

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def close(self) -> None:
        proc = self._proc
        if proc is None or self._closed:
            return
        self._closed = True
        with contextlib.suppress(OSError):
            assert proc.stdin is not None
            proc.stdin.close()  # EOF: the agent exits (arms unmoved: bye rested them)
        try:
            proc.wait(0.5)
        except subprocess.TimeoutExpired:
            proc.terminate()
            try:
                proc.wait(0.5)
            except subprocess.TimeoutExpired:
                proc.kill()
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(2.0)
        self._drain_stderr()
        self.flush_stderr_lines()
        for f in (proc.stdout, proc.stderr):
            with contextlib.suppress(OSError):
                if f is not None:
                    f.close()


class SshTransport(Transport):
    """The agent on a remote host over ONE long-lived paramiko exec channel."""

    def __init__(self, host: HostConfig) -> None:
        super().__init__(host)
        self._client: Any = None
        self._chan: Any = None

    @staticmethod
    def remote_command(host: HostConfig, argv: list[str]) -> str:
        """The exec request: argv words each shlex-quoted; PYTHONPATH via ``env``."""
        words = (["env", f"PYTHONPATH={host.workdir}"] if host.workdir else []) + argv
        return " ".join(shlex.quote(w) for w in words)

    def open(self, argv: list[str], timeout_s: float) -> None:
        import paramiko  # only the SSH path needs it

        h = self.host
        if h.known_hosts is None or h.key_file is None or h.user is None:
            raise TransportError(f"host {h.name}: ssh needs user, key_file and known_hosts")
        if not argv or not argv[0].startswith("/"):
            raise TransportError(f"host {h.name}: over ssh the agent's interpreter must be "
                                 f"an absolute path, got {argv[:1]}")
        where = f"{h.address}:{h.port}"
        client = paramiko.SSHClient()
        try:
            client.load_host_keys(h.known_hosts)
        except (OSError, paramiko.SSHException) as exc:
            raise HostKeyError(f"host {h.name}: cannot read known_hosts file {h.known_hosts}: "
                               f"{exc}") from None
        client.set_missing_host_key_policy(_refusing_policy(h.name, h.known_hosts, h.port))
        try:
            sock = socket.create_connection((h.address, h.port), timeout=timeout_s)
        except OSError as exc:
            client.close()
            raise TransportError(f"host {h.name}: cannot reach {where}: {exc}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            client.connect(hostname=h.address, port=h.port, username=h.user,
                           key_filename=h.key_file, sock=sock, timeout=timeout_s,
                           banner_timeout=timeout_s, auth_timeout=timeout_s,
                           channel_timeout=timeout_s, allow_agent=False, look_for_keys=False)
            transport = client.get_transport()
            assert transport is not None
            chan = transport.open_session(timeout=timeout_s)
            chan.exec_command(self.remote_command(h, argv))
        except HostKeyError:
            client.close()
            raise
        except paramiko.BadHostKeyException as exc:
            client.close()
            raise HostKeyError(
                f"host {h.name} ({where}): the server's host key does NOT match the entry in "
                f"{h.known_hosts} (got {exc.key.get_name()} {exc.key.fingerprint}); refusing "
                f"to connect. If the host was reinstalled, verify and replace its entry.") from None
        except paramiko.AuthenticationException as exc:
            client.close()
            raise TransportError(f"host {h.name} ({where}): key authentication as {h.user!r} "
                                 f"with {h.key_file} failed: {exc}") from None
        except (paramiko.SSHException, OSError, EOFError) as exc:
            client.close()
            raise TransportError(f"host {h.name} ({where}): SSH failed: "
                                 f"{type(exc).__name__}: {exc}") from None
        self._client, self._chan = client, chan

    def _drain_stderr(self) -> None:
        chan = self._chan
        with contextlib.suppress(Exception):
            while chan is not None and chan.recv_stderr_ready():
                self._keep_stderr(chan.recv_stderr(65536))

    def read(self, n: int, deadline: float) -> bytes:
        chan = self._chan
        assert chan is not None
        if self._due_drain():
            self._drain_stderr()
        # Wait with select, not chan.settimeout: a heartbeat or a stop may be written
        # from another thread while this read waits, and the channel has ONE timeout,
        # which a write sets (it would cut this read short, or stretch it). The
        # channel's select pipe is also readable for stderr alone: drain that and wait on.
        # Past the deadline, bytes already received still count (see LocalTransport).
        try:
            while not (chan.recv_ready() or chan.eof_received or chan.closed):
                if chan.recv_stderr_ready():
                    self._drain_stderr()
                    continue
                timeout = max(deadline - time.monotonic(), 0.0)
                if not select.select([chan], [], [], timeout)[0] and timeout == 0.0:
                    raise DeadlineExceeded(f"{self.peer}: no reply within the deadline")
            data: bytes = chan.recv(n)  # data or EOF: never a wait
        except (OSError, EOFError, ValueError) as exc:
            raise LinkClosed(f"{self.peer}: SSH channel failed: {exc}") from None
        if not data:
            self._drain_stderr()
        return data

    def write(self, data: bytes, deadline: float) -> None:
        """Writes come one at a time (``AgentLink`` holds its write lock), so the
        channel's timeout is theirs alone."""
        chan = self._chan
        assert chan is not None
        timeout = deadline - time.monotonic()
        if timeout <= 0:
            raise DeadlineExceeded(f"{self.peer}: could not send within the deadline")
        chan.settimeout(timeout)
        try:
            chan.sendall(data)
        except TimeoutError:
            raise DeadlineExceeded(f"{self.peer}: could not send within the deadline") from None
        except (OSError, EOFError) as exc:
            raise LinkClosed(f"{self.peer}: SSH channel closed ({exc})") from None

    def exit_status(self) -> int | None:
        chan = self._chan
        if chan is not None and chan.exit_status_ready():
            return int(chan.recv_exit_status())
        return None

    def close(self) -> None:
        chan, client = self._chan, self._client
        self._client = None
        if chan is not None:
            with contextlib.suppress(Exception):
                chan.shutdown_write()  # EOF on the agent's stdin: it exits, arms unmoved
            # Its last stderr lines (for the host log): until it exits, briefly.
            until = time.monotonic() + 0.5
            with contextlib.suppress(Exception):
                while not chan.exit_status_ready() and time.monotonic() < until:
                    self._drain_stderr()
                    time.sleep(0.01)
            self._drain_stderr()
            self.flush_stderr_lines()
            with contextlib.suppress(Exception):
                chan.close()
        if client is not None:
            with contextlib.suppress(Exception):
                client.close()


def _fingerprint(key: Any) -> str:
    import base64
    import hashlib

    digest = hashlib.sha256(key.asbytes()).digest()
    return "SHA256:" + base64.b64encode(digest).decode().rstrip("=")


def _refusing_policy(host: str, known_hosts: str, port: int) -> Any:
    """A paramiko ``RejectPolicy`` whose refusal names the host and the known_hosts file."""
    import paramiko

    class RefuseUnknownHostKey(paramiko.RejectPolicy):
        def missing_host_key(self, client: Any, hostname: str, key: Any) -> None:
            raise HostKeyError(
                f"host {host}: the SSH server at {hostname} offered an unknown "
                f"{key.get_name()} host key ({_fingerprint(key)}) that is not in the "
                f"known_hosts file {known_hosts}; refusing to connect (unknown host keys "
                f"are refused). Verify the fingerprint on the host, then add it, e.g. "
                f"ssh-keyscan -p {port} ADDRESS >> {known_hosts}")

    return RefuseUnknownHostKey()


def make_transport(host: HostConfig) -> Transport:
    return SshTransport(host) if host.transport == "ssh" else LocalTransport(host)
