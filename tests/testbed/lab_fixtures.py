"""The hardware-twin lab's shared pieces for the rehearsal tests: the physical protocol
with learning sizes a test can afford, a policy of that size, and exact calibrations."""

from __future__ import annotations

import re
from pathlib import Path

from testbed.core.atomic import atomic_write_json
from testbed.experiments.fleet_config import FleetConfig
from testbed.lab.camera_model import true_calibration
from testbed.lab.hardware_twin import HardwareTwinLab

PHYSICAL = Path(__file__).resolve().parents[2] / "protocols" / "physical.toml"
TINY_LEARNING = """[fleet.learning]
ensemble_size = 2
batch_size = 16
demos = 16
critic_transitions = 8
pretrain_steps = 3
critic_pretrain_steps = 3

"""


def tiny_protocol(tmp: Path, *, t_R: int | None = None) -> Path:
    """physical.toml as shipped, but with learning sizes a test can afford."""
    text = PHYSICAL.read_text()
    text = re.sub(r"\[fleet\.learning\][^\[]*", TINY_LEARNING, text)
    if t_R is not None:
        text = re.sub(r"\nt_R = \d+", f"\nt_R = {t_R}", text)
    path = tmp / "physical-tiny.toml"
    path.write_text(text)
    return path


def tiny_policy(cfg: FleetConfig, path: Path) -> Path:
    from testbed.learning import Learner

    Learner(cfg.learning, seed=0).save(path)
    return path


def calibrate_exactly(lab: HardwareTwinLab) -> None:
    for name, host in lab.hosts.items():
        cam = host.lab.camera()
        for arm in host.arms:
            atomic_write_json(lab.calibration_path(name, arm), true_calibration(cam, arm))
