"""Protocols that stop when the answer is settled (issue 31's third part): the e-process
by betting, its false-positive rate under a symmetric null checked after every trial,
the futility rule, the stopping decision, the protocol's ``until`` field, the report's
table, and a real tiny protocol that stops, resumes and extends.

The e-process tests are numpy only (thousands of replays in well under a second); the
protocol test drives real twin hosts and the real learner, sized down, as
test_protocol_runs.py does.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.config import ConfigError
from testbed.core.humans import HumansStopRequested
from testbed.core.types import FleetStatus
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.protocol import Protocol, load_protocol, run_protocol, sequential_decision
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.records.steps import RunWriter
from testbed.results.report import write_report
from testbed.results.report_sequential import (
    FIXED_N_MARK,
    family_of,
    flag_fixed_n,
    sequential_table,
)
from testbed.results.report_tables import Table
from testbed.results.sequential import (
    CAP,
    RECORD,
    anytime_p,
    bets,
    decide,
    e_values,
    fewest_trials,
    reachable,
)

ALPHAS = (0.05, 0.1)


def _symmetric_nulls(rng: np.random.Generator, replays: int, trials: int
                     ) -> dict[str, np.ndarray]:
    """Paired differences with random signs, magnitudes of several shapes: what "no
    difference" looks like, whatever the metric."""
    signs = rng.choice([-1.0, 1.0], size=(replays, trials))
    scales = rng.uniform(0.1, 10.0, size=(1, trials))  # trials of very different spread
    return {
        "normal": signs * np.abs(rng.standard_normal((replays, trials))),
        "heavy tails": signs * np.abs(rng.standard_t(1.5, (replays, trials))),
        "counts with ties and zeros": signs * rng.integers(0, 4, (replays, trials)),
        "spread changing by trial": signs * scales * rng.exponential(1.0, (replays, trials)),
    }


@pytest.mark.parametrize("alpha", ALPHAS)
def test_under_a_symmetric_null_looking_after_every_trial_rejects_at_most_alpha(
        alpha: float) -> None:
    rng = np.random.default_rng(2026)
    for name, diffs in _symmetric_nulls(rng, 4000, 30).items():
        e = e_values(diffs)
        ever = np.mean((e >= 1 / alpha).any(axis=1))  # checked after every trial
        assert ever <= alpha, (name, ever)


def test_the_e_value_is_a_fair_game_over_each_trials_sign() -> None:
    """Exactly a martingale under the null: with trial k's sign flipped (all else the
    same), the two e-values at k average to the e-value at k - 1."""
    rng = np.random.default_rng(4)
    for name, diffs in _symmetric_nulls(rng, 200, 12).items():
        e = e_values(diffs)
        for k in range(12):
            flipped = diffs.copy()
            flipped[:, k] *= -1
            before = e[:, k - 1] if k else np.ones(len(e))
            assert np.allclose((e[:, k] + e_values(flipped)[:, k]) / 2, before,
                               rtol=1e-12, atol=0), (name, k)


def test_the_bet_and_the_scale_at_trial_k_see_only_the_trials_before_it() -> None:
    rng = np.random.default_rng(5)
    d = rng.normal(1.0, 2.0, 10)
    base = bets(d)
    for k in range(10):
        changed = d.copy()
        changed[k:] = rng.normal(-3.0, 5.0, 10 - k)  # trial k and later, anything
        other = bets(changed)
        assert np.array_equal(other.lam_up[:k + 1], base.lam_up[:k + 1])
        assert np.array_equal(other.lam_down[:k + 1], base.lam_down[:k + 1])
        assert np.array_equal(other.e[:k], base.e[:k])
    # trial 0 has no scale: its outcome is the difference's sign; later ones are
    # divided by half the mean |difference| before them, clipped to [-1, 1]
    b = bets([3.0, 1.0, -9.0, 0.0])
    assert b.x.tolist() == [1.0, 1.0 / 1.5, -1.0, 0.0]
    assert np.all((b.lam_up >= 0) & (b.lam_up <= CAP))
    assert np.all((b.lam_down <= 0) & (b.lam_down >= -CAP))
    # one trial is no evidence for a two-sided test: both wealths cancel
    assert bets([5.0]).e.tolist() == [1.0]


def test_many_replays_at_once_are_each_replay_alone() -> None:
    rng = np.random.default_rng(9)
    diffs = rng.normal(0.3, 1.0, (50, 12))
    together = e_values(diffs)
    for r in range(50):
        assert np.allclose(together[r], e_values(diffs[r]), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="finite"):
        e_values([1.0, float("nan")])


def test_a_real_difference_stops_before_max_trials() -> None:
    rng = np.random.default_rng(11)
    stops = []
    for _ in range(200):
        diffs = rng.normal(2.0, 1.0, 12)  # the algorithm above the reference by 2 sd
        for done in range(3, 13):
            decision = decide({"a": diffs[:done]}, alpha=0.05, min_trials=3, max_trials=12)
            if decision.stop:
                break
        stops.append(done)
        pair = decision.pairs["a"]
        if pair.settled_after is not None:
            assert pair.direction == 1 and decision.why == "every pair is settled"
            assert pair.e_values[pair.settled_after - 1] >= 20
    stops_ = np.asarray(stops)
    assert np.mean(stops_ < 12) >= 0.9 and np.median(stops_) <= 7
    # the same below: settled, pointing the other way
    decision = decide({"b": [-4.0, -5.0, -3.0, -6.0, -4.0, -5.0]}, alpha=0.05,
                      min_trials=2, max_trials=12)
    assert decision.stop and decision.pairs["b"].direction == -1
    assert decision.pairs["b"].settled_after == 6


def test_futility_stops_a_comparison_that_cannot_be_settled_in_time() -> None:
    # no difference at all: the e-value stays 1, and 1.9^r reaches 20 only for r >= 5
    assert reachable(1.0, 4) < 20 <= reachable(1.0, 5)
    for done in range(3, 8):
        d = decide({"a": [0.0] * done}, alpha=0.05, min_trials=3, max_trials=12)
        assert not d.stop and d.pairs["a"].status == "open"
    d = decide({"a": [0.0] * 8}, alpha=0.05, min_trials=3, max_trials=12)
    assert d.stop and d.pairs["a"].status == "cannot be settled"
    assert d.why == "no pair can be settled within max_trials (12)"
    # never before the minimum, always at the maximum
    assert not decide({"a": [0.0] * 8}, alpha=0.05, min_trials=10, max_trials=12).stop
    last = decide({"a": [1.0, -1.0] * 3}, alpha=0.05, min_trials=3, max_trials=6)
    assert last.stop and last.why == "max_trials (6) reached; not settled: a"
    # one settled, one hopeless: stop, and say which could not be settled
    both = decide({"big": [5.0] * 8, "none": [0.0] * 8}, alpha=0.05, min_trials=3,
                  max_trials=12)
    assert both.stop and both.pairs["big"].status == "settled"
    assert both.why.startswith("none cannot be settled within max_trials (12)")
    # one settled, one still open: go on
    assert not decide({"big": [5.0] * 6, "none": [0.0] * 6}, alpha=0.05, min_trials=3,
                      max_trials=12).stop


# ------------------------------------------------------------------ the protocol field
FLEET: dict[str, Any] = {
    "hosts": [{"name": "cell0"}],
    "humans": {"count": 1},
    "learning": {"ensemble_size": 2, "batch_size": 16, "demos": 16,
                 "critic_transitions": 8, "pretrain_steps": 4},
    "algorithm": {"random_budget": 1.0},
}


def test_until_is_checked_in_one_line_each() -> None:
    base: dict[str, Any] = {"name": "p", "trials": 3, "algorithms": ["bc", "cur"]}
    ok = Protocol.model_validate({**base, "until": {"max_trials": 12}})
    assert ok.until is not None and (ok.until.reference, ok.until.metric) == ("cur", "rohe")
    assert ok.until.alpha == 0.05 and ok.max_trials == 12
    assert Protocol.model_validate(base).max_trials == 3 and Protocol(name="p").until is None
    for until, extra, match in (
        ({"reference": "random"}, {}, "until.reference: 'random' is not one of"),
        ({"metric": "speed"}, {}, "unknown metric 'speed'"),
        ({"max_trials": 2}, {}, r"until.max_trials \(2\) is below trials \(3\)"),
        ({"alpha": 1.0}, {}, "alpha"),
        ({"max_trials": 200}, {}, "max_trials"),
        ({"when": "now"}, {}, "when"),
        ({"reference": "bc"}, {"algorithms": ["bc"]}, "at least two algorithms"),
        ({}, {"seeds": [1, 2]}, "seeds must have one seed per trial"),
    ):
        with pytest.raises(ValueError, match=match):
            Protocol.model_validate({**base, **extra, "until": until})
    # without until, seeds are one per trial exactly, as before
    with pytest.raises(ValueError, match="one seed per trial"):
        Protocol.model_validate({**base, "seeds": [1, 2, 3, 4]})


def test_trials_beyond_the_listed_seeds_get_seeds_after_the_largest() -> None:
    proto = Protocol.model_validate({"name": "p", "trials": 2, "algorithms": ["bc", "cur"],
                                     "seeds": [7, 5], "until": {"max_trials": 5}})
    assert [proto.seed(k) for k in range(5)] == [7, 5, 8, 9, 10]
    longer = proto.model_copy(update={"until": proto.until.model_copy(  # type: ignore[union-attr]
        update={"max_trials": 9})})
    assert [longer.seed(k) for k in range(5)] == [7, 5, 8, 9, 10]  # unchanged by the limit
    listed = Protocol.model_validate({"name": "p", "trials": 2, "algorithms": ["bc", "cur"],
                                      "seeds": [3, 4, 11], "until": {"max_trials": 5}})
    assert [listed.seed(k) for k in range(5)] == [3, 4, 11, 12, 13]
    plain = Protocol.model_validate({"name": "p", "trials": 2, "algorithms": ["bc", "cur"],
                                     "until": {"max_trials": 5}})
    assert [plain.seed(k) for k in range(5)] == [0, 1, 2, 3, 4]


def _fake_run(folder: Path, algorithm: str, trial: int, successes: int) -> None:
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t in range(10):
            w.write_step({"t": t, "robots": [
                {"robot": "h/a", "mode": "autonomous", "human": None, "action": 1,
                 "success": t < successes, "violation": False, "uncertainty": 0.1,
                 "risk": 0.0, "key": [0.0]}]})
    (folder / "run.json").write_text(json.dumps({
        "options": {"algorithm": algorithm}, "status": "complete",
        "protocol": {"name": "seq", "trial": trial}}))
    (folder / "summary.json").write_text("{}")


def test_the_decision_the_protocol_takes_from_its_runs_and_the_report_table(
        tmp_path: Path) -> None:
    """Synthetic runs through the function the protocol calls after each trial; bc is
    the primary endpoint, Fleet-ED secondary."""
    proto = Protocol.model_validate({
        "name": "seq", "trials": 3, "algorithms": ["bc", "fleet-ed", "cur"],
        "seeds": [1, 2, 3], "until": {"metric": "successes", "max_trials": 10,
                                      "primary": "bc"}})
    out = tmp_path / "p"
    for k in range(7):  # bc 4 below C.U.R. every trial; Fleet-ED alternately +-1
        _fake_run(out / f"cur-t{k}", "cur", k, 7)
        _fake_run(out / f"bc-t{k}", "bc", k, 3)
        _fake_run(out / f"fleet-ed-t{k}", "fleet-ed", k, 8 if k % 2 else 6)
    first = sequential_decision(proto, out, 3)
    assert not first.stop and first.trials == 3 and first.primary == ("bc",)
    rec = json.loads((out / RECORD).read_text())
    assert rec["trials_done"] == 3 and [t["seed"] for t in rec["trials"]] == [1, 2, 3]
    later = sequential_decision(proto, out, 6)
    assert later.stop and later.pairs["bc"].settled_after == 6
    assert later.pairs["bc"].direction == -1 and later.pairs["fleet-ed"].futile
    assert later.why == "the primary pair is settled"  # Fleet-ED is not waited for
    rec = json.loads((out / RECORD).read_text())
    assert (rec["primary"], rec["comparisons"], rec["family"]) == (["bc"], 1, {})
    assert rec["alpha"] == rec["family_alpha"] == 0.05 and rec["protocol"] == "seq"
    assert rec["pairs"]["bc"]["differences"] == [-4.0] * 6
    assert [t["e_values"]["bc"] for t in rec["trials"]] == rec["pairs"]["bc"]["e_values"]
    assert [t["seed"] for t in rec["trials"]] == [1, 2, 3, 4, 5, 6]
    # the report: the table right after the paired comparison, and its CSV
    report = write_report([out], tmp_path / "rep")
    keys = [t.key for t in report.tables]
    assert keys.index("sequential") == keys.index("learning-paired") + 1
    table = report.tables[keys.index("sequential")]
    rows = {r[0]: r for r in table.rows}
    assert table.header[1] == "endpoint" and rows["bc"][1] == "primary"
    assert rows["bc"][4] == "after 6 trials (t5): below cur" and rows["bc"][9] == "4"
    assert rows["fleet-ed"][1] == "secondary"
    assert rows["fleet-ed"][8] == "secondary: no sequential claim" and rows["fleet-ed"][4] == "-"
    assert "saved 4 trials (12 runs of 3 algorithms" in table.notes[0]
    assert "Secondary endpoint: fleet-ed" in table.notes[2]
    assert "Ville's inequality" in table.notes[3]
    # the anytime p beside the e-value: 1 / the largest e-value (six -4s: e 23.57)
    assert table.header[6] == "anytime p (1 / max e)"
    bc_e = rec["pairs"]["bc"]["e_values"]
    assert rows["bc"][6] == f"{1 / max(bc_e):.3g}" == "0.0424"
    fe_e = rec["pairs"]["fleet-ed"]["e_values"]
    assert rows["fleet-ed"][6] == f"{min(1.0, 1 / max(fe_e)):.3g}"
    # the confidence sequence: below 0 (settled below), to -1 (every outcome clipped)
    assert table.header[7] == "confidence sequence (0.95, clipped scale)"
    low, high = (float(x) for x in rows["bc"][7].strip("[]").split(", "))
    assert low == -1.0 and -0.05 < high < 0
    # one primary comparison, no family: alpha 0.05 unsplit, 6 trials at the fewest
    assert ("over the family's 1 primary comparison: 1 primary comparison here (bc)"
            in table.notes[1] and "settle a pair in at 0.05: 6 trials" in table.notes[1])
    csv = (tmp_path / "rep" / "report-sequential.csv").read_text().splitlines()
    assert csv[0].split(",")[:4] == ["algorithm", "endpoint", "metric", "trials"]
    # the fixed-n figures of the paired and the intervals tables flagged here, and not in
    # a fixed protocol
    paired = report.tables[keys.index("learning-paired")]
    assert paired.header[4:6] == [f"95% interval {FIXED_N_MARK}", f"sign-flip p {FIXED_N_MARK}"]
    assert paired.notes[0].startswith(f"{FIXED_N_MARK} fixed-n figures, not valid after "
                                      "optional stopping")
    ivs = report.tables[keys.index("learning-intervals")]
    assert ivs.header[:2] == ["algorithm", "trials"]
    assert all(h.endswith(FIXED_N_MARK) for h in ivs.header[2:])
    assert "intervals of the means over trials" in ivs.notes[0]
    (out / RECORD).rename(tmp_path / "kept.json")
    fixed = write_report([out], tmp_path / "rep-fixed")
    plain = fixed.tables[[t.key for t in fixed.tables].index("learning-paired")]
    assert plain.header[4:6] == ["95% interval", "sign-flip p"]
    assert not any(FIXED_N_MARK in n for n in plain.notes) and FIXED_N_MARK not in fixed.markdown
    (tmp_path / "kept.json").rename(out / RECORD)
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "Sequential test: each algorithm against cur on successes" in md
    page = (tmp_path / "rep" / "report.html").read_text()
    assert '<section id="sequential">' in page and "after 6 trials (t5): below cur" in page
    # a file this build cannot read: said, not a crash
    (out / RECORD).write_text('{"format": "sequential/0"}')
    report = write_report([out], tmp_path / "rep2")
    assert "cannot be read by this build" in report.markdown


def test_a_record_from_before_endpoints_reads_every_pair_primary_at_the_split() -> None:
    """Old sequential.json files (no primary, no family): both pairs primary, alpha /
    2 each, so six -4s (e 23.6 < 40) are not settled here though the protocol said so."""
    d = [-4.0] * 6
    e = [float(x) for x in e_values(d)]
    rec = {"format": "sequential/1", "reference": "cur", "metric": "rohe", "alpha": 0.05,
           "threshold": 20.0, "min_trials": 3, "max_trials": 12, "trials_done": 6,
           "cap": CAP, "stop": True, "why": "every pair is settled",
           "pairs": {"a": {"differences": d, "e_values": e, "settled_after": 6,
                           "direction": -1, "status": "settled"},
                     "b": {"differences": d, "e_values": e, "settled_after": 6,
                           "direction": -1, "status": "settled"}}}
    fam = family_of(rec)
    assert (fam.comparisons, fam.per_comparison, fam.declared) == (2, 0.025, False)
    table = sequential_table(rec)
    rows = {r[0]: r for r in table.rows}
    assert rows["a"][1] == "primary" and rows["a"][4] == "-" and rows["a"][8] == "open"
    assert table.title.endswith("settled at e-value >= 40 (per-comparison alpha 0.025)")
    assert "It decided at alpha 0.05 per pair" in table.notes[0]
    assert "predates declared endpoints" in table.notes[1]
    assert "settle a pair in at 0.025: 7 trials" in table.notes[1]
    low, high = (float(x) for x in rows["a"][7].strip("[]").split(", "))
    assert low == -1.0 and high > 0  # at 97.5 %, 0 is still inside after six
    # declared: a family of two protocols, one primary here
    new = {**rec, "primary": ["a"], "family": {"other": 1}, "comparisons": 2,
           "family_alpha": 0.05, "alpha": 0.025, "threshold": 40.0}
    table = sequential_table(new)
    rows = {r[0]: r for r in table.rows}
    assert rows["b"][1] == "secondary" and "other (1)" in table.notes[1]
    assert "It decided at" not in table.notes[0]


def test_every_table_with_fixed_n_figures_is_flagged_and_no_other() -> None:
    gain = Table("gain-intervals", "g", ["algorithm", "trials", "learning_gain"], [])
    gp = Table("gain-paired", "g", ["algorithm", "metric", "per trial", "mean difference",
                                    "95% interval", "sign-flip p", "pairs"], [])
    auroc = Table("prediction-auroc", "a", ["algorithm", "signal"], [], ["n1"])
    humans = Table("humans", "h", ["algorithm"], [], ["n"])
    assert flag_fixed_n(gain).header[2] == f"learning_gain {FIXED_N_MARK}"
    assert flag_fixed_n(gp).header[4:6] == [f"95% interval {FIXED_N_MARK}",
                                            f"sign-flip p {FIXED_N_MARK}"]
    flagged = flag_fixed_n(auroc)
    assert flagged.header == auroc.header and flagged.notes[0].startswith(FIXED_N_MARK)
    assert "intervals over runs" in flagged.notes[0] and flagged.notes[1] == "n1"
    assert flag_fixed_n(humans) is humans


def test_primary_and_family_are_checked_in_one_line_each(tmp_path: Path) -> None:
    base: dict[str, Any] = {"name": "p", "trials": 3, "algorithms": ["bc", "fleet-ed", "cur"]}
    old = Protocol.model_validate({**base, "until": {}})
    assert old.until is not None and old.until.primaries(old.algorithms) == ["bc", "fleet-ed"]
    assert old.until.per_comparison_alpha(old.algorithms) == 0.025
    new = Protocol.model_validate({**base, "until": {"primary": "bc", "family": {"q": 2}}})
    assert new.until is not None and new.until.comparisons(new.algorithms) == 3
    assert new.until.per_comparison_alpha(new.algorithms) == pytest.approx(0.05 / 3)
    for until, match in (({"primary": "cur"}, "until.primary: 'cur' is not one of the "
                          "algorithms compared with 'cur'; use one of bc, fleet-ed"),
                         ({"primary": "random"}, "until.primary: 'random' is not one"),
                         ({"family": {"p": 1}}, "until.family: names this protocol"),
                         ({"family": {"q": 0}}, "until.family.q")):
        path = tmp_path / "p.toml"
        fam = ", ".join(f"{k} = {v}" for k, v in until.get("family", {}).items())
        extra = (f'primary = "{until["primary"]}"' if "primary" in until
                 else f"family = {{ {fam} }}")
        path.write_text('name = "p"\ntrials = 3\nalgorithms = ["bc", "fleet-ed", "cur"]\n'
                        f"until = {{ {extra} }}\n[fleet]\nname = \"x\"\n")
        with pytest.raises(ConfigError, match=match) as err:
            load_protocol(path, check_files=False)
        assert "\n" not in str(err.value)


def test_a_secondary_pair_neither_holds_nor_stops_the_protocol() -> None:
    settled, unsure = [-4.0] * 6, [1.0, -1.0] * 3
    d = decide({"a": settled, "b": unsure}, alpha=0.05, min_trials=3, max_trials=20,
               primary=["a"])
    assert d.stop and d.why == "the primary pair is settled"
    both = decide({"a": settled, "b": unsure}, alpha=0.05, min_trials=3, max_trials=20)
    assert both.pairs["b"].status == "open"
    assert not both.stop and both.primary == ("a", "b")
    waits = decide({"a": settled, "b": unsure}, alpha=0.05, min_trials=3, max_trials=20,
                   primary=["b"])
    assert not waits.stop
    with pytest.raises(ValueError, match="not a pair"):
        decide({"a": settled}, alpha=0.05, min_trials=3, max_trials=20, primary=["z"])


def test_the_anytime_p_is_one_over_the_largest_e_value_so_far() -> None:
    """Not the last e-value (it can fall back), never above 1, 1 with no trial."""
    assert anytime_p([1.0, 1.855, 25.0, 12.5]) == pytest.approx(1 / 25.0)
    assert anytime_p([1.0, 0.5, 0.2]) == 1.0 and anytime_p([]) == 1.0
    e = e_values([-4.0] * 6)
    assert anytime_p(e) == pytest.approx(1 / float(e[-1])) == pytest.approx(0.04242, abs=1e-5)
    wobbly = e_values([3.0, 2.0, 4.0, -9.0, -8.0])
    assert wobbly[-1] < wobbly.max()
    assert anytime_p(wobbly) == pytest.approx(1 / float(wobbly.max()))


@pytest.mark.parametrize("alpha", [0.2, 0.1, 0.05, 0.025, 0.05 / 3, 0.01])
def test_the_fewest_trials_match_every_sign_pattern_tried_by_brute_force(alpha: float) -> None:
    """Over every sign pattern of n equal-sized differences (and random sizes), no
    e-value reaches 1/alpha before the fewest trials, and one does at it."""
    n_min = fewest_trials(alpha)
    rng = np.random.default_rng(5)
    assert n_min is not None

    def best(n: int) -> float:
        signs = ((np.arange(2 ** n)[:, None] >> np.arange(n)) & 1) * 2.0 - 1.0
        sizes = rng.uniform(0.1, 10.0, (2 ** n, n))
        return float(max(e_values(signs).max(), e_values(signs * sizes).max()))

    assert best(n_min) >= 1 / alpha
    assert all(best(n) < 1 / alpha for n in range(1, n_min))
    assert fewest_trials(0.05) == 6 and fewest_trials(0.025) == 7
    assert fewest_trials(0.05, limit=5) is None


class _StopAt(ScriptedHumans):
    """The operator presses Esc during step ``k``'s overview."""

    def __init__(self, k: int) -> None:
        super().__init__()
        self.k = k

    def show(self, t: int, status: FleetStatus) -> None:
        if t == self.k:
            raise HumansStopRequested("Esc")


@pytest.mark.slow
def test_a_protocol_with_until_stops_resumes_and_extends(tmp_path: Path) -> None:
    """bc against Random with every human busy (random_budget 1): Random's human actions
    are above BC's in every trial, a difference planted by the fleet itself."""
    out = tmp_path / "p"
    spec: dict[str, Any] = {
        "name": "seq", "trials": 2, "algorithms": ["bc", "random"], "steps": 4,
        "out": str(out), "fleet": FLEET, "evaluate_steps": 0,
        "until": {"reference": "bc", "metric": "human_actions", "max_trials": 4}}
    started: list[str] = []
    stops: list[str] = []

    class Hooks(TrialHooks):
        def before_run(self, name: str) -> bool:
            started.append(name)
            return True

        def humans(self, name: str) -> ScriptedHumans:
            if name in stops:
                stops.remove(name)
                return _StopAt(1)
            return ScriptedHumans()

    # at most 4 trials: after 2, even winning every trial left cannot reach 20
    run_protocol(Protocol.model_validate(spec), ask=False, hooks=Hooks())
    rec = json.loads((out / RECORD).read_text())
    assert started == ["bc-t0", "random-t0", "bc-t1", "random-t1"]
    assert rec["trials_done"] == 2 and rec["stop"]
    assert rec["pairs"]["random"]["status"] == "cannot be settled"
    assert all(d > 0 for d in rec["pairs"]["random"]["differences"])
    # raised to 8: it goes on from trial 2; the operator stops trial 3's first run
    spec["until"]["max_trials"] = 8
    stops.append("bc-t3")
    started.clear()
    stopped = run_protocol(Protocol.model_validate(spec), ask=False, hooks=Hooks())
    assert started == ["bc-t2", "random-t2", "bc-t3"]
    assert any("bc-t3" in n for n in stopped.notes)
    rec = json.loads((out / RECORD).read_text())
    assert rec["trials_done"] == 3 and not rec["stop"]
    # run again: it resumes bc-t3, then runs until the pair is settled
    started.clear()
    report = run_protocol(Protocol.model_validate(spec), ask=False, hooks=Hooks())
    rec = json.loads((out / RECORD).read_text())
    assert started[:2] == ["bc-t3", "random-t3"]
    pair = rec["pairs"]["random"]
    assert pair["status"] == "settled" and pair["direction"] == 1
    assert rec["stop"] and rec["why"] == "every pair is settled"
    done = rec["trials_done"]
    assert done == pair["settled_after"] < 8
    assert [t["trial"] for t in rec["trials"]] == list(range(done))
    assert sorted(p.name for p in out.glob("*-t*")) == sorted(
        f"{a}-t{k}" for a in ("bc", "random") for k in range(done))
    assert {t.key for t in report.tables} >= {"sequential", "learning-paired"}
    # once more: nothing left to run, the same decision
    started.clear()
    run_protocol(Protocol.model_validate(spec), ask=False, hooks=Hooks())
    assert started == [] and json.loads((out / RECORD).read_text()) == rec
