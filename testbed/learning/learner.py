"""The Learner: the one object the fleet loop and the CLI use for everything learned.

Why a facade: the loop needs five verbs (act, add data, train, pretrain, save/load) and
must not know about ensembles, critics, target networks, replay or augmentation. One
lock makes every verb safe to call from the training thread and the main thread (the
loop joins training before act(), but a lock costs nothing and rules out a torn step).

    human labels ──► add_human ──► PolicyData (x factor augmented, bootstrap weights)
                                        │ per-member minibatches
                                        ▼
    images ──► act ──► PolicyEnsemble ──► actions, probs, uncertainty, novelty
                 │                │ pi(s), pi(s')
                 └──► safety / goal Critic ──► risk, goal_risk
    every push ──► add_transitions ──► TransitionBuffer ──► critic minibatches (25 % / 25 %)

Learning by class (issue 30): with ``learning.weighting = "intervention"`` the fleet loop
also gives the robot's own pushes as their episodes end (``add_robot``, fed by
``testbed.records.frame_classes.LabelFeed``), and each sample counts by its class and its
episode's outcome (``class_weights``) when a member draws its minibatch; pretraining
draws the demonstrations alike (theta_0 is the same for every weighting). ``"uniform"``
is today's training, draw for draw.

Learning by advantage (issue 46, ``advantage.py``): with ``weighting = "advantage"``
(AWR) or ``conditioning = "advantage"`` (RECAP's way) the robot's pushes come in as for
learning by class (every class counts), the value critic (:data:`VALUE`) trains beside
the policy, and every sample's advantage is refreshed on a schedule of update counts
(``_refresh_advantages``) and saved with the training state.

Parts (issue 13): a learner trains online only the parts its algorithm uses
(``train``: a subset of policy, safety, goal; default all three) and ``act`` computes
only the critics it reads (``read``; default both): C.U.R. trains the policy and the
safety critic, Fleet-ThriftyDAgger the policy and the goal critic, Fleet-ED and Random
the policy alone, BC nothing. The trial sets them from ``AlgorithmSpec`` after loading
theta_0 (``set_parts``), so one checkpoint serves every algorithm. ``pretrain`` takes
its own set of critics (what any algorithm of a protocol reads). Per-part counters
(``policy_updates``, ``safety_updates``, ``goal_updates``) are in ``stats()`` and the
checkpoint.

Reproducibility: the initial weights come from the seed (torch's global generator is
forked and restored, so other code's randomness is untouched), every minibatch from the
learner's own ``torch.Generator``, every augmentation from a per-chunk generator, and a
checkpoint holds the weights, the optimisers, the data and the generator state: the same
seed and the same calls give the same weights on CPU, also across save/load.

Over 450 lines, on purpose: the learner's data, networks, optimisers, sampler and
counters share one lock and one checkpoint; acting is in ``actor.py``, the critics in
``critics.py``, the features' density in ``features.py``.
"""

from __future__ import annotations

import copy
import threading
import warnings
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import torch

from testbed.core.types import EpisodeOutcome, FrameClass
from testbed.learning import checkpoint
from testbed.learning.actor import Actor, infer
from testbed.learning.advantage import AdvantageState, PushValues, push_values
from testbed.learning.api import (
    EnsembleImpl,
    PolicyOutput,
    ProgressFn,
    Transitions,
    check_actions,
    check_images,
)
from testbed.learning.critics import Combine, Critic, CriticBatch, CriticSpec
from testbed.learning.data import PolicyData, TransitionBuffer
from testbed.learning.features import FeatureDensity
from testbed.learning.learning_config import ClassWeights, LearningConfig
from testbed.learning.networks import TRUNK_FEATURES
from testbed.learning.policy import (
    POSITIVE,
    PolicyEnsemble,
    ensemble_signals,
    fit_saved_policy,
)
from testbed.learning.runtime import (
    STREAM_INIT,
    STREAM_SAMPLE,
    LearningError,
    configure_torch,
    derive_seed,
    generator,
    resolve_device,
    resolve_impl,
)

CRITICS: Final[tuple[str, ...]] = ("safety", "goal")
"""The critics ``act`` can read, in the order they are updated on a shared minibatch."""
VALUE: Final = "value"
"""The advantage's critic (``advantage.py``): the goal critic's targets at ``gamma_value``,
made when a learner learns by advantage or pretrains it, updated after the others."""
TRAINABLE: Final[tuple[str, ...]] = (*CRITICS, VALUE)

PARTS: Final[tuple[str, ...]] = ("policy", *TRAINABLE)
"""Everything a learner can train."""
DEFAULT_PARTS: Final[tuple[str, ...]] = ("policy", *CRITICS)
"""What a learner trains unless told (the value critic only where asked for)."""


def _parts(value: Iterable[str] | None, allowed: tuple[str, ...], what: str,
           default: tuple[str, ...] | None = None) -> frozenset[str]:
    """``value`` as a checked frozenset (None: ``default``, else all of ``allowed``)."""
    if value is None:
        return frozenset(allowed if default is None else default)
    if isinstance(value, str):
        raise TypeError(f"{what}: expected a collection of names, got the string {value!r}")
    parts = frozenset(value)
    unknown = sorted(parts - set(allowed))
    if unknown:
        raise ValueError(f"{what}: unknown part(s) {', '.join(map(repr, unknown))}; "
                         f"use {', '.join(allowed)}")
    return parts


def _copy_into(dst: Any, src: Any) -> bool:
    """Copy ``src``'s tensors into ``dst``'s of the same place, shape and dtype, and its
    other values over; False (``dst`` then half-written: drop it) where the two differ
    in layout."""
    if isinstance(src, dict | list):
        if type(dst) is not type(src) or len(dst) != len(src):
            return False
        keys = list(src) if isinstance(src, dict) else range(len(src))
        if isinstance(src, dict) and dst.keys() != src.keys():
            return False
        for k in keys:
            v = src[k]
            if isinstance(v, torch.Tensor | dict | list):
                if not _copy_into(dst[k], v):
                    return False
            else:
                dst[k] = copy.deepcopy(v)
        return True
    if isinstance(src, torch.Tensor):
        if (not isinstance(dst, torch.Tensor) or dst.shape != src.shape
                or dst.dtype != src.dtype or dst.device != src.device):
            return False
        dst.copy_(src)
        return True
    return False


def acted_table() -> torch.Tensor:
    """``weighting = "advantage"``'s class table: every push counts (a demonstration, a
    human's, the robot's in any episode); its advantage weighs it, not its class."""
    return class_table(ClassWeights(demo=1.0, teleop=1.0, robot=1.0, pre_intervention=1.0,
                                    robot_failed=1.0))


def class_table(w: ClassWeights) -> torch.Tensor:
    """Each (FrameClass, EpisodeOutcome)'s weight: a robot push counts ``robot`` in an
    episode that succeeded and ``robot_failed`` in any other (one still open, too: an
    episode that never ended is not a success); resets and frames nobody acted in carry
    no action and count 0."""
    table = torch.zeros(len(FrameClass), len(EpisodeOutcome), dtype=torch.float32)
    table[FrameClass.DEMO] = w.demo
    table[FrameClass.TELEOP] = w.teleop
    table[FrameClass.PRE_INTERVENTION] = w.pre_intervention
    table[FrameClass.ROBOT] = w.robot_failed
    table[FrameClass.ROBOT, EpisodeOutcome.SUCCESS] = w.robot
    return table


def _ticks(phase: str, total: int, progress: ProgressFn | None) -> Iterator[int]:
    """range(total) that reports each finished step to ``progress``."""
    for i in range(total):
        yield i
        if progress is not None:
            progress(phase, i + 1, total)


FEATURE_SAMPLE: Final = 64
"""Labelled images folded into the feature density (``_update_features``) every
``FEATURE_EVERY`` policy updates: the trunks alone, no head."""
FEATURE_EVERY: Final = 2
"""Every 2nd policy update (the first included): the trunks alone on 64 images, ~2 % of a
batch-256 step amortised (``benchmarks/bench_monitor.py``); every update with the heads
cost 120 ms. Every 4th lagged the trunk too far on a policy trained from scratch (noise
images ranked 0.68 against held-out scenes, docs/notes/monitor.md)."""
FEATURE_STRIDE: Final = 7919
"""A prime: the sweep's images are spread over the data, not 32 neighbours (one chunk)."""


class Learner:
    """Policy ensemble + safety critic + goal critic + their data, for one trial.

    ``impl`` picks how the ensemble runs (``auto``: the faster for the device);
    ``num_threads`` torch's CPU threads (default: all cores this process may use);
    ``train`` the parts ``train_step`` trains (default all of ``PARTS``), ``read`` the
    critics ``act`` computes (default both): see :meth:`set_parts`.
    """

    def __init__(
        self,
        cfg: LearningConfig,
        seed: int,
        *,
        impl: EnsembleImpl = "auto",
        num_threads: int | None = None,
        train: Iterable[str] | None = None,
        read: Iterable[str] | None = None,
    ) -> None:
        self.cfg = cfg
        self.seed = int(seed)
        self.num_threads = configure_torch(num_threads)
        self.device = resolve_device(cfg.device)
        self.impl = resolve_impl(impl, self.device)
        self._lock = threading.RLock()
        with torch.random.fork_rng(devices=[]):
            torch.random.default_generator.manual_seed(derive_seed(self.seed, STREAM_INIT))
            self.policy = PolicyEnsemble(cfg.ensemble_size, self.impl, conditioned=(
                cfg.conditioning == "advantage")).to(self.device)
            self.safety = Critic(CriticSpec("safety", cfg.gamma_safe, "max"), cfg.lr, self.device)
            self.goal = Critic(CriticSpec("goal", cfg.gamma_goal, "min"), cfg.lr, self.device)
        self.policy_optimizer = torch.optim.Adam(self.policy.parameters(), lr=cfg.lr)
        self.features = FeatureDensity(cfg.ensemble_size, TRUNK_FEATURES).to(self.device)
        """What the policy has trained on, in its own feature space (``act``'s ``ood``)."""
        self._sampler = generator(self.seed, STREAM_SAMPLE)
        self.policy_data = PolicyData(cfg.ensemble_size, cfg.augmentation_factor, self.seed)
        self._fleet_names: list[str] | None = None
        """The run's people by human index (``name_fleet``; not saved)."""
        self.transitions = TransitionBuffer()
        self.policy_updates = 0
        self.critic_updates = 0
        """Critic minibatches (one shared pi(s') each), whichever critics they updated."""
        self.safety_updates = 0
        self.goal_updates = 0
        self.value: Critic | None = None
        """The advantage's critic (:data:`VALUE`), once made (:meth:`_value_critic`)."""
        self.value_updates = 0
        if cfg.by_advantage:
            self._value_critic()
        self._class_table = (class_table(cfg.class_weights) if cfg.weighting == "intervention"
                             else acted_table() if cfg.by_advantage else None)
        self.advantages = (AdvantageState(
            cfg.advantage_temperature, cfg.advantage_max_weight, cfg.advantage_refresh,
            cfg.advantage_threshold, cfg.condition_dropout) if cfg.by_advantage else None)
        """Each policy sample's advantage (learning by advantage: ``weighting`` or
        ``conditioning``), else None."""
        self.train_parts: frozenset[str] = frozenset(DEFAULT_PARTS)
        self.read_critics: frozenset[str] = frozenset(CRITICS)
        self.set_parts(train=train, read=read)

    def _value_critic(self) -> Critic:
        """The value critic, made on first need from its own seed stream (the same
        weights whenever it is made; nothing else's draws move)."""
        if self.value is None:
            with torch.random.fork_rng(devices=[]):
                torch.random.default_generator.manual_seed(
                    derive_seed(self.seed, STREAM_INIT, 1))
                self.value = Critic(CriticSpec(VALUE, self.cfg.gamma_value, "min"),
                                    self.cfg.lr, self.device)
        return self.value

    def set_parts(self, *, train: Iterable[str] | None = None,
                  read: Iterable[str] | None = None) -> None:
        """What this learner's algorithm uses (``AlgorithmSpec.train_parts`` / ``critics``).

        ``train`` ⊆ {"policy", "safety", "goal", "value"}: the parts ``train_step``
        updates (default: all but "value"; the
        critics share one minibatch and one pi(s') forward pass, skipped when no critic
        trains); ``read`` ⊆ {"safety", "goal"}: the critics ``act`` evaluates. A critic
        not read gives ``act`` a placeholder of zeros (risk 0, goal_risk 0: finite, so
        logs, keys and the console's reason stay valid; nothing reads them). None: all.
        Learning by advantage (``weighting`` or ``conditioning`` = "advantage"), the
        value critic trains too whenever the policy does: the advantages are its
        (``advantage.py``).
        Weights, data and counters are untouched; ``pretrain`` takes its own set.
        """
        with self._lock:
            self.train_parts = _parts(train, PARTS, "train", DEFAULT_PARTS)
            if self.advantages is not None and "policy" in self.train_parts:
                self.train_parts |= {VALUE}
            if VALUE in self.train_parts:
                self._value_critic()
            self.read_critics = _parts(read, CRITICS, "read")

    # ------------------------------------------------------------------ queries
    @property
    def has_data(self) -> bool:
        """Whether the policy has labelled data (an untrained policy acts at random)."""
        return len(self.policy_data) > 0

    def stats(self) -> dict[str, int]:
        """Sizes and counters, for logs and the console."""
        with self._lock:
            return {
                "human_samples": len(self.policy_data),
                **self.transitions.counts(),
                "policy_updates": self.policy_updates,
                "critic_updates": self.critic_updates,
                "safety_updates": self.safety_updates,
                "goal_updates": self.goal_updates,
                "value_updates": self.value_updates,
            }

    def numerics(self) -> dict[str, Any]:
        """What decides this learner's numbers besides the seed (for run.json): the same
        seed gives the same weights only with the same torch, thread count, device and
        ``compile_act`` (reductions split differently across threads)."""
        return {"torch": torch.__version__, "threads": self.num_threads,
                "device": str(self.device), "impl": self.impl,
                "compile_act": self.cfg.compile_act}

    def critics(self) -> dict[str, Critic]:
        """The critics by name (``CRITICS`` order)."""
        return {"safety": self.safety, "goal": self.goal}

    def _critic_nets(self) -> dict[str, tuple[torch.nn.Module, Combine]]:
        """What ``infer`` reads of the critics: each online net and its combination."""
        return {name: (c.net, c.spec.combine) for name, c in self.critics().items()}

    def act(self, images: npt.ArrayLike) -> PolicyOutput:
        """Actions and priority signals for uint8 images (N, 64, 64, 3).

        ``risk`` / ``goal_risk`` are zeros when their critic is not in ``read_critics``
        (the algorithm does not read it: the critic's forward pass is skipped)."""
        with self._lock:
            return infer(self.policy, self._critic_nets(), self.read_critics, self.device,
                         images, self.features)

    def acting_copy(self) -> Actor:
        """An ``Actor``: ``act`` on copies of these networks, brought up to date by its
        ``sync()``, so that act can run while ``train_step`` does (the fleet loop);
        compiled when ``cfg.compile_act``."""
        return Actor(self._lock, self.policy, self._critic_nets(), lambda: self.read_critics,
                     self.device, compile=self.cfg.compile_act, features=self.features)

    def signals_on_data(self, limit: int = 2000) -> dict[str, np.ndarray]:
        """``uncertainty`` and ``risk`` (the safety critic at pi(s)) on the states of this
        learner's transitions (theta_0's: its pretraining rollouts, the states the robots
        visit at first), or of its labelled images when it has no transition; the first
        ``limit``. Empty arrays without data. For thresholds given as quantiles."""
        with self._lock:
            if len(self.transitions):
                images = self.transitions.gather(torch.arange(min(limit, len(
                    self.transitions))))["images"].numpy()
            else:
                images = self.policy_data.originals()[:limit]
            if len(images) == 0:
                return {"uncertainty": np.zeros(0, np.float32), "risk": np.zeros(0, np.float32)}
            nets = self._critic_nets()
            out = [infer(self.policy, nets, frozenset({"safety"}), self.device,
                         images[i:i + 256]) for i in range(0, len(images), 256)]
        return {"uncertainty": np.concatenate([o.uncertainty for o in out]),
                "risk": np.concatenate([o.risk for o in out])}

    def critic_values(self, images: npt.ArrayLike, actions: npt.ArrayLike
                      ) -> dict[str, np.ndarray]:
        """The critics at given actions (diagnostics, tests): ``risk`` = Q_risk(s, a),
        ``goal_risk`` = 1 - Q_goal(s, a), float32 (N,) in [0, 1]."""
        arr = check_images(images)
        acts = check_actions(actions, arr.shape[0])
        with self._lock, torch.no_grad():
            x = torch.from_numpy(arr).to(self.device)
            a = torch.from_numpy(acts).to(self.device)
            return {
                "risk": self.safety.values(x, a).float().cpu().numpy(),
                "goal_risk": (1.0 - self.goal.values(x, a)).float().cpu().numpy(),
            }

    # ------------------------------------------------------------------ data
    def add_human(self, images: npt.ArrayLike, actions: npt.ArrayLike,
                  labellers: npt.ArrayLike | None = None,
                  names: Sequence[str] | None = None) -> None:
        """Human-labelled (image, action) pairs for the policy, stored x factor augmented;
        ``labellers``: who gave each label (None: no human of the fleet, e.g. an offline
        demonstration; -1 likewise), an index into ``names`` (a merged export's people)
        or, without ``names``, the fleet's human index (the loop's); kept beside it as
        one code per person (``labellers``, ``labeller_names``)."""
        arr = check_images(images)
        acts = check_actions(actions, arr.shape[0])
        who = None if labellers is None else np.asarray(labellers, dtype=np.int64).reshape(-1)
        if who is not None and who.shape[0] != arr.shape[0]:
            raise ValueError(f"{who.shape[0]} labellers for {arr.shape[0]} labels")
        with self._lock:
            self.policy_data.add(arr, acts, labellers=who,
                                 names=self._fleet_names if names is None else names)

    def name_fleet(self, names: Sequence[str]) -> None:
        """Who the fleet's human indices are in the run this learner now learns in (its
        config's ``[humans]`` names, as its run.json lists them): a label given by index
        alone (the loop's, a resume's replay) is kept under that person's name. Not
        saved with the learner: one loaded into another run is told that run's people
        (its index 0 may be someone else)."""
        with self._lock:
            self._fleet_names = list(names)

    @property
    def robot_frames(self) -> bool:
        """Whether this learner learns from the robot's own pushes too (``weighting =
        "intervention"``): the fleet loop then feeds it ``add_robot``."""
        return self._class_table is not None

    @property
    def pre_intervention_steps(self) -> int:
        """k of the frame classes (``learning.pre_intervention_steps``)."""
        return self.cfg.pre_intervention_steps

    def add_robot(self, images: npt.ArrayLike, actions: npt.ArrayLike,
                  classes: npt.ArrayLike, outcomes: npt.ArrayLike) -> None:
        """The robot's own pushes of ended episodes (``FrameClass`` ROBOT or
        PRE_INTERVENTION, with their ``EpisodeOutcome``): kept where their class weight
        is above 0 (``class_weights``), augmented and bootstrapped as a human's label.
        Ignored by a learner that does not learn from them (``robot_frames``)."""
        if self._class_table is None:
            return
        arr = check_images(images)
        acts = check_actions(actions, arr.shape[0])
        cls = np.asarray(classes, dtype=np.int64).reshape(-1)
        ends = np.asarray(outcomes, dtype=np.int64).reshape(-1)
        if cls.shape[0] != arr.shape[0] or ends.shape[0] != arr.shape[0]:
            raise ValueError(f"add_robot: {arr.shape[0]} images, {cls.shape[0]} classes, "
                             f"{ends.shape[0]} outcomes")
        keep = self._class_table[torch.from_numpy(cls), torch.from_numpy(ends)].numpy() > 0
        if keep.any():
            with self._lock:
                self.policy_data.add(arr[keep], acts[keep], classes=cls[keep],
                                     outcomes=ends[keep])

    def label_classes(self) -> tuple[np.ndarray, np.ndarray]:
        """Each policy sample's ``FrameClass`` and episode outcome, in the order added."""
        with self._lock:
            return self.policy_data.classes()

    @property
    def labellers(self) -> np.ndarray:
        """Who gave each of the policy's labels, in the order added: a code of
        ``labeller_names`` (-1: no human)."""
        with self._lock:
            return self.policy_data.labellers()

    @property
    def labeller_names(self) -> list[str]:
        """Labeller code -> the person: a name (the run's people, ``name_fleet``; or an
        export's), else ``"human<i>"`` (``unnamed_human``: the config named no one, or
        the learner was not told the run's people), else an export's unnamed human."""
        with self._lock:
            return list(self.policy_data.labeller_names)

    def add_transitions(
        self,
        images: npt.ArrayLike,
        actions: npt.ArrayLike,
        next_images: npt.ArrayLike,
        violation: npt.ArrayLike,
        success: npt.ArrayLike,
    ) -> None:
        """Pushes (any arm, any mode) for the critics."""
        t = Transitions.build(images, actions, next_images, violation, success)
        with self._lock:
            self.transitions.add(t)

    # ------------------------------------------------------------------ training
    def train_step(self) -> dict[str, float]:
        """``cfg.gradient_steps`` updates of the parts in ``train_parts``, at
        ``cfg.batch_size``. A part not trained or with no data is skipped and its key
        left out: ``policy_loss`` (mean cross-entropy over members), ``safety_loss``,
        ``goal_loss`` (TD losses, BCE). With no part to train: ``{}``, nothing drawn."""
        steps = self.cfg.gradient_steps
        with self._lock:
            sums: dict[str, float] = {}
            for _ in range(steps):
                for key, value in self._one_step().items():
                    sums[key] = sums.get(key, 0.0) + value
            return {k: v / steps for k, v in sums.items()}

    def _one_step(self) -> dict[str, float]:
        losses: dict[str, float] = {}
        if "policy" in self.train_parts and len(self.policy_data):
            losses["policy_loss"] = self._policy_update()
        critics = tuple(c for c in TRAINABLE if c in self.train_parts)
        if critics and len(self.transitions):
            losses.update(self._critic_update(critics, online=True))
        return losses

    def push_values(self, images: npt.ArrayLike, actions: npt.ArrayLike) -> PushValues:
        """The value critic's Q(s, a), V(s) = Q(s, pi(s)) and pi(s) of uint8 images
        (N, 64, 64, 3) and their pushes; ``.advantage`` is A(s, a)
        (``testbed/learning/advantage.py``). A learner without a value critic makes an
        untrained one (``value_updates`` says whether it learnt anything)."""
        arr = check_images(images)
        acts = check_actions(actions, arr.shape[0])
        with self._lock:
            value = self._value_critic()
            return push_values(self.policy, value.net, value.spec.combine,
                               torch.from_numpy(arr), torch.from_numpy(acts), self.device)

    def _refresh_advantages(self) -> AdvantageState | None:
        """The samples' advantages (learning by advantage), every sample valued again
        first when the update count says so, else the samples added since, every
        ``NEW_EVERY``-th update (:class:`AdvantageState`); None when not learning by
        advantage."""
        adv = self.advantages
        if adv is None:
            return None
        images, actions = self.policy_data.originals_and_actions()
        start = 0 if adv.due(self.policy_updates) else int(adv.advantage.shape[0])
        if start < images.shape[0] and (start == 0 or adv.new_due(self.policy_updates)):
            value = self._value_critic()
            got = torch.from_numpy(push_values(
                self.policy, value.net, value.spec.combine, images[start:], actions[start:],
                self.device).advantage)
            if start == 0:
                adv.set_advantages(got)
            else:
                adv.extend(got)
        return adv

    def _policy_update(self, weighted: bool = True) -> float:
        adv = self._refresh_advantages() if weighted else None
        awr = (adv.weights(len(self.policy_data))
               if adv is not None and self.cfg.weighting == "advantage" else None)
        images, actions, index = self.policy_data.sample(
            self.cfg.batch_size, self._sampler, self._class_table if weighted else None,
            awr, with_index=True)
        indicator = None
        if self.policy.conditions is not None:
            indicator = (adv.indicators(index, self._sampler) if adv is not None
                         else torch.full(index.shape, POSITIVE))  # pretraining: the demos
            indicator = indicator.to(self.device)
        loss, per_member = self.policy.loss(images.to(self.device), actions.to(self.device),
                                            indicator)
        self.policy_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.policy_optimizer.step()
        self._update_features()
        self.policy_updates += 1
        return float(per_member.mean())

    def _update_features(self) -> None:
        """Every ``FEATURE_EVERY`` updates, fold ``FEATURE_SAMPLE`` of the labelled images,
        as they were added (not the augmented copies the step trained on: the colour
        jitter would teach the density that any colour is familiar), into ``features``,
        through the trunks just updated. The images are a strided sweep through the data
        by update count: no random draw, so training's random streams are untouched and a
        resume picks up exactly."""
        n = len(self.policy_data)
        if n == 0 or self.policy_updates % FEATURE_EVERY:
            return
        k = min(FEATURE_SAMPLE, n)
        index = (self.policy_updates * k + torch.arange(k) * FEATURE_STRIDE) % n
        with torch.no_grad():
            images = self.policy_data.original_images(index).to(self.device)
            self.features.update(self.policy.trunk_features(images))

    def _critic_update(self, critics: tuple[str, ...] = CRITICS, online: bool = False
                       ) -> dict[str, float]:
        """One minibatch for ``critics`` (non-empty, in ``TRAINABLE`` order): one sample,
        one pi(s') forward pass shared by them, one update each; ``online`` (a training
        step's, not pretraining's): the value critic only every ``value_every``-th."""
        index = self.transitions.sample_indices(self.cfg.batch_size, self._sampler)
        b = {k: v.to(self.device) for k, v in self.transitions.gather(index).items()}
        with torch.no_grad():
            next_actions = ensemble_signals(self.policy(b["next_images"]))["actions"]
        violation = b["violation"].float()
        success = b["success"].float()
        losses: dict[str, float] = {}
        if "safety" in critics:
            losses["safety_loss"] = self.safety.update(CriticBatch(
                b["images"], b["actions"], b["next_images"], next_actions,
                reward=violation, done=violation,
            ))
            self.safety_updates += 1
        if "goal" in critics:
            losses["goal_loss"] = self.goal.update(CriticBatch(
                b["images"], b["actions"], b["next_images"], next_actions,
                reward=success, done=torch.maximum(success, violation),
            ))
            self.goal_updates += 1
        if VALUE in critics and not (online and self.critic_updates % self.cfg.value_every):
            losses["value_loss"] = self._value_critic().update(CriticBatch(
                b["images"], b["actions"], b["next_images"], next_actions,
                reward=success, done=torch.maximum(success, violation),
            ))
            self.value_updates += 1
        self.critic_updates += 1
        return losses

    def pretrain(
        self,
        demo_images: npt.ArrayLike | None = None,
        demo_actions: npt.ArrayLike | None = None,
        transitions: Transitions | None = None,
        steps: int | None = None,
        progress: ProgressFn | None = None,
        critics: Iterable[str] | None = None,
        demo_labellers: npt.ArrayLike | None = None,
        labeller_names: Sequence[str] | None = None,
    ) -> dict[str, float]:
        """Offline training (``testbed pretrain``), in the order the data arrives:

        1. with demos: add them (augmented) and train the policy alone for ``steps``;
        2. with transitions (the BC policy's rollouts for the safety critic, the expert's
           for the goal critic; both critics see all): add them and train ``critics``
           (default both; a protocol passes what any of its algorithms reads) for
           ``steps``, with pi(s') from the policy as trained so far. With no critic the
           transitions are added and no step runs (no ``"critics"`` progress).

        Call it once with both, or once per phase. ``steps`` defaults to
        ``cfg.pretrain_steps``. Returns the mean losses over the last 20 steps of each
        phase run (no key for a phase that ran no step). With ``steps`` None the critics
        take ``cfg.critic_steps`` (``critic_pretrain_steps``, else ``pretrain_steps``).
        ``demo_labellers``, ``labeller_names``: who gave each demo label
        (``add_human``'s ``labellers`` and ``names``; exported runs' teleop labels keep
        their labeller by name, offline demonstrations are -1).
        """
        total = self.cfg.pretrain_steps if steps is None else int(steps)
        critic_total = self.cfg.critic_steps if steps is None else int(steps)
        which = tuple(c for c in TRAINABLE
                      if c in _parts(critics, TRAINABLE, "critics", CRITICS))
        if (demo_images is None) != (demo_actions is None):
            raise ValueError("pretrain needs demo_images and demo_actions together")
        result: dict[str, float] = {}
        with self._lock:
            if demo_images is not None:
                self.add_human(demo_images, demo_actions,  # type: ignore[arg-type]
                               labellers=demo_labellers, names=labeller_names)
                tail = [self._policy_update(weighted=False)
                        for _ in _ticks("policy", total, progress)]
                if tail:
                    result["policy_loss"] = float(np.mean(tail[-20:]))
            if transitions is not None:
                self.transitions.add(transitions)
                if which:
                    tail_c = [self._critic_update(which)
                              for _ in _ticks("critics", critic_total, progress)]
                    for key in (f"{c}_loss" for c in which):
                        if tail_c:
                            result[key] = float(np.mean([d[key] for d in tail_c[-20:]]))
        return result

    def reseed(self, seed: int) -> None:
        """Give this learner a new seed for everything random from now on (minibatches,
        augmentation and bootstrap weights of new data); weights and data are kept.

        Why: every trial of a protocol starts from the same pretrained theta_0 (loaded
        from one checkpoint), and each trial's seed must still make its own training
        reproducible and distinct."""
        with self._lock:
            self.seed = int(seed)
            self._sampler = generator(self.seed, STREAM_SAMPLE)
            self.policy_data.seed = self.seed

    # ------------------------------------------------------------------ persistence
    def state_dict(self) -> dict[str, Any]:
        """Everything a trial needs to continue exactly, its data included (theta_0, a
        run's final policy, ``testbed pretrain``)."""
        return self.state_dict_parts(data=True)

    def state_dict_parts(self, *, data: bool) -> dict[str, Any]:
        """``state_dict()``, with or without the data (``training_state``)."""
        with self._lock:
            state = {
                "format": checkpoint.FORMAT,
                "cfg": self.cfg.model_dump(),
                "seed": self.seed,
                "policy": self.policy.state_dict(),
                "policy_optimizer": self.policy_optimizer.state_dict(),
                "safety": self.safety.state_dict(),
                "goal": self.goal.state_dict(),
                "features": self.features.state_dict(),
                "sampler": self._sampler.get_state(),
                "counters": [self.policy_updates, self.critic_updates,
                             self.safety_updates, self.goal_updates],
            }
            if self.advantages is not None:
                state["advantages"] = self.advantages.state_dict()
            if self.value is not None:
                state["value"] = {**self.value.state_dict(), "updates": self.value_updates}
            if data:
                state["policy_data"] = self.policy_data.state_dict()
                state["transitions"] = self.transitions.state_dict()
            return state

    def data_sizes(self) -> dict[str, int]:
        """How much data the learner holds: labelled images, their ``add`` chunks (the
        augmentation seeds follow the chunk count) and transitions."""
        with self._lock:
            return {"policy": len(self.policy_data), "chunks": self.policy_data.num_chunks,
                    "transitions": len(self.transitions)}

    def training_state(self, into: dict[str, Any] | None = None) -> dict[str, Any]:
        """``state_dict()`` without the data: weights, optimisers, the sampler, the
        counters and the data's sizes, every tensor its own copy. The per-step
        checkpoint: a resumed trial gets its data back from the run's data store
        (``testbed.records.store.replay``), so this stays ~the weights' size however long the
        run (the whole state grew ~0.3 MB a step at 4 arms, ~2.5 MB at 100).

        ``into``: an earlier ``training_state()`` that nobody reads any more (the
        checkpoint writer's, once written): its tensors are overwritten in place and it
        is returned, 7 ms instead of 45 ms for the paper's learner (fresh memory is what
        costs, in the loop's thread); a fresh copy if its layout no longer matches."""
        with self._lock:
            state = self.state_dict_parts(data=False)
            state["format"] = checkpoint.TRAINING_FORMAT
            state["data_sizes"] = self.data_sizes()
            if into is not None and _copy_into(into, state):
                return into
            return copy.deepcopy(state)

    def load_training_state(self, state: dict[str, Any], where: str = "checkpoint") -> None:
        """Weights, optimisers, sampler and counters from ``training_state()``; the data
        must already be back (replayed) and match the sizes the state was taken at."""
        with self._lock:
            have, want = self.data_sizes(), dict(state["data_sizes"])
            if have != want:
                raise LearningError(f"{where}: the learner's data {have} is not the data "
                                    f"the checkpoint was taken with {want}")
            self._load_training(state, where)

    def _load_training(self, state: dict[str, Any], where: str = "checkpoint") -> None:
        self.seed = int(state["seed"])
        self.policy_data.seed = self.seed
        policy, optimizer = fit_saved_policy(self.policy, state["policy"],
                                             state["policy_optimizer"], where)
        self.policy.load_state_dict(policy)
        self.policy_optimizer.load_state_dict(optimizer)
        self.safety.load_state_dict(state["safety"])
        self.goal.load_state_dict(state["goal"])
        if "features" in state:  # saved before issue 36: none yet, the next update starts it
            self.features.load_state_dict(state["features"])
        if "value" in state:  # a learner by advantage, or one that pretrained it
            saved = dict(state["value"])
            self.value_updates = int(saved.pop("updates"))
            self._value_critic().load_state_dict(saved)
            self._value_critic().set_lr(self.cfg.lr)
        if self.advantages is not None and "advantages" in state:
            self.advantages.load_state_dict(state["advantages"])  # else: the next refresh
        for group in self.policy_optimizer.param_groups:
            group["lr"] = self.cfg.lr
        self.safety.set_lr(self.cfg.lr)
        self.goal.set_lr(self.cfg.lr)
        self._sampler.set_state(state["sampler"])
        counters = [int(c) for c in state["counters"]]
        if len(counters) == 2:  # before per-critic counters every critic step trained both
            counters += [counters[1], counters[1]]
        (self.policy_updates, self.critic_updates, self.safety_updates,
         self.goal_updates) = counters

    def save(self, path: str | Path) -> Path:
        """Write a checkpoint atomically (temp file, fsync, os.replace)."""
        with self._lock:
            return checkpoint.save_atomic(self.state_dict(), path)

    @classmethod
    def load(
        cls,
        path: str | Path,
        cfg: LearningConfig | None = None,
        *,
        impl: EnsembleImpl = "auto",
        num_threads: int | None = None,
        train: Iterable[str] | None = None,
        read: Iterable[str] | None = None,
    ) -> Learner:
        """A learner from a checkpoint. ``cfg`` defaults to the saved one; a given one
        may change the training knobs (lr, batch size, gradient steps, device) but not the
        ensemble size or the augmentation factor, which shape the saved state. Both
        critics are always loaded (whatever trained them); ``train`` / ``read`` as for
        the constructor (the parts are not saved: the caller's algorithm decides)."""
        state = checkpoint.load(path)
        saved = LearningConfig.model_validate(state["cfg"])
        cfg = saved if cfg is None else cfg
        for field in ("ensemble_size", "augmentation_factor"):
            if getattr(cfg, field) != getattr(saved, field):
                raise LearningError(
                    f"{path}: checkpoint has learning.{field} = {getattr(saved, field)}, "
                    f"config asks for {getattr(cfg, field)}; use the checkpoint's value"
                )
        learner = cls(cfg, int(state["seed"]), impl=impl, num_threads=num_threads,
                      train=train, read=read)
        if not learner.policy_data.load_state_dict(state["policy_data"]):
            warnings.warn(
                f"{path}: the re-made augmented copies differ from the saved run's "
                "(another torch/kornia version?); training continues, not bit-exact",
                RuntimeWarning, stacklevel=2,
            )
        learner.transitions.load_state_dict(state["transitions"])
        learner._load_training(state, str(path))
        return learner
