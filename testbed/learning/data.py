"""Replay data: the policy's human-labelled samples and the critics' transitions.

Why augmented copies are stored, not made on the fly: a training step draws 5 x 256
policy images; augmenting them per step would cost ~0.1 s on top of a ~0.5 s step,
while storing the 10 copies costs ~20 augmented images per fleet step (milliseconds)
and 120 KiB per labelled image in memory. Each ``add`` call is a chunk whose copies are
a fixed function of the chunk's seed, so a checkpoint holds only the originals (its
policy data 10x smaller): ``PolicyData`` re-creates the copies on load, chunk by chunk,
and compares each chunk's digest, taken when it was added.

Bootstrap: each labelled image gets one Poisson(1) weight per member when it arrives
(the online bootstrap of Oza and Russell); a member samples its minibatches in
proportion to its weights, and an image's 10 copies share its weight (bootstrapping the
copies separately would give each member nearly the same data). About 37 % of the
images are outside any one member's bootstrap, which is what makes members disagree
away from the data.

Classes (issue 30): each sample keeps its ``FrameClass`` and its episode's outcome
(``testbed/records/frame_classes.py``). With a class-weight table (``weighting =
"intervention"``) a member draws in proportion to its bootstrap weight times its sample's
class weight, so the classes reweigh the data without touching the bootstrap or the
augmentation (an image's copies share both); without one, the draw is today's exactly.

Critic minibatches are shared by both critics (one policy pass for pi(s') serves both):
25 % violating transitions (the paper's 8.3.2, Recovery RL), 25 % successful ones (the goal
critic's rare positive, "in the same manner"), the rest uniform; a class that has no
transition yet gives its share to the uniform part.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import torch
from torch import Tensor

from testbed.core.humans import unnamed_human
from testbed.core.types import IMAGE_SIZE, EpisodeOutcome, FrameClass
from testbed.learning.api import Transitions
from testbed.learning.augment import augment_copies
from testbed.learning.runtime import STREAM_AUGMENT, derive_seed

IMAGE_SHAPE = (IMAGE_SIZE, IMAGE_SIZE, 3)
POSITIVE_FRACTION = 0.25


class _Growable:
    """Named tensors that share a first dimension, grown by doubling (amortised O(1))."""

    def __init__(self, specs: dict[str, tuple[tuple[int, ...], torch.dtype]],
                 capacity: int = 256) -> None:
        self._specs = specs
        self._data = {k: torch.zeros((capacity, *shape), dtype=dt)
                      for k, (shape, dt) in specs.items()}
        self.size = 0

    def append(self, **columns: Tensor) -> None:
        n = next(iter(columns.values())).shape[0]
        need = self.size + n
        cap = next(iter(self._data.values())).shape[0]
        if need > cap:
            new_cap = max(need, 2 * cap)
            for k, old in self._data.items():
                grown = torch.zeros((new_cap, *old.shape[1:]), dtype=old.dtype)
                grown[: self.size] = old[: self.size]
                self._data[k] = grown
        for k, value in columns.items():
            self._data[k][self.size : need] = value
        self.size = need

    def __getitem__(self, name: str) -> Tensor:
        """The filled rows of a column (a view)."""
        return self._data[name][: self.size]


def _digest(t: Tensor) -> str:
    return hashlib.blake2b(t.contiguous().numpy().data, digest_size=16).hexdigest()


NO_LABELLER: Final = -1
"""The labeller of a label no human of the fleet gave (theta_0's offline demonstrations)."""


class PolicyData:
    """Human-labelled (image, action) pairs, each with ``factor`` stored copies, and who
    gave each label (``labellers``: a code into ``labeller_names``, one per person;
    ``NO_LABELLER`` for an offline demonstration), kept for learning that weighs labels
    by their labeller; the sampling does not read it.

    Why codes into a table of names: a label's giver arrives as an index into the
    people of the run it came from (the loop's) or of a merged export (``testbed
    train``); the table is what makes one person one labeller across them."""

    def __init__(self, ensemble_size: int, factor: int, seed: int) -> None:
        self.ensemble_size = ensemble_size
        self.factor = factor
        self.seed = seed
        self.labeller_names: list[str] = []
        """Labeller code -> the person: a name, an unnamed human of a source
        (``testbed.datasets``), or ``unnamed_human`` of the fleet's index (the loop's
        labels: the run's run.json names that index)."""
        self._store = self._new_store()
        self._chunks: list[tuple[int, int, str]] = []  # (size, seed, digest) per add()

    def _new_store(self, capacity: int = 256) -> _Growable:
        return _Growable({
            "images": ((self.factor, *IMAGE_SHAPE), torch.uint8),
            "actions": ((), torch.int64),
            "weights": ((self.ensemble_size,), torch.float32),
            "labellers": ((), torch.int16),
            "classes": ((), torch.int8),
            "outcomes": ((), torch.int8),
        }, capacity)

    def __len__(self) -> int:
        return self._store.size

    @property
    def num_chunks(self) -> int:
        """``add`` calls so far (each chunk's augmentation seed follows from its index)."""
        return len(self._chunks)

    def add(self, images: np.ndarray, actions: np.ndarray, chunk_seed: int | None = None,
            labellers: np.ndarray | None = None, classes: np.ndarray | None = None,
            outcomes: np.ndarray | None = None,
            names: Sequence[str] | None = None) -> None:
        """Append validated uint8 images (N, 64, 64, 3) and int64 actions (N,), each
        labelled by ``labellers`` (N,) (default: ``NO_LABELLER``; an index into
        ``names``, else the fleet's human index, named ``unnamed_human``), of ``classes`` (N,)
        (``FrameClass``; default: TELEOP where a human labelled, else DEMO) in episodes
        of ``outcomes`` (N,) (``EpisodeOutcome``; default OPEN). The copies and
        bootstrap weights come from ``chunk_seed`` (default: derived from the data's
        seed and the chunk's index)."""
        n = int(images.shape[0])
        if n == 0:
            return
        if chunk_seed is None:
            chunk_seed = derive_seed(self.seed, STREAM_AUGMENT, len(self._chunks))
        gen = torch.Generator().manual_seed(chunk_seed)
        copies = augment_copies(torch.from_numpy(images), self.factor, gen)
        weights = torch.poisson(torch.ones(n, self.ensemble_size), generator=gen)
        who = (np.full(n, NO_LABELLER) if labellers is None
               else self._codes(np.asarray(labellers, np.int64).reshape(n), names))
        if classes is None:
            classes = np.where(who >= 0, FrameClass.TELEOP, FrameClass.DEMO)
        if outcomes is None:
            outcomes = np.full(n, EpisodeOutcome.OPEN)
        self._store.append(images=copies, actions=torch.from_numpy(actions), weights=weights,
                           labellers=torch.from_numpy(who.astype(np.int16)),
                           classes=torch.from_numpy(np.asarray(classes, np.int8).reshape(n)),
                           outcomes=torch.from_numpy(np.asarray(outcomes, np.int8).reshape(n)))
        self._chunks.append((n, chunk_seed, _digest(copies)))

    def _codes(self, given: np.ndarray, names: Sequence[str] | None) -> np.ndarray:
        """``given`` labellers as codes of ``labeller_names`` (a person new to it is
        appended, in the order of their first label, so a reload rebuilds the same)."""
        out = np.full(given.shape, NO_LABELLER, np.int64)
        humans = given >= 0
        values, first = np.unique(given[humans], return_index=True)
        if names is not None and len(values) and values[-1] >= len(names):
            raise ValueError(f"labeller {values[-1]} has no name ({len(names)} names given)")
        for g in values[np.argsort(first)]:
            person = names[g] if names is not None else unnamed_human(int(g))
            if person not in self.labeller_names:
                self.labeller_names.append(person)
            out[given == g] = self.labeller_names.index(person)
        return out

    def sample(self, batch: int, gen: torch.Generator, class_weights: Tensor | None = None,
               sample_weights: Tensor | None = None, *, with_index: bool = False
               ) -> Any:
        """Per-member bootstrap minibatches: images (E, B, 64, 64, 3), actions (E, B),
        and with ``with_index`` each drawn sample's index (E, B). ``class_weights``
        (len(FrameClass), len(EpisodeOutcome)): each sample's weight by its class and
        outcome, times its bootstrap weight (None: the bootstrap alone);
        ``sample_weights`` (N,): a weight of each sample's own besides (AWR's)."""
        n = len(self)
        if n == 0:
            raise ValueError("no policy data yet")
        weights = self._store["weights"]
        per_sample = None
        if class_weights is not None:
            per_sample = class_weights[self._store["classes"].long(),
                                       self._store["outcomes"].long()]
        if sample_weights is not None:
            if sample_weights.shape != (n,):
                raise ValueError(f"sample_weights: shape {tuple(sample_weights.shape)}, "
                                 f"not ({n},)")
            per_sample = sample_weights if per_sample is None else per_sample * sample_weights
        if per_sample is not None:
            weights = weights * per_sample[:, None]
        rows = []
        for m in range(self.ensemble_size):
            w = weights[:, m]
            if float(w.sum()) <= 0.0:  # tiny data: this member's bootstrap came out empty
                w = torch.ones(n) if per_sample is None else per_sample
            rows.append(torch.multinomial(w, batch, replacement=True, generator=gen))
        index = torch.stack(rows)
        copy = torch.randint(self.factor, index.shape, generator=gen)
        if with_index:
            return self._store["images"][index, copy], self._store["actions"][index], index
        return self._store["images"][index, copy], self._store["actions"][index]

    def classes(self) -> tuple[np.ndarray, np.ndarray]:
        """Each sample's ``FrameClass`` and episode outcome, in the order added (int8)."""
        return (self._store["classes"].numpy().copy(), self._store["outcomes"].numpy().copy())

    def labellers(self) -> np.ndarray:
        """Who gave each label, in the order added (int16 (N,): codes of
        ``labeller_names``; -1: no human)."""
        return self._store["labellers"].numpy().copy()

    def original_images(self, index: Tensor) -> Tensor:
        """The labelled images at ``index`` as they were added (uint8 (K, 64, 64, 3))."""
        return self._store["images"][index, 0]

    def originals_and_actions(self) -> tuple[Tensor, Tensor]:
        """Every labelled image as it was added (uint8 (N, 64, 64, 3)) and its action
        (int64 (N,)), views of the store: for valuing every sample (``advantage.py``)."""
        return self._store["images"][:, 0], self._store["actions"]

    def originals(self) -> np.ndarray:
        """The labelled images as they were added (uint8 (N, 64, 64, 3), a copy)."""
        return self._store["images"][:, 0].numpy().copy()

    def state_dict(self) -> dict[str, Any]:
        """Originals, weights and per-chunk (size, seed, digest of the copies): the copies
        themselves are re-made on load (a checkpoint ~10x smaller, no hashing at save)."""
        return {
            "originals": self._store["images"][:, 0].clone(),
            "actions": self._store["actions"].clone(),
            "weights": self._store["weights"].clone(),
            "labellers": self._store["labellers"].clone(),
            "labeller_names": list(self.labeller_names),
            "classes": self._store["classes"].clone(),
            "outcomes": self._store["outcomes"].clone(),
            "chunks": [list(c) for c in self._chunks],
        }

    def load_state_dict(self, state: dict[str, Any]) -> bool:
        """Rebuild from originals; returns whether the re-made copies match the digests."""
        originals = state["originals"].numpy()
        actions = state["actions"].numpy()
        who = state.get("labellers")  # checkpoints before labellers were kept: unknown
        labellers = (np.full(originals.shape[0], NO_LABELLER) if who is None
                     else who.numpy())
        # checkpoints before names: codes were the fleet's human indices (unnamed)
        names = state.get("labeller_names")
        kinds, ends = state.get("classes"), state.get("outcomes")  # before issue 30: derived
        classes = None if kinds is None else kinds.numpy()
        outcomes = None if ends is None else ends.numpy()
        start = 0
        self._store = self._new_store(capacity=max(256, originals.shape[0]))
        self._chunks = []
        self.labeller_names = []
        same = True
        for i, chunk in enumerate(state["chunks"]):
            # older checkpoints stored the size alone (seed derived from the data's seed),
            # or (size, seed) with one digest of all the copies
            entry = [chunk] if isinstance(chunk, int) else list(chunk)
            size = int(entry[0])
            seed = int(entry[1]) if len(entry) > 1 else derive_seed(self.seed, STREAM_AUGMENT, i)
            part = slice(start, start + size)
            self.add(originals[part], actions[part], seed, labellers[part],
                     None if classes is None else classes[part],
                     None if outcomes is None else outcomes[part], names)
            if len(entry) > 2:
                same = same and self._chunks[-1][2] == entry[2]
            start += size
        if start != originals.shape[0]:
            raise ValueError("policy data: chunk sizes do not add up to the stored images")
        self._store["weights"].copy_(state["weights"])
        if "digest" in state:
            same = same and _digest(self._store["images"]) == state["digest"]
        return same


class TransitionBuffer:
    """All (s, a, s', violation, success) pushes the critics learn from."""

    def __init__(self) -> None:
        self._store = self._new_store()

    @staticmethod
    def _new_store(capacity: int = 256) -> _Growable:
        return _Growable({
            "images": (IMAGE_SHAPE, torch.uint8),
            "next_images": (IMAGE_SHAPE, torch.uint8),
            "actions": ((), torch.int64),
            "violation": ((), torch.bool),
            "success": ((), torch.bool),
        }, capacity)

    def __len__(self) -> int:
        return self._store.size

    def add(self, t: Transitions) -> None:
        if len(t) == 0:
            return
        self._store.append(
            images=torch.from_numpy(t.images),
            next_images=torch.from_numpy(t.next_images),
            actions=torch.from_numpy(t.actions),
            violation=torch.from_numpy(t.violation),
            success=torch.from_numpy(t.success),
        )

    def counts(self) -> dict[str, int]:
        return {
            "transitions": len(self),
            "violations": int(self._store["violation"].sum()),
            "successes": int(self._store["success"].sum()),
        }

    def sample_indices(self, batch: int, gen: torch.Generator) -> Tensor:
        """``batch`` indices: 25 % violating, 25 % successful, the rest uniform."""
        n = len(self)
        if n == 0:
            raise ValueError("no transitions yet")
        parts = []
        taken = 0
        for flag in ("violation", "success"):
            pool = torch.nonzero(self._store[flag]).view(-1)
            k = round(POSITIVE_FRACTION * batch) if len(pool) else 0
            k = min(k, batch - taken)
            if k:
                parts.append(pool[torch.randint(len(pool), (k,), generator=gen)])
                taken += k
        parts.append(torch.randint(n, (batch - taken,), generator=gen))
        return torch.cat(parts)

    def gather(self, index: Tensor) -> dict[str, Tensor]:
        return {k: self._store[k][index] for k in
                ("images", "next_images", "actions", "violation", "success")}

    def state_dict(self) -> dict[str, Any]:
        return {k: self._store[k].clone() for k in
                ("images", "next_images", "actions", "violation", "success")}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._store = self._new_store(capacity=max(256, len(state["actions"])))
        self.add(Transitions(
            images=state["images"].numpy(),
            actions=state["actions"].numpy(),
            next_images=state["next_images"].numpy(),
            violation=state["violation"].numpy(),
            success=state["success"].numpy(),
        ))
