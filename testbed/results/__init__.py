"""Reading results: what finished runs say, with their uncertainty.

``testbed report`` (``report.py`` and its tables), the intervals and paired tests
(``intervals.py``), the anytime-valid sequential test a protocol's ``until`` stops on
(``sequential.py``), and failure prediction scored from a run's records
(``prediction_runs.py``, ``prediction_features.py``). Why a room of its own: it reads
records and never runs a fleet; running experiments (``testbed.experiments``) and
planning the lab (``testbed.planning``) read results, not the other way round
(docs/ARCHITECTURE.md).
"""
