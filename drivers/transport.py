"""Byte pipes to a host agent: a local subprocess or one SSH exec channel (paramiko).

Why two transports with one interface: the agent speaks the same frames either way, so
twin mode needs no SSH server, and the tests can still run the lab path against a real
OpenSSH on loopback. A transport only moves bytes with deadlines; framing and meaning
live in ``drivers.wire`` and ``drivers.link``.

Rules kept here (the security rules; docs/notes/drivers.md, "SSH"):

* The agent's command line is a fixed argv built by :func:`agent_argv`; over SSH every
  word is quoted with ``shlex.quote`` (the remote side always runs a shell), so no config
  value is ever interpolated into a shell string; no local shell is ever started.
* SSH (how a host is reached: ``drivers.ssh_setup``): every hop's host key checked
  against its known_hosts files only; an unknown key is refused (a ``RejectPolicy``)
  with a message naming the hop and the file; key auth only: the named key, else the
  ssh-agent's keys (no passwords, no ~/.ssh key search); no local process (no ssh
  binary, no ProxyCommand): a bastion is crossed by a ``direct-tcpip`` channel;
  TCP_NODELAY on the socket (Nagle + delayed ACK stall small frames by ~40 ms).
* Reads and writes take an absolute deadline (``time.monotonic()``); nothing blocks
  past it. ``close`` is bounded too.
"""

from __future__ import annotations

import contextlib
import os
import select
import shlex
import subprocess
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

from drivers.backends.plugin import agent_plugin
from drivers.errors import DeadlineExceeded, LinkClosed, TransportError
from testbed.core.host_config import HostConfig

PROJECT_ROOT = Path(__file__).resolve().parent.parent
STDERR_KEEP = 8192
STDERR_LINE_MAX = 16384


def agent_argv(host: HostConfig, *, seed: int, python: str, idle_timeout_s: float,
               calibrating: Collection[str] = ()) -> list[str]:
    """The agent's argv for ``host`` (no shell words; quoting is the transport's job).

    The backend's own flags are its plugin's (``BackendPlugin.agent_argv``: the same
    object reads them in the agent). ``calibrating``: arms started in calibration mode
    (``--calibrate ARM``). The watchdog is one second past the heartbeat period: the
    session heartbeats every ``heartbeat_s`` during a call too, so a longer silence
    while a motion runs means the link stopped answering."""
    argv = [python, "-m", "drivers.agent", "--backend", host.backend, "--host", host.name,
            "--arms", ",".join(a.name for a in host.arms),
            "--mirror", ",".join("1" if a.mirror else "0" for a in host.arms),
            "--seed", str(seed), "--idle-timeout", f"{idle_timeout_s:g}",
            "--watchdog", f"{host.heartbeat_s + 1:g}"]
    argv += agent_plugin(host.backend).agent_argv(host)
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
        self._conn: Any = None
        """The ``ssh_setup.Connection``: the host's SSH connection and its bastions'."""
        self._chan: Any = None

    @staticmethod
    def remote_command(host: HostConfig, argv: list[str]) -> str:
        """The exec request: argv words each shlex-quoted; PYTHONPATH via ``env``."""
        words = (["env", f"PYTHONPATH={host.workdir}"] if host.workdir else []) + argv
        return " ".join(shlex.quote(w) for w in words)

    def open(self, argv: list[str], timeout_s: float) -> None:
        """Log in along the host's route (``drivers.ssh_setup``: an ssh config alias,
        bastions, agent or passphrase keys) and start the agent on one exec channel."""
        import paramiko  # only the SSH path needs it

        from drivers import ssh_setup

        h = self.host
        if not argv or not argv[0].startswith("/"):
            raise TransportError(f"host {h.name}: over ssh the agent's interpreter must be "
                                 f"an absolute path, got {argv[:1]}")
        deadline = time.monotonic() + timeout_s
        route = ssh_setup.resolve_route(h)
        conn = ssh_setup.connect(route, timeout_s)
        try:
            chan = conn.transport.open_session(timeout=max(deadline - time.monotonic(), 0.1))
            chan.exec_command(self.remote_command(h, argv))
        except (paramiko.SSHException, OSError, EOFError) as exc:
            conn.close()
            target = route.target
            raise TransportError(ssh_setup.one_line(
                f"{target.role} ({target.where}): SSH failed: {type(exc).__name__}: "
                f"{exc}")) from None
        self._conn, self._chan = conn, chan

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
        chan, conn = self._chan, self._conn
        self._conn = None
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
        if conn is not None:
            conn.close()  # the host's connection, then each bastion's


def make_transport(host: HostConfig) -> Transport:
    return SshTransport(host) if host.transport == "ssh" else LocalTransport(host)
