"""Running experiments: one trial end to end, protocols (trials x algorithms), sweeps,
progress, pretraining theta_0, the Ray fan-out, and the hosts and humans of a config.

Why a room: this is where the fleet loop meets the world a run needs (hosts, humans, a
learner, a run folder); ``build`` is its one module that reaches ``drivers`` and
``gui``, lazily. A caller adds to a run through one ``hooks.TrialHooks`` object. What the
runs say is read in ``testbed.results``; the lab is planned in ``testbed.planning``.
"""
