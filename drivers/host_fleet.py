"""``HostFleet``: the controller-side API the fleet loop calls (docs/ARCHITECTURE.md).

Why it looks like this: the loop wants "observe every arm" and "execute these pushes and
resets" as two calls that return a value for EVERY robot and never hang, whatever the
hosts do. Each host runs ONE agent process (``python -m drivers.agent``) that drives
all of its arms at once: the host's camera and robot controller are shared by its two
arms (one picture, one MultiMove program), so one process per host, not per arm. That
agent is the host's worker process, in Gymnasium's sense: it runs the environment,
reports every exception as an ``error`` frame naming the arm, with its traceback, and
a crash of it faults that host only.

The controller talks to all agents from the calling thread, without a relay process in
between (measured: a relay process per host made a loopback SSH step 2-5x slower on
the 2-core test machine, worse under load; see docs/notes/drivers.md):

    observe()/execute()/rest()
      1. write each host's request(s) to its link (local pipe or SSH channel)
      2. read each host's reply, each with its own absolute deadline; replies of fast
         hosts wait in their pipe/channel buffers meanwhile, so hosts run in parallel
      3. a host that fails (error, deadline, EOF, malformed frame) -> Fault for its arms

    keeper thread (every 0.1 s): per host, start a reconnect (backoff) or a heartbeat
    (write-only while a call holds the host's link: the agent's watchdog hears us);
    each observe() also retries a host that is down, at most once a second, so a host
    whose link is back has its arms back at the next step, whatever the backoff

    stop_motion() (any thread, a signal handler included): ``stop`` to every agent,
    write-only, even mid-call; Ctrl-C during a call sends it to the hosts in flight
    before their links are dropped

Faults are as narrow as we can know them: an arm whose own entry in a push or observe
reply carries ``error`` is a Fault alone (its sibling's push happened and is reported);
an error frame for the whole request faults the whole host, since we cannot know what
moved (its reason names the arm when the agent does).

Besides the loop's calls, single-host calls for calibration and checks (``frame``,
``move_tcp``, ``save_calibration``) and ``reseed`` raise :class:`HostCallError` (one
line) on failure instead of returning a Fault.

Over 450 lines, on purpose: one class, ``HostFleet``, whose calls (observe, execute,
close) share the host sessions, their threads and their faults: the loop's one door to
the hosts, read as one.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import weakref
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from drivers import wire as p
from drivers.errors import AgentError, DriverError
from drivers.hostlog import HostLog
from drivers.link import AgentLink
from drivers.session import HostSession, HostStatus, describe, remote_traceback
from testbed.core.backend_registry import backend_of
from testbed.core.host_config import HostConfig
from testbed.core.types import NUM_ACTIONS, ArmObservation, Fault, PushResult

__all__ = ["HostCallError", "HostFleet", "HostStatus", "derive_seed"]

log = logging.getLogger("drivers.host_fleet")

KEEPER_PERIOD_S = 0.1
STOP_WRITE_S = 0.5
"""How long a stop may wait to be written to one host (all hosts at once)."""
Program = list[tuple[str, dict[str, Any]]]
T = TypeVar("T")
Outcome = tuple[str, Any]
"""("ok", payload) or ("fault", {"reason", "traceback", "arm"})."""


class HostCallError(DriverError):
    """A single-host call (frame, move_tcp, save_calibration, reseed) failed; the message
    is one line naming the host, ``traceback`` has the agent's side."""

    def __init__(self, message: str, *, host: str, traceback: str = "") -> None:
        super().__init__(message)
        self.host = host
        self.traceback = traceback


def derive_seed(trial_seed: int, host_index: int) -> int:
    """Deterministic, well-mixed twin cell seed for host ``host_index`` of a trial."""
    state = np.random.SeedSequence([trial_seed & 0xFFFFFFFF, 0xF1EE7, host_index])
    return int(state.generate_state(1)[0] & 0x7FFFFFFF)


def _keep(sessions: Sequence[HostSession], stop: threading.Event) -> None:
    """The keeper thread: per host, start a reconnect or a heartbeat when one is due."""
    while not stop.wait(KEEPER_PERIOD_S):
        now = time.monotonic()
        for s in sessions:
            s.tick(now)


def _shutdown(sessions: Sequence[HostSession], stop: threading.Event) -> None:
    """Close every session in parallel (bounded); also run for a fleet never closed."""
    try:
        _close_all(sessions, stop)
    finally:
        for s in sessions:
            if s.log is not None:
                s.log.close()


def _close_all(sessions: Sequence[HostSession], stop: threading.Event) -> None:
    stop.set()
    closers: list[threading.Thread] = []
    for s in sessions:
        t = threading.Thread(target=s.close, daemon=True)
        try:
            t.start()
        except RuntimeError:  # no new threads at interpreter shutdown: one by one
            s.close()
            continue
        closers.append(t)
    deadline = time.monotonic() + 8.0
    for t in closers:
        t.join(max(deadline - time.monotonic(), 0.0))


def _stop_sessions(sessions: Sequence[HostSession]) -> list[str]:
    """``stop`` to every session's agent at once, in threads of their own, so that the
    caller (a signal handler, maybe, in the thread that holds a link's locks) never
    waits longer than ``STOP_WRITE_S`` and a little; the hosts it reached."""
    reached: list[str] = []

    def stop(s: HostSession) -> None:
        if s.stop_motion(STOP_WRITE_S):
            reached.append(s.name)

    threads: list[threading.Thread] = []
    for s in sessions:
        t = threading.Thread(target=stop, args=(s,), name=f"stop-{s.name}", daemon=True)
        try:
            t.start()
        except RuntimeError:  # no new threads at interpreter shutdown: EOF stops them
            continue
        threads.append(t)
    deadline = time.monotonic() + STOP_WRITE_S + 0.1
    for t in threads:
        t.join(max(deadline - time.monotonic(), 0.0))
    return [s.name for s in sessions if s.name in reached]


def _fault(reason: str, tb: str = "", arm: str | None = None, *, refused: bool = False
           ) -> Outcome:
    """``refused``: a clean error reply from a healthy agent (the link is kept)."""
    return ("fault", {"reason": reason, "traceback": tb, "arm": arm, "refused": refused})


def _seed_of(host: HostConfig, index: int, trial_seed: int) -> int:
    seed = getattr(host, "seed", None)  # twin hosts only
    return int(seed) if seed is not None else derive_seed(trial_seed, index)


class HostFleet:
    """All hosts of a fleet; every call returns a result for every robot, never hangs."""

    def __init__(self, hosts: Sequence[HostConfig], *, trial_seed: int = 0,
                 reconnect_backoff_s: float = 1.0, log_dir: Path | str | None = None,
                 calibrating: Mapping[str, Collection[str]] | None = None) -> None:
        """``log_dir``: one rotating, timestamped log per host (``<host>.log``): every
        stderr line of its agent and our events about it. ``calibrating``: host name ->
        arms whose agent starts in calibration mode (``--calibrate ARM``)."""
        names = [h.name for h in hosts]
        if not hosts or len(set(names)) != len(names):
            raise ValueError(f"need at least one host and unique host names, got {names}")
        calibrating = dict(calibrating or {})
        for host, arms in calibrating.items():
            cfg = next((h for h in hosts if h.name == host), None)
            if cfg is None:
                raise ValueError(f"calibrating names unknown host {host!r}; hosts: {names}")
            if unknown := sorted(set(arms) - {a.name for a in cfg.arms}):
                raise ValueError(f"host {host}: cannot calibrate unknown arm(s) {unknown}")
        logs = ({h.name: HostLog(Path(log_dir), h.name) for h in hosts}
                if log_dir is not None else {})
        self._sessions = [
            HostSession(h, _seed_of(h, i, trial_seed), reconnect_backoff_s,
                        calibrating=tuple(calibrating.get(h.name, ())), log=logs.get(h.name))
            for i, h in enumerate(hosts)]
        self.robot_names: list[str] = [f"{s.name}/{a}" for s in self._sessions for a in s.arms]
        self._stop = threading.Event()
        self._keeper: threading.Thread | None = None
        self._started = False
        self._closed = False
        # A fleet dropped without close() still says bye to its agents when collected
        # (the keeper thread holds no reference to the fleet, so it can be collected).
        self._finalizer = weakref.finalize(self, _shutdown, self._sessions, self._stop)

    # -- lifecycle --------------------------------------------------------------------
    def start(self, timeout_s: float | None = None) -> None:
        """Start every host's agent and wait for its handshake (or its failure).

        A host that cannot be reached does not make this raise: its arms are ``Fault``
        until it comes back; :meth:`host_status` says why.
        """
        if self._started:
            return
        self._started = True
        now = time.monotonic()
        for s in self._sessions:
            s.tick(now)
        self._keeper = threading.Thread(target=_keep, args=(self._sessions, self._stop),
                                        name="fleet-keeper", daemon=True)
        self._keeper.start()
        limit = timeout_s if timeout_s is not None else max(
            s.cfg.connect_timeout_s for s in self._sessions) + 5.0
        deadline = time.monotonic() + limit
        while (not all(s.status.reported for s in self._sessions)
               and time.monotonic() < deadline):
            time.sleep(0.01)
        for s in self._sessions:
            if not s.status.connected:
                log.warning("host %s not connected at start: %s", s.name, s.status.error)

    def close(self) -> None:
        """Say bye to every agent (it rests its arms and exits); bounded time."""
        if self._closed:
            return
        self._closed = True
        try:
            self._finalizer()
        except BaseException:  # Ctrl-C while the agents rest at bye: stop those motions
            _stop_sessions(self._sessions)
            raise

    def __enter__(self) -> HostFleet:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def host_status(self) -> dict[str, HostStatus]:
        return {s.name: s.status for s in self._sessions}

    def hosts_info(self) -> dict[str, dict[str, Any]]:
        """What each host is, as its agent said at hello (run.json ``hosts``, the
        optional call of ``testbed.core.hosts``): ``backend`` (the agent's own word:
        twin, twin-canned for a twin without physics, yumi), ``transport``, ``build``,
        ``arms`` and, for a backend with the ``controller`` capability (a YuMi),
        ``controller`` (``serial``, ``robotware``, ``system``; None where not known). A
        host that never answered: its config's backend, build None. Read from memory, no
        request: the hello already said it all, and it never carries a credential."""
        out: dict[str, dict[str, Any]] = {}
        for s in self._sessions:
            status = s.status
            entry: dict[str, Any] = {"backend": status.backend or s.cfg.backend,
                                     "transport": s.cfg.transport, "build": status.build,
                                     "arms": list(s.arms)}
            if backend_of(s.cfg).capabilities.controller:
                said = status.controller or {}
                entry["controller"] = ({k: said.get(k) for k in p.CONTROLLER_KEYS}
                                       if said else None)
            out[s.name] = entry
        return out

    def stop_motion(self) -> list[str]:
        """Stop every motion in progress NOW: ``stop`` to every connected agent,
        write-only, even while a call is in flight (the agent answers it at once and
        the call's reply still comes: an error or the outcome of the stopped motion).

        Callable from any thread, a signal handler or a console's Stop included: the
        hosts are written to at once, each within ``STOP_WRITE_S``, so it returns within
        about half a second whatever the hosts do. Returns the hosts the stop reached."""
        reached = _stop_sessions(self._sessions)
        if len(reached) < sum(1 for s in self._sessions if s.link is not None):
            log.warning("stop reached only hosts %s", reached)
        return reached

    # -- the broadcast ----------------------------------------------------------------
    def _run(self, programs: Mapping[int, Program],
             parse: Callable[[HostSession, AgentLink, list[p.Frame]], Any],
             timeout_s: float | None = None) -> dict[int, Outcome]:
        """Pipelined broadcast: every host's requests are written first (back to back),
        then every host's replies are read in order, each with its own deadline
        (``timeout_s`` per request instead of the host's ``deadline_s``, e.g. a motion)."""
        out: dict[int, Outcome] = {}
        inflight: list[tuple[int, HostSession, AgentLink, list[tuple[str, int, float]]]] = []
        try:
            # A heartbeat may hold a host's lock for a moment: send to the free hosts
            # first, then wait for the busy ones, so no host waits for another.
            busy = [i for i in programs if not self._sessions[i].lock.acquire(blocking=False)]
            order = [i for i in programs if i not in busy] + busy
            for i in order:
                s = self._sessions[i]
                if i in busy and not s.lock.acquire(timeout=s.cfg.deadline_s):
                    out[i] = _fault(f"host {s.name}: link busy beyond the deadline")
                    continue
                link = s.link
                if link is None:
                    s.lock.release()
                    out[i] = _fault(s.down_reason(), s.status.traceback or "")
                    continue
                sent: list[tuple[str, int, float]] = []
                inflight.append((i, s, link, sent))
                start = time.monotonic()
                per_request = s.cfg.deadline_s if timeout_s is None else timeout_s
                try:
                    for k, (mtype, fields) in enumerate(programs[i]):
                        deadline = start + (k + 1) * per_request
                        sent.append((mtype, link.send(mtype, deadline, **fields), deadline))
                except Exception as exc:
                    s.drop(link, exc)
                    out[i] = _fault(describe(exc), remote_traceback(exc))
            for i, s, link, sent in inflight:
                if i in out:
                    continue
                out[i] = self._collect(s, link, sent, parse)
        except BaseException:
            # Ctrl-C mid-call: stop the motions in flight first (at once, write-only),
            # then drop those streams, which may be mid-frame (at EOF each agent stops
            # and exits without moving its arms), and let the caller handle the interrupt.
            pending = [(s, link) for i, s, link, _ in inflight if i not in out]
            _stop_sessions([s for s, _ in pending])
            for s, link in pending:
                s.drop(link, RuntimeError("interrupted during a call"))
            raise
        finally:
            for _, s, _, _ in inflight:
                s.lock.release()
        return out

    @staticmethod
    def _collect(s: HostSession, link: AgentLink, sent: list[tuple[str, int, float]],
                 parse: Callable[[HostSession, AgentLink, list[p.Frame]], Any]) -> Outcome:
        frames: list[p.Frame] = []
        agent_error: AgentError | None = None
        try:
            for mtype, mid, deadline in sent:
                try:
                    frames.append(link.receive(mtype, mid, deadline))
                except AgentError as exc:  # a clean refusal: later replies still come
                    if exc.fatal:
                        raise
                    agent_error = agent_error or exc
            if agent_error is not None:
                return _fault(str(agent_error), agent_error.remote_traceback, agent_error.arm,
                              refused=True)
            return ("ok", parse(s, link, frames))
        except Exception as exc:  # protocol error, deadline, EOF, or a bug: this host only
            s.drop(link, exc)
            return _fault(describe(exc), remote_traceback(exc))

    def _faults(self, s: HostSession, info: Mapping[str, Any]) -> dict[str, Fault]:
        reason = str(info.get("reason") or "unknown failure")
        tb = str(info.get("traceback") or "")
        if s.log is not None and not reason.startswith(f"host {s.name} is unreachable"):
            s.note_fault(reason, s.arms)  # (an unreachable host's drop is logged once)
        return {f"{s.name}/{a}": Fault(f"{s.name}/{a}", reason, tb) for a in s.arms}

    def _per_robot(self, res: Mapping[int, Outcome],
                   value: Callable[[int, str, str, Any], T | Fault]) -> dict[str, T | Fault]:
        """Per-host outcomes -> a value for every robot, in fleet order: ``value(host
        index, robot, arm, payload)`` for a host that answered (a Fault for an arm that
        failed alone), ``Fault`` for every arm of a host that did not."""
        out: dict[str, T | Fault] = {}
        for i, s in enumerate(self._sessions):
            if i not in res:
                continue
            kind, payload = res[i]
            if kind != "ok":
                out.update(self._faults(s, payload))
                continue
            for a in s.arms:
                r = f"{s.name}/{a}"
                v = out[r] = value(i, r, a, payload)
                if isinstance(v, Fault) and s.log is not None:
                    s.note_fault(v.reason, [a])
        return {r: out[r] for r in self.robot_names if r in out}

    def _arm_fault(self, s: HostSession, r: str, arm: str, why: str) -> Fault:
        return Fault(r, f"agent on host {s.name}: arm {arm!r} failed: "
                        f"{why.splitlines()[0] if why else 'no reason given'}", why)

    def _require_started(self) -> None:
        if self._closed:
            raise RuntimeError("HostFleet is closed")
        if not self._started:
            self.start()

    # -- the API ----------------------------------------------------------------------
    def observe(self) -> dict[str, ArmObservation | Fault]:
        """One picture per host, all hosts at once; a value for every robot. A host that
        is down is retried now (``HostSession.retry_for_call``): its arms are back at the
        first step after its link is."""
        self._require_started()
        now = time.monotonic()
        for s in self._sessions:
            s.retry_for_call(now)

        def parse(s: HostSession, link: AgentLink, frames: list[p.Frame]) -> Any:
            return p.parse_observe_reply(frames[0], s.arms, link.peer)

        def view(i: int, r: str, arm: str, payload: Any) -> ArmObservation | Fault:
            v = payload[arm]
            if isinstance(v, p.ArmFailed):
                return self._arm_fault(self._sessions[i], r, arm, v.error)
            return ArmObservation(r, v.image, v.violating, v.goal, v.expert_action)

        res = self._run({i: [("observe", {})] for i in range(len(self._sessions))}, parse)
        return self._per_robot(res, view)

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> dict[str, PushResult | Fault]:
        """Push the arms in ``pushes`` at once, complete the resets; others wait."""
        self._require_started()
        self._check_execute(pushes, resets)
        programs: dict[int, Program] = {}
        faces_of: dict[int, dict[str, int]] = {}
        for i, s in enumerate(self._sessions):
            faces = {a: int(pushes[f"{s.name}/{a}"]) for a in s.arms if f"{s.name}/{a}" in pushes}
            rs = [a for a in s.arms if f"{s.name}/{a}" in resets]
            faces_of[i] = faces
            programs[i] = ([("reset", {"arms": rs})] if rs else []) + (
                [("push", {"faces": faces})] if faces else [])

        def parse(s: HostSession, link: AgentLink, frames: list[p.Frame]) -> Any:
            i = self._sessions.index(s)
            if not faces_of[i]:
                if programs[i]:
                    p.parse_reset_reply(frames[0], programs[i][0][1]["arms"], link.peer)
                return {}
            if len(frames) == 2:
                p.parse_reset_reply(frames[0], programs[i][0][1]["arms"], link.peer)
            return p.parse_push_reply(frames[-1], list(faces_of[i]), link.peer)

        def result(i: int, r: str, arm: str, payload: Any) -> PushResult | Fault:
            if arm not in payload:  # reset or waiting
                return PushResult(r, None, False, False)
            o = payload[arm]
            if o.error is not None:
                return self._arm_fault(self._sessions[i], r, arm, o.error)
            # refused: the face asked for, not pushed, and the backend's reason
            return PushResult(r, faces_of[i][arm], o.success, o.violation, o.refused,
                              tuple(sorted(o.readings.items())))

        return self._per_robot(self._run(programs, parse), result)

    def rest(self) -> None:
        """Every arm to its rest pose; hosts that fail are logged, never raised."""
        if not self._started or self._closed:
            return
        res = self._run({i: [("rest", {})] for i in range(len(self._sessions))},
                        lambda s, link, frames: None)
        for i, s in enumerate(self._sessions):
            kind, payload = res[i]
            if kind != "ok":
                log.warning("rest failed on host %s: %s", s.name, payload.get("reason"))
                s.event("rest failed: %s", payload.get("reason"))

    # -- reseed and the single-host calls (calibration, checks) ------------------------
    def reseed(self, trial_seed: int) -> None:
        """Every host's task afresh, as a fleet built with ``trial_seed`` would start it
        (twin: ``seed`` of the host config if set, else ``derive_seed(trial_seed, i)``).

        A host that is down, or whose link breaks during the call, is reseeded by
        construction: its next agent starts with the new seed. Raises
        :class:`HostCallError` when an agent answers that it cannot (its backend keeps
        its old state)."""
        self._require_started()
        for i, s in enumerate(self._sessions):
            s.seed = _seed_of(s.cfg, i, trial_seed)
        res = self._run({i: [("reseed", {"seed": s.seed})]
                         for i, s in enumerate(self._sessions)}, lambda s, link, frames: None)
        failed: list[tuple[HostSession, Mapping[str, Any]]] = []
        for i, s in enumerate(self._sessions):
            kind, info = res[i]
            if kind == "ok":
                s.event("reseeded: seed %d", s.seed)
            elif info.get("refused"):
                s.event("reseed refused: %s", info.get("reason"))
                failed.append((s, info))
            else:
                s.event("reseed not delivered (the next agent starts with seed %d): %s",
                        s.seed, info.get("reason"))
        if failed:
            s, info = failed[0]
            more = f" (and {len(failed) - 1} more host(s))" if len(failed) > 1 else ""
            raise HostCallError(f"reseed failed on host {s.name}{more}: "
                                f"{_one_line(info.get('reason'))}", host=s.name,
                                traceback=str(info.get("traceback") or ""))

    def frame(self, host: str, *, timeout_s: float | None = None) -> np.ndarray:
        """The host camera's full frame (H, W, 3) uint8 BGR, lossless, arms maybe in view."""
        return self._call_one(host, "frame", {},
                              lambda f, peer: p.parse_frame_reply(f, peer), timeout_s)

    def move_tcp(self, host: str, arm: str, xyz_mm: Sequence[float], *,
                 timeout_s: float | None = None) -> tuple[float, float, float]:
        """Calibration: ``arm``'s TCP to ``xyz_mm`` (the robot's world frame (wobj0), mm,
        from above); the TCP
        the controller reports there. Default timeout: ``max(deadline_s, 60)`` (a motion)."""
        s = self._session(host)
        if arm not in s.arms:
            raise ValueError(f"host {host} has no arm {arm!r}; it has {s.arms}")
        xyz = [float(v) for v in xyz_mm]
        if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
            raise ValueError(f"xyz_mm must be three finite numbers, got {list(xyz_mm)!r}")
        return self._call_one(host, "move_tcp", {"arm": arm, "xyz_mm": xyz},
                              lambda f, peer: p.parse_move_tcp_reply(f, peer),
                              timeout_s if timeout_s is not None
                              else max(s.cfg.deadline_s, 60.0))

    def describe(self, host: str, *, timeout_s: float | None = None) -> dict[str, Any]:
        """What the host's robot controller says of itself (``testbed check``); a backend
        without a controller (the twin) answers with a ``HostCallError``."""
        return self._call_one(host, "describe", {},
                              lambda f, peer: p.parse_describe_reply(f, peer), timeout_s)

    def save_calibration(self, host: str, arm: str, data: Mapping[str, Any], *,
                         timeout_s: float | None = None) -> str:
        """Write ``arm``'s calibration file on the host (atomically); its path there."""
        s = self._session(host)
        if arm not in s.arms:
            raise ValueError(f"host {host} has no arm {arm!r}; it has {s.arms}")
        return self._call_one(host, "save_calibration", {"arm": arm, "data": dict(data)},
                              lambda f, peer: p.parse_save_calibration_reply(f, peer),
                              timeout_s)

    def _session(self, host: str) -> HostSession:
        for s in self._sessions:
            if s.name == host:
                return s
        raise ValueError(f"unknown host {host!r}; the fleet has "
                         f"{[s.name for s in self._sessions]}")

    def _call_one(self, host: str, mtype: str, fields: dict[str, Any],
                  parse: Callable[[p.Frame, str], T], timeout_s: float | None) -> T:
        self._require_started()
        s = self._session(host)
        i = self._sessions.index(s)
        res = self._run({i: [(mtype, fields)]},
                        lambda s, link, frames: parse(frames[0], link.peer), timeout_s)
        kind, payload = res[i]
        if kind == "ok":
            return payload  # type: ignore[no-any-return]
        s.event("%s failed: %s", mtype, payload.get("reason"))
        raise HostCallError(f"{mtype} on host {host} failed: "
                            f"{_one_line(payload.get('reason'))}", host=host,
                            traceback=str(payload.get("traceback") or ""))

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


def _one_line(reason: object) -> str:
    text = str(reason or "unknown failure").strip()
    return text.splitlines()[0] if text else "unknown failure"
