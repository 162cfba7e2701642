"""The trials planner (``testbed plan --trials``, issue 31's second part): the sign-flip
count against a brute-force enumeration, the t approximation against textbook values,
the sign-flip power by simulation, and the Markdown from a pilot's run folders."""

from __future__ import annotations

import itertools
import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from testbed.core.config import ConfigError
from testbed.planning.plan_trials import (
    extreme_patterns,
    floor_trials,
    normal_trials,
    plan_trials,
    sign_flip_power,
    sign_flip_ps,
    t_power,
    t_trials,
)
from testbed.records.steps import RunWriter
from testbed.results.intervals import sign_flip_p


def _brute(diffs: list[Fraction]) -> int:
    """Every sign pattern, in exact arithmetic: how many reach the observed |sum|."""
    observed = abs(sum(diffs))
    return sum(1 for signs in itertools.product((-1, 1), repeat=len(diffs))
               if abs(sum(s * d for s, d in zip(signs, diffs, strict=True))) >= observed)


def test_the_sign_flip_count_is_the_enumeration_and_the_reports_p_value() -> None:
    rng = np.random.default_rng(7)
    for n in range(1, 11):
        for _ in range(6):
            # small integers (many ties, the hard case) and quarters (exact in floats)
            ints = [Fraction(int(v)) for v in rng.integers(-3, 4, n)]
            quarters = [Fraction(int(v), 4) for v in rng.integers(-40, 41, n)]
            for diffs in (ints, quarters):
                count = extreme_patterns([float(d) for d in diffs])
                assert count == _brute(diffs), diffs
                if n > 1:
                    assert count / 2 ** n == pytest.approx(
                        sign_flip_p([float(d) for d in diffs]), abs=1e-12)
        floats = rng.normal(size=n)
        if n > 1:
            assert extreme_patterns(floats) / 2 ** n == pytest.approx(sign_flip_p(floats),
                                                                       abs=1e-12)
    # the batch p-values are the same counts, row by row
    rows = rng.integers(-2, 3, (20, 7)).astype(float)
    assert sign_flip_ps(rows).tolist() == [extreme_patterns(r) / 2 ** 7 for r in rows]
    assert extreme_patterns([0.0, 0.0, 0.0]) == 8  # every pattern ties 0: p = 1
    assert extreme_patterns([2.0, 2.0, 2.0]) == 2  # only all + and all -: the floor


def test_the_floor_is_the_fewest_pairs_that_can_reach_alpha() -> None:
    assert floor_trials(0.05) == 6  # 2/32 = 0.0625 > 0.05 >= 2/64
    assert floor_trials(0.25) == 3
    assert floor_trials(0.01) == 8


def test_the_t_approximation_gives_the_textbook_sample_sizes() -> None:
    # paired t, two-sided alpha 0.05, power 0.8 (Cohen 1988; G*Power): d_z = 0.5 needs
    # 34 pairs, d_z = 1 needs 10, d_z = 0.8 needs 15
    assert t_trials(0.5, 0.05, 0.8, 100)[0] == 34
    assert t_trials(1.0, 0.05, 0.8, 100)[0] == 10
    assert t_trials(0.8, 0.05, 0.8, 100)[0] == 15
    assert t_power(0.5, 34, 0.05) == pytest.approx(0.8078, abs=1e-3)
    # the normal formula with Guenther's correction: 31.4 + 1.92 -> 34
    assert normal_trials(0.5, 0.05, 0.8) == 34
    assert normal_trials(0.0, 0.05, 0.8) == float("inf")
    assert t_trials(0.1, 0.05, 0.8, 20) == (None, pytest.approx(t_power(0.1, 20, 0.05)))


def test_sign_flip_power_sits_above_the_floor_and_near_the_t_tests() -> None:
    rng = np.random.default_rng(3)
    huge = 5 + 0.01 * rng.standard_normal((500, 20))  # every pair positive
    assert sign_flip_power(huge, 0.05, 0.8, 20) == (6, 1.0)  # exactly the floor
    null = rng.standard_normal((500, 12))
    n, share = sign_flip_power(null, 0.05, 0.8, 12)
    assert n is None and share <= 0.08  # no difference: about alpha, whatever n
    d1 = 1 + rng.standard_normal((1000, 30))
    n1, _ = sign_flip_power(d1, 0.05, 0.8, 30)
    # d = 1: t needs 10; the sign-flip test a little more, never fewer than its floor
    assert n1 is not None and 10 <= n1 <= 13


def _run(folder: Path, algorithm: str, trial: int, successes: int) -> None:
    folder.mkdir(parents=True)
    with RunWriter(folder) as w:
        for t in range(12):
            w.write_step({"t": t, "robots": [
                {"robot": "h/a", "mode": "autonomous", "human": None, "action": 1,
                 "success": t < successes, "violation": False, "uncertainty": 0.1,
                 "risk": 0.0, "key": [0.0]}]})
    (folder / "run.json").write_text(json.dumps({
        "options": {"algorithm": algorithm}, "status": "complete",
        "protocol": {"name": "pilot", "trial": trial}}))


def test_plan_trials_reads_a_pilot_and_shows_both_answers(tmp_path: Path) -> None:
    pilot = tmp_path / "pilot"
    for k, (cur, bc, rnd) in enumerate([(8, 5, 8), (9, 5, 7), (7, 3, 8), (8, 4, 9)]):
        _run(pilot / f"cur-t{k}", "cur", k, cur)
        _run(pilot / f"bc-t{k}", "bc", k, bc)
        _run(pilot / f"random-t{k}", "random", k, rnd)
    _run(pilot / "eval-cur-t0", "eval:cur", 0, 1)  # an evaluation: not a learning row
    md = plan_trials([pilot], reference=None, metric="successes", alpha=0.05, power=0.8,
                     max_trials=30)
    assert md.startswith("# Trials a comparison needs")
    assert "reference cur; metric successes" in md and "fewer than 6 pairs" in md
    rows = {line.split(" | ")[0].lstrip("| "): line.split(" | ") for line in md.splitlines()
            if line.startswith("| ") and "algorithm" not in line}
    assert set(rows) == {"bc", "random"}
    bc = rows["bc"]  # -3, -4, -4, -4: mean -3.75, sd 0.5
    assert bc[1] == "4" and bc[2] == "t0: -3.0, t1: -4.0, t2: -4.0, t3: -4.0"
    assert bc[3] == "-3.8" and bc[4] == "0.5"
    assert bc[6].startswith("6 (") and bc[7].startswith("6 (")  # a huge effect: the floor
    assert bc[8].startswith("2 (") or bc[8].startswith("3 (")
    rnd = rows["random"]  # 0, -2, +1, +1: mean 0, no answer within 30
    assert rnd[6].startswith("> 30") and rnd[8].startswith("> 30")
    assert "noncentral t" in md and "Guenther" in md
    # the reference and the metric as asked; errors in one line
    md = plan_trials([pilot], reference="bc", metric="rohe", alpha=0.1, power=0.9,
                     max_trials=12)
    assert "reference bc; metric rohe" in md and "| cur |" in md
    for kwargs, match in (({"reference": "fleet-td"}, "--reference"),
                          ({"metric": "speed"}, "--metric"),
                          ({"alpha": 1.5}, "--alpha"),
                          ({"max_trials": 1}, "--max-trials")):
        args = {"reference": None, "metric": "rohe", "alpha": 0.05, "power": 0.8,
                "max_trials": 30} | kwargs
        with pytest.raises(ConfigError, match=match):
            plan_trials([pilot], **args)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="no finished learning run"):
        plan_trials([tmp_path / "nothing"], reference=None, metric="rohe", alpha=0.05,
                    power=0.8, max_trials=30)
