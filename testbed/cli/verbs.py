"""Every verb of ``testbed``, in the order ``testbed --help`` lists them.

One place that names them all: ``build_parser`` adds a subparser per entry and ``main``
runs the entry of the verb given, so a verb is added here and in its module, nothing
else. The verbs live by what they are about: ``run_verbs`` (trials), ``data_verbs``
(learners, datasets, reports), ``theta0_verbs`` (theta_0 ahead: demonstrations and
pretraining), ``lab_verbs`` (the lab's hardware).
"""

from __future__ import annotations

from testbed.cli import data_verbs, lab_verbs, run_verbs, theta0_verbs
from testbed.cli.arguments import Verb

__all__ = ["VERBS", "Verb"]

VERBS: tuple[Verb, ...] = (
    run_verbs.TRIAL,
    run_verbs.PROTOCOL,
    run_verbs.SWEEP,
    data_verbs.REPORT,
    data_verbs.PLAN,
    lab_verbs.DEPLOY,
    lab_verbs.CHECK,
    lab_verbs.CALIBRATE,
    lab_verbs.REHEARSE,
    theta0_verbs.COLLECT,
    theta0_verbs.PRETRAIN,
    run_verbs.EVALUATE,
    data_verbs.EXPORT,
    data_verbs.TRAIN,
    data_verbs.VALUES,
)
