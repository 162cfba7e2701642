"""``TrialHooks``: what a caller adds around the runs of a trial, a protocol or a sweep.

Why one object (as Stable-Baselines3's ``common/callbacks.py``): a rehearsal, the
progress bar, a test's fault drill each want to hear about a run, supply its humans or
wrap its hosts. Threaded one by one as loose callbacks through ``run_protocol`` ->
``run_protocol_run`` -> ``run_named`` -> ``run_trial``, every layer had to know every
callback. Now each layer passes one ``TrialHooks`` down, and ``HookList`` chains several
(the progress bar and the caller's own, say) in order.

Override what you need; every default does nothing:

* ``before_run(name)``: a run is about to start or resume. Return True when the hook
  put the cubes back itself (a rehearsal's lab hand): the protocol then does not
  prompt the operator.
* ``humans(name)``: the humans of that run (None: built from the config).
* ``wrap_humans(humans, run)``: the humans the run asks, given the ones built from the
  config (a rehearsal's lab around them): built by the trial, so a web console keeps
  the run's links and says it was resumed.
* ``wrap_hosts(hosts, run)``: the hosts the run drives (a ``HostsWrapper``, say).
* ``on_phase(name, done, total)``: pretraining's progress (collect, pretrain ...).
* ``on_phase_resumed(name, done, total)``: a phase goes on from ``done`` that an
  earlier try kept (a collection cut short); default: ``on_phase``.
* ``on_step(outcome)``: a timestep finished (logged and checkpointed).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from testbed.core.hosts import Hosts
from testbed.core.humans import Humans
from testbed.records.run_dir import RunDir

if TYPE_CHECKING:
    from testbed.fleet.loop import StepOutcome

__all__ = ["HookList", "TrialHooks", "as_hooks"]


class TrialHooks:
    """One run's hooks; subclass and override (every default does nothing)."""

    def before_run(self, name: str) -> bool:
        """Run ``name`` starts or resumes now; True: the cubes are back (no prompt)."""
        return False

    def humans(self, name: str) -> Humans | None:
        """The humans of run ``name``, or None for the config's."""
        return None

    def wrap_hosts(self, hosts: Hosts, run: RunDir) -> Hosts:
        """The hosts run ``run`` drives, given the ones built for it."""
        return hosts

    def wrap_humans(self, humans: Humans, run: RunDir) -> Humans:
        """The humans run ``run`` asks, given the ones the trial built from the config
        (never called for humans that ``humans`` supplied)."""
        return humans

    def on_phase(self, name: str, done: int, total: int) -> None:
        """Pretraining phase ``name`` is at ``done`` of ``total``."""

    def on_phase_resumed(self, name: str, done: int, total: int) -> None:
        """Phase ``name`` goes on from ``done`` of ``total`` kept by an earlier try (a
        display then counts its speed from here); by default as ``on_phase``."""
        self.on_phase(name, done, total)

    def on_step(self, outcome: StepOutcome) -> None:
        """A timestep finished: logged, its data stored, its checkpoint submitted."""


class HookList(TrialHooks):
    """Several hooks as one, called in order: every ``before_run``, ``on_phase`` and
    ``on_step``; ``humans`` from the first that has them; ``wrap_hosts`` and
    ``wrap_humans`` composed (the first hook's wrapper innermost)."""

    def __init__(self, hooks: Iterable[TrialHooks | None]) -> None:
        self.hooks: list[TrialHooks] = [h for h in hooks if h is not None]

    def before_run(self, name: str) -> bool:
        handled = [h.before_run(name) for h in self.hooks]
        return any(handled)

    def humans(self, name: str) -> Humans | None:
        for h in self.hooks:
            got = h.humans(name)
            if got is not None:
                return got
        return None

    def wrap_hosts(self, hosts: Hosts, run: RunDir) -> Hosts:
        for h in self.hooks:
            hosts = h.wrap_hosts(hosts, run)
        return hosts

    def wrap_humans(self, humans: Humans, run: RunDir) -> Humans:
        for h in self.hooks:
            humans = h.wrap_humans(humans, run)
        return humans

    def on_phase(self, name: str, done: int, total: int) -> None:
        for h in self.hooks:
            h.on_phase(name, done, total)

    def on_phase_resumed(self, name: str, done: int, total: int) -> None:
        for h in self.hooks:
            h.on_phase_resumed(name, done, total)

    def on_step(self, outcome: StepOutcome) -> None:
        for h in self.hooks:
            h.on_step(outcome)


def as_hooks(*hooks: TrialHooks | None) -> TrialHooks:
    """``hooks`` as one object: a ``TrialHooks()`` for none, the hook itself for one."""
    given = [h for h in hooks if h is not None]
    if not given:
        return TrialHooks()
    return given[0] if len(given) == 1 else HookList(given)
