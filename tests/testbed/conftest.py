"""Fixtures shared by the testbed tests: a robot host's install, made once per session.

Why once: ``scripts/setup.sh --host`` takes about a minute (pip resolving and unpacking
OpenCV, numpy, pydantic and the ABB clients); every test that needs a host install
shares that one venv, and each test installs the build it needs into it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from host_install import HostVenv, make_host_venv


@pytest.fixture(scope="session")
def host_venv(tmp_path_factory: pytest.TempPathFactory) -> HostVenv:
    """A robot host's environment: ``scripts/setup.sh --host DIR`` in a temporary DIR."""
    where: Path = tmp_path_factory.mktemp("host-install") / ".venv-host"
    return make_host_venv(where)
