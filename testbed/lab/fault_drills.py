"""``testbed rehearse --faults``: the stops a lab meets on a YuMi, injected into a trial.

Why it exists: a trial on real YuMis meets guard stops, motors that go off, RAPID
errors, zone stops, a camera that freezes and a network that drops, and a person clears
each; the trial must come through them: the host's arms wait (``fault`` rows, what
``drivers.host_fleet`` makes of a broken host), no label is lost, no step is recorded
twice, and the trial finishes. A rehearsal is the place to show it before a robot is
touched (issue 29, point 5).

The schedule (:func:`fault_schedule`) is drawn from the run's seed, so a run's faults
are the same each time it is rehearsed: every kind once (in ``steps >= MIN_STEPS``), in a
shuffled order, each planned in a slot of its own, on a host and an arm drawn at random,
held 1 or 2 steps (longer while no arm has shown it). At most one fault is active per
host (:class:`FaultDrills`).
A fault is injected between two steps (after the loop logged a step), and the
scripted person clears it between two steps: reproducible, where a stop mid-motion would
depend on timing. How each is injected and cleared is the twin's
(``sim_twin.lab_faults``: the controller's states and event log, its camera), but for
the lost link, which is the lab's network: the host's sshd is stopped (its sessions die
with it) and started again; the fleet's own reconnect (``drivers.session.HostSession``:
attempts with backoff, and one at each step's observe) brings the agent back.

:class:`FaultDrills` does it, one line on the console for each fault, and keeps the
run's ``faults.jsonl`` (``testbed.lab.fault_report`` adds what the arms did).
"""

from __future__ import annotations

import json
import random
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.lab.fault_report import FAULTS_FILE, read_faults

if TYPE_CHECKING:
    from testbed.lab.hardware_twin import HardwareTwinLab

__all__ = ["FAULTS_FILE", "FAULT_KINDS", "MIN_STEPS", "FaultDrills", "PlannedFault",
           "RunFaults", "fault_room", "fault_schedule"]

FAULT_KINDS: dict[str, str] = {
    "guard_stop": "guard stop (a safety circuit opened: ctrlstate guardstop)",
    "motors_off": "motors off (ctrlstate motoroff)",
    "rapid_error": "RAPID error (event log 40223 'Execution error', the task stopped)",
    "zone_stop": "zone stop (event log 50000 'World zone reached', the task stopped)",
    "camera_frozen": "frozen camera (the same picture again and again)",
    "link_lost": "lost SSH link (the host's sshd and its sessions gone)",
}
"""Each kind and the words that name it, once, on the console and in the report."""
LINK = "link_lost"
LEAD_STEPS = 2
"""Steps at a run's start without a fault (the first pictures, the first pushes)."""
TAIL_STEPS = 3
"""Steps at a run's end without a fault: a host whose link was lost reconnects."""
SLOT_STEPS = 4
"""The steps planned for each fault: injected, held 1-2 steps, the arms back."""
MAX_POSTPONE = 3
"""Steps a fault waits for its host to be at work before it is injected all the same, and
for a row to show it before the person clears it all the same."""
ARM_KINDS = ("rapid_error", "zone_stop")
AT_OBSERVE = ("camera_frozen", "link_lost")
"""Faults the next observe meets, whatever the arms are doing."""
"""Faults of one arm's RAPID task (the others are the whole host's)."""
MIN_STEPS = LEAD_STEPS + TAIL_STEPS + SLOT_STEPS * len(FAULT_KINDS)
"""A run this long has every kind of fault (29 steps); a shorter one the first few."""
FROZEN_SETTLE_S = 1.3
"""After freezing the camera, wait this long before the next step: the seam calls a
camera frozen after 1 s of identical frames (``drivers.cameras.frozen_frames``), and a
picture taken in that first second is believed, as on a real robot."""

Say = Callable[[str], None]


@dataclass(frozen=True)
class PlannedFault:
    """One fault of a run's schedule: injected before ``step`` at the earliest (see
    :class:`FaultDrills` for when exactly), cleared ``held`` steps after."""

    step: int
    held: int
    kind: str
    host: str
    arm: str


def fault_schedule(seed: int, steps: int, hosts: Mapping[str, Sequence[str]]
                   ) -> list[PlannedFault]:
    """The run's faults (see the module doc): the same for the same seed, steps, hosts."""
    rng = random.Random(f"testbed-faults/{seed}")
    kinds = list(FAULT_KINDS)
    rng.shuffle(kinds)
    first, end = LEAD_STEPS, steps - TAIL_STEPS
    n = min(len(kinds), max(end - first, 0) // SLOT_STEPS)
    if n == 0:
        return []
    slot = (end - first) // n
    names = sorted(hosts)
    out = []
    for i, kind in enumerate(kinds[:n]):
        held = rng.randint(1, 2)
        step = first + i * slot + rng.randint(0, slot - SLOT_STEPS)
        host = rng.choice(names)
        out.append(PlannedFault(step, held, kind, host, rng.choice(list(hosts[host]))))
    return out


@dataclass
class _Active:
    fault: PlannedFault
    step: int
    shows: str
    wall: float
    seen: int | None = None
    """The first step a row showed the host's arms ``fault``."""


class FaultDrills:
    """Injects one run's faults and has the scripted person clear them, between steps.

    At most one fault per host at a time: a fault is injected at its planned step or
    later, once its host is free (no fault active on it, and its arms back after the
    last one: a row without ``fault``; a host whose link was lost first reconnects).
    A stop of the controller shows only when an arm pushes, so one waits for its host
    to be at work (an arm of it pushed in the last step; after :data:`MAX_POSTPONE`
    steps, whatever it does). At most one fault is injected per step, in the schedule's
    order among those whose host is free; none in a run's last :data:`TAIL_STEPS`
    steps. The person clears a fault ``held`` steps after it was injected once a row
    showed it (its host's arms ``fault``), else up to :data:`MAX_POSTPONE` steps later:
    a person clears the stop they see, and a host at work at the injection may rest the
    next step (its arms idle, or a reset by hand), when a stop of its controller shows
    nothing yet (a CI run met that: a guard stop held one step, never seen)."""

    def __init__(self, lab: HardwareTwinLab, schedule: Sequence[PlannedFault],
                 folder: Path, steps: int, say: Say) -> None:
        self.lab, self.schedule, self.say = lab, list(schedule), say
        self.path = folder / FAULTS_FILE
        self.last_step = steps - TAIL_STEPS
        self.pending = list(schedule)
        self.active: dict[str, _Active] = {}
        """Host -> the fault active on it."""
        self.recovering: set[str] = set()
        """Hosts whose fault was cleared, until a row shows their arms back."""
        self._replay: dict[tuple[int, str], dict[str, Any]] | None = None
        """While :meth:`resume` replays: the killed sessions' faults.jsonl rows by
        (step injected, kind); the drills then touch nothing and say nothing."""
        self._replayed: list[dict[str, Any]] = []

    def resume(self, rows: Sequence[Mapping[str, Any]]) -> Callable[[], None]:
        """A run resumed after its steps ``rows`` (those its checkpoint kept, the last
        one's drills perhaps not done). The drills' decisions depend only on the rows,
        so the steps before the last are replayed without touching the lab (their
        faults.jsonl rows, written then, are kept; later ones, of steps the checkpoint
        dropped, go); what returns, run before the resumed run's first step, puts the
        faults active at that point back into the fresh twins (a restart of the
        operator's side does not close a guard or bring a link back) and does the last
        step's drills."""
        from testbed.core.atomic import atomic_write_bytes

        self._replay = {(int(r["step"]), str(r["kind"])): r for r in read_faults(self.path.parent)}
        try:
            for row in rows[:-1]:
                self.after_step(int(row["t"]), row)
        finally:
            self._replay = None
        text = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in self._replayed)
        atomic_write_bytes(self.path, text.encode())

        def first_step() -> None:
            for host, a in list(self.active.items()):
                self.active.pop(host)
                self._inject(a.fault, a.step, again=True)
                self.active[host].seen, self.active[host].wall = a.seen, a.wall
            if rows:
                self.after_step(int(rows[-1]["t"]), rows[-1])
        return first_step

    def after_step(self, t: int, row: Mapping[str, Any]) -> None:
        """Step ``t`` was logged (``row``); before step ``t + 1``: clear what is due,
        then inject what is due."""
        modes = {r["robot"]: r["mode"] for r in row["robots"]}
        back = {h for h in self.recovering if "fault" not in self._modes(modes, h)}
        self.recovering -= back
        for host, a in list(self.active.items()):
            if a.seen is None and "fault" in self._modes(modes, host):
                a.seen = t
            due = a.step + a.fault.held
            if t + 1 >= due and (a.seen is not None or t + 1 >= due + MAX_POSTPONE):
                self._clear(host, t + 1)
        if not t + 1 < self.last_step:
            return
        for f in self.pending:
            if f.host in self.active or f.host in self.recovering or f.step > t + 1:
                continue
            at_work = {"autonomous", "teleop"} & set(self._modes(modes, f.host))
            if at_work or f.kind in AT_OBSERVE or t + 1 >= f.step + MAX_POSTPONE:
                self.pending.remove(f)
                self._inject(f, t + 1)
            return

    @staticmethod
    def _modes(modes: Mapping[str, str], host: str) -> list[str]:
        return [m for r, m in modes.items() if r.startswith(f"{host}/")]

    def end(self) -> None:
        """The run is over (finished or not): nothing stays broken for the next run."""
        for host in list(self.active):
            self._clear(host, None)
        for f in self.pending:
            self.say(f"  not injected: {f.kind} on {f.host} (the run ended first)")
        self.pending = []

    def _number(self, f: PlannedFault) -> str:
        return f"{self.schedule.index(f) + 1}/{len(self.schedule)}"

    def _inject(self, f: PlannedFault, step: int, again: bool = False) -> None:
        if self._replay is not None:  # resume's replay: what the killed session did
            old = self._replay.get((step, f.kind), {})
            self.active[f.host] = _Active(f, step, str(old.get("shows", "")),
                                          float(old.get("injected_wall", time.time())))
            return
        if f.kind == LINK:
            self.lab.hosts[f.host].sshd.stop()
            shows = "sshd stopped: the link and the agent's session are gone"
        else:
            shows = self.lab.hosts[f.host].lab.fault(f.kind, f.arm)["shows"]
        self.active[f.host] = _Active(f, step, shows, time.time())
        self.say(f"FAULT {self._number(f)} {'still there after the restart, ' if again else ''}"
                 f"before step {step} on {f.host}"
                 f"{'/' + f.arm if f.kind in ARM_KINDS else ''}: {FAULT_KINDS[f.kind]}; "
                 f"{shows}")
        if f.kind == "camera_frozen":
            time.sleep(FROZEN_SETTLE_S)

    def _clear(self, host: str, t: int | None) -> None:
        a = self.active.pop(host)
        f = a.fault
        self.recovering.add(f.host)
        if self._replay is not None:  # resume's replay: the row the killed session wrote
            old = self._replay.get((a.step, f.kind))
            self._replayed.append({**(old or {}), "seen": a.seen, "cleared": t}
                                  if old else self._row(a, t, ["(not recorded)"]))
            return
        if f.kind == LINK:
            self.lab.hosts[f.host].sshd.start()
            self.lab.record_pids()
            actions = ["started the host's sshd again (the link is back)"]
        else:
            actions = self.lab.hosts[f.host].lab.clear(f.kind)["actions"]
        when = f"before step {t}" if t is not None else "after the run"
        self.say(f"  cleared {self._number(f)} {when} on {f.host}: {'; '.join(actions)}")
        with open(self.path, "a", encoding="utf-8") as out:
            out.write(json.dumps(self._row(a, t, actions), separators=(",", ":")) + "\n")

    @staticmethod
    def _row(a: _Active, t: int | None, actions: list[str]) -> dict[str, Any]:
        f = a.fault
        return {"step": a.step, "planned": f.step, "kind": f.kind, "host": f.host,
                "arm": f.arm, "name": FAULT_KINDS[f.kind], "shows": a.shows,
                "injected_wall": round(a.wall, 3), "seen": a.seen, "cleared": t,
                "actions": actions}


def fault_room(steps: int) -> str:
    """The console's line on what a run of ``steps`` steps has room for."""
    n = len(fault_schedule(0, steps, {"h": ["a"]}))
    if n == len(FAULT_KINDS):
        return (f"faults: each run gets all {n} kinds ({', '.join(FAULT_KINDS)}), at steps "
                "drawn from its seed")
    return (f"faults: {steps} steps leave room for {n} of the {len(FAULT_KINDS)} kinds "
            f"(all of them need --steps {MIN_STEPS} or more)")


class RunFaults:
    """The rehearsal's side: one :class:`FaultDrills` per run, drawn from that run's seed
    and length (its ``run.json``), on the lab's hosts and arms."""

    def __init__(self, lab: HardwareTwinLab, say: Say) -> None:
        self.lab, self.say = lab, say
        self.drills: FaultDrills | None = None

    def begin(self, run: Path, resumed: Sequence[Mapping[str, Any]] = ()
              ) -> Callable[[], None] | None:
        """The run's drills; for a run ``resumed`` after these steps, what to do before
        its first step (:meth:`FaultDrills.resume`)."""
        self.end()
        options = json.loads((run / "run.json").read_text(encoding="utf-8"))["options"]
        hosts = {name: h.arms for name, h in self.lab.hosts.items()}
        steps = int(options["steps"])
        schedule = fault_schedule(int(options["seed"]), steps, hosts)
        self.drills = FaultDrills(self.lab, schedule, run, steps, self.say)
        if not resumed:
            (run / FAULTS_FILE).unlink(missing_ok=True)
            return None
        return self.drills.resume(resumed)

    def after_step(self, t: int, row: Mapping[str, Any]) -> None:
        if self.drills is not None:
            self.drills.after_step(t, row)

    def end(self) -> None:
        if self.drills is not None:
            self.drills.end()
        self.drills = None
