"""``testbed check``: before a trial, is every host, agent, camera and arm ready?

A lab operator runs it before the 250-step trial: it reaches each host, lets the
handshake check the agent's protocol version, takes one frame of every arm, reports
each arm's state in one line, and writes a mosaic PNG of all arms' images so a glance
shows a camera that is dark, a crop that is off, or a cube out of its workspace.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from testbed.config import FleetConfig
from testbed.types import ArmObservation, Fault


def preflight(cfg: FleetConfig, mosaic_path: Path, print_line: Callable[[str], None]) -> bool:
    import cv2

    from testbed.trial import build_hosts, mosaic

    hosts = build_hosts(cfg, cfg.trial.seed)
    ok = True
    images = []
    try:
        hosts.start()
        obs = hosts.observe()
        for robot in hosts.robot_names:
            o = obs.get(robot)
            if isinstance(o, ArmObservation):
                state = "VIOLATING (needs a hard reset)" if o.violating else "ready"
                mean = float(o.image.mean())
                dark = " DARK IMAGE?" if mean < 10 else ""
                print_line(f"ok    {robot}: frame {o.image.shape}, {state}{dark}")
                images.append(o.image)
            else:
                ok = False
                reason = o.reason if isinstance(o, Fault) else "no answer"
                print_line(f"FAULT {robot}: {reason}")
        hosts.rest()
    finally:
        hosts.close()
    if images:
        cv2.imwrite(str(mosaic_path), cv2.cvtColor(mosaic(images), cv2.COLOR_RGB2BGR))
        print_line(f"mosaic of {len(images)} arms -> {mosaic_path}")
    return ok
