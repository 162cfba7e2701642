"""The planner's fit finds the rates a run was made with.

The rows come from the real fleet loop in a world whose rates are set by hand
(``plan_fakes``): teleop requests at 0.4 per arm-step for the first 100 steps and 0.15
after, the policy's pushes succeeding 0.2 and violating 0.02, the expert's (the scripted
humans') 0.5 and 0.02, "bo" 2 steps late and away 30% of the time. Tolerances: four
binomial standard errors of the counts the fit had (plus the bins' prior, 0.02), so a
fit that reads the wrong rows (a held arm's key, a violating arm's push, another
human's push) fails while the sampling noise of these seeds never does.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from plan_fakes import Trouble, World, run_world

from testbed.core.config import ConfigError
from testbed.people.people_config import HumanProfile
from testbed.planning.plan_fit import PlanFit, fit_runs, key_order
from testbed.records.metrics import summarize
from testbed.records.steps import read_steps

WORLD = World(policy=(0.2, 0.02))
PEOPLE = [HumanProfile(name="ana"), HumanProfile(name="bo", latency=2, availability=0.7)]
BIN = 50


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    root = tmp_path_factory.mktemp("plan-fit")
    return [run_world(root / f"cur-t{s}", WORLD, arms=6, people=PEOPLE, steps=400, seed=s)
            for s in (1, 2)]


@pytest.fixture(scope="module")
def fit(runs: list[Path]) -> PlanFit:
    fits, notes = fit_runs(runs, BIN)
    assert len(fits) == 1 and notes == []
    return fits[0]


def near(k: float, n: float, truth: float, prior: float = 0.0) -> bool:
    """Is k/n within four binomial standard errors (and ``prior``) of ``truth``?"""
    return abs(k / n - truth) <= 4 * np.sqrt(truth * (1 - truth) / n) + prior


def test_the_fit_recovers_the_request_rates_by_phase(fit: PlanFit) -> None:
    assert (fit.bins, fit.own, fit.steps, fit.order) == (8, (6, 2), 400, "resets_first")
    for rates in (fit.requests, fit.continues):
        k, n = rates.arrays(fit.bins)
        early, late = slice(0, WORLD.switch // BIN), slice(WORLD.switch // BIN, None)
        assert near(k[early].sum(), n[early].sum(), WORLD.request_early)
        assert near(k[late].sum(), n[late].sum(), WORLD.request_late)
    means = fit.requests.means(fit.bins)
    k, n = fit.requests.arrays(fit.bins)
    for b in range(fit.bins):
        assert near(means[b] * n[b], n[b], WORLD.request(b * BIN), prior=0.02), (b, means)


def test_the_fit_recovers_the_pushes_of_the_policy_and_each_human(fit: PlanFit) -> None:
    policy = fit.policy.total()
    assert near(policy[0], policy.sum(), WORLD.policy[0])
    assert near(policy[1], policy.sum(), WORLD.policy[1])
    for h in fit.humans:
        pushes = h.pushes.total()
        assert pushes.sum() > 50, h.name
        assert near(pushes[0], pushes.sum(), WORLD.human[0]), h.name
        assert near(pushes[1], pushes.sum(), WORLD.human[1]), h.name


def test_the_fit_recovers_each_humans_times_and_availability(fit: PlanFit) -> None:
    ana, bo = fit.humans
    assert (ana.name, bo.name) == ("ana", "bo")
    assert set(ana.latency) == {0} and set(bo.latency) == {2}
    assert set(ana.reset_steps) == {WORLD.t_R} and set(bo.reset_steps) == {WORLD.t_R + 2}
    assert ana.away == 0 and ana.present == 800
    assert near(bo.present, bo.present + bo.away, 0.7)


def test_the_posterior_draws_centre_on_the_fit(fit: PlanFit) -> None:
    d = fit.draw(4000, np.random.default_rng(0))
    # a world without trouble: whatever EM calls trouble, a calm arm asks at the world's
    # rate by phase, and the draws are distributions
    assert d.trouble.calm_ask.shape == (4000, fit.bins)
    assert abs(d.trouble.calm_ask[:, -1].mean() - WORLD.request_late) < 0.05
    assert np.abs(d.trouble.calm_push.sum(axis=-1) - 1).max() < 1e-9
    assert d.available[:, 0].mean() > 0.99 and abs(d.available[:, 1].mean() - 0.7) < 0.05
    # Each human's times: their own observations (and a little of the pool's).
    cdf = d.latency_cdf.mean(axis=0)
    assert d.latency_values.tolist() == [0, 2] and cdf[0, 0] > 0.95 and cdf[1, 0] < 0.05
    assert d.reset_values.tolist() == [WORLD.t_R, WORLD.t_R + 2]


def test_what_the_fit_measured_is_what_the_summary_says(runs: list[Path],
                                                        fit: PlanFit) -> None:
    for path, measured in zip(runs, fit.measured, strict=True):
        s = summarize(read_steps(path / "steps.jsonl"), "cur", 2, 6)
        for k in ("successes", "hard_resets", "idle_time", "human_actions", "rohe"):
            assert measured[k] == pytest.approx(s[k])
        assert measured["utilisation"] == pytest.approx(s["human_actions"] / (2 * 400))
        assert 0 < measured["unserved"] < 1 and measured["wait"] > 0


@pytest.mark.parametrize(("algorithm", "order"), [
    ("cur", "resets_first"), ("random", "resets_first"), ("bc", "resets_first"),
    ("fleet-ed", "teleops_first"), ("fleet-td", "teleops_first"), ("u", "mixed"),
    ("ru", "mixed"), ("uc", "teleops_first")])
def test_the_key_order_is_the_registrys(algorithm: str, order: str) -> None:
    assert key_order(algorithm) == order


def test_evaluations_and_unfinished_runs_are_left_out_with_a_note(runs: list[Path],
                                                                   tmp_path: Path) -> None:
    folders = []
    for name, meta in (("eval-cur-t1", {"options": {"label": "eval:cur", "evaluate": True},
                                        "status": "complete"}),
                       ("cur-t9", {"options": {"label": "cur"}, "status": "running"})):
        d = tmp_path / name
        d.mkdir()
        (d / "steps.jsonl").write_text((runs[0] / "steps.jsonl").read_text())
        (d / "run.json").write_text(json.dumps(meta))
        folders.append(d)
    fits, notes = fit_runs([*folders, runs[0]])
    assert [f.label for f in fits] == ["cur"] and len(fits[0].runs) == 1
    assert any("evaluations" in n and "eval-cur-t1" in n for n in notes)
    assert any("unfinished (running" in n and "cur-t9" in n for n in notes)
    with pytest.raises(ConfigError, match="RUN_OR_PROTOCOL_DIR: no finished run to fit"):
        fit_runs(folders)


TROUBLE = World(policy=(0.2, 0.005), trouble=Trouble())


def test_the_fit_recovers_the_hidden_trouble(tmp_path: Path) -> None:
    """Arms with the planner's hidden state (plan_fakes.Trouble: into trouble at 0.08 a
    step, then asking at 0.9 and violating at 0.2 a push until a human's push fixes it
    at 0.9): EM finds every rate from the rows alone, apart from the calm arm's."""
    runs = [run_world(tmp_path / f"cur-t{s}", TROUBLE, arms=6, people=PEOPLE[:1], steps=300,
                      seed=s) for s in (1, 2)]
    fits, _ = fit_runs(runs, BIN)
    f = fits[0]
    c, tr = f.trouble, TROUBLE.trouble
    assert c is not None and tr is not None and len(f.trouble_runs) == 2

    def rate(kn: np.ndarray) -> float:
        return float(kn[0] / kn[1])

    assert abs(rate(c.trouble_ask) - tr.ask) < 0.06
    assert abs(rate(c.to_trouble) - tr.to_trouble) < 0.03
    assert abs(rate(c.recover) - tr.recover) < 0.04
    assert abs(rate(c.fixed) - tr.fixed) < 0.06
    assert abs(rate(c.start) - tr.start) < 0.08
    assert abs(c.trouble_push[1] / c.trouble_push.sum() - tr.push[1]) < 0.05
    calm = c.calm_push.sum(0)
    assert abs(calm[1] / calm.sum() - 0.005) < 0.01 and abs(calm[0] / calm.sum() - 0.2) < 0.03
    ask = c.calm_ask[:, 0] / c.calm_ask[:, 1]
    assert np.all(np.abs(ask[:2] - TROUBLE.request_early) < 0.06)
    assert np.all(np.abs(ask[2:] - TROUBLE.request_late) < 0.06)
    # the per-run counts add up to the whole, for the bootstrap over runs
    assert np.allclose(sum(r.calm_ask for r in f.trouble_runs), c.calm_ask)


def test_the_fit_keeps_each_persons_place_and_the_plan_says_it(tmp_path: Path) -> None:
    """A run with a remote person (``where``): no reset row is theirs, the fit reads the
    place from the run's config, and the plan says where its people are."""
    from testbed.planning.plan import PlanOptions, write_fits

    people = [HumanProfile(name="ana", where="remote"), HumanProfile(name="bo")]
    run = run_world(tmp_path / "cur-t1", WORLD, arms=4, people=people, steps=150, seed=4)
    rows = [r for s in read_steps(run / "steps.jsonl") for r in s["robots"]]
    assert any(r["mode"] == "reset" for r in rows)
    assert all(r["human"] == 1 for r in rows if r["mode"] == "reset")
    assert any(r["mode"] == "teleop" and r["human"] == 0 for r in rows)
    fits, _ = fit_runs([run], BIN)
    assert [(h.name, h.on_site) for h in fits[0].humans] == [("ana", False), ("bo", True)]
    plan = write_fits(fits, [], PlanOptions((4,), (1, 2), replicates=20), tmp_path / "plan")
    assert ("Places as in the runs (ana remote, bo on site): planned person j is fitted "
            "person j mod 2, in their place; only those on site reset.") in plan.markdown
