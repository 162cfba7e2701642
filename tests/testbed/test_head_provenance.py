"""A failure head used live is checked against what it was fitted on (issue 45, item 1):
a run whose alarm watched a head fitted on the run's own theta_0 is flagged in the report,
as is a head that does not say which theta_0 it saw (the shipped twin head); a run of a
theta_0 the head never saw is not."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from testbed.monitor.failure_head import FailureHead
from testbed.results.head_provenance import head_seen, live_head_notes
from testbed.results.prediction_features import theta0_digest
from tests.testbed.test_monitor_runs import theta0

ROOT = Path(__file__).resolve().parents[2]


def _head(path: Path, fitted_on: dict[str, object]) -> Path:
    FailureHead(("risk",), np.zeros(2), np.ones(2), np.zeros(2), 0.0, 0, 3,
                dict(fitted_on)).save(path)
    return path


def _run(run: Path, weights: int, head: Path | None) -> Path:
    run.mkdir(parents=True)
    theta0(run, kept_as=weights + 7, weights=weights)
    monitor = "" if head is None else f'score = "fail_head"\nhead = "{head}"\n'
    (run / "config.toml").write_text(f"[monitor]\nalpha = 0.05\n{monitor}")
    return run


def test_a_head_that_saw_a_runs_theta_0_is_flagged_and_one_that_did_not_is_not(
        tmp_path: Path) -> None:
    seen = tmp_path / "seen"
    seen.mkdir()
    theta0(seen, kept_as=0, weights=0)
    digest = theta0_digest(seen)
    head = _head(tmp_path / "head.json", {"theta0_digests": [digest], "trial_seeds": [0]})
    same = _run(tmp_path / "same", 0, head)  # another seed, the head's policy
    other = _run(tmp_path / "other", 1, head)  # a policy the head never saw
    plain = _run(tmp_path / "plain", 0, None)  # its alarm read no head: nothing to check
    notes = live_head_notes([same, other, plain])
    assert len(notes) == 1 and notes[0].startswith(f"same: alarm on the failure head {head}")
    assert f"fitted on runs of this run's theta_0 (policy digest {digest[:12]})" in notes[0]
    assert head_seen(FailureHead.load(head), theta0_digest(other)) is None


def test_a_head_without_its_theta_0_record_cannot_vouch_for_any_run(tmp_path: Path) -> None:
    """The twin's shipped head was fitted before heads recorded their theta_0 digests
    (on trial seeds 0-2 of the one theta_0 the head-until protocol's runs also start
    from): every run that uses it is flagged."""
    shipped = ROOT / "protocols" / "heads" / "twin-baseline.json"
    fitted = FailureHead.load(shipped).fitted_on
    assert "theta0_digests" not in fitted and fitted["trial_seeds"] == [0, 1, 2]
    assert fitted["theta_0"] == 1 and fitted["split"] == "trial seed"
    run = _run(tmp_path / "monitor-head-t4", 3, shipped)
    (note,) = live_head_notes([run])
    assert "does not record the theta_0 it was fitted on (it says trial seeds [0, 1, 2])" \
        in note
    missing = _run(tmp_path / "moved", 3, tmp_path / "gone.json")
    (note,) = live_head_notes([missing])
    assert note.startswith("moved: alarm on the failure head") and "not checked" in note
