"""The planner's simulation is Algorithm 1, and replays the loop's world.

* ``BatchAllocator`` (the planner's vectorised allocation) against the real
  ``testbed.fleet.allocator.Allocator`` on the same requests, step by step: the same
  assignments, kinds and served counts, with keys that tie (so the tie draw, reproduced
  from each allocator's seed, decides too), away humans, M above and below N, K = 1..3.
* the whole simulation gives the same numbers whichever engine allocates (the real
  allocators one replicate after another, or the batch), for each key order.
* with the world's true rates (no fit), the simulation's means are the real loop's
  (``plan_fakes``: the real ``FleetLoop`` and scripted humans in a world of known rates)
  at fleet sizes other than the fit's: what makes it a model of the loop.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from plan_fakes import Trouble, World, run_world

from testbed.fleet.allocator import Allocator
from testbed.people.people_config import HumanProfile
from testbed.planning.plan_fit import METRICS, Draws, KeyOrder, fit_runs
from testbed.planning.plan_sim import BatchAllocator, FleetShape, sim_params, simulate
from testbed.planning.plan_trouble import TroubleDraws


@pytest.mark.parametrize(("n", "m", "k"), [(7, 3, 2), (3, 5, 3), (9, 1, 1), (6, 6, 2)])
def test_the_batch_allocator_is_algorithm_1_on_the_same_requests(n: int, m: int,
                                                                  k: int) -> None:
    replicates, t_T, t_R = 5, 2, 3
    real = [Allocator(n, m, t_T, t_R, seed=s) for s in range(replicates)]
    streams = [np.random.default_rng(s) for s in range(replicates)]  # the allocators' own
    batch = BatchAllocator(replicates, n, m, t_T, t_R)
    rng = np.random.default_rng(42)
    viol = np.zeros((replicates, n), dtype=bool)
    kinds_seen: set[int] = set()
    for _ in range(400):
        viol = (viol & (rng.random((replicates, n)) > 0.3)) | (rng.random((replicates, n)) < 0.1)
        keys = rng.choice([-1.0, 0.0, 0.0, 0.5, 1.0], size=(replicates, n, k))  # ties galore
        available = rng.random((replicates, m)) < 0.8
        tie = np.stack([s.random(n) for s in streams])
        human, kind, served = batch.step(keys, viol, available, tie)
        for r, a in enumerate(real):
            assert a.step(keys[r], viol[r], available[r]).tolist() == human[r].tolist()
            assert a.kind_codes.tolist() == kind[r].tolist()
            assert a.served.tolist() == served[r].tolist()
        kinds_seen |= set(kind.ravel().tolist())
    assert kinds_seen == {0, 1, 2}  # teleops and resets both happened


@pytest.mark.parametrize(("n", "m", "on_site"), [
    (7, 3, [True, False, False]), (3, 5, [False, True, False, True, False]),
    (6, 6, [True, False] * 3), (9, 2, [False, True]), (4, 1, [False])])
def test_the_batch_allocator_follows_the_allocator_with_remote_people(
        n: int, m: int, on_site: list[bool]) -> None:
    # Only the on-site people reset (issue 44), candidate by candidate in key order, in
    # both engines: the same assignments, kinds and served counts, ties included.
    replicates, t_T, t_R = 5, 2, 3
    real = [Allocator(n, m, t_T, t_R, seed=s, on_site=np.array(on_site))
            for s in range(replicates)]
    streams = [np.random.default_rng(s) for s in range(replicates)]
    batch = BatchAllocator(replicates, n, m, t_T, t_R, on_site=on_site)
    rng = np.random.default_rng(43)
    viol = np.zeros((replicates, n), dtype=bool)
    resets = 0
    for _ in range(300):
        viol = (viol & (rng.random((replicates, n)) > 0.3)) | (rng.random((replicates, n)) < 0.1)
        keys = rng.choice([-1.0, 0.0, 0.0, 0.5, 1.0], size=(replicates, n, 2))
        available = rng.random((replicates, m)) < 0.8
        tie = np.stack([s.random(n) for s in streams])
        human, kind, served = batch.step(keys, viol, available, tie)
        for r, a in enumerate(real):
            assert a.step(keys[r], viol[r], available[r]).tolist() == human[r].tolist()
            assert a.kind_codes.tolist() == kind[r].tolist()
            assert a.served.tolist() == served[r].tolist()
        assert np.array(on_site)[human[kind == 2]].all()
        resets += int((kind == 2).sum())
    assert resets > 0 or not any(on_site)


def test_the_plan_places_its_people_as_the_runs_or_as_asked() -> None:
    from testbed.planning.plan import planned_on_site
    from testbed.planning.plan_fit import HumanFit, PlanFit

    fit = PlanFit("cur", "cur", [], [], 10, 2, 3, 0, 50, "resets_first", False,
                  humans=[HumanFit(0, "ana", False), HumanFit(1, "bo", True)])
    # planned person j is fitted person j mod H, in their place ...
    assert planned_on_site(fit, 4).tolist() == [False, True, False, True]
    # ... but a fleet with people has one on site, as its config must
    assert planned_on_site(fit, 1).tolist() == [True]
    assert planned_on_site(fit, 3, on_site=1).tolist() == [True, False, False]
    assert planned_on_site(PlanFit("x", "cur", [], [], 10, 2, 3, 0, 50, "resets_first",
                                   False), 2).tolist() == [True, True]


def truth(world: World, replicates: int, bins: int, bin_steps: int, *,
          available: tuple[float, float] = (1.0, 0.7), eligible: float = 1.0) -> Draws:
    """The world's own rates as one draw per replicate (no fit): ana instant, bo 2
    steps late to a first push and to finish a reset, and away 30% of the time."""
    req = np.array([world.request(b * bin_steps) for b in range(bins)])
    tr = world.trouble or Trouble(ask=0.5, push=world.policy, to_trouble=0.0, recover=1.0,
                                  fixed=1.0, start=0.0)  # never in trouble
    s, v = world.policy
    ts, tv = tr.push
    hs, hv = world.human
    r = replicates

    def each(x: float) -> np.ndarray:
        return np.full(r, x)

    hidden = TroubleDraws(
        calm_ask=np.tile(req, (r, 1)), trouble_ask=each(tr.ask),
        to_trouble=each(tr.to_trouble), recover=each(tr.recover), fixed=each(tr.fixed),
        start=each(tr.start), calm_push=np.tile([s, v, 1 - s - v], (r, bins, 1)),
        trouble_push=np.tile([ts, tv, 1 - ts - tv], (r, 1)))
    return Draws(
        trouble=hidden, eligible=np.full((replicates, bins), eligible),
        human=np.tile([hs, hv, 1 - hs - hv], (replicates, 2, 1)),
        available=np.tile(available, (replicates, 1)),
        latency_values=np.array([0, 2]),
        latency_cdf=np.tile([[1.0, 1.0], [0.0, 1.0]], (replicates, 1, 1)),
        reset_values=np.array([world.t_R, world.t_R + 2]),
        reset_cdf=np.tile([[1.0, 1.0], [0.0, 1.0]], (replicates, 1, 1)))


@pytest.mark.parametrize(("order", "initial"), [("resets_first", True),
                                                ("teleops_first", False), ("mixed", False)])
def test_the_simulation_allocates_as_the_real_allocator(order: KeyOrder,
                                                        initial: bool) -> None:
    world = World(policy=(0.2, 0.06))
    draws = truth(world, 8, 3, 50, eligible=0.6)
    shape = FleetShape(world.t_T, world.t_R, 20, 50, order, initial)
    got = {engine: simulate(sim_params(draws, 3), shape, 7, 3, 120, seed=5, engine=engine)
           for engine in ("batch", "real")}
    for metric in METRICS:
        np.testing.assert_array_equal(got["batch"][metric], got["real"][metric])
    busy = got["batch"]
    assert (busy["hard_resets"] > 0).all() and (busy["human_actions"] > 0).all()
    assert (busy["unserved"] > 0).all()  # the humans were short: the allocation mattered
    # one person on site of three: the engines still agree, and resets wait longer
    places = {engine: simulate(sim_params(draws, 3, [False, True, False]), shape, 7, 3, 120,
                               seed=5, engine=engine) for engine in ("batch", "real")}
    for metric in METRICS:
        np.testing.assert_array_equal(places["batch"][metric], places["real"][metric])
    assert places["batch"]["wait"].mean() > busy["wait"].mean()


@pytest.mark.parametrize("world", [
    World(policy=(0.2, 0.02)), World(policy=(0.2, 0.005), trouble=Trouble())],
    ids=["calm", "trouble"])
@pytest.mark.slow
def test_the_simulation_with_the_true_rates_measures_what_the_loop_measures(
        world: World, tmp_path: Path) -> None:
    # The loop's runs at two fleet sizes against the simulation's 400 replicates of the
    # same world: every metric's mean within 3.5 standard errors (with these seeds the
    # largest is ~1.3). With trouble, an arm falls into a state where it asks at 0.9 and
    # violates 40 times as often until a human's push fixes it: the simulation must
    # move the same hidden states as the loop's arms.
    people = [HumanProfile(name="ana"), HumanProfile(name="bo", latency=2, availability=0.7)]
    shape = FleetShape(world.t_T, world.t_R, 0, 50, "resets_first", False)
    draws = truth(world, 400, 4, 50)
    for n, m in ((4, 1), (9, 3)):
        sim = simulate(sim_params(draws, m), shape, n, m, 200, seed=1)
        runs = [run_world(tmp_path / f"n{n}m{m}s{s}", world, arms=n, steps=200, seed=100 + s,
                          people=[people[h % 2] for h in range(m)]) for s in range(6)]
        measured = fit_runs(runs, 50)[0][0].measured
        for metric in METRICS:
            x = np.array([row[metric] for row in measured])
            v = sim[metric]
            se = np.sqrt(v.var() / x.size + v.var() / v.size)
            assert abs(x.mean() - v.mean()) <= 3.5 * se + 1e-9, (n, m, metric, x, v.mean())
