"""The failure alarm's arithmetic, value by value (issue 45, item 5: tests that notice a
change to ``testbed/monitor/conformal.py``). Each expected value follows from the
definitions in the module's docstring, worked out here by hand: the threshold is the k-th
smallest of n peaks, k = ceil((n + 1)(1 - level)); ACI moves the level by
gamma (alpha - err); its bound is alpha + (alpha + A gamma (1 - alpha)) / (gamma T)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.monitor.conformal import (
    DEFAULT_GAMMA,
    DEFAULT_WINDOW,
    AdaptiveAlarm,
    ConformalAlarm,
    Replay,
    aci_bounds,
    check_alpha,
    check_gamma,
    episodes_needed,
    level_threshold,
    make_alarm,
    replay_online,
    replay_split,
)
from testbed.monitor.false_alarms import AlarmRate, alarm_rate


def test_alpha_and_gamma_are_checked_with_the_value_named() -> None:
    for bad, shown in ((1.5, "1.5"), (0.0, "0.0"), (1.0, "1.0"), (-2, "-2")):
        with pytest.raises(ValueError) as err:
            check_alpha(bad)
        assert str(err.value) == f"alpha must be in (0, 1), got {shown}"
    assert check_alpha(1e-9) == 1e-9 and check_alpha(1 - 1e-9) == 1 - 1e-9
    assert type(check_alpha(np.float32(0.5))) is float
    with pytest.raises(ValueError) as err:
        check_gamma(2)
    assert str(err.value) == "gamma must be in (0, 1], got 2"
    assert check_gamma(1) == 1.0 and type(check_gamma(1)) is float
    assert check_gamma(1e-9) == 1e-9


def test_the_fewest_episodes_for_a_finite_threshold() -> None:
    """n peaks give a finite threshold when ceil((n + 1)(1 - alpha)) <= n, i.e. when
    n >= 1/alpha - 1: 19 at 0.05 (1/alpha exact: 19 peaks, k = 19), 3 at 0.3
    (k = ceil(4 x 0.7) = 3; 2 peaks: ceil(2.1) = 3 > 2), and at least 1 however large
    alpha is."""
    assert episodes_needed(0.05) == 19 and episodes_needed(0.1) == 9
    assert episodes_needed(0.25) == 3 and episodes_needed(0.3) == 3
    assert episodes_needed(0.5) == 1 and episodes_needed(0.9) == 1
    assert episodes_needed(1 - 1e-13) == 1  # 1/alpha - 1 below the tolerance: still 1
    for a in (0.05, 0.1, 0.25, 0.3, 0.5, 0.9):
        n = episodes_needed(a)
        assert level_threshold(np.arange(n, dtype=float), a) < math.inf
        if n > 1:
            assert level_threshold(np.arange(n - 1, dtype=float), a) == math.inf
    with pytest.raises(ValueError, match="alpha must be in"):
        episodes_needed(0.0)


def test_the_threshold_refuses_nan_in_the_peaks_or_the_level() -> None:
    with pytest.raises(ValueError) as err:
        level_threshold([1.0, math.nan, 2.0], 0.5)
    assert str(err.value) == "episode peaks or the level have NaN"
    with pytest.raises(ValueError, match="NaN"):
        level_threshold([1.0, 2.0], math.nan)
    assert level_threshold([], 0.5) == math.inf  # k = ceil(0.5) = 1 > 0 peaks
    assert level_threshold([3, 1, 2], 0.5) == 2.0  # ints are peaks too: k = 2
    assert type(level_threshold([3, 1, 2], 0.5)) is float


def test_the_bounds_at_one_judged_episode_and_on_several_arms() -> None:
    """T = 1, alpha = gamma = 0.05: high 0.05 + (0.05 + 0.0475) / 0.05 = 2.0, low
    0.05 - (0.95 + 0.0025) / 0.05 = -19.0; 4 arms, T = 80: low
    0.05 - (0.95 + 4 x 0.0025) / 4 = -0.19."""
    low, high = aci_bounds(0.05, 0.05, 1)
    assert low == pytest.approx(-19.0) and high == pytest.approx(2.0)
    assert aci_bounds(0.05, 0.05, 80, arms=4)[0] == pytest.approx(-0.19)
    assert aci_bounds(0.05, 0.05, -3) == (-math.inf, math.inf)
    with pytest.raises(ValueError, match="alpha"):
        aci_bounds(0.0, 0.05, 10)
    with pytest.raises(ValueError, match="gamma"):
        aci_bounds(0.05, 0.0, 10)


def test_a_new_alarm_and_its_window() -> None:
    fresh = ConformalAlarm(0.05)
    assert fresh.window == DEFAULT_WINDOW == 200 and fresh.threshold == math.inf
    assert (fresh.judged, fresh.fired, fresh.calibrated_on) == (0, 0, 0)
    assert not fresh.ready and fresh.level == 0.05
    assert ConformalAlarm(0.05, window=19).window == 19  # exactly enough is enough
    with pytest.raises(ValueError) as err:
        ConformalAlarm(0.05, window=18)
    assert str(err.value) == "window must hold at least 19 episodes for alpha 0.05, got 18"
    aci = AdaptiveAlarm(0.1)
    assert aci.window == 200 and aci.gamma == DEFAULT_GAMMA == 0.05 and aci.a_t == 0.1
    assert aci.level == 0.1 and aci.threshold == math.inf
    with pytest.raises(ValueError, match="gamma"):
        AdaptiveAlarm(0.1, 20, gamma=0.0)


def test_the_window_keeps_the_latest_peaks() -> None:
    """alpha 0.5, window 3: after 10, 20, 30, 1, 2 the window is 30, 1, 2 and the
    threshold its k-th smallest, k = ceil(4 x 0.5) = 2: 2."""
    alarm = ConformalAlarm(0.5, window=3)
    for p in (10.0, 20.0, 30.0, 1.0, 2.0):
        alarm.add(p)
    assert alarm.calibrated_on == 3 and alarm.threshold == 2.0
    assert alarm.state_dict()["peaks"] == [30.0, 1.0, 2.0]


def test_a_peak_must_be_finite() -> None:
    alarm = ConformalAlarm(0.5, window=3)
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError) as err:
            alarm.add(bad)
        assert str(err.value) == f"an episode's peak must be finite, got {bad!r}"
    assert alarm.calibrated_on == 0
    alarm.add(np.float32(1.5))
    assert alarm.state_dict()["peaks"] == [1.5] and type(alarm.state_dict()["peaks"][0]) is float


def test_the_alarm_fires_strictly_above_its_threshold_and_never_before_ready() -> None:
    alarm = ConformalAlarm(0.5, window=3)
    silent = alarm.fires([1e9, -1e9])
    assert silent.dtype == np.bool_ and silent.tolist() == [False, False]
    assert alarm.fires(5.0).shape == ()
    alarm.add(1.0)  # one peak at 0.5: k = ceil(2 x 0.5) = 1, threshold 1.0
    assert alarm.ready and alarm.threshold == 1.0
    out = alarm.fires([0.5, 1.0, 1.5])
    assert out.dtype == np.bool_ and out.tolist() == [False, False, True]


def test_a_judged_episode_counts_once_and_fired_only_when_it_fired() -> None:
    alarm = ConformalAlarm(0.5, window=10)
    alarm.add(1.0, fired=False)  # not ready before it: not judged
    assert (alarm.judged, alarm.fired) == (0, 0)
    alarm.add(2.0, fired=False)
    assert (alarm.judged, alarm.fired) == (1, 0)
    alarm.add(3.0, fired=True)
    alarm.add(4.0, fired=True)
    assert (alarm.judged, alarm.fired) == (3, 2)
    assert alarm.level == 0.5  # the split alarm does not move


def test_the_aci_level_after_a_known_sequence() -> None:
    """alpha 0.2, gamma 0.5: fired, fired, not: 0.2 + 0.5(-0.8) + 0.5(-0.8) + 0.5(0.2)
    = -0.5, at which the threshold is +inf (k = ceil(n 1.5) > n): silent."""
    alarm = AdaptiveAlarm(0.2, window=10, gamma=0.5)
    for p in (1.0, 2.0, 3.0, 4.0):  # 4 = episodes_needed(0.2): ready after them
        alarm.add(p)
    assert alarm.ready and alarm.threshold == 4.0  # k = ceil(5 x 0.8) = 4
    alarm.add(5.0, fired=True)
    assert alarm.a_t == pytest.approx(-0.2) and alarm.level == alarm.a_t
    assert alarm.threshold == math.inf  # k = ceil(6 x 1.2) = 8 > 5
    alarm.add(6.0, fired=True)
    alarm.add(0.5, fired=False)
    assert alarm.a_t == pytest.approx(-0.5) and (alarm.judged, alarm.fired) == (3, 2)
    assert not alarm.fires([1e12]).any()
    assert alarm.bounds() == aci_bounds(0.2, 0.5, 3, 1)
    assert alarm.bounds(arms=3) == aci_bounds(0.2, 0.5, 3, 3)
    assert alarm.bounds()[1] == pytest.approx(0.2 + (0.2 + 0.5 * 0.8) / 1.5)


def test_the_states_hold_every_field() -> None:
    split = ConformalAlarm(0.5, window=4)
    for p, f in ((1.0, None), (2.0, True), (3.0, False)):
        split.add(p, f)
    assert split.state_dict() == {"kind": "split", "alpha": 0.5, "window": 4,
                                  "peaks": [1.0, 2.0, 3.0], "judged": 2, "fired": 1}
    aci = AdaptiveAlarm(0.5, window=4, gamma=0.25)
    for p, f in ((1.0, None), (2.0, True), (3.0, False)):
        aci.add(p, f)
    assert aci.state_dict() == {"kind": "aci", "alpha": 0.5, "window": 4,
                                "peaks": [1.0, 2.0, 3.0], "judged": 2, "fired": 1,
                                "gamma": 0.25, "a_t": pytest.approx(0.5)}


def test_a_loaded_state_keeps_the_window_and_defaults_what_it_lacks() -> None:
    """A state with more peaks than the window keeps the latest; counts and the level
    start at 0 and alpha where the state has none (a split alarm's, or an old one)."""
    state = {"alpha": 0.5, "window": 10, "peaks": [5.0, None, 1.0, 2.0, 3.0],
             "judged": 7, "fired": 3}
    split = ConformalAlarm(0.5, window=3)
    split.load_state_dict(state)
    assert split.state_dict()["peaks"] == [1.0, 2.0, 3.0] and split.threshold == 2.0
    assert (split.judged, split.fired) == (7, 3)
    aci = AdaptiveAlarm(0.5, window=3, gamma=0.1)
    aci.a_t = 0.9
    aci.load_state_dict(state)
    assert aci.a_t == 0.5 and (aci.judged, aci.fired) == (7, 3)
    aci.load_state_dict({"peaks": [1.0], "a_t": 0.3})
    assert aci.a_t == 0.3 and (aci.judged, aci.fired) == (0, 0)
    # the level loaded is the one the threshold is computed at: 3 peaks at 0.3:
    # k = ceil(4 x 0.7) = 3
    aci.load_state_dict({"peaks": [1.0, 2.0, 3.0], "a_t": 0.3})
    assert aci.threshold == 3.0
    split.load_state_dict({"peaks": [1.0, 2.0]})
    assert (split.judged, split.fired) == (0, 0)


def test_make_alarm_passes_on_every_setting() -> None:
    aci = make_alarm("aci", 0.1, 30, 0.2)
    assert type(aci) is AdaptiveAlarm and (aci.alpha, aci.window, aci.gamma) == (0.1, 30, 0.2)
    split = make_alarm("split", 0.1, 30)
    assert type(split) is ConformalAlarm and (split.alpha, split.window) == (0.1, 30)
    default = make_alarm("aci", 0.1)
    assert default.window == 200 and default.gamma == 0.05  # type: ignore[attr-defined]
    with pytest.raises(ValueError) as err:
        make_alarm("ACI", 0.1)
    assert str(err.value) == "alarm must be one of aci, split, got 'ACI'"


def test_the_split_sanity_check_needs_two_halves_of_enough_peaks() -> None:
    """A half needs episodes_needed(alpha) peaks: 38 peaks at 0.05 (halves of 19) run,
    37 (18) do not, nor 1 peak at any alpha; 2 peaks at 0.9 (needs 1) run."""
    short = replay_split(np.arange(37.0), 0.05, splits=10)
    assert math.isnan(short.rate) and math.isnan(short.mc_error)
    assert (short.alpha, short.episodes, short.splits) == (0.05, 37, 0)
    assert replay_split(np.arange(38.0), 0.05, splits=10).splits == 10
    one = replay_split([1.0], 0.9, splits=10)
    assert one.splits == 0 and one.episodes == 1
    assert replay_split([1.0, 2.0], 0.9, splits=10).splits == 10


def test_the_split_check_on_two_peaks_is_a_coin() -> None:
    """Peaks 1 and 2 at alpha 0.9: one peak calibrates (k = ceil(2 x 0.1) = 1: it is the
    threshold), the other alarms exactly when it is the 2: each split's rate is 0 or 1,
    the mean a share near 1/2 and its Monte-Carlo error that of a Bernoulli mean
    (sample standard deviation, ddof 1, over sqrt(splits))."""
    check = replay_split([1.0, 2.0], 0.9)
    assert check.splits == 1000 and check.episodes == 2 and check.alpha == 0.9
    p = check.rate
    assert abs(p - 0.5) < 4 * math.sqrt(0.25 / 1000)
    assert check.mc_error == pytest.approx(math.sqrt(p * (1 - p) * 1000 / 999 / 1000))
    assert replay_split([1.0, 2.0], 0.9, seed=0) == check  # seed 0 is the default
    assert replay_split([1.0, 2.0], 0.9, seed=1) != check
    # equal peaks never alarm: none is above the threshold (strictly)
    flat = replay_split(np.ones(40), 0.1, splits=20)
    assert flat.rate == 0.0 and flat.mc_error == 0.0


def test_within_guarantee_compares_each_run_with_its_bound() -> None:
    rate = AlarmRate(0.1, 2, 20, 2, 0.1, 0.3, "m")
    assert Replay("aci", (10, 10), (1, 1), rate, (0.1, 0.1)).within_guarantee  # 1 <= 1.0
    assert not Replay("aci", (10, 10), (1, 2), rate, (0.1, 0.1)).within_guarantee
    assert not Replay("aci", (10, 10), (2, 1), rate, (0.1, 0.1)).within_guarantee
    with pytest.raises(ValueError):
        Replay("aci", (10, 10), (1, 1), rate, (0.1,)).within_guarantee  # noqa: B018
    assert Replay("split", (10,), (1,), rate).guarantee == ()
    assert not Replay("split", (10,), (1,), rate).holds  # upper 0.3 > alpha 0.1
    low = AlarmRate(0.1, 2, 20, 0, 0.0, 0.1, "m")
    assert Replay("split", (10,), (0,), low).holds


def test_replay_online_judges_each_episode_by_the_alarm_before_it() -> None:
    """alpha 0.5, window 3, split: peaks 1, 3, 2, 5, 0. The 1 calibrates (not ready
    before it). Then each against the threshold before it, the k-th smallest of the
    window, k = ceil((n + 1) / 2): 3 > 1 fires; 2 vs {1, 3} (k = 2: 3): no; 5 vs
    {1, 3, 2} (k = 2: 2): fires; 0 vs {3, 2, 5} (3): no. 4 judged, 2 fired."""
    rep = replay_online([np.array([1.0, 3.0, 2.0, 5.0, 0.0])], 0.5, 3, kind="split")
    assert rep.kind == "split" and rep.judged == (4,) and rep.fired == (2,)
    assert rep.guarantee == ()
    assert rep.rate == alarm_rate([2], [4], 0.5)
    # ACI, gamma 1: after the first judged episode fired, a = 0.5 + (0.5 - 1) = 0: the
    # threshold is +inf and nothing fires until an episode that did not fire lifts it
    # back (a = 0.5 after the second): 3 fires; 2 (a = 0): no; 5 (a = 0.5, window
    # {1, 3, 2}: 2): fires; 0 (a = 0): no
    aci = replay_online([np.array([1.0, 3.0, 2.0, 5.0, 0.0])], 0.5, 3, gamma=1.0)
    assert aci.kind == "aci" and aci.judged == (4,) and aci.fired == (2,)
    assert aci.guarantee == (pytest.approx(aci_bounds(0.5, 1.0, 4)[1]),)
    two = replay_online([np.array([1.0, 3.0]), np.array([1.0, 3.0, 2.0])], 0.5, 3,
                        kind="split")
    assert two.judged == (1, 2) and two.fired == (1, 1)
    # the defaults: ACI over a 200-episode window at gamma 0.05
    peaks = [np.linspace(1.0, 2.0, 30)]
    assert replay_online(peaks, 0.1) == replay_online(peaks, 0.1, 200, kind="aci",
                                                      gamma=0.05)


def test_an_alarm_not_ready_has_no_threshold_whatever_its_level() -> None:
    """A state with a level above alpha but fewer peaks than alpha needs (19 at 0.05):
    the alarm is not ready, so it has no threshold (+inf) and is silent, though one peak
    at the level 0.6 alone would give one (k = ceil(2 x 0.4) = 1)."""
    aci = AdaptiveAlarm(0.05, window=50)
    aci.load_state_dict({"peaks": [1.0], "a_t": 0.6})
    assert not aci.ready and aci.level == 0.6
    assert level_threshold([1.0], 0.6) == 1.0
    assert aci.threshold == math.inf and not aci.fires([2.0]).any()
