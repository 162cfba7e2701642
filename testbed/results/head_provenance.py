"""What a failure head was fitted on, read against the runs it is used on (issue 45, item
1): a head scored live on runs whose theta_0 it was fitted on says nothing about a policy
it never saw.

Why the report checks it: the head a monitor run's alarm watches (``[monitor] head``,
``score = "fail_head"``) is a file fitted earlier by ``testbed report``; the twin's
shipped head was fitted on trial seeds 0-2 of one theta_0 and then run live on seeds 0-5
of that same theta_0. ``prediction_runs.add_failure_head`` keeps in the head's
``fitted_on`` the theta_0 digests (a hash of the policy's weights,
``prediction_features.theta0_digest``), the trial seeds and the split it was scored by;
a run whose theta_0 digest is among the head's is flagged, and so is a head that does
not say (fitted before this record existed), since nothing then shows the policy was
held out.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from testbed.monitor.failure_head import FailureHead, HeadError
from testbed.results.prediction_features import theta0_digest

__all__ = ["head_seen", "live_head_notes"]


def head_seen(head: FailureHead, digest: str | None) -> str | None:
    """Why ``head``'s figures on a run of theta_0 ``digest`` are not on a held-out
    policy, or None when its record shows it never saw that theta_0."""
    fitted = head.fitted_on.get("theta0_digests")
    if not isinstance(fitted, list):
        seeds = head.fitted_on.get("trial_seeds")
        said = f" (it says trial seeds {seeds})" if seeds else ""
        return ("its head does not record the theta_0 it was fitted on" + said + ": "
                "nothing shows this run's policy was held out")
    if digest is None:
        return "the run kept no theta_0 (learner-start.pt): not checked"
    if digest in fitted:
        return (f"its head was fitted on runs of this run's theta_0 (policy digest "
                f"{digest[:12]}): the head's alarm here is not on a held-out policy")
    return None


def _head_of(run: Path) -> Path | None:
    """The head file a run's alarm watched (its config.toml ``[monitor]``), else None."""
    try:
        raw: dict[str, Any] = tomllib.loads((run / "config.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return None
    monitor = raw.get("monitor", {})
    if not isinstance(monitor, dict) or monitor.get("score") != "fail_head":
        return None
    head = monitor.get("head")
    return Path(str(head)) if head else None


def live_head_notes(runs: Sequence[Path]) -> list[str]:
    """One note per run whose alarm watched a failure head that saw its theta_0 (or
    cannot show it did not), naming the head file; none for the other runs. The head's
    path is read as the run gave it (relative to where testbed ran)."""
    notes: list[str] = []
    heads: dict[Path, FailureHead | str] = {}
    for run in runs:
        path = _head_of(run)
        if path is None:
            continue
        if path not in heads:
            try:
                heads[path] = FailureHead.load(path)
            except HeadError as exc:
                heads[path] = str(exc)
        head = heads[path]
        why = (f"its head could not be read here ({head}): not checked"
               if isinstance(head, str) else head_seen(head, theta0_digest(run)))
        if why is not None:
            notes.append(f"{run.name}: alarm on the failure head {path}: {why}.")
    return notes
