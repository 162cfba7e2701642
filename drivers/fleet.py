"""``HostFleet``: the controller-side API the fleet loop calls (docs/ARCHITECTURE.md).

Why it looks like this: the loop wants "observe every arm" and "execute these pushes and
resets" as two calls that return a value for EVERY robot and never hang, whatever the
hosts do. So each call is broadcast to all host workers at once (one process per host,
see ``drivers.worker`` for why), and the answers are collected until each host's
deadline; a host that fails, is late, or whose worker died gives ``Fault`` for all of
its arms, with the reason and the traceback, and the trial goes on. Reconnection
happens in the workers, in the background, with exponential backoff; a dead worker is
respawned here with backoff too.

    observe()/execute()/rest()
        │ send ("call", rid, op, args) to every worker, then
        │ multiprocessing.connection.wait(...) until all answered or deadlines passed
        ▼
    {robot: ArmObservation | PushResult | Fault}  for every robot, in config order
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import subprocess
import sys
import time
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import Any

import numpy as np

from drivers.backends.base import ArmView
from drivers.transport import PROJECT_ROOT
from drivers.worker import MAX_BACKOFF_S, WorkerSpec
from testbed.config import HostConfig
from testbed.types import NUM_ACTIONS, ArmObservation, Fault, PushResult

log = logging.getLogger("drivers.fleet")

GRACE_S = 2.0
"""Slack over a host's own deadlines before its worker counts as wedged (and is killed)."""


def derive_seed(trial_seed: int, host_index: int) -> int:
    """Deterministic, well-mixed twin cell seed for host ``host_index`` of a trial."""
    state = np.random.SeedSequence([trial_seed & 0xFFFFFFFF, 0xF1EE7, host_index])
    return int(state.generate_state(1)[0] & 0x7FFFFFFF)


@dataclass
class HostStatus:
    """What the fleet knows of one host (for ``testbed check`` and the console)."""

    name: str
    connected: bool = False
    backend: str | None = None
    agent_pid: int | None = None
    error: str | None = None
    traceback: str | None = None
    worker_alive: bool = False
    reported: bool = False
    """The worker has reported the outcome of its first connection attempt."""


@dataclass
class _Handle:
    cfg: HostConfig
    index: int
    seed: int
    status: HostStatus
    proc: Any = None
    conn: Connection | None = None
    next_rid: int = 1
    respawns: int = 0
    respawn_at: float = 0.0
    expect: int = 0
    deadline: float = 0.0
    budget: float = 0.0
    arm_names: list[str] = field(default_factory=list)

    def robot(self, arm: str) -> str:
        return f"{self.cfg.name}/{arm}"


class HostFleet:
    """All hosts of a fleet; every call returns a result for every robot, never hangs."""

    def __init__(self, hosts: Sequence[HostConfig], *, trial_seed: int = 0,
                 reconnect_backoff_s: float = 1.0) -> None:
        names = [h.name for h in hosts]
        if not hosts or len(set(names)) != len(names):
            raise ValueError(f"need at least one host and unique host names, got {names}")
        self._backoff = reconnect_backoff_s
        self._handles = [
            _Handle(h, i, h.seed if h.seed is not None else derive_seed(trial_seed, i),
                    HostStatus(h.name), arm_names=[a.name for a in h.arms])
            for i, h in enumerate(hosts)]
        self.robot_names: list[str] = [hd.robot(a) for hd in self._handles for a in hd.arm_names]
        self._started = False
        self._closed = False

    # -- lifecycle --------------------------------------------------------------------
    def _spawn(self, h: _Handle) -> None:
        cfg = h.cfg
        spec = WorkerSpec(host=cfg, seed=h.seed, backoff_s=self._backoff,
                          heartbeat_s=cfg.heartbeat_s, connect_timeout_s=cfg.connect_timeout_s,
                          idle_timeout_s=max(30.0, 5 * cfg.heartbeat_s + cfg.deadline_s))
        # A plain subprocess, not multiprocessing's spawn: that one re-imports the
        # caller's __main__ and breaks every script without an ``if __name__`` guard.
        parent, child = socket.socketpair()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(PROJECT_ROOT), env.get("PYTHONPATH", "")) if p)
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "drivers.worker", str(child.fileno())],
                pass_fds=(child.fileno(),), env=env, stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL, start_new_session=True)
        finally:
            child.close()
        conn = Connection(parent.detach())
        h.proc, h.conn = proc, conn
        h.expect = 0
        h.status.worker_alive = True
        h.status.reported = False
        try:
            conn.send(spec)
        except OSError:
            self._worker_died(h)

    def start(self, timeout_s: float | None = None) -> None:
        """Spawn the workers and wait for each host's first handshake (or its failure).

        A host that cannot be reached does not make this raise: its arms are ``Fault``
        until it comes back (see :meth:`host_status` for why).
        """
        if self._started:
            return
        self._started = True
        for h in self._handles:
            self._spawn(h)
        limit = timeout_s if timeout_s is not None else max(
            h.cfg.connect_timeout_s for h in self._handles) + 15.0
        deadline = time.monotonic() + limit
        while (pending := [h for h in self._handles if not h.status.reported
                           and h.conn is not None]) and time.monotonic() < deadline:
            ready = wait([h.conn for h in pending if h.conn is not None],
                         deadline - time.monotonic())
            for h in pending:
                if h.conn in ready:
                    self._receive(h)
        for h in self._handles:
            if not h.status.connected:
                log.warning("host %s not connected at start: %s", h.cfg.name, h.status.error)

    def close(self) -> None:
        """Stop every worker (its agent gets ``bye``: arms to rest, agent exits)."""
        if self._closed:
            return
        self._closed = True
        for h in self._handles:
            if h.conn is not None and self._alive(h):
                with contextlib.suppress(OSError, ValueError):
                    h.conn.send(("close", 0))
        deadline = time.monotonic() + 6.0
        for h in self._handles:
            if h.proc is not None:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    h.proc.wait(max(deadline - time.monotonic(), 0.1))
        for h in self._handles:
            self._kill(h)

    def __enter__(self) -> HostFleet:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _alive(self, h: _Handle) -> bool:
        return h.proc is not None and h.proc.poll() is None

    def _kill(self, h: _Handle) -> None:
        proc, conn = h.proc, h.conn
        h.proc, h.conn = None, None
        h.status.worker_alive = False
        h.status.connected = False
        if conn is not None:
            conn.close()  # EOF: a live worker closes its link (the agent rests) and exits
        if proc is not None and proc.poll() is None:
            try:
                proc.wait(0.5)
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(1.0)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(2.0)

    def host_status(self) -> dict[str, HostStatus]:
        for h in self._handles:
            self._drain(h)
        return {h.cfg.name: h.status for h in self._handles}

    # -- messages from workers --------------------------------------------------------
    def _receive(self, h: _Handle) -> tuple[int, str, Any] | None:
        """One message from a worker; status updates are absorbed, replies returned."""
        assert h.conn is not None
        try:
            msg = h.conn.recv()
        except (EOFError, OSError):
            self._worker_died(h)
            return None
        if msg[0] == "status":
            st = msg[1]
            h.status.connected = st["connected"]
            h.status.reported = True
            h.status.error = st["error"]
            h.status.traceback = st["traceback"]
            if st["connected"]:
                h.respawns = 0
                h.status.backend = st["info"].get("backend")
                h.status.agent_pid = st["info"].get("pid")
            return None
        return msg[1], msg[2], msg[3]

    def _drain(self, h: _Handle) -> None:
        while h.conn is not None and h.conn.poll(0):
            self._receive(h)

    def _worker_died(self, h: _Handle) -> None:
        code = h.proc.poll() if h.proc is not None else None
        self._kill(h)
        h.respawns += 1
        h.respawn_at = time.monotonic() + min(self._backoff * 2 ** (h.respawns - 1),
                                              MAX_BACKOFF_S)
        h.status.error = f"worker process died (exit code {code})"
        h.status.reported = True

    # -- the broadcast ----------------------------------------------------------------
    def _broadcast(self, calls: Mapping[int, tuple[str, dict[str, Any], int]]
                   ) -> dict[int, tuple[str, Any]]:
        """Send each host its call; gather ("ok", payload) or ("fault", info) per host."""
        results: dict[int, tuple[str, Any]] = {}
        waiting: list[_Handle] = []
        now = time.monotonic()
        for i, (op, args, n_calls) in calls.items():
            h = self._handles[i]
            if h.conn is None and not self._closed and now >= h.respawn_at:
                self._spawn(h)  # its first connection happens in the background
            if h.conn is None:
                results[i] = ("fault", {"reason": f"host {h.cfg.name}: {h.status.error}; "
                                        f"worker restarts in "
                                        f"{max(h.respawn_at - now, 0):.1f} s",
                                        "traceback": "", "arm": None})
                continue
            self._drain(h)
            if h.conn is None:  # died while draining
                results[i] = ("fault", {"reason": f"host {h.cfg.name}: {h.status.error}",
                                        "traceback": "", "arm": None})
                continue
            h.expect = h.next_rid
            h.next_rid += 1
            try:
                h.conn.send(("call", h.expect, op, args))
            except (OSError, ValueError):
                self._worker_died(h)
                results[i] = ("fault", {"reason": f"host {h.cfg.name}: {h.status.error}",
                                        "traceback": "", "arm": None})
                continue
            h.budget = n_calls * h.cfg.deadline_s + GRACE_S
            h.deadline = now + h.budget
            waiting.append(h)
        while waiting:
            now = time.monotonic()
            for h in [h for h in waiting if now >= h.deadline]:
                waiting.remove(h)
                results[h.index] = ("fault", {
                    "reason": f"host {h.cfg.name}: its worker did not answer within "
                              f"{h.budget:.1f} s (deadline_s {h.cfg.deadline_s:g} + grace); "
                              f"worker restarted",
                    "traceback": "", "arm": None})
                self._worker_died(h)
            if not waiting:
                break
            timeout = min(h.deadline for h in waiting) - now
            ready = wait([h.conn for h in waiting if h.conn is not None], max(timeout, 0.0))
            for h in list(waiting):
                if h.conn not in ready:
                    continue
                got = self._receive(h)
                if h.conn is None:  # worker died
                    waiting.remove(h)
                    results[h.index] = ("fault", {"reason": f"host {h.cfg.name}: "
                                                  f"{h.status.error}", "traceback": "",
                                                  "arm": None})
                elif got is not None and got[0] == h.expect:
                    waiting.remove(h)
                    results[h.index] = (got[1], got[2])
        return results

    def _faults(self, h: _Handle, info: Mapping[str, Any]) -> dict[str, Fault]:
        reason = str(info.get("reason") or "unknown failure")
        return {h.robot(a): Fault(h.robot(a), reason, str(info.get("traceback") or ""))
                for a in h.arm_names}

    # -- the API ----------------------------------------------------------------------
    def observe(self) -> dict[str, ArmObservation | Fault]:
        """One picture per host, all hosts at once; a value for every robot."""
        self._require_started()
        res = self._broadcast({h.index: ("observe", {}, 1) for h in self._handles})
        out: dict[str, ArmObservation | Fault] = {}
        for h in self._handles:
            kind, payload = res[h.index]
            if kind != "ok":
                out.update(self._faults(h, payload))
                continue
            views: dict[str, ArmView] = payload
            for a in h.arm_names:
                v = views[a]
                out[h.robot(a)] = ArmObservation(h.robot(a), v.image, v.violating, v.goal,
                                                 v.expert_action)
        return {r: out[r] for r in self.robot_names}

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> dict[str, PushResult | Fault]:
        """Push the arms in ``pushes`` at once, complete the resets; others wait."""
        self._require_started()
        self._check_execute(pushes, resets)
        per_host: dict[int, tuple[str, dict[str, Any], int]] = {}
        for h in self._handles:
            faces = {a: int(pushes[h.robot(a)]) for a in h.arm_names if h.robot(a) in pushes}
            rs = [a for a in h.arm_names if h.robot(a) in resets]
            per_host[h.index] = ("execute", {"faces": faces, "resets": rs},
                                 int(bool(faces)) + int(bool(rs)) or 1)
        res = self._broadcast(per_host)
        out: dict[str, PushResult | Fault] = {}
        for h in self._handles:
            kind, payload = res[h.index]
            if kind != "ok":
                out.update(self._faults(h, payload))
                continue
            pushed = payload["push"]
            for a in h.arm_names:
                r = h.robot(a)
                if a in pushed:
                    o = pushed[a]
                    out[r] = PushResult(r, int(pushes[r]), o.success, o.violation)
                else:
                    out[r] = PushResult(r, None, False, False)
        return {r: out[r] for r in self.robot_names}

    def rest(self) -> None:
        """Every arm to its rest pose; hosts that fail are logged, never raised."""
        if not self._started or self._closed:
            return
        res = self._broadcast({h.index: ("rest", {}, 1) for h in self._handles})
        for h in self._handles:
            kind, payload = res[h.index]
            if kind != "ok":
                log.warning("rest failed on host %s: %s", h.cfg.name, payload.get("reason"))

    def _require_started(self) -> None:
        if self._closed:
            raise RuntimeError("HostFleet is closed")
        if not self._started:
            self.start()

    def _check_execute(self, pushes: Mapping[str, int], resets: Collection[str]) -> None:
        known = set(self.robot_names)
        if unknown := sorted((set(pushes) | set(resets)) - known):
            raise ValueError(f"unknown robot(s) {unknown}; the fleet has {self.robot_names}")
        if both := sorted(set(pushes) & set(resets)):
            raise ValueError(f"robot(s) {both} both pushed and reset in one step")
        for r, face in pushes.items():
            if isinstance(face, bool) or not isinstance(face, int | np.integer) or not (
                    0 <= int(face) < NUM_ACTIONS):
                raise ValueError(f"{r}: action must be a face in 0..{NUM_ACTIONS - 1}, "
                                 f"got {face!r}")
