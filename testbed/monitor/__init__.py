"""Failure prediction: how well a signal foresees an arm's failure, and an alarm with a
bounded false-alarm rate (issue 36).

Why a room of its own: Fleet-DAgger asks for a person on signals (the ensemble's
uncertainty, the safety critic's risk, ...) that are predictions of a failure, and a
prediction is only as good as its measured ranking, lead time, false alarms and
calibration. The labels come from the records (a push's episode outcome and the steps to
its violation, ``testbed.records.frame_classes``); the arithmetic is here, numpy and
scipy only (no torch: the fleet's allocation reads the alarm, and that layer stays
light). docs/notes/monitor.md says what each figure means and what the twin showed.

* :mod:`testbed.monitor.labels`: the policy's own pushes and what came after each one;
* :mod:`testbed.monitor.predictor_metrics`: AUROC, average precision, lead time, false alarms,
  reliability;
* :mod:`testbed.monitor.conformal`: split-conformal thresholds from successful episodes,
  the online (recalibrated) alarm and its replay.
"""
