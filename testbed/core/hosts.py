"""The hosts contract: what a trial asks of the fleet of robot hosts.

Why here, in ``core``: the fleet loop (``testbed.fleet``) drives hosts it never builds,
``drivers.host_fleet.HostFleet`` implements them, and wrappers (an evaluation's expert,
a rehearsal's truth recorder: ``testbed.core.wrappers.HostsWrapper``) sit between the
two. All three meet here, so none imports another.

``LoopHosts`` is the part the loop itself calls each step (a test's double needs only
that); ``Hosts`` adds the lifecycle that a trial's setup and teardown call.

Two calls are optional, found with ``getattr`` (an in-process test double has neither):

* ``stop_motion()``: stop every motion in progress NOW, from any thread, returning
  within about half a second (``HostFleet.stop_motion``: a console's confirmed Stop must
  not wait for a push of seconds to end). Call it through :func:`stop_motion_of`.
* ``hosts_info()``: host name -> what that host is, as its agent said when it answered
  (``HostFleet.hosts_info``: backend, transport, build, arms, a YuMi's controller),
  JSON types only and never a credential, for run.json ``hosts``: which hosts produced
  a run. Call it through :func:`hosts_info_of` (None: these hosts cannot say).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any, Protocol, runtime_checkable

from testbed.core.types import ArmObservation, Fault, PushResult

__all__ = ["Hosts", "LoopHosts", "hosts_info_of", "stop_motion_of"]


@runtime_checkable
class LoopHosts(Protocol):
    """The calls of one timestep: look at every arm, then act on every arm at once."""

    robot_names: list[str]
    """``"host/arm"``, in config order."""

    def observe(self) -> Mapping[str, ArmObservation | Fault]: ...

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> Mapping[str, PushResult | Fault]: ...


@runtime_checkable
class Hosts(LoopHosts, Protocol):
    """A trial's hosts, lifecycle included (``drivers.host_fleet.HostFleet``)."""

    def start(self) -> None: ...

    def rest(self) -> None: ...

    def reseed(self, trial_seed: int) -> None: ...

    def close(self) -> None: ...


def stop_motion_of(hosts: LoopHosts) -> bool:
    """``hosts.stop_motion()`` if these hosts can stop their motions (the optional call
    of the contract), and whether they could."""
    stop = getattr(hosts, "stop_motion", None)
    if not callable(stop):
        return False
    stop()
    return True


def hosts_info_of(hosts: LoopHosts) -> dict[str, dict[str, Any]] | None:
    """``hosts.hosts_info()`` if these hosts can say what they are (the optional call of
    the contract), else None: nothing to record, rather than a guess."""
    info = getattr(hosts, "hosts_info", None)
    if not callable(info):
        return None
    found: dict[str, dict[str, Any]] | None = info()
    return found
