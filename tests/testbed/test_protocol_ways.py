"""A protocol's ways (issue 30): one algorithm run several ways, theta_0 evaluated, and
the report's learning gain per human action, paired by trial.

The protocol drives real twin hosts and the real learner, sized down (one host, a tiny
ensemble), as test_protocol_runs.py does.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from testbed.experiments.protocol import Protocol, load_protocol, run_protocol
from testbed.records.run_dir import RunDir

ROOT = Path(__file__).resolve().parents[2]
FLEET = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                 "critic_transitions": 8, "pretrain_steps": 4},
}
WAYS = {"cur-weighted": {"algorithm": "cur", "set": {"learning.weighting": "intervention"}}}


def test_ways_are_checked_in_one_line_each() -> None:
    base = {"name": "p", "algorithms": ["cur", "cur-weighted"], "fleet": FLEET}
    ok = Protocol.model_validate({**base, "ways": WAYS})
    assert ok.algorithm_of("cur-weighted") == "cur" and ok.algorithm_of("cur") == "cur"
    assert ok.fleet_of("cur-weighted").learning.weighting == "intervention"
    assert ok.fleet_of("cur").learning.weighting == "uniform"
    for ways, match in (
        ({"cur": {"algorithm": "cur"}}, "ways.cur: the name of an algorithm"),
        ({"cur-weighted": {"algorithm": "curr"}}, "unknown algorithm 'curr'"),
        ({"cur-weighted": {"algorithm": "cur", "set": {"learning.weighting": "heavy"}}},
         "weighting"),
        ({"cur-weighted": {"algorithm": "cur", "set": {"learning.nope": 1}}},
         "no such config field"),
        ({}, "unknown algorithm 'cur-weighted'"),
    ):
        with pytest.raises(ValueError, match=match):
            Protocol.model_validate({**base, "ways": ways})


def test_the_shipped_learning_protocol_runs_cur_three_ways() -> None:
    proto = load_protocol(ROOT / "protocols" / "twin-learning.toml")
    assert proto.trials >= 6 and proto.evaluate_start
    assert [proto.algorithm_of(a) for a in proto.algorithms] == ["cur"] * 3
    ways = {a: (proto.fleet_of(a).learning.weighting, proto.fleet_of(a).algorithm.operators)
            for a in proto.algorithms}
    assert sorted(ways.values()) == [("intervention", "blind"), ("intervention", "matched"),
                                     ("uniform", "blind")]
    people = tomllib.loads((ROOT / "protocols" / "twin-learning.toml").read_text())[
        "fleet"]["humans"]["people"]
    assert [p.get("skill", 1.0) for p in people] == [1.0, 0.6]
    assert [p.get("latency", 0) for p in people] == [0, 2]


@pytest.mark.slow
def test_a_protocol_of_ways_reports_the_learning_gain_per_human_action(tmp_path: Path) -> None:
    proto = Protocol.model_validate({
        "name": "ways", "trials": 2, "algorithms": ["cur", "cur-weighted"], "steps": 8,
        "seeds": [3, 4], "out": str(tmp_path / "p"), "fleet": FLEET, "ways": WAYS,
        "evaluate_steps": 4, "evaluate_expert": False, "evaluate_start": True,
    })
    report = run_protocol(proto, ask=False)
    out = tmp_path / "p"
    for k in range(2):
        run = RunDir(out / f"cur-weighted-t{k}")
        meta = run.read_meta()
        assert meta["options"]["algorithm"] == "cur"
        assert meta["options"]["label"] == "cur-weighted"
        config = tomllib.loads((run.path / "config.toml").read_text())
        assert config["learning"]["weighting"] == "intervention"
        plain = tomllib.loads((out / f"cur-t{k}" / "config.toml").read_text())
        assert plain["learning"]["weighting"] == "uniform"
        start = json.loads((out / f"eval-theta0-t{k}" / "run.json").read_text())
        assert start["evaluates"]["algorithm"] == "theta0"
        assert start["evaluates"]["policy"] == str(out / f"{proto.run_order(k)[0]}-t{k}"
                                                   / "learner-start.pt")
    tables = {t.key: t for t in report.tables}
    gains = tables["gain-intervals"]
    assert [row[0] for row in gains.rows] == ["cur", "cur-weighted"]
    # the gain is what the report says it is: from the runs' and evaluations' summaries
    header = gains.csv_rows[0]
    for row in gains.csv_rows[1:]:
        way = row[0]
        values = []
        for k in range(2):
            alone = json.loads((out / f"eval-{way}-t{k}" / "summary.json").read_text())
            before = json.loads((out / f"eval-theta0-t{k}" / "summary.json").read_text())
            run = json.loads((out / f"{way}-t{k}" / "summary.json").read_text())
            values.append((alone["successes"] - before["successes"])
                          / run["human_actions"])
        mean = row[header.index("learning_gain_mean")]
        assert mean == pytest.approx(sum(values) / 2, abs=1e-6)
    paired = tables["gain-paired"]
    assert {r[0] for r in paired.rows} == {"cur-weighted"}
    assert {r[1] for r in paired.rows} >= {"learning_gain", "eval_successes", "rohe"}
    assert "What the humans taught" in (out / "report.md").read_text()
