"""One training step by weighting: ``intervention`` (issue 30), ``advantage`` (AWR) and
the policy conditioned on the advantage (``conditioned``, RECAP's way; issue 46) against
``uniform``.

The targets: a step by class costs no more than 1.05x uniform's (issue 30); a step by
advantage, either way, no more than 1.10x today's (issue 46; uniform's and by class's
both printed). Every learner holds the data of the end of a 250-step, 4-arm C.U.R. trial
(375 demonstrations, 400 human labels, 1000 transitions); all but ``uniform`` hold the
robot's own pushes too (``--robot``, default 600), which they train on, so their
multinomial runs over more samples. Each member draws its minibatch in proportion to
bootstrap weight x class weight (x AWR's weight): a gather and a multiply over the
samples per step, against a forward and backward pass of 5 members on the minibatch. The
advantage's steps (AWR's and the conditioned one's) also train the value critic (on the
critics' shared minibatch and pi(s'): ``testbed/learning/advantage.py``), and every
``advantage_refresh`` (100) steps they value every sample again (a forward pass of the
policy and the value critic over the data), and at every step the samples added since
(a trial's labels come in every step: each learner here is given 4 new human labels
before every timed step, the valuing of new samples timed with the step). The mean over
the 100 timed steps carries one full re-valuing and a third of them the value critic's
update (``value_every`` 3): the mean is the figure, the median one step without them.

All are timed in the same run, interleaved (the order flips every repeat, so a load spike
hits all alike); minima, medians, means and the ratios of the medians and of the means
are printed for the parts C.U.R. trains (policy + safety critic) at the twin protocol's
batch (64) and the paper's (256).

    .venv/bin/python benchmarks/bench_weighting.py [--repeats 100] [--robot 600]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.core.types import EpisodeOutcome, FrameClass
from testbed.learning import Learner
from testbed.learning.learning_config import LearningConfig

WAYS = {"uniform": {}, "intervention": {"weighting": "intervention"},
        "advantage": {"weighting": "advantage"}, "conditioned": {"conditioning": "advantage"}}
"""Each way's ``[learning]`` fields: AWR (``advantage``) and RECAP's (``conditioned``)."""


def _learner(way: str, batch: int, robot: int, seed: int) -> Learner:
    cfg = LearningConfig(batch_size=batch, **WAYS[way])  # type: ignore[arg-type]
    learner = Learner(cfg, seed=seed, train={"policy", "safety"}, read={"safety"})
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (1375, 64, 64, 3), dtype=np.uint8)
    actions = rng.integers(0, 4, 1375)
    learner.add_human(images[:375], actions[:375])
    for k in range(375, 775, 4):  # labels arrive a step's few at a time
        learner.add_human(images[k : k + 4], actions[k : k + 4], labellers=np.zeros(4, np.int64))
    for k in range(775, 775 + robot, 6):  # an ended episode's pushes at a time
        n = min(6, 775 + robot - k)
        learner.add_robot(images[k : k + n], actions[k : k + n],
                          np.full(n, FrameClass.ROBOT), np.full(n, EpisodeOutcome.SUCCESS))
    idx = rng.integers(0, 775, 1000)
    learner.add_transitions(images[idx], actions[idx], images[(idx + 1) % 775],
                            rng.random(1000) < 0.05, rng.random(1000) < 0.05)
    return learner


WEIGHTINGS = tuple(WAYS)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=100,
                        help="timed steps each (100: one full advantage re-valuing among them)")
    parser.add_argument("--robot", type=int, default=600)
    args = parser.parse_args(argv)
    worst = {"intervention / uniform": 0.0, "advantage / uniform": 0.0,
             "advantage / intervention": 0.0, "conditioned / uniform": 0.0,
             "conditioned / intervention": 0.0}
    for batch in (64, 256):
        learners = {w: _learner(w, batch, args.robot, 0) for w in WEIGHTINGS}
        print(f"batch {batch}: samples " + ", ".join(
            f"{w} {x.data_sizes()['policy']}" for w, x in learners.items()))
        for learner in learners.values():  # warm up (the advantage's first refresh)
            learner.train_step()
        times: dict[str, list[float]] = {w: [] for w in WEIGHTINGS}
        order = list(learners.items())
        rng = np.random.default_rng(1)
        for r in range(args.repeats):
            labels = rng.integers(0, 256, (4, 64, 64, 3), dtype=np.uint8)
            for name, learner in order if r % 2 == 0 else order[::-1]:
                learner.add_human(labels, np.arange(4), labellers=np.zeros(4, np.int64))
                start = time.perf_counter()
                learner.train_step()
                times[name].append(time.perf_counter() - start)
        for name, ts in times.items():
            print(f"  {name:12s} min {min(ts) * 1e3:7.1f} ms   median "
                  f"{statistics.median(ts) * 1e3:7.1f} ms   "
                  f"mean {statistics.mean(ts) * 1e3:7.1f} ms")
        for key in worst:
            a, b = key.split(" / ")
            med = statistics.median(times[a]) / statistics.median(times[b])
            mean = statistics.mean(times[a]) / statistics.mean(times[b])
            worst[key] = max(worst[key], med, mean)
            print(f"  ratio {key}: medians {med:.3f}, means {mean:.3f}")
    print("targets: intervention / uniform <= 1.05 (issue 30); advantage and conditioned "
          "<= 1.10 of today's (issue 46)")
    for key, value in worst.items():
        print(f"worst ratio {key}: {value:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
