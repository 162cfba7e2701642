"""One host as the controller sees it: its link, why it is down, when to retry.

Why this exists: the fleet must never wait for a host that is gone. A session keeps
the host's live :class:`~drivers.link.AgentLink` (or the reason there is none), and the
three things that happen to it outside the fleet's calls run in background threads:

* (re)connecting, with exponential backoff (1, 2, 4, ... s, at most 30 s), in a thread
  of its own per attempt, so an SSH connect that hangs in the network hangs nothing;
* the application heartbeat, when nothing has gone to or come from the agent for
  ``heartbeat_s`` (SSH keepalives do not notice a dead peer; the agent exits when it
  hears nothing). While a fleet call holds the link (a motion of seconds), the
  heartbeat is written write-only and the call's reader skips its reply, so the
  agent's watchdog (``--watchdog``, ``heartbeat_s + 1``) hears the controller all along;
* closing a dropped link (waits for the agent to exit, bounded).

A link is dropped as soon as its byte stream can no longer be trusted (protocol error,
deadline, EOF); the agent sees EOF, stops any motion in progress and exits WITHOUT
moving its arms (nobody would be watching them). ``lock`` serialises the fleet's calls
and the heartbeat's own calls on the link; :meth:`HostSession.stop_motion` needs no
lock (a write-only ``stop``, from any thread).

With a :class:`~drivers.hostlog.HostLog`, every event of the host (attempts, connected,
dropped, faults, close) and every stderr line of its agent goes to its log file.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Collection, Mapping
from dataclasses import dataclass

from drivers.build_id import BuildMismatch
from drivers.errors import AgentError, DeadlineExceeded, DriverError, LinkClosed
from drivers.hostlog import HostLog
from drivers.link import AgentLink
from drivers.transport import LocalTransport, agent_argv, make_transport
from testbed.core.host_config import HostConfig

MAX_BACKOFF_S = 30.0
STEP_RETRY_S = 1.0
"""A fleet call that finds the host down retries it at once, if its last attempt is at
least this old (:meth:`HostSession.retry_for_call`)."""
WRITE_ONLY_S = 1.0
"""The longest a write-only heartbeat may take (it holds the link's write lock)."""


@dataclass
class HostStatus:
    """What the fleet knows of one host (for ``testbed check`` and the console)."""

    name: str
    connected: bool = False
    backend: str | None = None
    agent_pid: int | None = None
    build: str | None = None
    """The build the host's last agent reported at hello (None: none answered yet)."""
    controller: Mapping[str, str] | None = None
    """A YuMi's controller as that agent's hello named it (serial, RobotWare, system)."""
    error: str | None = None
    """Why the host is down (None while connected)."""
    traceback: str | None = None
    reported: bool = False
    """At least one connection attempt has finished (either way)."""
    attempts: int = 0
    """Failed attempts since the host was last up."""


class HostSession:
    def __init__(self, cfg: HostConfig, seed: int, backoff_s: float, *,
                 calibrating: Collection[str] = (), log: HostLog | None = None) -> None:
        self.cfg = cfg
        self.name = cfg.name
        self.arms = [a.name for a in cfg.arms]
        self.seed = seed
        """The seed a new agent starts with (``HostFleet.reseed`` changes it, so an agent
        started after a reseed is already reseeded)."""
        self.calibrating = tuple(calibrating)
        self.log = log
        self.backoff_s = backoff_s
        self.lock = threading.Lock()
        self.link: AgentLink | None = None
        self._closing_link: AgentLink | None = None  # the link saying bye (stop reaches it)
        self.status = HostStatus(cfg.name)
        self.closed = False
        self._state = threading.Lock()  # guards the fields below and self.link swaps
        self._connecting = False
        self._heartbeating = False
        self._next_attempt = 0.0
        self._last_attempt = -STEP_RETRY_S
        self._down_since = time.monotonic()
        self.status.error = "not connected yet"

    # -- background work (called by the fleet's keeper thread) ----------------------
    def argv(self) -> list[str]:
        h = self.cfg
        python = LocalTransport.python_for(h) if h.transport == "local" else h.python
        idle = max(30.0, 5 * h.heartbeat_s + h.deadline_s)
        return agent_argv(h, seed=self.seed, python=python, idle_timeout_s=idle,
                          calibrating=self.calibrating)

    def event(self, msg: str, *args: object) -> None:
        if self.log is not None:
            self.log.event(msg, *args)

    def tick(self, now: float) -> None:
        """Start a reconnect or a heartbeat if one is due (never blocks)."""
        with self._state:
            if self.closed:
                return
            if self.link is None:
                if not self._connecting and now >= self._next_attempt:
                    self._connecting = True
                    self._last_attempt = now
                    _spawn(self._connect, f"connect-{self.name}")
                return
            link = self.link
            due = now - max(link.last_io, link.last_write) >= self.cfg.heartbeat_s
            if not due or self._heartbeating:
                return
            self._heartbeating = True
        _spawn(self._heartbeat, f"heartbeat-{self.name}")

    def _connect(self) -> None:
        transport = make_transport(self.cfg)
        if self.log is not None:
            transport.on_stderr_line = self.log.agent_line
        link = AgentLink(self.cfg, transport)
        seed = self.seed
        argv = self.argv()
        self.event("starting the agent (attempt %d, %s): %s", self.status.attempts + 1,
                   self.cfg.transport, " ".join(argv))
        try:
            info = link.open(argv, self.cfg.connect_timeout_s)
            if self.seed != seed:  # reseeded while this agent was starting
                link.call("reseed", time.monotonic() + self.cfg.deadline_s, seed=self.seed)
        except Exception as exc:
            close_async(link)
            with self._state:
                self._connecting = False
                self.status.attempts += 1
                delay = min(self.backoff_s * 2 ** (self.status.attempts - 1), MAX_BACKOFF_S)
                self._next_attempt = time.monotonic() + delay
                self.status.error = describe(exc)
                self.status.traceback = remote_traceback(exc)
                self.status.reported = True
                attempts = self.status.attempts
            if self.log is not None:
                self.event("attempt %d failed, next in %.1f s: %s\n%s", attempts, delay,
                           describe(exc), _indent(remote_traceback(exc)))
            return
        with self._state:
            self._connecting = False
            if self.closed:
                close_async(link)
                return
            self.link = link
            self.status.connected = True
            self.status.backend = info.backend
            self.status.agent_pid = info.pid
            self.status.build = info.build
            self.status.controller = info.controller
            self.status.error = self.status.traceback = None
            self.status.attempts = 0
            self.status.reported = True
        self.event("connected: agent pid %d, backend %s, arms %s, seed %d, build %s%s",
                   info.pid, info.backend, ",".join(info.arms), self.seed, info.build,
                   "".join(f", controller {k} {v}" for k, v in (info.controller or {}).items()))

    def _heartbeat(self) -> None:
        try:
            if self.lock.acquire(blocking=False):
                try:
                    link = self.link
                    if link is not None:
                        try:
                            link.heartbeat(time.monotonic() + self.cfg.deadline_s)
                        except Exception as exc:
                            self.drop(link, exc)
                finally:
                    self.lock.release()
                return
            # A call holds the link (a motion may run for seconds): heartbeat write-only;
            # the call's reader skips the reply. A failed write may have torn a frame.
            link = self.link
            if link is not None:
                try:
                    link.send_only("heartbeat", time.monotonic() + min(
                        self.cfg.deadline_s, WRITE_ONLY_S))
                except Exception as exc:
                    self.drop(link, exc)
        finally:
            with self._state:
                self._heartbeating = False

    def stop_motion(self, timeout_s: float) -> bool:
        """``stop`` to the agent now, write-only, even while a call holds the link: it
        stops the motion in progress. True if it was written within ``timeout_s``.
        Never blocks longer; a failed write may have torn a frame, so the link is
        dropped (the agent stops at EOF all the same)."""
        link = self.link or self._closing_link
        if link is None:
            return False
        try:
            sent = link.send_only("stop", time.monotonic() + timeout_s) is not None
        except Exception as exc:
            self.drop(link, exc)
            return False
        if sent:
            self.event("stop sent to the agent")
        else:
            self.event("stop not sent: the link was busy writing for %.1f s", timeout_s)
        return sent

    def retry_for_call(self, now: float) -> None:
        """A fleet call (a step) finds this host down: attempt to reconnect now rather
        than when the backoff says, if the last attempt is ``STEP_RETRY_S`` old. Why: the
        backoff (up to 30 s) spares a host that stays down, but a host whose link came
        back (a cable plugged in, an sshd restarted) should have its arms back at the
        next step, not half a minute later; a step asks at most once a second."""
        with self._state:
            if self.closed or self.link is not None or self._connecting:
                return
            self._next_attempt = min(self._next_attempt,
                                     max(now, self._last_attempt + STEP_RETRY_S))
        self.tick(now)

    # -- used by the fleet's calls ----------------------------------------------------
    def drop(self, link: AgentLink, exc: BaseException) -> None:
        """The stream can't be trusted: forget the link, reconnect after the backoff."""
        with self._state:
            if self.link is not link:
                return
            self.link = None
            self._down_since = time.monotonic()
            self._next_attempt = self._down_since + self.backoff_s
            self.status.connected = False
            self.status.error = describe(exc)
            self.status.traceback = remote_traceback(exc)
        if self.log is not None:
            self.event("dropped the link (reconnecting in %.1f s): %s\n%s", self.backoff_s,
                       describe(exc), _indent(remote_traceback(exc)))
        close_async(link)

    def note_fault(self, reason: str, arms: Collection[str]) -> None:
        """A call's Fault for ``arms`` of this host (the host log only)."""
        self.event("fault for %s: %s", ",".join(arms), reason)

    def down_reason(self) -> str:
        with self._state:
            now = time.monotonic()
            retry = ("reconnecting now" if self._connecting else
                     f"next attempt in {max(self._next_attempt - now, 0.0):.1f} s")
            return (f"host {self.name} is unreachable (down {now - self._down_since:.1f} s, "
                    f"{retry}): {self.status.error}")

    def close(self) -> None:
        """Bye to the agent (it rests its arms, answers, exits), then close; bounded."""
        locked = self.lock.acquire(timeout=min(self.cfg.deadline_s, 3.0))
        try:
            with self._state:
                self.closed = True
                link, self.link = self.link, None
                self.status.connected = False
            if link is not None:
                said = "not said (link busy)"
                if locked:  # never interleave with a heartbeat on the same stream
                    self._closing_link = link  # a stop still reaches the rest at bye
                    try:  # the agent rests its arms before it answers: give it time
                        link.bye(time.monotonic() + min(self.cfg.deadline_s, 5.0))
                        said = "answered"
                    except Exception as exc:
                        said = f"failed: {describe(exc)}"
                    finally:
                        self._closing_link = None
                link.close()
                self.event("closed: bye %s; agent exit status %s", said,
                           link.transport.exit_status())
        finally:
            if locked:
                self.lock.release()


def _indent(text: str) -> str:
    return "\n".join("    " + ln for ln in text.rstrip().splitlines())


def _spawn(target: object, name: str) -> None:
    threading.Thread(target=target, name=name, daemon=True).start()  # type: ignore[arg-type]


def close_async(link: AgentLink) -> None:
    """Close a link off the call path (it waits, bounded, for the agent to exit)."""
    _spawn(link.close, "link-reaper")


def _text(exc: BaseException) -> str:
    if isinstance(exc, AgentError | BuildMismatch):  # their message is the whole line
        return str(exc)
    if isinstance(exc, DriverError):
        kind = {LinkClosed: "link closed", DeadlineExceeded: "deadline exceeded"}.get(
            type(exc), type(exc).__name__)
        return f"{kind}: {exc}"
    return f"{type(exc).__name__}: {exc}"


def describe(exc: BaseException) -> str:
    """One line for a Fault's reason (the agent's exit status kept, its stderr not)."""
    lines = _text(exc).splitlines() or [""]
    status = [ln for ln in lines[1:] if ln.startswith("agent exited with status")]
    return "; ".join([lines[0], *status])


def remote_traceback(exc: BaseException) -> str:
    """Everything else: the agent's stderr tail and the (remote, else local) traceback."""
    extra = "\n".join(_text(exc).splitlines()[1:])
    if isinstance(exc, AgentError) and exc.remote_traceback:
        tb = exc.remote_traceback
    else:
        tb = "".join(traceback.format_exception(exc))
    return f"{extra}\n{tb}" if extra else tb
