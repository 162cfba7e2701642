"""The twin's truth beside perception's calls: ``twin_truth.jsonl`` and its scoring.

Why it exists: a rehearsal is the one place where what really happened on the table is
known, so it is the place to score perception. ``TruthRecorder`` sits around the trial's
hosts (a ``testbed.core.wrappers.HostsWrapper``: every call passes through unchanged)
to learn each step's goals and pushes, asks the twin where the cubes really are, and
writes one row per step and arm to ``runs/<run>/twin_truth.jsonl``; nothing it learns
flows back into the trial. ``truth_agreement`` then compares the run's
``steps.jsonl`` (perception's success and violation calls) with it, and says of each
disagreement whether it was a call within perception's resolution (``BORDERLINE``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.hosts import Hosts
from testbed.core.types import SUCCESS_RADIUS, ArmObservation, Fault, PushResult
from testbed.core.wrappers import HostsWrapper
from testbed.lab.lab_client import LabClient, LabError

if TYPE_CHECKING:
    from testbed.lab.lab_humans import ArmView

__all__ = ["BORDERLINE", "TruthRecorder", "agreement_table", "edge_distance",
           "keep_truth_before", "truth_agreement"]

BORDERLINE = 1.0 / 64.0
"""A cube this close (one canonical pixel, ~5 mm) to the workspace edge or to the success
circle is a call perception may make either way: its centre error is ~0.2/64."""


def _polygon() -> Any:
    import numpy as np

    from testbed.perception.cube import WORKSPACE_POLYGON

    return np.asarray(WORKSPACE_POLYGON, dtype=float)


def _inside_workspace(xy: Sequence[float]) -> bool:
    import numpy as np

    poly = _polygon()
    e = np.roll(poly, -1, axis=0) - poly
    rel = np.asarray(xy, dtype=float)[None, :] - poly
    cross = e[:, 0] * rel[:, 1] - e[:, 1] * rel[:, 0]
    return bool(np.all(cross >= 0) or np.all(cross <= 0))


def edge_distance(xy: Sequence[float]) -> float:
    """Distance (canonical units) from a point to the workspace polygon's boundary."""
    import numpy as np

    poly = _polygon()
    a, b = poly, np.roll(poly, -1, axis=0)
    p = np.asarray(xy, dtype=float)[None, :]
    ab = b - a
    u = np.clip(np.sum((p - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + u[:, None] * ab - p, axis=1)))


class TruthRecorder(HostsWrapper):
    """Writes ``twin_truth.jsonl``: the twin's ground truth per step and arm, for scoring
    perception only (one JSON object a line: ``t``, ``robot``, ``success``,
    ``violation``, ``cube_xy``, ``pushed``, ``goal``). It wraps the controller's
    ``HostFleet`` (every call passes through unchanged) to learn each step's goals and
    pushes, and asks the twin where the cubes really are; nothing it learns flows back
    into the trial.
    """

    def __init__(self, hosts: Hosts, labs: Mapping[str, LabClient],
                 views: Mapping[str, ArmView], path: Path, *, start: int = 0,
                 before_first_step: Callable[[], None] | None = None) -> None:
        super().__init__(hosts)
        self.labs = labs
        self.views = views
        self.path = path
        self.next_t = start
        """The loop's next step: rows are written with it at ``execute``."""
        self.before_first_step = before_first_step
        """Called once, at the first observe (a resumed run: the drills' restart)."""
        self._pretraining = False
        self._goals: dict[str, tuple[float, float]] = {}
        self._inside: dict[str, bool] = {}
        keep_truth_before(path, start)

    def reseed(self, trial_seed: int) -> None:
        """Pretraining reseeds the hosts to its own seed first and to the trial's after
        (``testbed.experiments.learners.pretrained_learner``): its pushes are not the
        trial's steps and write no truth."""
        from testbed.experiments.learners import PRETRAIN_HOSTS_SEED

        self._pretraining = trial_seed == PRETRAIN_HOSTS_SEED
        super().reseed(trial_seed)

    def _truth(self) -> dict[str, tuple[tuple[float, float], bool]]:
        out: dict[str, tuple[tuple[float, float], bool]] = {}
        for host, lab in self.labs.items():
            try:
                arms = lab.truth()
            except LabError:
                continue  # the twin of a host being killed in a fault drill
            for arm, t in arms.items():
                robot = f"{host}/{arm}"
                if robot in self.views:
                    xy = self.views[robot].canonical(t["cube_px"])
                    out[robot] = (xy, bool(t["on_table"]) and _inside_workspace(xy))
        return out

    def observe(self) -> Mapping[str, ArmObservation | Fault]:
        if self.before_first_step is not None:
            first, self.before_first_step = self.before_first_step, None
            first()
        obs = self.hosts.observe()
        self._goals = {r: o.goal for r, o in obs.items() if isinstance(o, ArmObservation)}
        self._inside = {r: inside for r, (_, inside) in self._truth().items()}
        return obs

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> Mapping[str, PushResult | Fault]:
        results = self.hosts.execute(pushes, resets)
        after = self._truth()
        rows = []
        for robot in self.views:
            if robot not in after:
                continue
            xy, inside = after[robot]
            res = results.get(robot)
            pushed = (robot in pushes and isinstance(res, PushResult) and not res.refused)
            goal = self._goals.get(robot)
            success = bool(pushed and inside and goal is not None
                           and math.dist(xy, goal) <= SUCCESS_RADIUS)
            violation = bool(pushed and self._inside.get(robot, True) and not inside)
            rows.append({"robot": robot, "success": success, "violation": violation,
                         "cube_xy": [round(xy[0], 5), round(xy[1], 5)], "pushed": pushed,
                         "goal": None if goal is None else [round(g, 5) for g in goal]})
        if not self._pretraining and rows:
            # on disk before the step's row and its checkpoint: a kill after the
            # checkpoint landed never loses them; a resume drops those past it
            with open(self.path, "a", encoding="utf-8") as f:
                f.write("".join(json.dumps({"t": self.next_t, **row}, separators=(",", ":"))
                                + "\n" for row in rows))
        return results

    def on_step(self, t: int) -> None:
        """The loop finished step ``t``; the next one is ``t + 1``."""
        self.next_t = t + 1


def keep_truth_before(path: Path, start: int) -> None:
    """``twin_truth.jsonl`` cut back to the steps before ``start`` (a resumed run's first
    step; its own and later rows were written by a session killed before its checkpoint
    landed, and are written again): each step's rows once."""
    if not path.exists():
        return
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    keep = [x for x in lines if x.endswith("\n") and x.strip()
            and int(json.loads(x)["t"]) < start]
    if len(keep) != len(lines):
        from testbed.core.atomic import atomic_write_bytes

        atomic_write_bytes(path, "".join(keep).encode())


def _borderline(row: Mapping[str, Any], prev: Mapping[str, Any] | None) -> bool:
    """Whether a disagreement is a call within perception's resolution: the cube (now, or
    one step earlier for a violation seen one step late) within BORDERLINE of the
    workspace edge, or of the success circle around the goal."""
    for r in (row, prev):
        if r is None:
            continue
        if edge_distance(r["cube_xy"]) <= BORDERLINE:
            return True
        goal = r.get("goal")
        if goal is not None and abs(math.dist(r["cube_xy"], goal) - SUCCESS_RADIUS) <= BORDERLINE:
            return True
    return False


def _read_truth(run: Path) -> dict[tuple[int, str], dict[str, Any]]:
    """The run's ``twin_truth.jsonl`` by (step, robot); empty when it has none."""
    truth: dict[tuple[int, str], dict[str, Any]] = {}
    tpath = run / "twin_truth.jsonl"
    if tpath.exists():
        for line in tpath.read_text(encoding="utf-8").splitlines():
            if line.strip():
                row = json.loads(line)
                truth[(int(row["t"]), str(row["robot"]))] = row
    return truth


def truth_agreement(run: Path) -> dict[str, Any]:
    """Perception's success/violation decisions (steps.jsonl) against the twin's truth,
    over every arm-step the twin recorded that was not a fault; each disagreement says
    whether it was borderline (see :data:`BORDERLINE`)."""
    from testbed.records.steps import read_steps

    truth = _read_truth(run)
    n = agree = pushed_n = pushed_agree = 0
    disagreements: list[dict[str, Any]] = []
    for step in read_steps(run / "steps.jsonl"):
        t = int(step["t"])
        for r in step["robots"]:
            tr = truth.get((t, r["robot"]))
            if tr is None or r["mode"] == "fault":
                continue
            same = (bool(r["success"]) == tr["success"] and bool(r["violation"]) == tr["violation"])
            n += 1
            agree += same
            if tr.get("pushed"):
                pushed_n += 1
                pushed_agree += same
            if not same:
                disagreements.append({
                    "t": t, "robot": r["robot"], "perceived": [r["success"], r["violation"]],
                    "truth": [tr["success"], tr["violation"]], "cube_xy": tr["cube_xy"],
                    "borderline": _borderline(tr, truth.get((t - 1, r["robot"])))})
    return {"arm_steps": n, "agree": agree, "rate": agree / n if n else float("nan"),
            "pushed_arm_steps": pushed_n, "pushed_agree": pushed_agree,
            "pushed_rate": pushed_agree / pushed_n if pushed_n else float("nan"),
            "disagreements": disagreements,
            "borderline": sum(d["borderline"] for d in disagreements)}


def agreement_table(agreement: Mapping[str, Mapping[str, Any]]) -> str:
    """The rehearsal report's table: each run's agreement with the twin's truth."""
    lines = ["Perception (steps.jsonl) against the twin's truth (twin_truth.jsonl):", "",
             "| run | arm-steps | agree | pushed arm-steps | agree | disagreements "
             "(borderline) |", "|---|---|---|---|---|---|"]
    for name, a in agreement.items():
        lines.append(f"| {name} | {a['arm_steps']} | {a['rate']:.2%} | {a['pushed_arm_steps']} "
                     f"| {a['pushed_rate']:.2%} | {len(a['disagreements'])} "
                     f"({a['borderline']}) |")
    return "\n".join(lines) + "\n"
