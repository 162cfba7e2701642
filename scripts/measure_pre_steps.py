"""How long an arm asks for help before a human takes it: the data behind k.

k (``learning.pre_intervention_steps``) says how many of the robot's steps before a
takeover are pre-intervention (``testbed/records/frame_classes.py``). This measures, for
every takeover in the runs given (a frame with a human after one without, per arm), how
many consecutive steps right before it the arm was already asking for a human -- its
priority key lexicographically positive in the steps.jsonl row -- without getting one:
the steps the allocator saw the arm in trouble while every human was busy. Teleop
takeovers and hard resets are counted apart (a violated arm waits idle: none of its
waiting steps is a robot push). docs/notes/learning.md, "Frame classes", has the result.

    .venv/bin/python scripts/measure_pre_steps.py RUN_OR_PROTOCOL_DIR...
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from testbed.records.steps import read_steps


def positive(key: list[float]) -> bool:
    """Lexicographically positive: the first non-zero entry is > 0 (may get a human)."""
    for x in key:
        if x != 0:
            return x > 0
    return False


def waits(rows: list[dict[str, Any]]) -> list[tuple[str, int, int]]:
    """(kind, waiting steps, robot pushes among them) for every takeover in ``rows``."""
    out = []
    n = len(rows[0]["robots"]) if rows else 0
    for a in range(n):
        arm = [r["robots"][a] for r in rows]
        for t, r in enumerate(arm):
            if r["human"] is None or (t > 0 and arm[t - 1]["human"] is not None):
                continue
            wait = pushes = 0
            s = t - 1
            while s >= 0 and arm[s]["human"] is None and positive(arm[s]["key"]):
                wait += 1
                pushes += arm[s]["mode"] == "autonomous" and arm[s]["action"] is not None
                s -= 1
            out.append((r["mode"] if r["mode"] in ("teleop", "reset") else "other", wait,
                        pushes))
    return out


def main(dirs: list[str]) -> int:
    found: list[tuple[str, int, int]] = []
    runs = 0
    for d in map(Path, dirs):
        for steps in [d / "steps.jsonl"] if (d / "steps.jsonl").exists() else sorted(
                d.glob("*/steps.jsonl")):
            found += waits(read_steps(steps, validate=False))
            runs += 1
    print(f"{runs} run(s), {len(found)} takeovers")
    for kind in ("teleop", "reset", "other"):
        w = np.asarray([x[1] for x in found if x[0] == kind])
        p = np.asarray([x[2] for x in found if x[0] == kind])
        if len(w) == 0:
            continue
        hist = dict(sorted(Counter(w.tolist()).items()))
        q = {f"q{int(x * 100)}": float(np.quantile(w, x)) for x in (0.5, 0.75, 0.9)}
        print(f"{kind}: {len(w)} takeovers; steps asking before it {hist}; mean "
              f"{w.mean():.2f}, {q}, max {int(w.max())}; robot pushes among them: "
              f"mean {p.mean():.2f}, max {int(p.max())}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
