"""Fixtures for the driver tests: local and SSH host configs, real sshd servers.

Every process a fixture starts is stopped by it (by pid), pass or fail.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from drivers.testing.sshd import SshServer, sshd_available
from drivers.yumi import layout_check


@pytest.fixture(autouse=True)
def _layout_checks_made_anew() -> Iterator[None]:
    """Each driver test checks its layouts afresh: ``check_layout`` keeps the last few
    in its process, and a mutation run (scripts/mutation.sh) forks every mutant from a
    process that ran the tests on the unmutated code, whose kept checks would answer."""
    layout_check._KEPT.clear()
    yield
    layout_check._KEPT.clear()


@pytest.fixture
def sshd_factory(tmp_path: Path) -> Iterator[Callable[[str], SshServer]]:
    """Start real OpenSSH servers on loopback; all are stopped at teardown."""
    if not sshd_available():
        pytest.skip("needs /usr/sbin/sshd and ssh-keygen (Debian: openssh-server)")
    servers: list[SshServer] = []

    def make(name: str = "host") -> SshServer:
        s = SshServer(tmp_path / f"sshd-{name}")
        s.start()
        servers.append(s)
        return s

    yield make
    for s in servers:
        s.thaw()
        s.stop()
