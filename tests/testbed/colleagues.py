"""Colleagues on other machines, for the first-day rehearsal: a network namespace each.

Why: the web console's promise is that a person on *another* machine reaches it through
the link the operator sends. On one test machine the nearest honest thing is another
network stack: each colleague gets a Linux network namespace (``ip netns``) joined to
this one by a veth pair, with an address of its own and its own loopback, so nothing
of theirs can reach the operator's ``127.0.0.1`` and every byte crosses an interface as
it would cross the lab's network. Their browser (Debian's Chromium, headless, driven by
``tests/testbed/first_day_person.py``) runs inside the namespace.

Needs root (CAP_NET_ADMIN) and iproute2, which ``scripts/setup.sh --dev`` installs;
``netns_missing`` says what is missing so the test can say it in one line.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

SUBNET = "10.231"
"""The colleagues' addresses: colleague k is ``10.231.k.2``, this machine ``10.231.k.1``."""


def _ip(*args: str, ns: str | None = None) -> None:
    cmd = ["ip", *(("-n", ns) if ns else ()), *args]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {done.stderr.strip()}")


def netns_missing() -> str | None:
    """Why colleagues' namespaces cannot be made here, or None."""
    if shutil.which("ip") is None:
        return "no ip command: apt-get install -y iproute2 (scripts/setup.sh --dev does it)"
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN)"
    probe = f"fd-probe-{os.getpid()}"
    try:
        _ip("netns", "add", probe)
    except RuntimeError as exc:
        return f"cannot make a network namespace: {exc}"
    _ip("netns", "del", probe)
    return None


@dataclass(frozen=True, slots=True)
class Colleague:
    """One colleague's machine: a namespace, its address, and this machine's as it
    sees it."""

    ns: str
    address: str
    """The colleague's own address (their side of the veth)."""
    gateway: str
    """This machine's address on the colleague's link."""

    def command(self, *argv: str) -> list[str]:
        """``argv`` run inside the colleague's namespace."""
        return ["ip", "netns", "exec", self.ns, *argv]


@contextmanager
def colleagues(count: int) -> Iterator[list[Colleague]]:
    """``count`` namespaces, each with a veth to this machine and a default route
    through it; deleted (veths with them) on exit."""
    tag = os.getpid() % 100000
    made: list[Colleague] = []
    try:
        for k in range(1, count + 1):
            ns, here, there = f"fd-{tag}-{k}", f"fdh{tag}x{k}", f"fdc{tag}x{k}"
            _ip("netns", "add", ns)
            made.append(Colleague(ns, f"{SUBNET}.{k}.2", f"{SUBNET}.{k}.1"))
            _ip("link", "add", here, "type", "veth", "peer", "name", there)
            _ip("link", "set", there, "netns", ns)
            _ip("addr", "add", f"{SUBNET}.{k}.1/24", "dev", here)
            _ip("link", "set", here, "up")
            _ip("addr", "add", f"{SUBNET}.{k}.2/24", "dev", there, ns=ns)
            _ip("link", "set", there, "up", ns=ns)
            _ip("link", "set", "lo", "up", ns=ns)
            _ip("route", "add", "default", "via", f"{SUBNET}.{k}.1", ns=ns)
        yield made
    finally:
        for c in made:
            subprocess.run(["ip", "netns", "del", c.ns], capture_output=True, timeout=30)
