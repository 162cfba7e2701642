"""Whether the advantage is right, on the twin: is a push the critic values above the
policy's own push better in truth?

Why: the advantage of a push (``testbed/learning/advantage.py``) is the value critic's
estimate; the twin knows what each push does. States are drawn as a trial meets them
(:func:`draw_states`: a hard reset near the centre with a new goal, then pushes, half the
scripted expert's and half at random, a violation reset at once), in a cell whose seed
no trial or pretraining uses (:data:`TRUTH_SEED`): states the learner never saw. For
each state the twin is put back into it once per push (``TwinCell.set_arm_state``) and
the push is run in PyBullet; its truth (:func:`push_truth`) is the cube's distance to
the goal afterwards, a violation worse than any distance and a success better than any.

The figures (:func:`judge`), per push other than the policy's own (A = 0 there by
definition): the ROC AUC of A(s, a) for "this push ends better than the policy's push
from the same state", pooled over states (it also credits knowing in which states the
policy's push is poor), and the share of pairs within a state (a better push, one not)
the advantage orders right, which credits ranking pushes alone; each with a 95 %
percentile interval from resampling whole goal episodes (the states of one episode
follow one another and share its goal, so episodes are the unit); and the share of
states whose highest-advantage push is the scripted expert's, beside the share where
the policy's own push is. The push's jitter is drawn by the twin as in a trial, so a truth
is one draw of a noisy push, as a lab's would be.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from testbed.core.types import NUM_ACTIONS

__all__ = ["TRUTH_SEED", "TUNING_SEED", "AdvantageTruth", "TwinState", "check_on_twin",
           "draw_states", "judge", "push_truth", "truth_of_states"]

TRUTH_SEED: Final = 4_600_047
"""The twin cell's seed for the check's states: no protocol's trial or theta_0 uses it,
nor the states the value critic's horizon was chosen on (:data:`TUNING_SEED`)."""
TUNING_SEED: Final = 4_600_046
"""The cell whose 200 states chose ``gamma_value`` (docs/notes/learning.md, "The value of
every push"): a figure on them would be a figure on the data that picked the setting."""
P_EXPERT: Final = 0.5
RESAMPLES: Final = 2000

ValueFn = Callable[[npt.NDArray[np.uint8], npt.NDArray[np.int64]], Any]
"""(images, actions) -> ``PushValues`` (``Learner.push_values``): ``.advantage`` and
``.policy_action`` per push."""


@dataclass(frozen=True)
class TwinState:
    """One arm's state as the twin holds it, and its image as the policy sees it."""

    arm: str
    cube_xy: tuple[float, float]
    yaw: float
    goal_xy: tuple[float, float]
    image: npt.NDArray[np.uint8]
    expert: int
    episode: int = 0
    """The goal episode the state belongs to (arm and goal): states of one episode
    follow one another and are resampled together (:func:`judge`)."""


def draw_states(cell: Any, n: int, rng: np.random.Generator) -> list[TwinState]:
    """``n`` states of ``cell``'s arms as a trial meets them (the module doc), each with
    its goal episode (a new one after a success, a timeout or a reset)."""
    out: list[TwinState] = []
    episode = {a: k for k, a in enumerate(cell.arm_names)}
    while len(out) < n:
        images = cell.observe()
        for arm in cell.arm_names:
            s = cell.arm_state(arm)
            if not s.violating:
                out.append(TwinState(arm, tuple(s.cube_xy), float(s.yaw), tuple(s.goal_xy),
                                     images[arm], cell.expert_action(arm), episode[arm]))
        faces = {a: cell.expert_action(a) if rng.random() < P_EXPERT
                 else int(rng.integers(NUM_ACTIONS)) for a in cell.arm_names}
        for arm, o in cell.push(faces).items():
            if o.violation:
                cell.hard_reset(arm)
            if o.violation or o.soft_reset:
                episode[arm] += len(cell.arm_names)
    return out[:n]


def push_truth(cell: Any, state: TwinState, face: int) -> float:
    """What push ``face`` does from ``state`` in the twin: minus the cube's distance to
    the goal after it; -inf for a violation, +inf for a success."""
    cell.set_arm_state(state.arm, state.cube_xy, state.yaw, state.goal_xy)
    o = cell.push({state.arm: face})[state.arm]
    if o.violation:
        return -np.inf
    if o.success:
        return np.inf
    after = cell.arm_state(state.arm).cube_xy
    return -float(np.hypot(after[0] - state.goal_xy[0], after[1] - state.goal_xy[1]))


def truth_of_states(cell: Any, states: list[TwinState]) -> npt.NDArray[np.float64]:
    """(S, NUM_ACTIONS): every push's truth from every state."""
    return np.asarray([[push_truth(cell, s, a) for a in range(NUM_ACTIONS)]
                       for s in states])


@dataclass(frozen=True)
class AdvantageTruth:
    """The check's figures (module doc)."""

    states: int
    pushes: int
    better: int
    """Pushes (not the policy's) that ended strictly better than the policy's push."""
    auroc: float
    auroc_low: float
    auroc_high: float
    within: float
    """Within states only: the share of pairs (a push better than the policy's, one not,
    from the same state) the advantage orders right (ties half): ranking pushes, not
    states."""
    within_low: float
    within_high: float
    episodes: int
    top_is_expert: float
    policy_is_expert: float

    def line(self) -> str:
        return (f"advantage vs the twin's truth, {self.states} held-out states in "
                f"{self.episodes} goal episodes: AUROC {self.auroc:.3f} "
                f"[{self.auroc_low:.3f}, {self.auroc_high:.3f}], within states "
                f"{self.within:.3f} [{self.within_low:.3f}, {self.within_high:.3f}] (95 %, "
                f"episodes resampled) for 'better than the policy's push' over "
                f"{self.pushes} pushes ({self.better} better); highest-advantage push = "
                f"the expert's in {self.top_is_expert:.0%} of states, the policy's own "
                f"push in {self.policy_is_expert:.0%}")


def judge(states: list[TwinState], truth: npt.NDArray[np.float64], value: ValueFn,
          seed: int = 0) -> AdvantageTruth:
    """The figures for ``states`` and their pushes' ``truth`` (:func:`truth_of_states`),
    the advantages from ``value``."""
    from testbed.monitor.predictor_metrics import auroc

    s = len(states)
    images = np.repeat(np.stack([x.image for x in states]), NUM_ACTIONS, axis=0)
    actions = np.tile(np.arange(NUM_ACTIONS, dtype=np.int64), s)
    got = value(images, actions)
    adv = np.asarray(got.advantage, np.float64).reshape(s, NUM_ACTIONS)
    pi = np.asarray(got.policy_action, np.int64).reshape(s, NUM_ACTIONS)[:, 0]
    own = truth[np.arange(s), pi]
    other = np.arange(NUM_ACTIONS)[None, :] != pi[:, None]
    better = truth > own[:, None]
    per_state = [(adv[i][other[i]], better[i][other[i]]) for i in range(s)]
    pairs = [_concordance(*per_state[i]) for i in range(s)]  # (right, pairs) per state

    def area(idx: npt.NDArray[np.int64]) -> float:
        return auroc(np.concatenate([per_state[i][0] for i in idx]),
                     np.concatenate([per_state[i][1] for i in idx]))

    def within(idx: npt.NDArray[np.int64]) -> float:
        right, total = np.sum([pairs[i] for i in idx], axis=0)
        return float(right / total) if total else float("nan")

    # states of one goal episode follow one another: whole episodes are resampled
    episode = np.asarray([x.episode for x in states])
    groups = [np.flatnonzero(episode == e) for e in np.unique(episode)]
    rng = np.random.default_rng(seed)
    draws = [np.concatenate([groups[g] for g in rng.integers(0, len(groups), len(groups))])
             for _ in range(RESAMPLES)]
    low, high = np.nanquantile([area(d) for d in draws], [0.025, 0.975])
    w_low, w_high = np.nanquantile([within(d) for d in draws], [0.025, 0.975])
    expert = np.asarray([x.expert for x in states])
    every = np.arange(s)
    return AdvantageTruth(
        states=s, pushes=int(other.sum()), better=int(better[other].sum()),
        auroc=area(every), auroc_low=float(low), auroc_high=float(high),
        within=within(every), within_low=float(w_low), within_high=float(w_high),
        episodes=len(groups), top_is_expert=float(np.mean(adv.argmax(axis=1) == expert)),
        policy_is_expert=float(np.mean(pi == expert)))


def _concordance(score: npt.NDArray[np.float64], label: npt.NDArray[np.bool_]
                 ) -> tuple[float, int]:
    """(pairs ordered right, ties half; pairs) of one state's pushes: each better push
    against each one not better."""
    pos, neg = score[label], score[~label]
    if not len(pos) or not len(neg):
        return 0.0, 0
    diff = pos[:, None] - neg[None, :]
    return float((diff > 0).sum() + 0.5 * (diff == 0).sum()), int(diff.size)


def check_on_twin(value: ValueFn, states: int, seed: int = TRUTH_SEED) -> AdvantageTruth:
    """The whole check (``testbed values --truth N``): ``states`` states of the twin cell
    ``seed`` (:data:`TRUTH_SEED`: held out), their pushes' truth, judged for ``value``.
    The twin is imported here, on this path alone (the lab reaches the twin)."""
    import sim_twin.cell as twin

    with twin.TwinCell(seed=seed) as cell:
        drawn = draw_states(cell, states, np.random.default_rng(seed))
        return judge(drawn, truth_of_states(cell, drawn), value)
