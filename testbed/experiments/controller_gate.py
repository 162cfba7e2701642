"""The read-only part of ``testbed check`` that every trial runs first (issue 43).

Why: the margins that keep an arm out of the world zones (the layout, the paths' sweep),
the tool frame, the zones known active since the last restart and our RAPID's version
were judged only by ``testbed check``, which a trial never ran; so a trial could push in
Auto on a controller nobody had checked since its last restart. Now ``testbed trial``,
``evaluate``, ``protocol`` and ``rehearse`` (every run: :func:`run_trial` calls it)
check every host whose backend has the ``controller`` capability once its agent
answers, before the first observation or push, with the very report ``testbed check``
prints (``Backend.controller_report`` of the host's ``describe()`` answer: state, mode,
options, RAPID version, zones active, tool frame, layout and sweep margins, an arm in
the camera's view), and any FAULT refuses the trial (:class:`TrialRefused`) with those
lines. Both are read-only: ``describe`` moves nothing (``drivers/yumi/backend.py``), and
an agent asked nothing that moves an arm does not rest one at bye
(``drivers/agent/agent_session.py`` ``MAY_MOVE``), so a refused trial leaves every arm
where it was. A host without the capability (the twin) costs nothing.

A host that did not answer is a FAULT too: a check that cannot be made fails closed
(the fleet would reconnect it mid-trial, unchecked).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from testbed.core.backend_registry import backend_of
from testbed.core.host_config import HostConfig

__all__ = ["TrialRefused", "controller_faults", "controller_hosts", "controller_report"]

LOG = logging.getLogger(__name__)


class TrialRefused(RuntimeError):
    """A trial refused before its first step: the FAULT lines of its controllers' check
    (``faults``, each ``FAULT <host>: <what to fix>``). Nothing moved."""

    def __init__(self, faults: Sequence[str]) -> None:
        self.faults = list(faults)
        super().__init__(f"refused before its first step: the controllers' check found "
                         f"{len(self.faults)} FAULT(s); nothing moved. Fix them, then run "
                         f"again (testbed check shows the whole report)")


def controller_hosts(hosts: Sequence[HostConfig]) -> list[HostConfig]:
    """The hosts whose backend has the ``controller`` capability (a YuMi), in order."""
    return [h for h in hosts if backend_of(h).capabilities.controller]


def controller_report(fleet: Any, host: HostConfig, say: Callable[[str], None]) -> list[str]:
    """``host``'s report lines to ``say``; its FAULT lines returned (``FAULT <host>: ...``).

    ``fleet``: a ``drivers.host_fleet.HostFleet`` (``host_status``, ``describe``). Read
    only: ``describe`` and the backend's ``controller_report`` (``drivers/yumi/
    check_report.py`` for a YuMi) words it. A host that is not connected, or whose
    ``describe`` or the report fails, is one FAULT: a check that could not be made fails
    closed."""
    status = fleet.host_status()[host.name]
    if not status.connected:
        return [f"FAULT {host.name}: not connected, so its controller was not checked: "
                f"{status.error}"]
    try:
        info = fleet.describe(host.name)
    except Exception as exc:  # HostCallError, a dropped link: fail closed, one line
        return [f"FAULT {host.name}: cannot read the controller's state: {exc}"]
    try:
        lines, faults = backend_of(host).controller_report(host, info)
    except Exception as exc:  # a report that cannot be made refuses, as a FAULT would
        LOG.exception("host %s: the controller's report failed", host.name)
        return [f"FAULT {host.name}: the controller's report could not be made: "
                f"{type(exc).__name__}: {exc}"]
    for line in lines:
        say(line)
    return [f"FAULT {host.name}: {why}" for why in faults]


def controller_faults(fleet: Any, hosts: Sequence[HostConfig],
                      say: Callable[[str], None] | None = None) -> list[str]:
    """Every controller host's FAULT lines (:func:`controller_report`), in host order;
    the report lines to ``say`` (default: this module's debug log)."""
    say = say if say is not None else LOG.debug
    faults: list[str] = []
    for host in controller_hosts(hosts):
        faults += controller_report(fleet, host, say)
    return faults
