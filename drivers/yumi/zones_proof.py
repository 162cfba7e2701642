"""Whether the YuMi's world zones are known active since its last restart, from the
controller's event log, and how the driver keeps that proof while the log rolls over.

Why it exists: the zones live on the controller and a restart erases them; only the
POWER_ON event routine ``tb_zones`` (robot/rapid/TestbedZones.sys) defines them again,
and it ends with an info entry "Testbed Zones Active" (80003; args: the title, the task,
``zones <n>``, the time) per task. TASK PERS (``tb_zones_n``) survive a restart in which
the routine did not run, so only the ORDER of the log's entries shows the zones on: a
restart entry, then each task's Zones Active entry after it. Everything here fails
closed: a log that does not positively show that (cleared over RWS, "Clear all elog
messages", ``POST rw/elog?action=clearall`` in the RWS Application manual 3HAC050973-001;
or rolled over: a controller keeps a bounded number of entries per domain, domain 0 1000
in that manual's example) shows nothing, and nothing starts.

``testbed check`` judges one read of the log (:func:`zones_known`,
:func:`zones_known_problem`). The driver cannot: a long trial rolls the log past the
restart entry. It keeps its proof (:class:`ZonesProof`): proved once from a log that
shows it, the proof holds while every read still holds the newest entry of the read
before (no entry was missed) and no restart entry came without a Zones Active entry
after it. A gap (cleared, or rolled past what the driver saw) forgets the proof: the log
must show it again by itself.

From one agent to the next on the same robot host (the next trial, ``testbed trial
--resume`` after a crash): a domain of 1000 entries and about 4 per push roll the restart
entry out after about 250 pushes, and an agent that started after that could prove
nothing until the lab restarts the controller. So the agent that holds the proof records
it (:meth:`ZonesProof.save`, at most once per start, a new file renamed over the old) in
a file beside the robot's lock (:func:`proof_path`: the agent's lock folder, by default
``/run/lock/fleet-testbed``, named after the controller's serial): the format
(:data:`PROOF_FORMAT`), the serial, the restart entry and each task's Zones Active entry
(sequence number, code, time stamp) and the NEWEST entry the agent saw (the same three:
a number alone could be another entry of a wrapped or cleared log). A fresh agent reads
the controller's serial (``ctrl/identity``) and continues that proof
(:meth:`ZonesProof.load`) only if the file is this controller's, of this format,
consistent, a plain file of the agent's own user that no one else may write (the lock
folder is every user's: a record is worth what its writer is), and its
first read of the log still holds the recorded newest entry unchanged (number, code and
time stamp; and every recorded entry still in the log unchanged); then only the entries
after it are folded in, so a restart after the record refuses until its Zones Active
entries. Anything else (no file, unreadable, another serial or format, a gap) and the
proof starts from the log alone, refused as a first agent is when the log cannot show
it. A record that lags (a write that failed, starts refused before the motion) is as
safe: continued, it folds in every entry after it, as its writer would have. The default
folder lies in ``/run`` (a tmpfs): a host reboot loses the record (a proof from the log
alone then: the fail-closed side).
"""

from __future__ import annotations

import json
import os
import re
import stat
from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from testbed.core.atomic import atomic_write_bytes

RESTART_CODES = {10045: "System restarted", 10046: "System restarted in cold mode"}
"""The event log entries that mark a restart, each counted as one: after any of them the
zones are known active again only once a Zones Active entry follows. None of ABB's
manuals the project could search lists the restart family (the RWS Application manual
3HAC050973-001 documents the log's resources, not its codes); 10045 for a restart and for
"Reset RAPID" (its description naming it) and 10046 for the first (cold) start of a
system are ASSUMED until docs/rws-checklist.md's restart line is filled in. Counting a
code that is not a restart only refuses more; a restart code missing here is what could
let an old Zones Active entry stand for a restart that ran no ``tb_zones``."""
RESTARTED = 10045
"""The restart entry the twin writes (sim_twin/rws/irc5.py)."""
ZONES_ACTIVE = "Testbed Zones Active"
"""The title of the info entry (80003) ``tb_zones`` writes once every zone is active:
the task, ``zones <n>``, the time (robot/rapid/TestbedZones.sys)."""
ZONES_COUNT = 5
"""``TB_WZ_COUNT`` of robot/rapid/TestbedZones.sys: the zones a Zones Active entry must
name (the driver's floor; ``testbed check`` reads the controller's own count)."""
ZONES_FIX = ("restart the controller so tb_zones runs (the POWER_ON event routine) and "
             "writes its entries (robot/README.md, 'The zones')")
"""What every zones-not-known line ends with."""
UNKNOWN, RESTARTED_ONLY, PROVED = "unknown", "restarted", "proved"
"""A task's zones as the driver's proof holds them: nothing shown, a restart with no
Zones Active entry (of enough zones) after it yet, or on since the last restart."""


def zones_active_count(e: Any, task: str) -> int | None:
    """The ``zones <n>`` of ``e`` if it is ``task``'s Zones Active entry (80003, args
    [title, task, 'zones <n>', time]; 0 when it names no count), else None."""
    args = [str(a) for a in (getattr(e, "args", None) or [])]
    if e.code != 80003 or ZONES_ACTIVE not in (str(e.title), args[0] if args else "") \
            or task not in args[1:2]:
        return None
    m = re.search(r"zones (\d+)", " ".join(args))
    return int(m.group(1)) if m else 0


def zones_known(log: Sequence[Any], task: str) -> dict[str, Any]:
    """Whether the event log (newest first) POSITIVELY shows ``task``'s world zones active
    since the last restart: ``restart`` and ``active`` are the sequence numbers of the
    newest restart entry (:data:`RESTART_CODES`) and of the newest Zones Active entry of
    ``task`` after it (None: not in the log), ``zones`` the count that entry names,
    ``known`` whether there is a restart entry AND such an entry after it, whatever else
    lies between. No restart entry left (cleared, rolled over): not known. The order in
    the log decides, not the numbers (they wrap at 65535)."""
    out: dict[str, Any] = {"restart": None, "restart_code": None, "active": None,
                           "zones": None, "known": False}
    for e in log:
        if e.code in RESTART_CODES:
            out.update(restart=e.seqnum, restart_code=e.code,
                       known=out["active"] is not None)
            break
        if out["active"] is None and (n := zones_active_count(e, task)) is not None:
            out.update(active=e.seqnum, zones=n)
    return out


def zones_known_problem(task: str, known: Mapping[str, Any], count: float | None = None
                        ) -> str | None:
    """``testbed check``'s line unless the log shows ``task``'s zones active since the
    last restart (:func:`zones_known`): a restart entry, and after it a Zones Active entry
    naming at least ``count`` zones (``TB_WZ_COUNT``; :data:`ZONES_COUNT`)."""
    want = int(count) if count is not None else ZONES_COUNT
    if known.get("known") and (known.get("zones") or 0) >= want:
        return None
    code = known.get("restart_code") or RESTARTED
    if known.get("restart") is None:
        why = ("the event log holds no restart entry (cleared over RWS, or rolled over), "
               "so it cannot show them written since the last restart")
    elif known.get("known"):
        why = (f"the newest {ZONES_ACTIVE!r} entry since the last restart (event log "
               f"{code}, seq {known['restart']}) says zones {known.get('zones')}, not {want}")
    else:
        why = (f"no {ZONES_ACTIVE!r} entry with zones {want} since the last restart (event "
               f"log {code}, seq {known['restart']})")
    return f"task {task}: the world zones are not known active: {why}; {ZONES_FIX}"


def zones_refusal(log: Sequence[Any], tasks: Sequence[str],
                  count: int = ZONES_COUNT) -> str | None:
    """One line unless ``log`` by itself shows every task's zones active since the last
    restart (:func:`zones_known`, at least ``count`` zones), else None."""
    for task in tasks:
        if (why := zones_known_problem(task, zones_known(log, task), count)) is not None:
            return why
    return None


def stamp(tstamp: Any) -> str:
    """An entry's time stamp as text (abb_robot_client gives a ``datetime``, to the
    second), the form a proof file records and compares."""
    return tstamp.isoformat() if isinstance(tstamp, datetime) else str(tstamp)


def entry_key(e: Any) -> tuple[int, int, str]:
    """What names one entry across reads and agents: its number (which wraps at 65535),
    code and time stamp."""
    return (int(e.seqnum), int(e.code), stamp(getattr(e, "tstamp", None)))


def entry_record(key: tuple[int, int, str]) -> dict[str, Any]:
    """An entry as a proof file records it."""
    return {"seqnum": key[0], "code": key[1], "tstamp": key[2]}


class ProofFileError(ValueError):
    """A proof file that cannot be trusted (unreadable, another controller, another
    format, inconsistent, not this user's own): the proof starts from the log alone."""


class ZonesProof:
    """The driver's proof that every task's zones are on since the last restart, kept
    across its reads of the event log (see the module: proved once, it holds while no
    read misses an entry and no restart comes without its Zones Active entries), with
    its evidence: the restart entry and each task's Zones Active entry after it."""

    def __init__(self, tasks: Sequence[str], count: int = ZONES_COUNT) -> None:
        self.tasks = tuple(tasks)
        self.count = int(count)
        self.state: dict[str, str] = dict.fromkeys(self.tasks, UNKNOWN)
        self.restart: tuple[int, int, str] | None = None
        """The newest restart entry the proof saw (seqnum, code, tstamp)."""
        self.active: dict[str, tuple[int, int, str] | None] = dict.fromkeys(self.tasks)
        """Each proved task's Zones Active entry after :attr:`restart`."""
        self.newest: tuple[int, int, str] | None = None
        """The newest entry of the last read: the next read must still hold it."""
        self.gap = False
        """Whether a read missed entries (the log cleared or rolled past the newest entry
        of the read before, or of a recorded proof) since the proof last held every task:
        a read without a gap after it (a report's, then a start's) still names it."""
        self._gap_past = ""
        """What the gap rolled past, in the refusal's words."""
        self.resumed_from: str | None = None
        """The proof file this proof continues (:meth:`resume`) until its first read."""

    def read(self, log: Sequence[Any]) -> str | None:
        """Take in one read of the log (newest first); one line naming the fix unless
        every task is proved, else None."""
        keys = [entry_key(e) for e in log]
        at = keys.index(self.newest) if self.newest in keys else None
        if at is not None and self._evidence_matches(keys[at:]):
            unseen = log[:at]
        else:  # the first read, or a gap: only the log itself can show it
            unseen = log
            if self.newest is not None:
                self.gap = True
                self._gap_past = (f"the newest entry the agent before this one recorded "
                                  f"({self.resumed_from})" if self.resumed_from
                                  else "the entries this driver saw")
            self.state = dict.fromkeys(self.tasks, UNKNOWN)
            self.restart, self.active = None, dict.fromkeys(self.tasks)
        self._fold(reversed(unseen))
        if all(v == PROVED for v in self.state.values()):
            self.gap = False
        self.newest = keys[0] if keys else None
        why = self.refusal(log)
        self.resumed_from = None
        return why

    def _evidence_matches(self, seen: Sequence[tuple[int, int, str]]) -> bool:
        """Whether every recorded entry still in ``seen`` (the log up to the newest entry
        seen before: one number names one entry there) is the entry recorded."""
        by_seq = {k[0]: k for k in seen}
        recorded = [self.restart, *self.active.values()]
        return all(k is None or by_seq.get(k[0], k) == k for k in recorded)

    def _fold(self, entries: Iterable[Any]) -> None:
        """The proof after ``entries``, OLDEST first: a restart entry leaves every task
        waiting for its Zones Active entry; that entry proves the task once a restart came
        before it (at least :attr:`count` zones; fewer: not proved); nothing else changes
        anything."""
        for e in entries:
            if e.code in RESTART_CODES:
                self.state = dict.fromkeys(self.tasks, RESTARTED_ONLY)
                self.restart, self.active = entry_key(e), dict.fromkeys(self.tasks)
                continue
            for task, now in self.state.items():
                n = zones_active_count(e, task)
                if n is not None and now != UNKNOWN:
                    ok = n >= self.count
                    self.state[task] = PROVED if ok else RESTARTED_ONLY
                    self.active[task] = entry_key(e) if ok else None

    def refusal(self, log: Sequence[Any]) -> str | None:
        """The line for the first task not proved (``log``: the read that left it so)."""
        for task in self.tasks:
            if self.state[task] == PROVED:
                continue
            if self.state[task] == RESTARTED_ONLY:
                e = next((e for e in log if e.code in RESTART_CODES), None)
                at = f" (event log {e.code}, seq {e.seqnum})" if e is not None else ""
                why = (f"a restart{at} with no {ZONES_ACTIVE!r} entry with zones "
                       f"{self.count} after it")
            elif self.gap:
                why = (f"the event log was cleared or rolled over past {self._gap_past}, "
                       f"and what is left shows no restart entry followed by a "
                       f"{ZONES_ACTIVE!r} entry")
            else:
                why = (f"the event log shows no restart entry followed by a "
                       f"{ZONES_ACTIVE!r} entry (cleared over RWS, or rolled over)")
            return (f"task {task}: the world zones are not known active since the last "
                    f"restart: {why}; {ZONES_FIX}")
        return None

    def known(self, task: str) -> dict[str, Any] | None:
        """``task``'s proof in :func:`zones_known`'s form, for ``testbed check`` when the
        log alone no longer shows it (rolled past the restart entry): the restart and
        Zones Active entries the proof holds, ``zones`` the count it checked them for
        (:attr:`count`: the entry named at least that many), ``kept`` where it comes from;
        None unless ``task`` is proved."""
        restart, active = self.restart, self.active.get(task)
        if self.state.get(task) != PROVED or restart is None or active is None:
            return None
        return {"restart": restart[0], "restart_code": restart[1], "active": active[0],
                "zones": self.count, "known": True,
                "kept": "the driver's proof, kept across the event log's rollovers"}

    # -- from one agent to the next -------------------------------------------------------
    def record(self, serial: str) -> dict[str, Any]:
        """The proof as its file holds it (:data:`PROOF_FORMAT`), for controller
        ``serial``; only after a read that left a newest entry."""
        if self.newest is None:
            raise ValueError("no read with an entry to record yet")
        return {"format": PROOF_FORMAT, "serial": serial, "count": self.count,
                "restart": entry_record(self.restart) if self.restart else None,
                "tasks": {t: {"state": self.state[t], "zones": entry_record(k) if (
                    k := self.active[t]) else None} for t in self.tasks},
                "newest": entry_record(self.newest),
                "written": datetime.now().astimezone().isoformat(timespec="seconds")}

    def resume(self, data: Any, serial: str, source: str) -> None:
        """Continue the proof ``data`` (a proof file's, named ``source``) that another
        agent recorded for this controller (``serial``) and these tasks; the next
        :meth:`read` keeps it only if the log still holds its newest entry unchanged.
        :class:`ProofFileError` on anything odd; then nothing changes."""
        if not isinstance(data, dict) or set(data) != _RECORD_KEYS:
            what = sorted(data) if isinstance(data, dict) else type(data).__name__
            raise ProofFileError(f"not a zones proof record ({what})")
        if data["format"] != PROOF_FORMAT:
            raise ProofFileError(f"format {data['format']!r}, not {PROOF_FORMAT!r}")
        if data["serial"] != serial or not serial:
            raise ProofFileError(f"recorded for controller {data['serial']!r}, not {serial!r}")
        if type(data["count"]) is not int or data["count"] != self.count:
            raise ProofFileError(f"zones {data['count']!r}, not {self.count}")
        tasks = data["tasks"]
        if not isinstance(tasks, dict) or set(tasks) != set(self.tasks):
            raise ProofFileError(f"tasks {tasks!r}, not {list(self.tasks)}")
        restart, newest = _key(data["restart"]), _key(data["newest"])
        if newest is None or not isinstance(data["written"], str):
            raise ProofFileError("no newest entry or no time written")
        state: dict[str, str] = {}
        active: dict[str, tuple[int, int, str] | None] = {}
        for t in self.tasks:
            if not isinstance(tasks[t], dict) or set(tasks[t]) != {"state", "zones"}:
                raise ProofFileError(f"task {t}: {tasks[t]!r}")
            state[t], active[t] = tasks[t]["state"], _key(tasks[t]["zones"])
            evidence = (restart is not None, active[t] is not None)
            if _EVIDENCE.get(state[t]) != evidence:
                raise ProofFileError(f"task {t}: state {state[t]!r} with restart "
                                     f"{data['restart']!r} and zones {tasks[t]['zones']!r}")
        self.state, self.active, self.restart, self.newest = state, active, restart, newest
        self.resumed_from = source

    def load(self, path: str | os.PathLike[str], serial: str) -> str | None:
        """Continue the proof recorded at ``path`` (:meth:`resume`); None when it was
        taken, else why not (no file, or one not to trust: the proof starts from the
        log alone, as for a first agent)."""
        try:
            data = read_proof_file(path)
            if data is None:
                return f"no zones proof file {path}"
            self.resume(data, serial, str(path))
        except (OSError, ProofFileError) as exc:
            return f"zones proof file {path} not used: {exc}"
        return None

    def save(self, path: str | os.PathLike[str], serial: str) -> bool:
        """Record the proof at ``path`` (write a new file, then rename it over the old:
        a reader sees the old record or the new one, never half); False when there is
        nothing to record yet (no read with an entry). OSError when it cannot."""
        if self.newest is None:
            return False
        write_proof_file(path, self.record(serial))
        return True


PROOF_FORMAT = "fleet-testbed zones proof 1"
"""The proof file's format: a file of any other (older, newer) is not used."""
_RECORD_KEYS = {"format", "serial", "count", "restart", "tasks", "newest", "written"}
_EVIDENCE = {PROVED: (True, True), RESTARTED_ONLY: (True, False), UNKNOWN: (False, False)}
"""Per state, whether a restart entry and a Zones Active entry must be recorded."""
MAX_PROOF_BYTES = 65536


def _key(rec: Any) -> tuple[int, int, str] | None:
    """A recorded entry back as (seqnum, code, tstamp); None for None."""
    if rec is None:
        return None
    if not isinstance(rec, dict) or set(rec) != {"seqnum", "code", "tstamp"} or \
            type(rec["seqnum"]) is not int or type(rec["code"]) is not int or \
            not isinstance(rec["tstamp"], str) or not 0 <= rec["seqnum"] <= 65535:
        raise ProofFileError(f"not an event log entry: {rec!r}")
    return (rec["seqnum"], rec["code"], rec["tstamp"])


def proof_path(state_dir: str | os.PathLike[str], serial: str) -> Path:
    """The proof file of controller ``serial`` in the agent's state folder: beside the
    robot's lock file, named as it is (``IRC5_<serial>-<digest>.zones.json``;
    drivers/hostlock.py)."""
    from drivers.hostlock import lock_path

    return lock_path(state_dir, f"IRC5 {serial}").with_suffix(".zones.json")


def read_proof_file(path: str | os.PathLike[str]) -> Any:
    """The JSON in ``path``; None when there is no file. :class:`ProofFileError` unless it
    is a plain file (not a link) of this user's own that no one else may write: the lock
    folder is shared by every user of the host (drivers/hostlock.py), and a proof is
    worth only what its writer is."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    except OSError as exc:  # a link (ELOOP), no permission
        raise ProofFileError(f"cannot open it ({exc.strerror})") from exc
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid() or \
                st.st_mode & 0o022 or st.st_size > MAX_PROOF_BYTES:
            raise ProofFileError(f"not a plain file of uid {os.geteuid()} that only it may "
                                 f"write (uid {st.st_uid}, mode {stat.filemode(st.st_mode)}, "
                                 f"{st.st_size} bytes)")
        raw = f.read(MAX_PROOF_BYTES + 1)
    try:
        return json.loads(raw.decode("utf-8"))
    except ValueError as exc:
        raise ProofFileError(f"not JSON ({exc})") from exc


def write_proof_file(path: str | os.PathLike[str], data: Mapping[str, Any]) -> None:
    """Write ``data`` to ``path`` atomically (``testbed.core.atomic``: a temp file in the
    same folder, created mode 0600 by ``mkstemp``, fsynced and renamed over ``path``);
    OSError when it cannot."""
    text = json.dumps(data, indent=1, sort_keys=True) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))
