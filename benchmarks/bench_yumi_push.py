"""One YuMi push over Robot Web Services: where its wall time goes, against the motion.

Why this exists: on the robot a push is a motion of a second or two, and everything the
driver adds around it (state checks, the upload of each arm's program, the start, the
polling until RAPID stops, the event log read for the result) is time the fleet waits.
This runs the agent's unchanged controller client (``RwsYumiController``, the ABB
``RWS`` client underneath) against the RWS twin at REAL-TIME speed (``realtime = 1``:
the twin's pushers move at the commanded speeds, as the robot's would), one two-arm push
per step (the driver's path, ``drivers/yumi/paths.py``: rest by joints to the gate at clear
height, straight to above the start at travel height, down, the stroke, up, straight to
the gate, by joints to rest), then one-arm pushes (the other task runs the driver's "stay"
program, issue 35: no task ever replays its old file), and splits each push's wall
time by the client's own phase timers. The reference, measured in the same run, is the
motion alone: the wall time of the twin controller's program run (our RAPID's semantics,
``TestbedRapid``), from the start request to its end. The ratio push / motion is the
driver's overhead factor on the wire.

    .venv/bin/python benchmarks/bench_yumi_push.py [--pushes 10]

Prints the figures: push wall time against the motion alone, each phase, RWS requests
per push, for two-arm pushes and for one-arm pushes.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
from typing import Any

from drivers.yumi.paths import DEFAULT_Z_CLEAR_MM, gate_xy, leave_rest, to_rest
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, serve
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_geometry import workspace_mm

PUSHER_MM = 184.2
Z_TRAVEL_MM = 80.0
PHASES = ("checks", "upload", "start", "wait", "log")


class TimedRapid(TestbedRapid):
    """Our RAPID on the twin, timing each program run (the motion alone)."""

    __test__ = False

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.runs: list[float] = []

    def __call__(self, run: Any) -> None:
        t0 = time.perf_counter()
        try:
            super().__call__(run)
        finally:
            self.runs.append(time.perf_counter() - t0)


def push(box: tuple[float, float, float, float]) -> list[Waypoint]:
    """A push as ``plan_push`` makes one at the box's centre: 40 mm stroke at 50 mm/s,
    travel at 150 mm/s, by the gate both ways."""
    x, y = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    start, end = (x - 30.0, y), (x + 10.0, y)
    gate = gate_xy(box)
    return [*leave_rest(gate, start, DEFAULT_Z_CLEAR_MM, Z_TRAVEL_MM, 150.0),
            Waypoint("move_l", (*start, 12.0), 100.0),
            Waypoint("move_l", (*end, 12.0), 50.0),
            Waypoint("move_l", (*end, Z_TRAVEL_MM), 100.0, fine=False),
            *to_rest(gate, DEFAULT_Z_CLEAR_MM, 150.0)]


def timed(client: RwsYumiController, hook: TimedRapid, programs: dict[str, list[Waypoint]],
          n: int) -> dict[str, Any]:
    """``n`` executions of ``programs``: wall times, the motion alone, requests, phases."""
    out: dict[str, Any] = {"wall": [], "requests": [], **{p: [] for p in PHASES}}
    hook.runs.clear()
    for _ in range(n):
        n0 = client.requests
        t0 = time.perf_counter()
        client.execute(programs)
        out["wall"].append(time.perf_counter() - t0)
        out["requests"].append(client.requests - n0)
        for p in PHASES:
            out[p].append(client.timing.get(p, 0.0))
    out["motion"] = list(hook.runs)
    return out


def report(title: str, r: dict[str, Any]) -> None:
    motion, wall = statistics.median(r["motion"]), statistics.median(r["wall"])
    print(f"{title} ({len(r['wall'])} pushes, medians):")
    print(f"  push wall time      {wall * 1000:8.1f} ms")
    print(f"  motion alone (ref)  {motion * 1000:8.1f} ms   (the twin controller's program run)")
    for p in PHASES:
        print(f"    {p:<8}          {statistics.median(r[p]) * 1000:8.1f} ms")
    polling = statistics.median(w - m for w, m in zip(r["wait"], r["motion"], strict=True))
    print(f"    of wait, polling past the motion's end {polling * 1000:6.1f} ms")
    print(f"  RWS requests per push: {statistics.median(r['requests']):.0f}")
    print(f"  ratio push / motion: {wall / motion:.3f}  (overhead {(wall - motion) * 1000:.0f} ms)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pushes", type=int, default=10)
    a = ap.parse_args()
    cell = YumiTwinCell(3, realtime=1.0)
    lock = threading.Lock()
    hook = TimedRapid(cell, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses, on_start=hook)
    TestbedInstall(ctrl, hook)  # our RAPID's symbols: tool_pusher, the zones
    server = serve(ctrl)
    poses = {u.arm: ArmPose(u.task, u.name, tuple(hook.poses.joints(u)), tool_z_mm=PUSHER_MM)
             for u in YUMI_UNITS}
    client = RwsYumiController(server.url, poses, http_timeout_s=20.0, motion_timeout_s=60.0)
    try:
        boxes = {u.arm: workspace_mm(cell.sides[u.arm]) for u in YUMI_UNITS}
        both = {a: push(b) for a, b in boxes.items()}
        client.execute(both)  # warm: sessions, paths
        two = timed(client, hook, both, a.pushes)
        one = timed(client, hook, {"left": both["left"]}, a.pushes)  # the right: a stay
    finally:
        client.close()
        server.stop()
        cell.close()
    report("one two-arm push over RWS on the twin at real-time speed", two)
    report("one one-arm push (the other task a stay)", one)


if __name__ == "__main__":
    main()
