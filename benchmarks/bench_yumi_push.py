"""One YuMi push over Robot Web Services: where its wall time goes, against the motion.

Why this exists: on the robot a push is a motion of a second or two, and everything the
driver adds around it (state checks, the upload of each arm's program, the start, the
polling until RAPID stops, the event log read for the result) is time the fleet waits.
This runs the agent's unchanged controller client (``RwsYumiController``, the ABB
``RWS`` client underneath) against the RWS twin at REAL-TIME speed (``realtime = 1``:
the twin's pushers move at the commanded speeds, as the robot's would), one two-arm push
per step (above the start, down, the stroke, up, to rest), and splits each push's wall
time by the client's own phase timers. The reference, measured in the same run, is the
motion alone: the wall time of the twin controller's program run (our RAPID's semantics,
``TestbedRapid``), from the start request to its end. The ratio push / motion is the
driver's overhead factor on the wire.

    .venv/bin/python benchmarks/bench_yumi_push.py [--pushes 10]
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
from typing import Any

from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, serve
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_geometry import workspace_mm

PUSHER_MM = 100.0
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


def push(centre: tuple[float, float]) -> list[Waypoint]:
    """A push as ``plan_push`` makes one: 40 mm stroke at 50 mm/s, travel at 150 mm/s."""
    x, y = centre
    start, end = (x - 30.0, y), (x + 10.0, y)
    return [Waypoint("move_j", (*start, 80.0), 150.0, fine=False),
            Waypoint("move_l", (*start, 12.0), 100.0),
            Waypoint("move_l", (*end, 12.0), 50.0),
            Waypoint("move_l", (*end, 80.0), 100.0, fine=False),
            Waypoint("rest", None, 150.0)]


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
    walls: list[float] = []
    phases: dict[str, list[float]] = {p: [] for p in PHASES}
    requests: list[int] = []
    try:
        boxes = {u.arm: workspace_mm(cell.sides[u.arm]) for u in YUMI_UNITS}
        centres = {a: ((b[0] + b[2]) / 2, (b[1] + b[3]) / 2) for a, b in boxes.items()}
        client.execute({a: push(c) for a, c in centres.items()})  # warm: sessions, paths
        hook.runs.clear()
        for _ in range(a.pushes):
            n0 = client.requests
            t0 = time.perf_counter()
            client.execute({arm: push(c) for arm, c in centres.items()})
            walls.append(time.perf_counter() - t0)
            requests.append(client.requests - n0)
            for p in PHASES:
                phases[p].append(client.timing.get(p, 0.0))
    finally:
        client.close()
        server.stop()
        cell.close()
    motion = statistics.median(hook.runs)
    wall = statistics.median(walls)
    print(f"one two-arm push over RWS on the twin at real-time speed ({a.pushes} pushes, "
          f"medians):")
    print(f"  push wall time      {wall * 1000:8.1f} ms")
    print(f"  motion alone (ref)  {motion * 1000:8.1f} ms   (the twin controller's program run)")
    for p in PHASES:
        print(f"    {p:<8}          {statistics.median(phases[p]) * 1000:8.1f} ms")
    polling = statistics.median(w - m for w, m in zip(phases["wait"], hook.runs, strict=True))
    print(f"    of wait, polling past the motion's end {polling * 1000:6.1f} ms")
    print(f"  RWS requests per push: {statistics.median(requests):.0f}")
    print(f"  ratio push / motion: {wall / motion:.3f}  (overhead {(wall - motion) * 1000:.0f} ms)")


if __name__ == "__main__":
    main()
