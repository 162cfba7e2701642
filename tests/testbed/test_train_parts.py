"""What an algorithm reads decides what is trained (issue 13), from the registry to a
protocol on twins: the declared signals are exactly the ones the keys read, a protocol
pretrains once the critics any of its algorithms reads, and each run trains online only
its own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.pretraining import load_transitions, pretrain_key
from testbed.experiments.protocol import Protocol, pretrain_critics, run_protocol
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import ALGORITHM_NAMES, ALGORITHMS, AlgorithmSpec, get_algorithm
from testbed.fleet.priorities import LEARNED_SIGNALS, PrioritySignals

PARAMS = AlgorithmConfig(t_T=2, t_R=3, t_I=5, u_hat=0.1, r_hat=0.5, random_budget=0.4)
SIGNALS = {"uncertainty": np.array([0.3, 0.1, 0.0, 0.2]),
           "risk": np.array([0.9, 0.2, 0.5, 0.4]),
           "goal_risk": np.array([0.1, 0.7, 0.3, 0.2]),
           "novelty": np.array([0.2, 0.1, 0.6, 0.0]),
           "ood": np.array([1.1, 0.9, 2.5, 1.0])}
VIOL = np.array([True, False, False, False])


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_keys_read_exactly_the_signals_the_algorithm_declares(name: str) -> None:
    """``reads`` cannot drift from the keys: the keys work with only the declared
    signals (the others None) and refuse to work without any one of them."""
    spec = ALGORITHMS[name]
    assert spec.reads <= LEARNED_SIGNALS
    assert get_algorithm(name, PARAMS, 4, 2, 0).priority.reads == spec.reads  # type: ignore[attr-defined]
    only = {k: (v if k in spec.reads else None) for k, v in SIGNALS.items()}
    get_algorithm(name, PARAMS, 4, 2, 0).step(PrioritySignals(t=9, violating=VIOL, **only))
    for signal in spec.reads:
        without = {**only, signal: None}
        with pytest.raises(ValueError, match=f"signals.{signal} is required"):
            get_algorithm(name, PARAMS, 4, 2, 0).step(
                PrioritySignals(t=9, violating=VIOL, **without))


def test_a_factory_that_declares_nothing_is_taken_to_read_everything() -> None:
    spec = AlgorithmSpec("custom", lambda *a: ALGORITHMS["cur"].priority(*a))
    assert spec.reads == LEARNED_SIGNALS and spec.critics == {"safety", "goal"}
    assert spec.train_parts == {"policy", "safety", "goal"}


def test_a_protocol_pretrains_what_any_of_its_algorithms_reads() -> None:
    assert pretrain_critics(["bc", "fleet-ed"]) == []
    assert pretrain_critics(["cur", "fleet-ed"]) == ["safety"]
    assert pretrain_critics(["bc", "random", "fleet-ed", "cur"]) == ["safety"]
    assert pretrain_critics(["fleet-td", "cur"]) == ["goal", "safety"]
    cfg = FleetConfig()
    both = pretrain_key(cfg, 0)
    assert pretrain_key(cfg, 0, ["goal", "safety"]) == both  # old caches (both) stay valid
    keys = {both, pretrain_key(cfg, 0, ["safety"]), pretrain_key(cfg, 0, ["goal"]),
            pretrain_key(cfg, 0, [])}
    assert len(keys) == 4
    with pytest.raises(ValueError, match="unknown critic"):
        pretrain_key(cfg, 0, ["policy"])


FLEET = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                 "critic_transitions": 8, "pretrain_steps": 4},
}
STEPS = 3


def _counters(path: Path) -> dict[str, int]:
    from testbed.learning import checkpoint

    policy, _, safety, goal = checkpoint.load(path)["counters"]
    return {"policy": policy, "safety": safety, "goal": goal}


@pytest.mark.slow
@pytest.mark.parametrize(("algorithms", "pretrained"), [
    (["bc", "fleet-ed"], set()),
    (["cur", "fleet-ed"], {"safety"}),
])
def test_protocol_pretrains_once_and_each_run_trains_only_what_it_reads(
    tmp_path: Path, algorithms: list[str], pretrained: set[str],
) -> None:
    proto = Protocol.model_validate({
        "name": "parts", "trials": 1, "algorithms": algorithms, "steps": STEPS,
        "out": str(tmp_path / "proto"), "fleet": FLEET, "evaluate_steps": 0,
    })
    run_protocol(proto, ask=False)
    out = tmp_path / "proto"
    # demos/: the demonstrations every theta_0 of these arms draws on
    caches = [p for p in (out / ".pretrained").iterdir() if p.name != "demos"]
    assert len(caches) == 1  # one theta_0 for every algorithm of the protocol
    theta0 = _counters(caches[0] / "learner.pt")
    pre = 4  # pretrain_steps (the critics' too)
    assert theta0 == {"policy": pre, **{c: pre if c in pretrained else 0
                                        for c in ("safety", "goal")}}
    data = load_transitions(caches[0] / "transitions.npz")
    assert len(data) == (16 + 8 if pretrained else 16)  # no BC rollouts for no critic
    for name in algorithms:
        spec = ALGORITHMS[name]
        trained = _counters(out / f"{name}-t0" / "learner.pt")
        online = {p: trained[p] - theta0[p] for p in trained}
        assert online == {p: STEPS if p in spec.train_parts else 0 for p in online}, name


def test_a_collection_whose_pushes_are_all_refused_stops_with_the_reason() -> None:
    """A layout the arms cannot reach (every push refused by the driver) used to keep the
    collection waiting for ever; it stops after STALL_STEPS steps, naming the refusal."""
    from testbed.core.types import IMAGE_SIZE, ArmObservation, PushResult
    from testbed.experiments.pretraining import STALL_STEPS, collect_demos
    from testbed.experiments.scripted_humans import ScriptedHumans

    class Refusing:
        robot_names = ("h/left",)
        steps = 0

        def observe(self) -> dict[str, ArmObservation]:
            img = np.zeros((IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
            return {"h/left": ArmObservation("h/left", img, False, (0.5, 0.5), 1)}

        def execute(self, pushes: dict[str, int], resets: list[str]) -> dict[str, PushResult]:
            self.steps += 1
            return {r: PushResult(r, a, False, False, refused="target out of reach")
                    for r, a in pushes.items()}

    hosts = Refusing()
    with pytest.raises(RuntimeError, match=r"collect: no arm pushed in 50 steps; the last "
                                           r"refusal: target out of reach"):
        collect_demos(hosts, ScriptedHumans(), 10, t_R=2)  # type: ignore[arg-type]
    assert hosts.steps == STALL_STEPS == 50
