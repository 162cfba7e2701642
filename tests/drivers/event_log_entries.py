"""Hand-made controller event-log entries for the zone-proof tests (newest first in a
log): the fields ``drivers/yumi/zones_proof.py`` reads of an ``abb_robot_client`` entry."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from drivers.yumi.zones_proof import ZONES_ACTIVE


def e(seq: int, code: int, *args: str, title: str | None = None) -> Any:
    """An entry: its title the first argument unless given."""
    return SimpleNamespace(seqnum=seq, code=code, msgtype=1,
                           title=title if title is not None else (args[0] if args else "t"),
                           args=list(args), desc="", causes="", tstamp=f"t{seq}")


def restart(seq: int, code: int = 10045) -> Any:
    return e(seq, code, "System restarted")


def on(seq: int, task: str, n: int = 5) -> Any:
    """Our RAPID's "Testbed Zones Active" entry for ``task`` with ``n`` zones."""
    return e(seq, 80003, ZONES_ACTIVE, task, f"zones {n}", "2026-01-01 00:00:00")


def other(seq: int) -> Any:
    return e(seq, 10002, "Program pointer has been reset")
