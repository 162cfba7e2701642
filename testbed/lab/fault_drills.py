"""``testbed rehearse --faults``: the stops a lab meets on a YuMi, injected into a trial.

Why it exists: a trial on real YuMis meets guard stops, motors that go off, RAPID
errors, zone stops, a camera that freezes and a network that drops, and a person clears
each; the trial must come through them: the host's arms wait (``fault`` rows, what
``drivers.host_fleet`` makes of a broken host), no label is lost, no step is recorded
twice, and the trial finishes. A rehearsal is the place to show it before a robot is
touched (issue 29, point 5).

The schedule (:func:`fault_schedule`) is drawn from the run's seed, so a run's faults
are the same each time it is rehearsed: every kind once (in ``steps >= MIN_STEPS``), in a
shuffled order, each in a slot of its own (so at most one fault is active in the whole
fleet, and so per host), on a host and an arm drawn at random, held 1 or 2 steps. A fault
is injected between two steps (after the loop logged step ``step - 1``), and the
scripted person clears it between steps ``clear - 1`` and ``clear``: both are
reproducible, where a stop mid-motion would depend on timing. How each is injected and
cleared is the twin's (``sim_twin.lab_faults``: the controller's states and event log,
its camera), but for the lost link, which is the lab's network: the host's sshd is
stopped (its sessions die with it) and started again; the fleet's own reconnect
(``drivers.session.HostSession``: attempts with backoff) brings the agent back.

:class:`FaultDrills` does it, one line on the console for each fault, and keeps the
run's ``faults.jsonl`` (``testbed.lab.fault_report`` adds what the arms did).
"""

from __future__ import annotations

import json
import random
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

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
"""The fewest steps a fault takes: injected, held 1-2 steps, then a clean step."""
MIN_STEPS = LEAD_STEPS + TAIL_STEPS + SLOT_STEPS * len(FAULT_KINDS)
"""A run this long has every kind of fault (29 steps); a shorter one the first few."""
FROZEN_SETTLE_S = 1.3
"""After freezing the camera, wait this long before the next step: the seam calls a
camera frozen after 1 s of identical frames (``drivers.yumi.frozen_frames``), and a
picture taken in that first second is believed, as on a real robot."""
FAULTS_FILE = "faults.jsonl"

Say = Callable[[str], None]


@dataclass(frozen=True)
class PlannedFault:
    """One fault of a run's schedule: injected before ``step``, cleared before ``clear``."""

    step: int
    clear: int
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
        start = first + i * slot
        held = rng.randint(1, min(2, slot - 2))
        step = start + rng.randint(0, slot - held - 1)  # the slot's last step is clean
        host = rng.choice(names)
        out.append(PlannedFault(step, step + held, kind, host, rng.choice(list(hosts[host]))))
    return out


class FaultDrills:
    """Injects one run's faults and has the scripted person clear them, step by step."""

    def __init__(self, lab: HardwareTwinLab, schedule: Sequence[PlannedFault],
                 folder: Path, say: Say) -> None:
        self.lab, self.schedule, self.say = lab, list(schedule), say
        self.path = folder / FAULTS_FILE
        self.active: dict[PlannedFault, dict[str, Any]] = {}

    def before_step(self, t: int) -> None:
        """Between steps ``t - 1`` and ``t``: clear what is due, then inject what is due."""
        for f in [f for f in self.active if f.clear <= t]:
            self._clear(f, t)
        for f in self.schedule:
            if f.step == t and f not in self.active:
                self._inject(f)

    def end(self) -> None:
        """The run is over (finished or not): nothing stays broken for the next run."""
        for f in list(self.active):
            self._clear(f, None)

    def _inject(self, f: PlannedFault) -> None:
        number = self.schedule.index(f) + 1
        if f.kind == LINK:
            self.lab.hosts[f.host].sshd.stop()
            shows = "sshd stopped: the link and the agent's session are gone"
        else:
            shows = self.lab.hosts[f.host].lab.fault(f.kind, f.arm)["shows"]
        self.active[f] = {"shows": shows, "injected_at": time.time()}
        self.say(f"FAULT {number}/{len(self.schedule)} before step {f.step} on {f.host}"
                 f"{'/' + f.arm if f.kind in ('rapid_error', 'zone_stop') else ''}: "
                 f"{FAULT_KINDS[f.kind]}; {shows}")
        if f.kind == "camera_frozen":
            time.sleep(FROZEN_SETTLE_S)

    def _clear(self, f: PlannedFault, t: int | None) -> None:
        info = self.active.pop(f)
        if f.kind == LINK:
            self.lab.hosts[f.host].sshd.start()
            actions = ["started the host's sshd again (the link is back)"]
        else:
            actions = self.lab.hosts[f.host].lab.clear(f.kind)["actions"]
        number = self.schedule.index(f) + 1
        when = f"before step {t}" if t is not None else "after the run"
        self.say(f"  cleared {number}/{len(self.schedule)} {when} on {f.host}: "
                 f"{'; '.join(actions)}")
        row = {**asdict(f), "name": FAULT_KINDS[f.kind], "shows": info["shows"],
               "cleared": t, "actions": actions}
        with open(self.path, "a", encoding="utf-8") as out:
            out.write(json.dumps(row, separators=(",", ":")) + "\n")


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

    def begin(self, run: Path) -> None:
        self.end()
        options = json.loads((run / "run.json").read_text(encoding="utf-8"))["options"]
        hosts = {name: h.arms for name, h in self.lab.hosts.items()}
        schedule = fault_schedule(int(options["seed"]), int(options["steps"]), hosts)
        self.drills = FaultDrills(self.lab, schedule, run, self.say)

    def before_step(self, t: int) -> None:
        if self.drills is not None:
            self.drills.before_step(t)

    def end(self) -> None:
        if self.drills is not None:
            self.drills.end()
        self.drills = None
