"""theta_0's phases are kept as they go and a re-run goes on from them (issue 44, "No
hidden hour"), on the real twin (transport local) with a real torch learner at tiny
sizes: a collection cut short keeps its pairs and the re-run collects only the rest; a
pretraining cut short in its rollouts keeps the trained policy and the rollouts so far;
a collection made ahead (``testbed collect``/``pretrain --config``) is the one the
trial and the protocol then use; and caches of the old layout are still found."""

from __future__ import annotations

import os
import re
from collections.abc import Collection, Mapping
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.core.types import Fault, PushResult
from testbed.core.wrappers import HostsWrapper
from testbed.experiments.fleet_config import FleetConfig, parse_config
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.pretraining import FIELDS, load_transitions
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.experiments.theta0 import (
    Report,
    cache_state,
    collect_into,
    demos_file,
    make_theta0,
    own_hosts,
    theta0_folder,
)

FLEET = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 24,
                 "critic_transitions": 12, "pretrain_steps": 3},
}
TOML = """[trial]
steps = 2
[humans]
count = 1
[learning]
ensemble_size = 2
batch_size = 16
demos = 24
critic_transitions = 12
pretrain_steps = 3
[[hosts]]
name = "cell0"
"""

PROTOCOL_FLEET = """[fleet.humans]
count = 1
[fleet.learning]
ensemble_size = 2
batch_size = 16
demos = 24
critic_transitions = 12
pretrain_steps = 3
[[fleet.hosts]]
name = "cell0"
"""


def fleet() -> FleetConfig:
    return parse_config(FLEET)


class Counting(HostsWrapper):
    """The hosts, counting the pushes they were asked for."""

    pushes = 0

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> Mapping[str, PushResult | Fault]:
        self.pushes += len(pushes)
        return super().execute(pushes, resets)


def stop_after(phase: str, k: int) -> Report:
    def progress(name: str, done: int, total: int) -> None:
        if name == phase and done >= k:
            raise KeyboardInterrupt

    return Report(progress, progress)


def collect(path: Path, cfg: FleetConfig, count: int, report: Report) -> tuple[int, object]:
    """``collect_into`` on the fleet's own hosts (the pretraining seed); the pushes made
    and what it returned (or the exception it raised)."""
    with own_hosts(cfg) as hosts:
        counted = Counting(hosts)
        try:
            got: object = collect_into(path, counted, ScriptedHumans(), count,  # type: ignore[arg-type]
                                       cfg.algorithm.t_R, report, every_s=1e9)
        except KeyboardInterrupt as exc:
            got = exc
        return counted.pushes, got


def test_a_collection_cut_short_keeps_its_pairs_and_the_rerun_does_only_the_rest(
        tmp_path: Path) -> None:
    cfg, n, k = fleet(), 24, 9
    arms = len(cfg.robot_names)
    whole = tmp_path / "whole.npz"
    pushes_whole, _ = collect(whole, cfg, n, Report())
    path = tmp_path / "demos.npz"
    pushes_1, got = collect(path, cfg, n, stop_after("collect", k))
    assert isinstance(got, KeyboardInterrupt)
    kept = load_transitions(path)  # saved when the interrupt went through the collection
    assert k <= len(kept) < n
    reported: list[tuple[str, int, int]] = []

    def resumed(name: str, done: int, total: int) -> None:
        reported.append((name, done, total))

    pushes_2, demos = collect(path, cfg, n, Report(None, resumed))
    assert reported == [("collect", len(kept), n)]
    assert len(demos) == n == len(load_transitions(path))  # type: ignore[arg-type]
    first = load_transitions(path)
    for f in FIELDS:  # the kept pairs are kept as they were
        assert np.array_equal(getattr(first, f)[:len(kept)], getattr(kept, f)), f
    # and they are the uninterrupted collection's first pairs (the same world until the
    # interrupt); after the resume the world starts again (not bit-identical: documented)
    ref = load_transitions(whole)
    for f in FIELDS:
        assert np.array_equal(getattr(ref, f)[:len(kept)], getattr(kept, f)), f
    # the re-run pushed only for the pairs it lacked (and the last step's stragglers)
    assert pushes_2 <= n - len(kept) + 2 * arms
    assert pushes_1 + pushes_2 <= pushes_whole + 3 * arms


@pytest.mark.slow
def test_a_pretraining_cut_short_in_its_rollouts_keeps_the_policy_and_the_rollouts(
        tmp_path: Path) -> None:
    cfg = fleet()
    critics = ("safety",)
    heard: list[tuple[str, int, int]] = []

    class Hooks(TrialHooks):
        def __init__(self, stop_at: int | None) -> None:
            self.stop_at = stop_at

        def on_phase(self, name: str, done: int, total: int) -> None:
            heard.append((name, done, total))
            if name == "rollout" and self.stop_at is not None and done >= self.stop_at:
                raise KeyboardInterrupt

        def on_phase_resumed(self, name: str, done: int, total: int) -> None:
            heard.append((f"resumed {name}", done, total))

    with own_hosts(cfg) as hosts, pytest.raises(KeyboardInterrupt):
        make_theta0(cfg, ScriptedHumans(), tmp_path, critics, hosts, Hooks(5))
    folder = theta0_folder(tmp_path, cfg, critics)
    st = cache_state(tmp_path, cfg, critics)
    assert st.policy and not st.done and st.demos == 24 and 5 <= st.rollouts < 12
    kept = load_transitions(folder / "rollouts.npz")
    heard.clear()
    with own_hosts(cfg) as hosts:
        learner = make_theta0(cfg, ScriptedHumans(), tmp_path, critics, hosts, Hooks(None))
    names = {h[0] for h in heard}
    assert "collect" not in names and "pretrain policy" not in names  # nothing redone
    assert ("resumed rollout", len(kept), 12) in heard
    assert "pretrain critics" in names
    assert learner.exists() and not (folder / "policy.pt").exists()
    assert not (folder / "rollouts.npz").exists()
    data = load_transitions(folder / "transitions.npz")
    assert len(data) == 24 + 12
    assert np.array_equal(data.actions[24:24 + len(kept)], kept.actions)
    from testbed.learning import checkpoint

    policy, _, safety, goal = checkpoint.load(learner)["counters"]
    assert (policy, safety, goal) == (3, 3, 0)  # the policy trained once, not twice


@pytest.mark.slow
def test_collect_then_pretrain_then_protocol_pretrains_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """`testbed collect --config P`, `testbed pretrain --config P`, then `testbed
    protocol P`: the protocol finds its theta_0 (the critics any of its algorithms
    reads) and neither collects nor pretrains again; its plan says so."""
    monkeypatch.setenv("TESTBED_PROGRESS", "plain")
    out = tmp_path / "proto"
    proto = tmp_path / "p.toml"
    proto.write_text(f'name = "p"\ntrials = 1\nalgorithms = ["bc", "cur"]\nsteps = 2\n'
                     f'evaluate_steps = 0\nout = "{out}"\n' + PROTOCOL_FLEET)
    assert main(["collect", "--config", str(proto)]) == 0
    got = capsys.readouterr()
    assert re.search(r"^  collect demonstrations +24 pairs +\d+ +~", got.out, re.M)
    assert "collect: started" in got.err
    cfg = parse_config(FLEET)
    shared = demos_file(out, cfg)
    inode = os.stat(shared).st_ino
    assert main(["pretrain", "--config", str(proto)]) == 0
    got = capsys.readouterr()
    assert "collect: started" not in got.err and "pretrain critics: started" in got.err
    assert "(safety)" in got.out  # the protocol's critics: cur reads the safety critic
    assert main(["protocol", str(proto), "--yes"]) == 0
    got = capsys.readouterr()
    assert re.search(r"^  theta_0 +1 learner +- +skipped  \(cached: ", got.out, re.M)
    for phase in ("collect", "rollout", "pretrain policy", "pretrain critics"):
        assert f"{phase}: started" not in got.err, phase
    assert os.stat(shared).st_ino == inode
    assert len(list((out / ".pretrained").iterdir())) == 2  # demos/ and one theta_0
    assert (out / "cur-t0" / "summary.json").exists()


def test_caches_of_the_old_layout_are_found(tmp_path: Path) -> None:
    """A theta_0 folder with learner.pt alone (before the shared demonstrations) is
    theta_0; one with demos.npz alone (a pretraining that died after its collection)
    gives its demonstrations: nothing is collected."""
    cfg = fleet()
    with own_hosts(cfg) as hosts:
        make_theta0(cfg, ScriptedHumans(), tmp_path, None, hosts, None)
    folder = theta0_folder(tmp_path, cfg, None)
    (demos_file(tmp_path, cfg)).unlink()  # the old layout had no shared collection
    assert cache_state(tmp_path, cfg, None).done
    (folder / "learner.pt").unlink()
    (folder / "transitions.npz").unlink()
    st = cache_state(tmp_path, cfg, None)
    assert not st.done and st.demos == 24 and not st.policy
    phases: list[str] = []
    with own_hosts(cfg) as hosts:
        make_theta0(cfg, ScriptedHumans(), tmp_path, None, hosts,
                    lambda name, done, total: phases.append(name))
    assert "collect" not in phases and "pretrain policy" in phases
    assert (folder / "learner.pt").exists() and not demos_file(tmp_path, cfg).exists()
