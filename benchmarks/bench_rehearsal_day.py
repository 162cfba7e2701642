"""The whole day rehearsed (issue 35, item 8): the physical protocol at full size through
``testbed rehearse --quick --faults``, the operator killed with SIGKILL and resumed.

Why this exists: a lab's day is 3 trials x 4 algorithms x 250 steps x 4 arms (12,000
pushes), and the operator's PC can die in the middle of it. The rehearsal must come
through as the lab would: the same command run again continues where it stopped (the
calibration kept, the finished runs skipped, the run in progress resumed from its
checkpoint), and nothing is lost or counted twice. This script runs it, SIGKILLs the
``testbed rehearse`` process at chosen points (its twins, sshds and agents die with it:
``testbed.lab.hardware_twin``'s reaper), runs the same command again, and at the end
checks, for every run:

* ``run.json`` complete; ``steps.jsonl`` has every step once;
* ``data/``: one frame per step and arm, each with its row's mode and action; the frame
  classes (``testbed.records.frame_classes.classify``) count the rows' teleop pushes,
  resets and robot pushes;
* ``twin_truth.jsonl``: one row per step and arm, none twice;
* ``faults.jsonl``: every scheduled kind once, each cleared by the person;
* perception against the twin's truth on the arm-steps not faulted: >= 99 %;
* no process of the lab left once the rehearsal ended (or was killed).

Printed (stdout, at the end): the wall time, the goal (45 min) and the ratio, and a
reference measured in the same run: the median duration of a steady-state step
(``steps.jsonl``'s ``duration_s``, every run's, first 3 steps of each session left out)
times the steps, beside what the rest cost (calibration, pretraining, restarts). Progress
goes to stderr, plainly.

    .venv/bin/python benchmarks/bench_rehearsal_day.py            # the whole day (defaults)
    .venv/bin/python benchmarks/bench_rehearsal_day.py --trials 1 --steps 20 \\
        --algorithms cur --kill-at 6,13 --out /tmp/day-small       # a small rehearsal
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

GOAL_S = 45 * 60.0
MIN_AGREEMENT = 0.99


def log(msg: str) -> None:
    sys.stderr.write(f"[{time.strftime('%H:%M:%S')}] {msg}\n")
    sys.stderr.flush()


def steps_done(out: Path) -> int:
    """Rows in every run's steps.jsonl (what the protocol has logged so far)."""
    n = 0
    for p in out.glob("*/steps.jsonl"):
        with contextlib.suppress(OSError):
            n += p.read_bytes().count(b"\n")
    return n


def lab_pids_alive(out: Path) -> list[int]:
    """The lab processes ``lab/pids.json`` lists that still run as themselves."""
    from testbed.lab.hardware_twin import PIDS_FILE, _proc_start

    try:
        entries = json.loads((out / "lab" / PIDS_FILE).read_text())
    except (OSError, ValueError):
        return []
    return [int(e["pid"]) for e in entries if _proc_start(int(e["pid"])) == e["start"]]


def session(cmd: list[str], out: Path, k: int, kill_at: int | None) -> tuple[int | None, float]:
    """One ``testbed rehearse`` process; SIGKILLed once ``kill_at`` steps are logged.
    Returns (exit status or None when killed, seconds the lab needed to be gone)."""
    out.parent.mkdir(parents=True, exist_ok=True)  # a fresh clone has no runs/ yet
    with open(out.parent / f"{out.name}-session{k}.log", "wb") as logf:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=logf, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    log(f"session {k}: testbed rehearse pid {proc.pid}"
        + (f", to be killed at {kill_at} logged steps" if kill_at is not None else ""))
    last, last_print = -1, 0.0
    while proc.poll() is None:
        done = steps_done(out)
        if done != last and time.monotonic() - last_print > 20:
            log(f"session {k}: {done} steps logged")
            last, last_print = done, time.monotonic()
        if kill_at is not None and done >= kill_at:
            os.kill(proc.pid, signal.SIGKILL)  # the operator's process, and only it
            proc.wait()
            began = time.monotonic()
            while lab_pids_alive(out) and time.monotonic() - began < 30:
                time.sleep(0.1)
            gone = time.monotonic() - began
            left = lab_pids_alive(out)
            log(f"session {k}: SIGKILL at {steps_done(out)} logged steps; the lab's "
                f"processes gone {gone:.1f} s later" + (f", LEFT: {left}" if left else ""))
            if left:
                raise SystemExit(f"lab processes left after the kill: {left}")
            return None, gone
        time.sleep(0.2)
    log(f"session {k}: exited with status {proc.returncode}")
    return proc.returncode, 0.0


def check_run(run: Path, steps: int) -> dict[str, Any]:
    """The invariants of one run (module doc); raises AssertionError naming the run."""
    import numpy as np

    from testbed.core.types import FrameClass
    from testbed.lab.fault_drills import FAULT_KINDS, MIN_STEPS
    from testbed.lab.fault_report import read_faults
    from testbed.lab.twin_truth import truth_agreement
    from testbed.records.frame_classes import classify
    from testbed.records.steps import read_steps
    from testbed.records.store import MODES, RunData

    meta = json.loads((run / "run.json").read_text())
    assert meta["status"] == "complete", (run.name, meta["status"])
    rows = read_steps(run / "steps.jsonl")
    assert [r["t"] for r in rows] == list(range(steps)), f"{run.name}: steps not each once"
    robots = [x["robot"] for x in rows[0]["robots"]]
    frames = RunData.of_run(run).frames()
    assert len(frames) == steps * len(robots), (run.name, len(frames))
    assert [(int(f["t"]), int(f["arm"])) for f in frames] == [
        (t, a) for t in range(steps) for a in range(len(robots))], f"{run.name}: frames"
    for f in frames:
        x = rows[int(f["t"])]["robots"][int(f["arm"])]
        assert MODES[int(f["mode"])] == x["mode"], (run.name, int(f["t"]), x["robot"])
        action = -1 if x.get("action") is None else int(x["action"])
        assert int(f["action"]) == action, (run.name, int(f["t"]), x["robot"])
    classes = classify(frames, len(robots)).classes
    counted = {c: int(np.sum(classes == int(c))) for c in FrameClass}
    pushes = {m: sum(1 for r in rows for x in r["robots"]
                     if x["mode"] == m and x.get("action") is not None)
              for m in ("teleop", "autonomous")}
    resets = sum(1 for r in rows for x in r["robots"] if x["mode"] == "reset")
    assert counted[FrameClass.TELEOP] == pushes["teleop"], (run.name, counted, pushes)
    assert counted[FrameClass.RESET] == resets, (run.name, counted, resets)
    assert (counted[FrameClass.ROBOT] + counted[FrameClass.PRE_INTERVENTION]
            == pushes["autonomous"]), (run.name, counted, pushes)
    truth = [json.loads(x) for x in (run / "twin_truth.jsonl").read_text().splitlines()]
    keys = [(r["t"], r["robot"]) for r in truth]
    assert len(keys) == len(set(keys)), f"{run.name}: a truth row twice"
    assert sorted(keys) == sorted((t, r) for t in range(steps) for r in robots), (
        f"{run.name}: truth rows missing")
    faults = read_faults(run)
    kinds = sorted(f["kind"] for f in faults)
    if steps >= MIN_STEPS:
        assert kinds == sorted(FAULT_KINDS), (run.name, kinds)
    assert len(kinds) == len(set(kinds)), (run.name, kinds)
    for f in faults:
        assert f["actions"] and "(not recorded)" not in f["actions"], (run.name, f)
    a = truth_agreement(run)
    return {"run": run.name, "resumed": len(meta.get("resumed", [])),
            "arm_steps": a["arm_steps"], "agree": a["agree"],
            "disagreements": len(a["disagreements"]), "borderline": a["borderline"],
            "faults": len(faults), "teleop": pushes["teleop"],
            "durations": [float(r.get("duration_s") or 0.0) for r in rows],
            "first_of_session": _session_starts(meta, rows)}


def _session_starts(meta: dict[str, Any], rows: list[dict[str, Any]]) -> list[int]:
    """The first step of each session (0, and each resume's): not steady state."""
    starts = {0}
    resumed = sorted(meta.get("resumed", []))
    for when in resumed:
        after = [r["t"] for r in rows if float(r.get("wall_time") or 0) >= when]
        if after:
            starts.add(min(after))
    return sorted(starts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--protocol", default=str(ROOT / "protocols" / "physical.toml"))
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--steps", type=int, default=250)
    ap.add_argument("--algorithms", help="a subset, A,B (default: the protocol's four)")
    ap.add_argument("--kills", type=int, default=2, help="SIGKILLs, spread evenly over the "
                    "steps (default 2)")
    ap.add_argument("--kill-at", help="kill once this many steps are logged, e.g. 300,1700 "
                    "(overrides --kills)")
    ap.add_argument("--out", default=str(ROOT / "runs" / "rehearsal-day"))
    ap.add_argument("--fresh", action="store_true", help="delete --out first")
    ap.add_argument("--camera-fps", type=float, default=30.0, help="the twins' camera "
                    "(rehearse --camera-fps; default 30, a lab's USB camera's)")
    args = ap.parse_args()

    from testbed.experiments.protocol import load_protocol

    proto = load_protocol(Path(args.protocol), check_files=False)
    algorithms = args.algorithms.split(",") if args.algorithms else list(proto.algorithms)
    total = args.trials * len(algorithms) * args.steps
    if args.kill_at:
        kills = [int(x) for x in args.kill_at.split(",")]
    else:
        kills = [round(total * (i + 1) / (args.kills + 1)) for i in range(args.kills)]
    out = Path(args.out)
    if args.fresh and out.exists():
        import shutil

        shutil.rmtree(out)
    cmd = [sys.executable, "-m", "testbed.cli", "rehearse", args.protocol, "--quick",
           "--faults", "--trials", str(args.trials), "--steps", str(args.steps),
           "--out", str(out), "--camera-fps", f"{args.camera_fps:g}"] + (
               ["--algorithms", ",".join(algorithms)] if args.algorithms else [])
    log(f"the day: {args.trials} trials x {len(algorithms)} algorithms x {args.steps} steps "
        f"x 4 arms = {total * 4} arm-steps; kills at {kills} logged steps")
    log("command (each session): " + " ".join(cmd))
    began = time.monotonic()
    k, status, gone, launched = 0, None, [], []
    for at in [*kills, None]:
        launched.append(time.time())
        status, g = session(cmd, out, k, at)
        k += 1
        if status is None:
            gone.append(g)
            continue
        break
    wall = time.monotonic() - began
    if status != 0:
        log(f"the rehearsal failed (status {status}); see {out}-session{k - 1}.log")
        return 1
    left = lab_pids_alive(out)
    assert not left, f"lab processes left after the rehearsal: {left}"
    return report(out, algorithms, args, wall, launched, gone)


def first_rows(runs: list[Path], launched: list[float]) -> list[float]:
    """Seconds from each resumed session's launch to its first step logged: the
    restart's cost (twins, sshds, the kept calibration's check, the agents, the run's
    data replayed onto the learner)."""
    from testbed.records.steps import read_steps

    walls = sorted(float(r["wall_time"]) for run in runs
                   for r in read_steps(run / "steps.jsonl") if r.get("wall_time"))
    out = []
    for when in launched[1:]:
        after = [w for w in walls if w >= when]
        if after:
            out.append(after[0] - when)
    return out


def report(out: Path, algorithms: list[str], args: argparse.Namespace, wall: float,
           launched: list[float], gone: list[float]) -> int:
    sessions = len(launched)
    runs = [out / f"{a}-t{t}" for t in range(args.trials) for a in algorithms]
    try:
        results = [check_run(r, args.steps) for r in runs]
    except AssertionError as exc:  # an invariant broken: say which, plainly
        print(f"FAIL: an invariant does not hold: {exc}")
        return 1
    restarts = first_rows(runs, launched)
    steady = [d for r in results for t, d in enumerate(r["durations"])
              if not any(s <= t < s + 3 for s in r["first_of_session"])]
    step_s = statistics.median(steady)
    total = len(runs) * args.steps
    reference = step_s * total
    arm_steps = sum(r["arm_steps"] for r in results)
    agree = sum(r["agree"] for r in results) / max(arm_steps, 1)
    print(f"## The whole day rehearsed: {len(runs)} runs x {args.steps} steps x 4 arms, "
          f"{sessions} sessions ({sessions - 1} SIGKILLs)\n")
    print("| run | resumed | arm-steps scored | agree | disagreements (borderline) | faults "
          "| teleop pushes |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in results:
        print(f"| {r['run']} | {r['resumed']} | {r['arm_steps']} | "
              f"{r['agree'] / max(r['arm_steps'], 1):.2%} | {r['disagreements']} "
              f"({r['borderline']}) | {r['faults']} | {r['teleop']} |")
    in_steps = sum(sum(r["durations"]) for r in results)
    print(f"\nwall {wall / 60:.1f} min ({wall:.0f} s) against the goal of "
          f"{GOAL_S / 60:.0f} min: ratio {wall / GOAL_S:.2f}")
    print(f"reference (same run): steady-state step {step_s:.3f} s (median of {len(steady)}) "
          f"x {total} steps = {reference:.0f} s; wall / reference {wall / reference:.2f}")
    print(f"time inside the steps (sum of duration_s) {in_steps:.0f} s; the rest "
          f"(calibration, pretraining, restarts, run changes) {wall - in_steps:.0f} s")
    print("lab processes gone after each kill: " + ", ".join(f"{g:.1f} s" for g in gone))
    print("each resumed session's first step, after its launch: "
          + ", ".join(f"{g:.1f} s" for g in restarts))
    odd = sum(r["disagreements"] - r["borderline"] for r in results)
    print(f"perception against the twin's truth: {agree:.2%} of {arm_steps} arm-steps "
          f"(floor {MIN_AGREEMENT:.0%}); disagreements not borderline: {odd}")
    print("invariants: every step, frame, class, truth row and fault once; all held")
    if agree < MIN_AGREEMENT:
        print("FAIL: perception below the floor")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
