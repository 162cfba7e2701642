"""A protocol with ``pretrain_per_trial`` (issue 45, item 1) plans and makes every
trial's theta_0: the printed plan counts one pretraining per trial still to start (its
own seed's cache, what it holds skipped), and ``testbed collect``/``pretrain --config``
make each of them, from its trial's seed, into the very folders the trials read. A
protocol without the field plans and makes its one shared theta_0 as before."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from testbed.cli import main
from testbed.experiments.pace import GradPace
from testbed.experiments.protocol import Protocol
from testbed.experiments.theta0 import (
    PRETRAIN_SEED,
    Theta0Spec,
    demos_file,
    theta0_folder,
)
from testbed.experiments.time_plan import Plan, protocol_plan, protocol_targets

GRAD = GradPace(1.0, 0.5, "given")
FLEET = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                 "critic_transitions": 8, "pretrain_steps": 4},
}
TOML_FLEET = """[fleet.humans]
count = 1
[fleet.learning]
ensemble_size = 2
batch_size = 16
demos = 16
critic_transitions = 8
pretrain_steps = 4
[[fleet.hosts]]
name = "cell0"
"""


def protocol(per_trial: bool, **more: object) -> Protocol:
    return Protocol.model_validate({
        "name": "p", "trials": 3, "seeds": [4, 7, 9], "algorithms": ["bc", "cur"],
        "steps": 5, "fleet": FLEET, "evaluate_steps": 0, "pretrain_per_trial": per_trial,
        **more})


def theta0_tags(plan: Plan, *, skipped: bool | None = None) -> list[str]:
    """The label of each theta_0 of ``plan`` (its phases' "(...)"), once each, in order;
    ``skipped``: only those whose every phase is (True) or is not (False)."""
    tags: dict[str, list[bool]] = {}
    for p in plan.phases:
        if p.theta0:
            m = re.search(r"\((.*)\)$", p.name)
            tags.setdefault(m.group(1) if m else "", []).append(p.skipped)
    return [t for t, s in tags.items() if skipped is None or all(s) == skipped]


def test_the_plan_has_one_theta_0_per_trial_each_from_its_seed(tmp_path: Path) -> None:
    per_trial = protocol(True)
    targets = protocol_targets(per_trial)
    assert [(t.label, t.seed) for t in targets] == [("trial 0", 4), ("trial 1", 7),
                                                    ("trial 2", 9)]
    assert all(t.critics == ("safety",) for t in targets)  # cur's, for bc's run too
    plan = protocol_plan(per_trial, tmp_path, grad=GRAD)
    assert theta0_tags(plan, skipped=False) == ["trial 0", "trial 1", "trial 2"]
    one = protocol_plan(protocol(False), tmp_path, grad=GRAD)
    assert theta0_tags(one) == [""]

    def pretraining(p: Plan) -> float:
        return sum(ph.seconds for ph in p.phases if ph.theta0)

    assert pretraining(one) > 0
    assert pretraining(plan) == pytest.approx(3 * pretraining(one))  # every one counted
    collections = [p for p in plan.phases if p.name.startswith("collect demonstrations")]
    assert len(collections) == 3 and all(not p.skipped for p in collections)


def test_a_trial_started_or_cached_is_not_pretrained_again(tmp_path: Path) -> None:
    """Trial 0's runs have started (no theta_0 to plan), trial 1's theta_0 is in its
    seed's cache (skipped, said so), trial 2 still pretrains."""
    per_trial = protocol(True)
    (tmp_path / "bc-t0").mkdir()
    (tmp_path / "bc-t0" / "summary.json").write_text("{}")
    (tmp_path / "cur-t0").mkdir()
    (tmp_path / "cur-t0" / "state.json").write_text('{"t": 1}')
    cached = theta0_folder(tmp_path, per_trial.fleet, ["safety"], 7)
    cached.mkdir(parents=True)
    (cached / "learner.pt").write_bytes(b"")
    plan = protocol_plan(per_trial, tmp_path, grad=GRAD)
    assert theta0_tags(plan) == ["trial 1", "trial 2"]
    assert theta0_tags(plan, skipped=True) == ["trial 1"]
    assert [p.note for p in plan.phases if p.name == "theta_0 (trial 1)"] == [
        f"cached: {cached}"]
    assert plan.pretrains


def test_without_the_field_the_plan_is_one_shared_theta_0_as_before(tmp_path: Path
                                                                    ) -> None:
    shared = protocol(False)
    assert protocol_targets(shared) == [Theta0Spec(shared.fleet, ("safety",), "",
                                                   PRETRAIN_SEED)]
    (tmp_path / "bc-t0").mkdir()
    (tmp_path / "bc-t0" / "summary.json").write_text("{}")
    assert theta0_tags(protocol_plan(shared, tmp_path, grad=GRAD), skipped=False) == [""]
    for k in range(3):
        for a in ("bc", "cur"):
            (tmp_path / f"{a}-t{k}").mkdir(exist_ok=True)
            (tmp_path / f"{a}-t{k}" / "summary.json").write_text("{}")
    assert theta0_tags(protocol_plan(shared, tmp_path, grad=GRAD)) == []


def test_a_way_of_another_fleet_is_named_with_its_trial() -> None:
    ways = {"ways": {"cur-big": {"algorithm": "cur", "set": {"learning.demos": 20}}},
            "algorithms": ["cur", "cur-big"]}
    assert [t.label for t in protocol_targets(protocol(False, **ways))] == [
        "for cur", "for cur-big"]
    per_trial = protocol_targets(protocol(True, **ways), [("cur-big", 2), ("cur", 1)])
    assert [(t.label, t.seed, t.cfg.learning.demos) for t in per_trial] == [
        ("for cur, trial 1", 7, 16), ("for cur-big, trial 2", 9, 20)]


def write_protocol(tmp_path: Path, per_trial: bool) -> Path:
    path = tmp_path / "p.toml"
    path.write_text(f'name = "p"\ntrials = 2\nseeds = [3, 5]\nalgorithms = ["bc", "cur"]\n'
                    f'steps = 2\nevaluate_steps = 0\nout = "{tmp_path / "proto"}"\n'
                    f"pretrain_per_trial = {str(per_trial).lower()}\n" + TOML_FLEET)
    return path


def test_pretrain_and_collect_dry_run_list_every_trials_theta_0(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_protocol(tmp_path, True)
    assert main(["pretrain", "--config", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    for k in (0, 1):
        for phase in ("collect demonstrations", "pretrain the policy",
                      "roll out the policy", "pretrain the critics"):
            assert re.search(rf"^  {phase} \(trial {k}\) +\S", out, re.M), (phase, k)
    assert "(trial 2)" not in out
    assert main(["collect", "--config", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert len(re.findall(r"^  collect demonstrations +16 pairs +\d+ +~", out, re.M)) == 2
    assert not (tmp_path / "proto").exists()  # a dry run touches nothing
    assert main(["pretrain", "--config", str(write_protocol(tmp_path, False)),
                 "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^  pretrain the policy +4 gradient steps", out, re.M)
    assert "trial" not in out


@pytest.mark.slow
def test_pretrain_fills_the_folders_each_trial_reads(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``testbed pretrain --config P`` makes each trial's theta_0 from its seed into
    ``theta0_folder(..., seed)``; the protocol then pretrains nothing."""
    monkeypatch.setenv("TESTBED_PROGRESS", "plain")
    path = write_protocol(tmp_path, True)
    out = tmp_path / "proto"
    assert main(["pretrain", "--config", str(path)]) == 0
    got = capsys.readouterr()
    assert got.err.count("pretrain critics: started") == 2
    cfg = Protocol.model_validate({"name": "p", "fleet": FLEET}).fleet
    learners = [theta0_folder(out, cfg, ["safety"], seed) / "learner.pt" for seed in (3, 5)]
    for seed, learner in zip((3, 5), learners, strict=True):
        assert learner.is_file() and demos_file(out, cfg, seed).is_file()
        assert f"; trial {(3, 5).index(seed)}) -> {learner}" in got.out
    assert learners[0].read_bytes() != learners[1].read_bytes()
    assert not theta0_folder(out, cfg, ["safety"]).exists()  # no shared theta_0
    assert main(["protocol", str(path), "--yes"]) == 0
    got = capsys.readouterr()
    assert len(re.findall(r"^  theta_0 \(trial \d\) +1 learner +- +skipped", got.out,
                          re.M)) == 2
    for phase in ("collect", "rollout", "pretrain policy", "pretrain critics"):
        assert f"{phase}: started" not in got.err, phase
    assert (out / "cur-t1" / "summary.json").exists()
