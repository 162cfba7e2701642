"""People by where they are (issue 44): only a person on site is given a hard reset.

The allocator's ``on_site`` mask (the config's ``humans.people[].where``): checked as
rules over thousands of random steps (a remote human never on a reset; a violating
candidate never waits while an on-site person is free; a teleop never takes a new
on-site person while a remote one stays free, their own arm aside; every teleop
candidate served while anyone is free), on hand-built steps (the conversion that frees
a remote human, remote first, the on-site person who leaves a teleop for a reset), and
against Algorithm 1: the pairing with places, with no remote person free, allocates
exactly as the allocator without places, arm for arm. The Random baseline sizes its
resets to the on-site people, so every arm it makes eligible still gets a person.
"""

from __future__ import annotations

import numpy as np
import pytest

from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.allocator import KIND_RESET, KIND_TELEOP, Allocator, lex_positive
from testbed.fleet.priorities import PrioritySignals


def _random_steps(rng: np.random.Generator, n: int, m: int, k: int, steps: int,
                  masks: bool, gains: bool
                  ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                  np.ndarray | None]]:
    """Keys that tie, violations that last, sometimes away humans and gains."""
    out = []
    viol = np.zeros(n, dtype=bool)
    for _ in range(steps):
        viol = (viol & (rng.random(n) > 0.3)) | (rng.random(n) < 0.1)
        keys = rng.choice([-1.0, 0.0, 0.0, 0.5, 1.0], size=(n, k))
        available = rng.random(m) < 0.8 if masks and rng.random() < 0.5 else None
        g = rng.choice([-0.2, 0.0, 0.1, 0.3], size=(m, n)) if gains else None
        out.append((keys, viol.copy(), available, g))
    return out


@pytest.mark.parametrize("gains", [False, True], ids=["blind", "matched"])
def test_the_pairing_for_remote_people_is_algorithm_1_when_no_remote_one_is_free(
        gains: bool) -> None:
    """The pairing with places (``_pair_matched`` with the on-site rules) against
    Algorithm 1's own (``_pair_blind``, or the matched pairing without places): a fleet
    with one more person, remote and never present, must allocate its on-site people
    exactly as the fleet without her, arm for arm, step after step. (A mask of all True
    is no mask by construction, the unchanged ``_pair_blind``; this fleet takes the
    pairing with places, which must reduce to Algorithm 1.)"""
    rng = np.random.default_rng(11)
    for case in range(60):
        n, m, k = int(rng.integers(1, 9)), int(rng.integers(1, 7)), int(rng.integers(1, 4))
        t_T, t_R = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        plain = Allocator(n, m, t_T, t_R, seed=case)
        places = Allocator(n, m + 1, t_T, t_R, seed=case,
                           on_site=np.array([True] * m + [False]))
        for keys, viol, available, g in _random_steps(rng, n, m, k, 60, True, gains):
            here = np.ones(m, dtype=bool) if available is None else available
            a = plain.step(keys, viol, available, g)
            b = places.step(keys, viol, np.append(here, False),
                            None if g is None else np.vstack([g, np.zeros((1, n))]))
            assert a.tolist() == b.tolist(), (case, keys, viol)
            assert plain.kind_codes.tolist() == places.kind_codes.tolist()
            assert plain.served.tolist() == places.served.tolist()
            assert plain.waited.tolist() == places.waited.tolist()


@pytest.mark.parametrize("gains", [False, True], ids=["blind", "matched"])
def test_the_rules_of_places_over_random_steps(gains: bool) -> None:
    rng = np.random.default_rng(11)
    resets = {0: 0, 1: 0}
    for case in range(120):
        n, m, k = int(rng.integers(1, 9)), int(rng.integers(1, 7)), int(rng.integers(1, 4))
        on_site = rng.random(m) < 0.5
        alloc = Allocator(n, m, int(rng.integers(1, 5)), int(rng.integers(1, 5)),
                          seed=case, on_site=on_site)
        for keys, viol, available, g in _random_steps(rng, n, m, k, 60, True, gains):
            before = alloc.assignment
            assign = alloc.step(keys, viol, available, g)
            kinds = alloc.kind_codes
            busy = assign >= 0
            # (1) a reset is an on-site person's, always
            assert on_site[assign[kinds == KIND_RESET]].all()
            resets[int(on_site.all())] += int((kinds == KIND_RESET).sum())
            # (2) a violating candidate never waits while an on-site person is free
            free = np.ones(m, dtype=bool)
            free[assign[busy]] = False
            if available is not None:
                free &= available
            waiting = ~busy & lex_positive(keys)
            assert not ((waiting & viol).any() and (free & on_site).any())
            if gains:
                continue
            # (3) blind: no teleop candidate waits while anyone free may take it
            assert not ((waiting & ~viol).any() and free.any())
            # (4) a new teleop is an on-site person's only if no remote one is left
            for i in np.flatnonzero(busy & (kinds == KIND_TELEOP) & (alloc.served == 0)):
                j = assign[i]
                if on_site[j] and before[i] != j:
                    assert not (free & ~on_site).any(), (i, j, free, on_site)
    assert resets[0] > 100, "the random steps rarely reset with remote humans around"


def test_a_violating_arm_frees_its_remote_teleoperator_for_an_on_site_reset() -> None:
    # human 0 remote, human 1 on site; t_T = 5: a teleop would be held 5 steps
    alloc = Allocator(2, 2, min_teleop_steps=5, hard_reset_steps=2, seed=0,
                      on_site=[False, True])
    assert alloc.step([1.0, 0.0], np.array([False, False])).tolist() == [0, -1]
    assert alloc.kinds == ["teleop", None]
    # arm 0 violates: not a reset for human 0 (all on site it would be, held t_R);
    # human 0 is free, the on-site human 1 resets it, starting at served 0
    assert alloc.held_humans(np.array([True, False])).tolist() == [False, False]
    assert alloc.step([1.0, 0.0], np.array([True, False])).tolist() == [1, -1]
    assert alloc.kinds == ["reset", None] and alloc.served.tolist() == [0, 0]
    everyone = Allocator(2, 2, min_teleop_steps=5, hard_reset_steps=2, seed=0)
    everyone.step([1.0, 0.0], np.array([False, False]))
    assert everyone.step([1.0, 0.0], np.array([True, False])).tolist() == [0, -1]


def test_a_violating_arm_waits_for_an_on_site_person_and_the_remote_one_teleops() -> None:
    alloc = Allocator(3, 2, min_teleop_steps=5, hard_reset_steps=2, seed=0,
                      on_site=[False, True])
    # the top arm to the remote human 0, the next to the on-site human 1
    assert alloc.step([2.0, 1.0, 0.0], np.zeros(3, bool)).tolist() == [0, 1, -1]
    # arm 0 violates: human 1 is held on arm 1, so arm 0 waits; the freed remote
    # human 0 takes the next candidate, arm 2, the same step
    assign = alloc.step([1.0, 0.0, 0.5], np.array([True, False, False]))
    assert assign.tolist() == [-1, 1, 0]
    assert alloc.kinds == [None, "teleop", "teleop"]
    assert alloc.waited.tolist() == [1, 0, 0]


def test_a_teleop_goes_to_a_free_remote_person_first() -> None:
    # human 0 on site, human 1 remote: blind Algorithm 1 would give arm 0 to human 0
    alloc = Allocator(2, 2, 1, 1, seed=0, on_site=[True, False])
    assert alloc.step([1.0, 0.0], np.zeros(2, bool)).tolist() == [1, -1]
    # a teleop above a reset: the teleop to the remote one, the reset to the on-site one
    alloc = Allocator(2, 2, 1, 1, seed=0, on_site=[True, False])
    assert alloc.step([2.0, 1.0], np.array([False, True])).tolist() == [1, 0]
    assert alloc.kinds == ["teleop", "reset"]
    plain = Allocator(2, 2, 1, 1, seed=0)  # index order: the reset would go to human 1
    assert plain.step([2.0, 1.0], np.array([False, True])).tolist() == [0, 1]


def test_an_on_site_person_leaves_their_teleop_to_a_remote_one_only_for_a_reset() -> None:
    def setup() -> Allocator:
        a = Allocator(3, 2, min_teleop_steps=1, hard_reset_steps=2, seed=0,
                      on_site=[True, False])
        assert a.step([2.0, 1.0, 0.0], np.zeros(3, bool)).tolist() == [1, 0, -1]
        # t_T = 1: both free again; each keeps their own arm (no needless switch)
        assert a.step([2.0, 1.0, 0.0], np.zeros(3, bool)).tolist() == [1, 0, -1]
        return a

    a = setup()  # arm 1 asks again, nothing violates: human 0 keeps it
    assert a.step([0.0, 2.0, 0.0], np.zeros(3, bool)).tolist() == [-1, 0, -1]
    a = setup()  # ... and arm 2 needs a reset: the remote human 1 takes arm 1
    assign = a.step([0.0, 2.0, 1.0], np.array([False, False, True]))
    assert assign.tolist() == [-1, 1, 0]
    assert a.kinds == [None, "teleop", "reset"]


def test_the_places_are_configuration_not_state() -> None:
    first = Allocator(2, 2, min_teleop_steps=1, hard_reset_steps=3, seed=5)
    assert first.step([1.0, 0.0], np.array([True, False])).tolist() == [0, -1]
    state = first.state_dict()
    assert "on_site" not in state
    # resumed with human 0 now remote: its reset is not held; human 1 (on site) takes it
    later = Allocator(2, 2, min_teleop_steps=1, hard_reset_steps=3, on_site=[False, True])
    later.load_state_dict(state)
    assert later.step([1.0, 0.0], np.array([True, False])).tolist() == [1, -1]
    assert later.kind_codes.tolist() == [KIND_RESET, 0] and later.served.tolist() == [0, 0]


@pytest.mark.parametrize(("on_site", "match"), [
    ([True], r"on_site must have shape \(2,\)"),
    ([1, 0], "on_site must be a bool array")])
def test_a_bad_mask_is_a_clear_value_error(on_site: list[object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Allocator(2, 2, 1, 1, on_site=on_site)  # type: ignore[arg-type]


def test_random_makes_eligible_only_resets_the_on_site_people_can_do() -> None:
    # Every arm Random makes eligible gets a person (its effort counts only what
    # happened), none of its resets a remote person's, and the budget is still met.
    n, m, steps = 12, 4, 1500
    on_site = [False, True, False, False]
    params = AlgorithmConfig(random_budget=0.5, t_T=3, t_R=4)
    alg = get_algorithm("random", params, n, m, seed=2, on_site=on_site)
    assert alg.allocator.on_site.tolist() == on_site
    rng = np.random.default_rng(2)
    violating = np.zeros(n, bool)
    busy = resets = 0
    for t in range(steps):
        violating |= rng.random(n) < 0.05
        assign = alg.step(PrioritySignals(t=t, violating=violating.copy()))
        kinds, served = alg.allocator.kind_codes, alg.allocator.served
        assert (assign[kinds == KIND_RESET] == 1).all()
        busy += int((assign >= 0).sum())
        resets += int((kinds == KIND_RESET).sum())
        violating &= ~((kinds == KIND_RESET) & (served + 1 >= params.t_R))
    assert alg.priority.effort == busy  # type: ignore[attr-defined]
    assert resets > 100
    assert busy / (m * steps) == pytest.approx(0.5, abs=0.05)
