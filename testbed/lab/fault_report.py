"""What the arms did during each injected fault: ``faults.jsonl`` completed, and its table.

Why it exists: the drills (``testbed.lab.fault_drills``) know when a fault was injected
and cleared; what the trial made of it is in ``steps.jsonl`` (a ``fault`` row for an arm
whose host failed, the reason the driver gave, the step the arm was back). A lab reading
a rehearsal wants both in one place: each fault's line in the run's ``faults.jsonl``
gets ``arms`` (per arm: the steps it was ``fault``, its first reason, the step it was
back) and ``back``, and the rehearsal's report gets one table of every run's faults.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from testbed.core.atomic import atomic_write_bytes

__all__ = ["FAULTS_FILE", "faults_table", "finish_faults", "read_faults"]

FAULTS_FILE = "faults.jsonl"
"""A rehearsal run's faults, one JSON line each: the drills write it as they inject
(``testbed.lab.fault_drills``), ``finish_faults`` completes it from the steps."""

REASON_CHARS = 160


def read_faults(run: Path) -> list[dict[str, Any]]:
    """The run's ``faults.jsonl`` (empty when it has none), in the order injected."""
    path = run / FAULTS_FILE
    if not path.exists():
        return []
    rows = [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines() if x.strip()]
    return sorted(rows, key=lambda r: int(r["step"]))


def _arm_story(rows: Sequence[Mapping[str, Any]], robot: str, start: int, stop: int,
               cleared: int | None) -> dict[str, Any]:
    """One arm from ``start`` to before ``stop``: its ``fault`` steps, why, when back."""
    fault_steps: list[int] = []
    reason = None
    back = None
    for row in rows:
        t = int(row["t"])
        if not start <= t < stop:
            continue
        mode = next((r["mode"] for r in row["robots"] if r["robot"] == robot), None)
        if mode == "fault":
            fault_steps.append(t)
            reason = reason or row.get("faults", {}).get(robot)
        elif cleared is not None and t >= cleared and back is None:
            back = t
    text = None if reason is None else " ".join(str(reason).split())[:REASON_CHARS]
    return {"fault_steps": fault_steps, "reason": text, "back": back}


def _logged_reason(run: Path, f: Mapping[str, Any]) -> str | None:
    """The first fault the host's log (``hosts/<host>.log``) names after the fault was
    injected: a failed observe's reason, which the step's row does not carry."""
    import datetime as dt

    path = run / "hosts" / f"{f['host']}.log"
    since = float(f.get("injected_wall") or 0.0)
    if not path.exists():
        return None
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        stamp, _, rest = line.partition(" fleet | fault for ")
        if not rest:
            continue
        try:
            when = dt.datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S.%f").timestamp()
        except ValueError:
            continue
        if when >= since:
            return " ".join(rest.partition(": ")[2].split())[:REASON_CHARS]
    return None


def finish_faults(run: Path) -> list[dict[str, Any]]:
    """Each fault of ``run`` with what its host's arms did (from ``steps.jsonl``), written
    back to ``faults.jsonl``; each arm's story runs until the next fault on its host."""
    from testbed.records.steps import read_steps

    faults = read_faults(run)
    if not faults or not (run / "steps.jsonl").exists():
        return faults
    rows = read_steps(run / "steps.jsonl")
    end = max((int(r["t"]) for r in rows), default=-1) + 1
    for k, f in enumerate(faults):
        stop = next((int(g["step"]) for g in faults[k + 1:] if g["host"] == f["host"]), end)
        robots = sorted({r["robot"] for row in rows for r in row["robots"]
                         if r["robot"].startswith(f"{f['host']}/")})
        f["arms"] = {robot: _arm_story(rows, robot, int(f["step"]), stop, f.get("cleared"))
                     for robot in robots}
        logged = _logged_reason(run, f)  # a fault at observe is in the host's log only
        for a in f["arms"].values():
            if a["fault_steps"] and a["reason"] is None:
                a["reason"] = logged
        backs = [a["back"] for a in f["arms"].values()]
        f["back"] = None if None in backs or not backs else max(backs)
    text = "".join(json.dumps(f, separators=(",", ":")) + "\n" for f in faults)
    atomic_write_bytes(run / FAULTS_FILE, text.encode())
    return faults


def _did(f: Mapping[str, Any]) -> str:
    arms = f.get("arms", {})
    parts = []
    for robot, a in arms.items():
        steps = a["fault_steps"]
        parts.append(f"{robot.split('/', 1)[1]}: fault at {_steps(steps)}" if steps
                     else f"{robot.split('/', 1)[1]}: no fault (nothing asked of it)")
    reason = next((a["reason"] for a in arms.values() if a["reason"]), None)
    text = "; ".join(parts) + (f" ({reason})" if reason else "")
    return text.replace("|", "/")  # a table cell


def _steps(steps: Sequence[int]) -> str:
    if len(steps) > 1 and steps[-1] - steps[0] == len(steps) - 1:
        return f"t {steps[0]}-{steps[-1]}"
    return "t " + ",".join(str(s) for s in steps)


def faults_table(runs: Mapping[str, Sequence[Mapping[str, Any]]]) -> str:
    """The rehearsal report's table: every run's faults, what the arms did, when back."""
    lines = ["## Faults injected (testbed rehearse --faults)", "",
             "| run | fault | host | injected before step | cleared before step | what the "
             "person did | what the arms did | all back at step |",
             "|---|---|---|---|---|---|---|---|"]
    for name, faults in runs.items():
        for f in faults:
            where = f["host"] + (f"/{f['arm']}" if f["kind"] in ("rapid_error", "zone_stop")
                                 else "")
            lines.append(f"| {name} | {f['kind']} | {where} | {f['step']} | "
                         f"{'-' if f.get('cleared') is None else f['cleared']} | "
                         f"{'; '.join(f.get('actions', []))} | {_did(f)} | "
                         f"{'-' if f.get('back') is None else f['back']} |")
    return "\n".join(lines) + "\n"
