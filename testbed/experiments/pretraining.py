"""Offline data and pretraining (the paper's 8.3.2, 8.3.3): what a trial starts from.

``collect_demos`` has the humans (the scripted expert in the twin, the console on
hardware) drive every arm and keeps the state-action pairs and full transitions;
``rollout_policy`` runs the pretrained BC policy (with a little noise, as the paper
suggests, to meet violations) for the safety critic's data. ``pretrain`` chains them:
demos -> policy steps -> BC rollouts -> critic steps, and ``cached_pretrain`` keeps
the result under a key of everything that shaped it, so later trials (every
algorithm of a protocol) start from the same theta_0 without paying for it again.

Which critics are pretrained is part of that key (issue 13): a protocol pretrains the
critics any of its algorithms reads, once; a lone trial its own algorithm's; ``testbed
pretrain --config`` what the trial or protocol of its config would (``--demos``: both).
With no critic to pretrain, the BC rollouts (the critics' data) are not collected either.

The collections keep what they have as they go (``Keep``) and go on from it, and
``pretrain`` skips what an earlier try kept (``Resume``): ``testbed.experiments.theta0``
holds them in the cache (issue 44). The demonstrations have a key of their own
(``demos_key``), without the learning config or the critics.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol

import numpy as np

from testbed.core.atomic import atomic_write_bytes
from testbed.core.config import ConfigError
from testbed.core.hosts import LoopHosts
from testbed.core.humans import Humans
from testbed.core.types import ArmObservation, HumanRequest, InterventionKind
from testbed.experiments.fleet_config import FleetConfig
from testbed.fleet.algorithms import ALGORITHMS
from testbed.learning.learning_config import LearningConfig

if TYPE_CHECKING:  # the learning package imports torch: only when data is really built
    from testbed.learning.api import Transitions

FIELDS = ("images", "actions", "next_images", "violation", "success")

CRITICS = ("safety", "goal")
"""The learner's critics ``act`` reads (``testbed.learning.learner.CRITICS``, without
importing torch)."""
TRAINABLE = (*CRITICS, "value")
"""Every critic theta_0 can pretrain: the value critic too (``learner.TRAINABLE``)."""


def critic_set(critics: Iterable[str] | None) -> tuple[str, ...]:
    """``critics`` checked and in ``TRAINABLE`` order; None: safety and goal."""
    if critics is None:
        return CRITICS
    if isinstance(critics, str):
        raise TypeError(f"critics: expected a collection of names, got the string {critics!r}")
    given = set(critics)
    unknown = sorted(given - set(TRAINABLE))
    if unknown:
        raise ValueError(f"critics: unknown critic(s) {', '.join(map(repr, unknown))}; "
                         f"use {', '.join(TRAINABLE)}")
    return tuple(c for c in TRAINABLE if c in given)


def pretrain_critics(algorithms: Iterable[str], weightings: Iterable[str] = ()) -> list[str]:
    """The critics theta_0 is pretrained with: every one that any of ``algorithms``
    reads (one theta_0 for a whole protocol, no critic pretrained for nobody), and the
    value critic where any of ``weightings`` (each run's ``learning.weighting``, or
    ``"advantage"`` for one conditioned on it) is ``"advantage"``: the advantage is its
    (``testbed/learning/advantage.py``)."""
    read: set[str] = set().union(*(ALGORITHMS[a].critics for a in algorithms))
    if "advantage" in set(weightings):
        read.add("value")
    return sorted(read)


Progress = Callable[[str, int, int], None]


def _transitions() -> type[Transitions]:
    from testbed.learning.api import Transitions

    return Transitions


def save_transitions(t: Transitions, path: Path) -> None:
    """Offline data as one compressed npz, written atomically."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: getattr(t, k) for k in FIELDS})
    atomic_write_bytes(path, buf.getvalue())


def load_transitions(path: Path) -> Transitions:
    with np.load(path) as z:
        missing = [k for k in FIELDS if k not in z.files]
        if missing:
            raise ConfigError(f"{path}: not a transitions file (missing {', '.join(missing)})")
        return _transitions().build(*(z[k] for k in FIELDS))


def concat(*parts: Transitions) -> Transitions:
    return _transitions().build(
        *(np.concatenate([getattr(p, k) for p in parts]) for k in FIELDS)
    )


def head(t: Transitions, n: int) -> Transitions:
    """The first ``n`` transitions of ``t`` (all of them when it has no more)."""
    return t if len(t) <= n else _transitions().build(*(getattr(t, k)[:n] for k in FIELDS))


class Keep(Protocol):
    """Where a collection keeps what it has as it goes (``testbed.experiments.theta0``:
    a partial npz in the cache, rewritten atomically), so that a crash, Ctrl-C or the
    operator's Esc loses at most the last few pairs, and a re-run goes on from them."""

    def due(self, unsaved: int) -> bool:
        """Whether to save now, with ``unsaved`` transitions not saved yet."""
        ...

    def save(self, part: Transitions) -> None:
        """This collection's transitions so far (the keeper adds what came before)."""
        ...


@dataclass
class _Pairs:
    """The transitions a collection has kept so far, and how many of them are saved."""

    images: list[np.ndarray] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    next_images: list[np.ndarray] = field(default_factory=list)
    violation: list[bool] = field(default_factory=list)
    success: list[bool] = field(default_factory=list)
    saved: int = 0

    def __len__(self) -> int:
        return len(self.actions)

    def add(self, image: np.ndarray, action: int, next_image: np.ndarray, violation: bool,
            success: bool) -> None:
        self.images.append(image)
        self.actions.append(action)
        self.next_images.append(next_image)
        self.violation.append(violation)
        self.success.append(success)

    def build(self) -> Transitions:
        return _transitions().build(np.stack(self.images), np.array(self.actions, np.int64),
                                    np.stack(self.next_images), np.array(self.violation),
                                    np.array(self.success))

    def keep(self, keep: Keep | None, *, now: bool = False) -> None:
        """Save through ``keep`` what is not saved yet: when it is due, or ``now``."""
        unsaved = len(self) - self.saved
        if keep is not None and unsaved > 0 and (now or keep.due(unsaved)):
            keep.save(self.build())
            self.saved = len(self)


STALL_STEPS = 50
"""Steps without one push that ran, after which the collection gives up (see _drive)."""


def _drive(
    hosts: LoopHosts,
    count: int,
    choose: Callable[[list[str], dict[str, ArmObservation], int], dict[str, int]],
    humans: Humans,
    t_R: int,
    progress: Progress | None,
    label: str,
    keep: Keep | None = None,
    done_before: int = 0,
) -> Transitions:
    """Push every healthy arm with ``choose`` until ``count`` transitions are kept.

    ``keep``: saves the transitions so far when it is due, and whatever ends the
    collection early (a fault, Ctrl-C, the operator's Esc) saves them before it goes on
    up; ``done_before``: what a resumed collection already had (progress counts it).
    """
    pairs = _Pairs()
    try:
        _drive_into(pairs, hosts, count, choose, humans, t_R, progress, label, keep,
                    done_before)
    except BaseException:
        pairs.keep(keep, now=True)
        raise
    return pairs.build()


def _drive_into(
    pairs: _Pairs,
    hosts: LoopHosts,
    count: int,
    choose: Callable[[list[str], dict[str, ArmObservation], int], dict[str, int]],
    humans: Humans,
    t_R: int,
    progress: Progress | None,
    label: str,
    keep: Keep | None,
    done_before: int,
) -> None:
    """``_drive``'s loop, into ``pairs``.

    Violating arms get a hard reset from the humans (t_R steps, as in a trial). When no
    arm has pushed for :data:`STALL_STEPS` steps (every push refused or faulted: a layout
    the arms cannot reach, a controller stopped) it stops with the last reason, instead
    of waiting for ever.
    """
    reset_served: dict[str, int] = {}
    prev: dict[str, tuple[np.ndarray, int]] = {}
    pending_outcome: dict[str, tuple[bool, bool]] = {}
    t, idle, why = 0, 0, ""
    while len(pairs) < count:
        obs = {r: o for r, o in hosts.observe().items() if isinstance(o, ArmObservation)}
        if not obs:
            raise RuntimeError("no arm answered: check the hosts (testbed check)")
        for r, (img, a) in prev.items():
            if r in obs and len(pairs) < count:
                v, s = pending_outcome[r]
                pairs.add(img, a, obs[r].image, v, s)
        pairs.keep(keep)
        prev, pending_outcome = {}, {}
        ready = [r for r, o in obs.items() if not o.violating]
        requests = [
            HumanRequest(r, i % 1_000_000, InterventionKind.RESET, o, reset_served.get(r, 0), t_R)
            for i, (r, o) in enumerate(obs.items())
            if o.violating
        ]
        answers = humans.act(requests, t) if requests else {}
        resets = [r for r, a in answers.items() if a.reset_done]
        for req in requests:
            reset_served[req.robot] = 0 if req.robot in resets else req.served + 1
        pushes = choose(ready, obs, t)
        results = hosts.execute(pushes, resets)
        for r, a in pushes.items():
            res = results.get(r)
            if res is not None and hasattr(res, "success") and not getattr(res, "refused",
                                                                            None):
                prev[r] = (obs[r].image, a)
                pending_outcome[r] = (bool(res.violation), bool(res.success))  # type: ignore[union-attr]
            else:
                why = str(getattr(res, "refused", None) or getattr(res, "reason", None) or
                          "no answer")
        idle = 0 if prev or not pushes else idle + 1
        if idle >= STALL_STEPS:
            raise RuntimeError(f"{label}: no arm pushed in {idle} steps; the last refusal: "
                               f"{why}")
        t += 1
        if progress is not None:
            progress(label, done_before + min(len(pairs), count), done_before + count)


def collect_demos(
    hosts: LoopHosts, humans: Humans, count: int, t_R: int, progress: Progress | None = None,
    *, keep: Keep | None = None, done_before: int = 0,
) -> Transitions:
    """``count`` human-driven pushes (every arm teleoperated); ``keep``, ``done_before``:
    as ``_drive``'s, for a collection kept as it goes and resumed."""

    def choose(ready: list[str], obs: dict[str, ArmObservation], t: int) -> dict[str, int]:
        reqs = [
            HumanRequest(r, i, InterventionKind.TELEOP, obs[r], 0, 1) for i, r in enumerate(ready)
        ]
        answers = humans.act(reqs, t) if reqs else {}
        return {r: int(a.action) for r, a in answers.items() if a.action is not None}

    return _drive(hosts, count, choose, humans, t_R, progress, "collect", keep, done_before)


def rollout_policy(
    hosts: LoopHosts,
    humans: Humans,
    learner: Any,
    count: int,
    t_R: int,
    seed: int,
    epsilon: float = 0.2,
    progress: Progress | None = None,
    *,
    keep: Keep | None = None,
    done_before: int = 0,
) -> Transitions:
    """``count`` pushes of the current policy, with epsilon-random actions; ``keep``,
    ``done_before``: as ``_drive``'s (a resumed rollout draws its noise from another
    stream, seeded by ``seed`` and ``done_before``)."""
    rng = np.random.default_rng(seed if done_before == 0 else [seed, done_before])

    def choose(ready: list[str], obs: dict[str, ArmObservation], t: int) -> dict[str, int]:
        if not ready:
            return {}
        acts = learner.act(np.stack([obs[r].image for r in ready])).actions
        noisy = rng.random(len(ready)) < epsilon
        rand = rng.integers(0, 4, len(ready))
        return {r: int(rand[i] if noisy[i] else acts[i]) for i, r in enumerate(ready)}

    return _drive(hosts, count, choose, humans, t_R, progress, "rollout", keep, done_before)


_HOW_TO_REACH = frozenset({"transport", "address", "port", "user", "key_file", "known_hosts",
                           "python", "workdir", "deadline_s", "heartbeat_s",
                           "connect_timeout_s", "ssh_alias", "ssh_config",
                           "credentials_file", "motion_timeout_s", "lock_dir"})
"""Host fields that say how a host is reached, not what it is: left out of the key, so a
rehearsal's fresh ports or a lab's new address do not throw theta_0 away."""


ONLINE_ONLY: Final = frozenset({"compile_act", "weighting", "pre_intervention_steps",
                                "class_weights", "advantage_temperature",
                                "advantage_max_weight", "advantage_refresh", "gamma_value",
                                "conditioning", "advantage_threshold", "condition_dropout",
                                "value_every"})
"""Learning fields that do not shape theta_0: left out of its key (``gamma_value`` shapes
a theta_0 that pretrains the value critic: its key then has it, :func:`pretrain_key`)."""


def pretrain_key(cfg: FleetConfig, seed: int, critics: Iterable[str] | None = None) -> str:
    """What shaped theta_0: the learning config, the fleet's robots, the seed, and the
    critics pretrained (None: both). Both critics keep the key of before the critics
    were a choice, so caches made then stay valid (they pretrained both)."""
    hosts = [{k: v for k, v in h.model_dump(mode="json").items() if k not in _HOW_TO_REACH}
             for h in cfg.hosts]
    which = critic_set(critics)
    fields: dict[str, Any] = {
        # compile_act changes how act runs, not what theta_0 is; the online weighting by
        # class changes what the trial learns after theta_0 (pretraining samples the
        # demonstrations alike whatever it says), so every way of a protocol shares theta_0
        "learning": cfg.learning.model_dump(mode="json", exclude=ONLINE_ONLY),
        "hosts": hosts,
        "t_R": cfg.algorithm.t_R,
        "seed": seed,
        # 3: theta_0 keeps the policy's feature density (issue 36's ood); one cached
        # before it would give ood 0 until its first training step, and BC never trains
        "v": 3,
    }
    if which != CRITICS:
        fields["critics"] = list(which)
    if "value" in which:
        fields["gamma_value"] = cfg.learning.gamma_value
    blob = json.dumps(fields, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def demos_key(cfg: FleetConfig, seed: int) -> str:
    """What shaped the demonstrations: the fleet's robots (as in :func:`pretrain_key`,
    without how they are reached), t_R and the seed; not the learning config nor the
    critics. Every theta_0 of these arms (any critics, any learning sizes, a protocol's
    ways) draws its demonstrations from one collection, which grows to the most any of
    them asks for (``testbed.experiments.theta0``)."""
    hosts = [{k: v for k, v in h.model_dump(mode="json").items() if k not in _HOW_TO_REACH}
             for h in cfg.hosts]
    fields = {"hosts": hosts, "t_R": cfg.algorithm.t_R, "seed": seed, "demos": 1}
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class Resume:
    """What an earlier try at this pretraining kept, and where this one keeps what it
    makes (``testbed.experiments.theta0`` fills it from its cache): a crash during the
    rollouts or the critics redoes neither the demonstrations nor the policy."""

    policy_trained: bool = False
    """The learner given already has its policy trained on the demos: skip that phase."""
    rollouts: Transitions | None = None
    """Rollouts kept from before: the rollout goes on from them."""
    keep_rollouts: Keep | None = None
    after_policy: Callable[[Any], None] | None = None
    """Called with the learner when its policy phase is done (theta_0's checkpoint)."""
    resumed: Progress | None = None
    """Told once of a phase that goes on from what was kept (the progress display's
    speed and ETA then count only this run's work)."""


def pretrain(
    learner: Any,
    lc: LearningConfig,
    demos: Transitions,
    hosts: LoopHosts,
    humans: Humans,
    t_R: int,
    seed: int,
    progress: Progress | None = None,
    critics: Iterable[str] | None = None,
    resume: Resume | None = None,
) -> Transitions:
    """Policy on the demos; then ``critics`` (None: both) on the expert's and the BC
    rollouts' pushes. Returns the transitions added to the learner.

    The safety critic needs violations, which the expert almost never makes: the
    rollouts of the pretrained (noisy) BC policy supply them (the paper's 8.3.2). With no
    critic to pretrain no rollout is made and only the demos' pushes are added.
    ``resume``: what an earlier try kept (:class:`Resume`).
    """
    which = critic_set(critics)
    kept = resume if resume is not None else Resume()

    def phase(name: str) -> Progress | None:
        if progress is None:
            return None
        return lambda _p, done, total: progress(f"pretrain {name}", done, total)

    if not kept.policy_trained:
        learner.pretrain(demos.images, demos.actions, steps=lc.pretrain_steps,
                         progress=phase("policy"))
        if kept.after_policy is not None:
            kept.after_policy(learner)
    rollouts = (_rollouts(learner, lc.critic_transitions, hosts, humans, t_R, seed, progress,
                          kept) if which and lc.critic_transitions > 0 else None)
    data = demos if rollouts is None else concat(demos, rollouts)
    learner.pretrain(transitions=data, steps=lc.critic_steps, progress=phase("critics"),
                     critics=which)
    return data


def _rollouts(learner: Any, count: int, hosts: LoopHosts, humans: Humans, t_R: int,
              seed: int, progress: Progress | None, kept: Resume) -> Transitions:
    """``count`` BC rollouts, going on from those kept before."""
    have = kept.rollouts
    n = 0 if have is None else len(have)
    if have is not None and n >= count:
        return head(have, count)
    if n and kept.resumed is not None:
        kept.resumed("rollout", n, count)
    new = rollout_policy(hosts, humans, learner, count - n, t_R, seed, progress=progress,
                         keep=kept.keep_rollouts, done_before=n)
    return new if have is None else concat(have, new)
