"""Explicit wrapper bases for the two contracts a trial is built from: hosts and humans.

Why (as Gymnasium's ``core.Wrapper`` and Stable-Baselines3's ``VecEnvWrapper``): an
evaluation's expert row, a rehearsal's truth recorder and its lab hand each change one
or two calls of the hosts or the humans and must pass every other call through. A base
that names each call of the contract and forwards it explicitly makes that visible and
checkable: a wrapper is a ``Hosts`` (or a ``Humans``) because its base is, not because a
``__getattr__`` happens to find the attribute; a call the contract does not have is an
``AttributeError``, not a silent pass-through; and ``presence()`` reaches the inner
humans whether or not they can be away.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

from testbed.core.hosts import Hosts, hosts_info_of, stop_motion_of
from testbed.core.humans import Humans, Presence, presence_of
from testbed.core.types import (
    ArmObservation,
    Fault,
    FleetStatus,
    HumanRequest,
    HumanResponse,
    PushResult,
)

__all__ = ["HostsWrapper", "HumansWrapper"]


class HostsWrapper:
    """Hosts around ``hosts``: every call of ``testbed.core.hosts.Hosts`` forwarded."""

    def __init__(self, hosts: Hosts) -> None:
        self.hosts = hosts

    @property
    def robot_names(self) -> list[str]:
        return list(self.hosts.robot_names)

    @property
    def unwrapped(self) -> Hosts:
        """The innermost hosts (through any number of wrappers)."""
        inner = self.hosts
        return inner.unwrapped if isinstance(inner, HostsWrapper) else inner

    def start(self) -> None:
        self.hosts.start()

    def observe(self) -> Mapping[str, ArmObservation | Fault]:
        return self.hosts.observe()

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> Mapping[str, PushResult | Fault]:
        return self.hosts.execute(pushes, resets)

    def rest(self) -> None:
        self.hosts.rest()

    def reseed(self, trial_seed: int) -> None:
        self.hosts.reseed(trial_seed)

    def close(self) -> None:
        self.hosts.close()

    def stop_motion(self) -> None:
        """The optional call: reaches the inner hosts whether or not they can stop."""
        stop_motion_of(self.hosts)

    def hosts_info(self) -> dict[str, dict[str, Any]] | None:
        """The other optional call: the inner hosts' (None when they cannot say)."""
        return hosts_info_of(self.hosts)


class HumansWrapper:
    """Humans around ``humans``: every call of ``testbed.core.humans.Humans`` forwarded,
    ``presence()`` and ``presence_at(t)`` included (None when the inner humans are always
    present)."""

    def __init__(self, humans: Humans) -> None:
        self.humans = humans

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        return self.humans.act(requests, t)

    def show(self, t: int, status: FleetStatus) -> None:
        self.humans.show(t, status)

    def presence(self) -> Presence | None:
        return presence_of(self.humans)

    def presence_at(self, t: int) -> Presence | None:
        return presence_of(self.humans, t)

    def close(self) -> None:
        self.humans.close()
