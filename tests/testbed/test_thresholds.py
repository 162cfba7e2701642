"""Thresholds from data (issue 12, item 2): ``u_hat = "q0.75"`` is resolved once on
theta_0's own pretraining rollouts, recorded in the run's config.toml and run.json, and
the same for every run that starts from that theta_0."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import FleetConfig, parse_config
from testbed.experiments.protocol import Protocol, run_protocol
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.thresholds import resolve_thresholds
from testbed.learning import Learner, Transitions
from testbed.learning.learning_config import LearningConfig


@pytest.mark.parametrize("bad", ["q2", "0.75", "q", "quartile", "q-0.1"])
def test_a_bad_quantile_is_a_one_line_error_naming_the_field(bad: str) -> None:
    with pytest.raises(ConfigError, match=r"algorithm\.u_hat") as err:
        parse_config({"algorithm": {"u_hat": bad}}, "f.toml")
    assert "\n" not in str(err.value)
    assert AlgorithmConfig(u_hat="q0.75", r_hat="q1").quantile_thresholds == {
        "u_hat": 0.75, "r_hat": 1.0}


def test_quantiles_resolve_on_the_learners_rollout_states() -> None:
    learner = Learner(LearningConfig(ensemble_size=3, batch_size=16, augmentation_factor=2),
                      seed=0)
    rng = np.random.default_rng(0)
    imgs = rng.integers(0, 256, (61, 64, 64, 3), dtype=np.uint8)
    b = Transitions.build(imgs[:60], rng.integers(0, 4, 60), imgs[1:], np.arange(60) % 7 == 0,
                          np.arange(60) % 5 == 0)
    learner.pretrain(b.images[:30], b.actions[:30], transitions=b, steps=5)
    cfg = FleetConfig(algorithm=AlgorithmConfig(u_hat="q0.75", r_hat="q0.5"))
    resolved_cfg, record = resolve_thresholds(cfg, learner)
    signals = learner.signals_on_data()
    assert len(signals["uncertainty"]) == 60  # the transitions' states, not the demos
    u = float(np.quantile(signals["uncertainty"], 0.75))
    r = float(np.quantile(signals["risk"], 0.5))
    assert resolved_cfg.algorithm.u_hat == pytest.approx(u) and 0.0 < u < 1.0
    assert resolved_cfg.algorithm.r_hat == pytest.approx(r)
    assert record["u_hat"] == {"quantile": 0.75, "value": pytest.approx(u),
                               "signal": "uncertainty", "states": 60}
    plain = FleetConfig()
    assert resolve_thresholds(plain, learner) == (plain, {})


@pytest.mark.slow
def test_protocol_runs_share_the_thresholds_resolved_on_their_theta0(tmp_path: Path) -> None:
    proto = Protocol.model_validate({
        "name": "q", "trials": 2, "algorithms": ["bc", "cur"], "steps": 3, "seeds": [1, 2],
        "out": str(tmp_path / "proto"), "evaluate_steps": 0,
        "fleet": {"hosts": [{"name": "cell0"}], "humans": {"count": 1},
                  "algorithm": {"u_hat": "q0.75", "r_hat": "q0.9"},
                  "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                               "critic_transitions": 12, "pretrain_steps": 4}},
    })
    run_protocol(proto, ask=False)
    out = tmp_path / "proto"
    values = []
    states: list[int] = []
    for k in range(2):
        cfg = tomllib.loads((out / f"cur-t{k}" / "config.toml").read_text())["algorithm"]
        meta = json.loads((out / f"cur-t{k}" / "run.json").read_text())["thresholds"]
        assert isinstance(cfg["u_hat"], float) and isinstance(cfg["r_hat"], float)
        assert meta["u_hat"]["value"] == cfg["u_hat"] and meta["u_hat"]["quantile"] == 0.75
        states.append(meta["r_hat"]["states"])
        values.append((cfg["u_hat"], cfg["r_hat"]))
        # BC reads neither signal: nothing resolved, its config keeps what was given
        bc = tomllib.loads((out / f"bc-t{k}" / "config.toml").read_text())["algorithm"]
        assert bc["u_hat"] == "q0.75"
        assert "thresholds" not in json.loads((out / f"bc-t{k}" / "run.json").read_text())
    assert values[0] == values[1]  # one theta_0, one resolution
    theta0 = Learner.load(next((out / ".pretrained").glob("*/learner.pt")))
    signals = theta0.signals_on_data()
    assert states == [len(signals["uncertainty"])] * 2 and states[0] > 0
    assert values[0][0] == pytest.approx(float(np.quantile(signals["uncertainty"], 0.75)))
    assert values[0][1] == pytest.approx(float(np.quantile(signals["risk"], 0.9)))
