"""Where does one rehearsal step's time go? Camera, perception, planning, motion, SSH.

Why this exists: a rehearsal step is the lab's step with the robot and the camera
replaced by the hardware twin, so its split tells a lab what the controller path costs
beside the robot's own motion. One YuMi host (2 arms) as a hardware twin behind a real
sshd on loopback, exactly calibrated. Two measurements alternate in blocks, in the same
run:

1. the fleet step: ``HostFleet.observe()`` + ``HostFleet.execute(both arms push)`` over
   SSH, to the agent running ``--backend yumi`` (the reference: 100 %);
2. the same step on a ``YumiBackend`` in this process (same camera URL, same controller
   URL, same calibration), its two seams and its perception wrapped in timers.

Shares of the fleet step (means, so the parts add up): camera (``Camera.read``: the
stream's drain and the wait for a frame made after the call, on average half a frame
interval at 15 fps), controller motion (``execute``/``tcp_xyz``: the twin integrates
the programs' physics), perception (``find_cube``/``is_success``/``is_violation``),
planning (the rest of the backend: crops, goals, waypoints) and SSH + agent (fleet step
minus the backend step: framing, PNG, the channel, the agent's dispatch), with its
standard error; the camera's frame phase makes that difference noisy, so the bare
round trip of a heartbeat on the same SSH link is printed as the transport's floor.
The simulated motion time is printed too: on a real YuMi the motion alone takes that
long.

    .venv/bin/python benchmarks/bench_rehearsal.py [--steps 20] [--blocks 3]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.yumi.yumi_host import YumiHost
from testbed.core.atomic import atomic_write_json
from testbed.core.types import ArmObservation
from testbed.experiments.protocol import load_protocol
from testbed.lab.camera_model import true_calibration
from testbed.lab.hardware_twin import HardwareTwinLab

PHYSICAL = Path(__file__).resolve().parents[1] / "protocols" / "physical.toml"
Clock = defaultdict[str, float]


class Timed:
    """Forwards every call to ``inner``, adding its wall time to ``clock[part]``."""

    def __init__(self, inner: Any, clock: Clock, part: str) -> None:
        self._inner, self._clock, self._part = inner, clock, part

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._inner, name)
        if not callable(attr):
            return attr

        def timed(*a: Any, **kw: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return attr(*a, **kw)
            finally:
                self._clock[self._part] += time.perf_counter() - t0

        return timed


def local_backend(host: YumiHost, clock: Clock) -> tuple[Any, Any]:
    from drivers.cameras.camera import VideoCaptureCamera
    from drivers.yumi.arm_calibration import ArmCalibration
    from drivers.yumi.backend import ArmSetup, YumiBackend
    from drivers.yumi.controllers import make_controller
    from testbed.perception import cube as perception

    setups = [ArmSetup(a.name, a.crop, a.mirror, ArmCalibration.load(a.calibration, a.name))
              for a in host.arms]  # type: ignore[arg-type]
    ctrl = make_controller(host.controller_url, {s.name: s.calibration.pose for s in setups})
    camera = VideoCaptureCamera(host.camera)
    backend = YumiBackend(setups, Timed(camera, clock, "camera"),
                          Timed(ctrl, clock, "motion"),
                          perception=Timed(perception, clock, "perception"), seed=1)
    return backend, ctrl


def faces(rng: np.random.Generator, arms: list[str]) -> dict[str, int]:
    return {a: int(rng.integers(4)) for a in arms}


def run_fleet(host: YumiHost, steps: int, rng: np.random.Generator,
              reset: Callable[[], None], rtts: list[float]) -> list[float]:
    from drivers.host_fleet import HostFleet

    out: list[float] = []
    with HostFleet([host]) as fleet:
        fleet.observe()  # warm
        session = fleet._sessions[0]  # the bare link, for the heartbeat floor
        for _ in range(steps):
            with session.lock:
                t0 = time.perf_counter()
                session.link.heartbeat(time.monotonic() + 5.0)
                rtts.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            obs = fleet.observe()
            live = {r: f for r, f in faces(rng, list(obs)).items()
                    if isinstance(obs[r], ArmObservation) and not obs[r].violating}
            fleet.execute(live, [])
            out.append(time.perf_counter() - t0)
            if len(live) < len(obs):
                reset()
    return out


def run_local(host: YumiHost, steps: int, rng: np.random.Generator,
              reset: Callable[[], None]) -> tuple[list[float], list[dict[str, float]], float]:
    clock: Clock = defaultdict(float)
    backend, ctrl = local_backend(host, clock)
    totals: list[float] = []
    parts: list[dict[str, float]] = []
    sim = 0.0
    try:
        backend.observe()
        for _ in range(steps):
            clock.clear()
            t0 = time.perf_counter()
            views = backend.observe()
            live = {a: f for a, f in faces(rng, list(views)).items() if not views[a].violating}
            if live:
                backend.push(live)
            totals.append(time.perf_counter() - t0)
            parts.append(dict(clock))
            sim += getattr(ctrl, "last_sim_s", 0.0) or 0.0
            if len(live) < len(views):
                reset()
    finally:
        backend.rest()
        backend.close()
    return totals, parts, sim / max(steps, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--blocks", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    proto = load_protocol(PHYSICAL, check_files=False)
    fleet_cfg = proto.fleet.model_copy(update={"hosts": proto.fleet.hosts[:1]})
    with tempfile.TemporaryDirectory() as tmp, HardwareTwinLab(fleet_cfg, Path(tmp)) as lab:
        name, twin = next(iter(lab.hosts.items()))
        cam = twin.lab.camera()
        for arm in twin.arms:
            atomic_write_json(lab.calibration_path(name, arm), true_calibration(cam, arm))
        host = lab.rewrite().hosts[0]
        assert isinstance(host, YumiHost)
        local_host = host.model_copy(update={"transport": "local"})

        def reset() -> None:
            lab.reset_all()

        fleet_t: list[float] = []
        local_t: list[float] = []
        rtts: list[float] = []
        parts: list[dict[str, float]] = []
        sims: list[float] = []
        for _ in range(args.blocks):
            reset()
            fleet_t += run_fleet(host, args.steps, rng, reset, rtts)
            reset()
            lt, lp, sim = run_local(local_host, args.steps, rng, reset)
            local_t += lt
            parts += lp
            sims.append(sim)
    fleet_ms = statistics.mean(fleet_t) * 1e3
    local_ms = statistics.mean(local_t) * 1e3
    mean = {k: statistics.mean(p.get(k, 0.0) for p in parts) * 1e3
            for k in ("camera", "motion", "perception")}
    planning = local_ms - sum(mean.values())
    ssh = fleet_ms - local_ms
    se = 1e3 * math.sqrt(statistics.variance(fleet_t) / len(fleet_t)
                         + statistics.variance(local_t) / len(local_t))
    print(f"rehearsal step, 1 YuMi host (2 arms), means of {len(fleet_t)} steps each way "
          f"in {args.blocks} alternating blocks")
    print(f"  fleet step over SSH (reference)   {fleet_ms:8.1f} ms   100.0 %")
    for label, ms in (("camera (drain + next frame)", mean["camera"]),
                      ("controller motion (twin physics)", mean["motion"]),
                      ("perception", mean["perception"]), ("planning (rest of backend)", planning),
                      ("SSH + agent (fleet - backend)", ssh)):
        print(f"  {label:<34}{ms:8.1f} ms   {100 * ms / fleet_ms:5.1f} %")
    print(f"    (SSH + agent: +- {se:.1f} ms standard error; bare heartbeat round trip on the "
          f"link: median {statistics.median(rtts) * 1e3:.2f} ms, "
          f"{100 * statistics.median(rtts) / (fleet_ms / 1e3):.2f} % of the step)")
    print(f"  backend step in-process           {local_ms:8.1f} ms   ratio to fleet step "
          f"{local_ms / fleet_ms:.3f}")
    print(f"  simulated motion per step         {statistics.mean(sims):8.2f} s   (what a real "
          f"YuMi's programs take at the calibration's speeds)")


if __name__ == "__main__":
    main()
