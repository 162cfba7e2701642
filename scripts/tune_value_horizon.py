"""Reproduce the value critic's horizon table (docs/notes/learning.md, "The value of every
push"): one learner per ``gamma_value``, trained as tests/testbed/learning/
test_critics_on_twin.py trains its learner (the same twin data: 3000 transitions of
cell 1, BC 100 steps on 500 expert labels, the value critic 600 steps at batch 64), each
judged on 200 states of the tuning cell (``TUNING_SEED``), never on ``TRUTH_SEED``'s.

    PYTHONPATH=. .venv/bin/python scripts/tune_value_horizon.py [--seeds 0,1,2] [GAMMA ...]

``--seeds``: the learners' seeds (their initial weights: one seed's figure moved by 0.16
between two initialisations at gamma 0.999, so a gamma is judged over several). About
50 s per gamma and seed on this 2-core machine. The data comes from the test module's
own ``collect`` (tests/ on the path), so the table is made from what the test trains on.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "testbed" / "learning")]

from test_critics_on_twin import CFG, CRITIC_STEPS, POLICY_STEPS, collect  # noqa: E402

import sim_twin.cell as cell_module  # noqa: E402
from testbed.lab.advantage_truth import TUNING_SEED, draw_states, judge, truth_of_states  # noqa: E402
from testbed.learning import Learner  # noqa: E402


def main(argv: list[str]) -> int:
    seeds = [0]
    if argv[:1] == ["--seeds"]:
        seeds, argv = [int(x) for x in argv[1].split(",")], argv[2:]
    gammas = [float(g) for g in argv] or [0.999, 0.9, 0.8, 0.7, 0.5]
    with cell_module.TwinCell(seed=1) as cell:
        train, expert, _ = collect(cell, 3000, np.random.default_rng(1))
    with cell_module.TwinCell(seed=TUNING_SEED) as cell:
        states = draw_states(cell, 200, np.random.default_rng(TUNING_SEED))
        truth = truth_of_states(cell, states)
    for g in gammas:
        got = []
        for seed in seeds:
            start = time.perf_counter()
            learner = Learner(CFG.model_copy(update={"gamma_value": g}), seed=seed)
            learner.pretrain(train.images[:500], expert[:500], steps=POLICY_STEPS)
            learner.pretrain(transitions=train, steps=CRITIC_STEPS, critics=["value"])
            got.append(judge(states, truth, learner.push_values))
            print(f"gamma_value {g} seed {seed}: {got[-1].line()} "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)
        print(f"gamma_value {g}: mean over seeds {seeds}: AUROC "
              f"{np.mean([x.auroc for x in got]):.3f}, within states "
              f"{np.mean([x.within for x in got]):.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
