"""The sequential test's edges that a mutation run found untested.

Why: testbed/results/sequential.py decides when an `until` protocol stops and what its
record (sequential.json) says a comparison showed; scripts/mutation.sh showed changes to
it that no test noticed (docs/notes/tests.md, "Tests that can fail"). The expected
values are derived by hand from the module docstring's rules. The one fact most of them
use: n outcomes of +1 (or n of -1) bet both wealths at their cap 0.9 on the first, the
growing one at 0.9 every time after (its running mean stays near 1, its variance near
0), the other at 0 from the second on, so the e-value after n is (1.9^n + 0.1) / 2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.results.sequential import (
    Decision,
    _finite,
    anytime_p,
    bets,
    confidence_sequence,
    decide,
    fewest_trials,
    outcomes,
    reachable,
    record,
)

# 1 / this float is exactly the e-value after four outcomes of +1, (1.9^4 + 0.1) / 2
AT_FOUR = 0.1522985661090001
# 1 / this float is exactly 1.9^2 = 3.61, what two more trials can multiply e = 1 by
AT_TWO_MORE = 0.2770083102493075


def _e_same_sign(n: int) -> float:
    return (1.9 ** n + 0.1) / 2


def test_the_e_value_of_same_sign_outcomes_by_hand() -> None:
    assert bets([4.0] * 6).e.tolist() == pytest.approx([_e_same_sign(n) for n in range(1, 7)],
                                                       rel=1e-12)
    assert bets([4.0] * 4).e[-1] == 1 / AT_FOUR
    assert 1 / AT_TWO_MORE == reachable(1.0, 2) == pytest.approx(3.61, rel=1e-15)


def test_outcomes_by_hand_with_a_zero_scale() -> None:
    # k0: no earlier trial, sign(0) = 0; k1: only a 0 before, scale 0, sign(0.5) = 1;
    # k2: scale 0.5 * 0.5 / 2 = 0.125, 2 / 0.125 = 16 -> 1; k3: scale 0.5 * 2.5 / 3,
    # -0.2 / that = -0.48
    assert outcomes([0.0, 0.5, 2.0, -0.2]).tolist() == pytest.approx([0.0, 1.0, 1.0, -0.48],
                                                                      rel=1e-12)
    two = outcomes([[0.0, 0.5, 2.0, -0.2], [3.0, 1.0, -9.0, 0.0]])
    assert two.shape == (2, 4) and two[1].tolist() == pytest.approx([1.0, 1 / 1.5, -1.0, 0.0])
    one = bets([3.0, 1.0])
    assert one.x.shape == one.lam_up.shape == one.up.shape == one.e.shape == (2,)
    many = bets([[3.0, 3.0], [-3.0, -3.0]])
    assert many.x.shape == many.lam_down.shape == many.down.shape == (2, 2)
    assert many.e.tolist() == [[1.0, 1.855], [1.0, 1.855]]  # (1.9^2 + 0.1) / 2


def test_outcomes_divide_by_no_zero_scale_and_refuse_what_is_not_finite() -> None:
    with np.errstate(all="raise"):  # a 0 / 0 or x / 0 would raise here
        assert outcomes([0.0, 0.5, 2.0]).tolist() == [0.0, 1.0, 1.0]
    with pytest.raises(ValueError) as err:
        outcomes([1.0, float("inf")])
    assert str(err.value) == "a paired difference is not a finite number"


def test_an_e_value_exactly_at_1_over_alpha_settles() -> None:
    d = decide({"a": [4.0] * 4}, alpha=AT_FOUR, min_trials=1, max_trials=10)
    assert d.pairs["a"].settled_after == 4 and d.pairs["a"].direction == 1
    assert d.pairs["a"].algorithm == "a" and d.pairs["a"].futile is False
    assert d.stop and d.why == "every pair is settled"
    assert fewest_trials(AT_FOUR) == 4
    assert fewest_trials(AT_FOUR, limit=4) == 4 and fewest_trials(AT_FOUR, limit=3) is None
    assert fewest_trials(0.5) == 3  # e 1.855 < 2 after two, 3.48 after three
    cs = confidence_sequence([4.0] * 4, AT_FOUR)
    assert cs.low[-1] == 0.0 and cs.low[-2] < 0.0  # 0 rejected at the fourth exactly


def test_fewest_trials_refuses_an_alpha_outside_0_1() -> None:
    for alpha in (0.0, 1.0, -0.5, 1.5):
        with pytest.raises(ValueError, match="alpha must be in"):
            fewest_trials(alpha)


def test_reachable_never_shrinks_and_counts_each_trial_once() -> None:
    assert reachable(2.0, -3) == 2.0 and reachable(2.0, 0) == 2.0
    assert reachable(2.0, 1) == pytest.approx(3.8) and reachable(1.0, 2) == pytest.approx(3.61)


def test_a_pair_that_can_reach_exactly_1_over_alpha_is_not_futile() -> None:
    """Zero differences keep e at 1; two more trials can bring it to 1.9^2 = 1/alpha,
    which would settle it: still open, not "cannot be settled"."""
    d = decide({"a": [0.0] * 3}, alpha=AT_TWO_MORE, min_trials=3, max_trials=5)
    assert d.pairs["a"].status == "open" and not d.pairs["a"].futile and not d.stop
    assert d.pairs["a"].best == 1 / AT_TWO_MORE
    assert decide({"a": [0.0] * 3}, alpha=AT_TWO_MORE, min_trials=3, max_trials=4).stop


def test_no_trial_yet_starts_from_an_e_value_of_1() -> None:
    d = decide({"a": []}, alpha=0.05, min_trials=0, max_trials=3)
    assert d.trials == 0 and d.pairs["a"].best == pytest.approx(1.9 ** 3)
    assert d.stop and d.why == "no pair can be settled within max_trials (3)"
    assert d.pairs["a"].e_values == () and d.pairs["a"].differences == ()
    assert not decide({"a": []}, alpha=0.05, min_trials=0, max_trials=5).stop  # 1.9^5 > 20


def test_the_decision_is_taken_at_min_trials_not_after() -> None:
    settled = [-4.0] * 6
    assert decide({"b": settled}, alpha=0.05, min_trials=6, max_trials=12).stop
    assert not decide({"b": settled}, alpha=0.05, min_trials=7, max_trials=12).stop
    with pytest.raises(ValueError, match="one difference per finished trial") as err:
        decide({"a": [1.0, 2.0], "b": [1.0]}, alpha=0.05, min_trials=1, max_trials=5)
    assert str(err.value) == "every pair needs one difference per finished trial"


def test_no_pair_is_no_trial() -> None:
    d = decide({}, alpha=0.05, min_trials=1, max_trials=5)
    assert (d.trials, d.pairs, d.primary, d.stop) == (0, {}, (), False)


def test_the_reasons_name_primary_pairs_and_every_futile_one() -> None:
    settled, none = [-4.0] * 8, [0.0] * 8
    d = decide({"a": settled, "b": settled, "c": none}, alpha=0.05, min_trials=3,
               max_trials=12, primary=["a", "b"])
    assert d.stop and d.why == "every primary pair is settled"
    d = decide({"a": none, "b": none, "c": settled}, alpha=0.05, min_trials=3,
               max_trials=12, primary=["a", "b"])
    assert d.stop and d.why == "no primary pair can be settled within max_trials (12)"
    d = decide({"a": none, "b": none, "c": settled}, alpha=0.05, min_trials=3,
               max_trials=12)
    assert d.why == ("a, b cannot be settled within max_trials (12); every other pair "
                     "is settled")
    d = decide({"a": none, "b": [1.0, -1.0] * 4}, alpha=0.05, min_trials=3, max_trials=8)
    assert d.why == "max_trials (8) reached; not settled: a, b"


def test_status_and_threshold() -> None:
    d = decide({"s": [-4.0] * 6, "f": [0.0] * 6, "o": [0.0] * 6}, alpha=0.05,
               min_trials=3, max_trials=10, primary=["s"])  # 1.9^4 < 20
    assert [d.pairs[n].status for n in ("s", "f")] == ["settled", "cannot be settled"]
    assert decide({"o": [0.0] * 6}, alpha=0.05, min_trials=3, max_trials=12
                  ).pairs["o"].status == "open"
    assert d.threshold == 20.0 and Decision(0, 0.25, 1, 2).threshold == 4.0


def test_the_record_holds_every_setting_and_every_pair() -> None:
    d = decide({"a": [4.0, 4.0], "b": [0.0, 0.0]}, alpha=0.05, min_trials=3, max_trials=4)
    rec = record(d, reference="cur", metric="rohe", seeds=[7], protocol="p",
                 family_alpha=0.1, family={"q": 2})
    assert rec == {
        "protocol": "p", "primary": ["a", "b"], "family": {"q": 2}, "family_alpha": 0.1,
        "comparisons": 4, "format": "sequential/1",
        "method": "testing by betting (Waudby-Smith and Ramdas, JRSS-B 2023, aGRAPA) on "
                  "the paired differences, clipped at a predictable scale; settled at "
                  "e >= 1/alpha (Ville's inequality)",
        "reference": "cur", "metric": "rohe", "alpha": 0.05, "threshold": 20.0,
        "min_trials": 3, "max_trials": 4, "trials_done": 2, "cap": 0.9,
        "scale_fraction": 0.5, "stop": False, "why": "",
        "trials": [{"trial": 0, "seed": 7, "e_values": {"a": 1.0, "b": 1.0}},
                   {"trial": 1, "seed": None,
                    "e_values": {"a": pytest.approx(1.855), "b": 1.0}}],
        "pairs": {"a": {"differences": [4.0, 4.0], "e_values": [1.0, pytest.approx(1.855)],
                        "settled_after": None, "direction": 0,
                        "status": "cannot be settled",
                        "best_reachable": pytest.approx(1.855 * 3.61)},
                  "b": {"differences": [0.0, 0.0], "e_values": [1.0, 1.0],
                        "settled_after": None, "direction": 0,
                        "status": "cannot be settled",
                        "best_reachable": pytest.approx(3.61)}}}
    settled = decide({"a": [-4.0] * 6}, alpha=0.05, min_trials=3, max_trials=12)
    rec = record(settled, reference="cur", metric="successes", seeds=[3, 4, 5, 6, 7, 8])
    assert (rec["protocol"], rec["family"], rec["family_alpha"], rec["comparisons"]) == (
        "", {}, 0.05, 1)
    assert (rec["stop"], rec["why"]) == (True, "every pair is settled")
    assert [t["seed"] for t in rec["trials"]] == [3, 4, 5, 6, 7, 8]
    pair = rec["pairs"]["a"]
    assert (pair["settled_after"], pair["direction"], pair["status"]) == (6, -1, "settled")
    assert pair["best_reachable"] == pytest.approx(_e_same_sign(6) * 1.9 ** 6)


def test_finite_keeps_a_number_and_drops_inf_and_nan() -> None:
    assert _finite(2.5) == 2.5 and _finite(0.0) == 0.0
    assert _finite(math.inf) is None and _finite(math.nan) is None


def test_the_anytime_p_reads_every_e_value_of_any_shape() -> None:
    assert anytime_p(np.array([[2.0, 4.0], [1.0, 0.5]])) == 0.25
    assert anytime_p([1.0]) == 1.0 and anytime_p([8.0]) == 0.125
    assert anytime_p([0.5, 0.25]) == 1.0  # min(1, 1 / max e): never above 1
    assert anytime_p([1.0, 1.855]) == 1 / 1.855  # any e above 1 counts, however small
