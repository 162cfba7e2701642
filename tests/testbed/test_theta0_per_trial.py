"""theta_0 pretrained per trial where the protocol asks for it (issue 45, item 1): each
trial seed gets a theta_0 of its own, cached apart, so leaving one theta_0 out holds out
a policy; a protocol that does not ask keeps the one theta_0 every trial shares, with the
cache key it had."""

from __future__ import annotations

from pathlib import Path

import pytest

from testbed.core.config import ConfigError
from testbed.experiments.fanout import protocol_critics
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.pretraining import demos_key, pretrain_key
from testbed.experiments.protocol import Protocol, load_protocol, run_protocol
from testbed.experiments.theta0 import (
    CACHE,
    PRETRAIN_HOSTS_SEED,
    PRETRAIN_SEED,
    demos_file,
    pretrain_hosts_seed,
    theta0_folder,
)
from testbed.results.prediction_features import theta0_digest

ROOT = Path(__file__).resolve().parents[2]


def test_the_shared_theta_0_keeps_its_cache_and_each_seed_gets_its_own() -> None:
    cfg = FleetConfig()
    out = Path("runs")
    shared = theta0_folder(out, cfg, ["safety"])
    assert shared == out / CACHE / pretrain_key(cfg, PRETRAIN_SEED, ["safety"])
    assert theta0_folder(out, cfg, ["safety"], PRETRAIN_SEED) == shared
    assert demos_file(out, cfg) == out / CACHE / "demos" / f"{demos_key(cfg, 0)}.npz"
    assert pretrain_hosts_seed(PRETRAIN_SEED) == PRETRAIN_HOSTS_SEED
    folders = {theta0_folder(out, cfg, ["safety"], s) for s in range(4)}
    demos = {demos_file(out, cfg, s) for s in range(4)}
    hosts = {pretrain_hosts_seed(s) for s in range(4)}
    assert len(folders) == len(demos) == len(hosts) == 4


def test_the_protocol_field_is_off_unless_asked_and_checked() -> None:
    for path in sorted((ROOT / "protocols").glob("*.toml")):
        proto = load_protocol(path, check_files=False)
        assert proto.pretrain_per_trial == (path.stem == "twin-monitor-per-trial"), path
        assert proto.pretrain_seed(0) == (proto.seed(0) if proto.pretrain_per_trial
                                          else None)
    per_trial = Protocol.model_validate({"name": "p", "seeds": [4, 7, 9],
                                         "pretrain_per_trial": True})
    assert [per_trial.pretrain_seed(k) for k in range(3)] == [4, 7, 9]
    assert Protocol.model_validate({"name": "p"}).pretrain_seed(2) is None


@pytest.mark.parametrize(("text", "message"), [
    ('pretrain_per_trial = "yes"', "pretrain_per_trial: Input should be a valid boolean"),
    ("pretrain_per_trial = true\nseeds = [1, 1, 2]", "pretrain_per_trial: seeds must differ"),
])
def test_a_bad_per_trial_field_is_refused_naming_it(tmp_path: Path, text: str,
                                                    message: str) -> None:
    path = tmp_path / "p.toml"
    path.write_text(f'name = "p"\ntrials = 3\n{text}\n')
    with pytest.raises(ConfigError, match=message):
        load_protocol(path)


def test_the_fan_out_pretrains_the_critics_of_what_each_name_runs() -> None:
    """A way's name is no algorithm: the Ray path asked the registry for it (KeyError)
    where the serial path asks for the algorithm the way runs."""
    proto = Protocol.model_validate({
        "name": "w", "algorithms": ["bc", "cur-weighted"],
        "ways": {"cur-weighted": {"algorithm": "cur",
                                  "set": {"learning.weighting": "intervention"}}}})
    assert protocol_critics(proto) == ["safety"]


FLEET = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                 "critic_transitions": 8, "pretrain_steps": 4},
}


@pytest.mark.slow
def test_each_trial_of_a_per_trial_protocol_starts_from_a_policy_of_its_own(
        tmp_path: Path) -> None:
    """Two trials, BC and C.U.R. each: one theta_0 per trial (its digest, the weights of
    its policy), shared by the trial's two algorithms, another for the other trial; each
    cached under its seed's key, with demonstrations of its own."""
    proto = Protocol.model_validate({
        "name": "own", "trials": 2, "seeds": [3, 5], "algorithms": ["bc", "cur"],
        "steps": 3, "out": str(tmp_path / "proto"), "fleet": FLEET, "evaluate_steps": 0,
        "pretrain_per_trial": True})
    run_protocol(proto, ask=False)
    out = tmp_path / "proto"
    digest = {(a, k): theta0_digest(out / f"{a}-t{k}") for a in ("bc", "cur") for k in (0, 1)}
    assert digest[("bc", 0)] == digest[("cur", 0)] and digest[("bc", 1)] == digest[("cur", 1)]
    assert digest[("bc", 0)] != digest[("bc", 1)]
    assert all(d is not None and not d.startswith("file:") for d in digest.values())
    cfg = proto.fleet
    for seed in (3, 5):
        assert (theta0_folder(out, cfg, ["safety"], seed) / "learner.pt").is_file()
        assert demos_file(out, cfg, seed).is_file()
    assert not theta0_folder(out, cfg, ["safety"]).exists()  # no shared theta_0 made
