"""What run.json says ran a run: its code (``code``) and its hosts (``hosts``).

The code is read by ``drivers.build_id``'s one git reader, reached from
``testbed.experiments.build.code_identity`` (the module of experiments that may reach
drivers); here against a tiny git checkout, so a modified product file is seen without
touching this one. The hosts come from the optional ``hosts_info`` call of the hosts
contract, through any wrapper; hosts without it record nothing. The end-to-end records
(a twin trial's run.json against ``git``, a resumed run's sessions, a YuMi host's
controller against the hardware twin) are asserted in tests/testbed/test_trial.py and
tests/testbed/test_controller_states.py, on trials those tests run anyway.
"""

from __future__ import annotations

import platform
import subprocess
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import pytest

from testbed.core.hosts import hosts_info_of
from testbed.core.types import ArmObservation, Fault, PushResult
from testbed.core.wrappers import HostsWrapper
from testbed.experiments.build import code_identity

GIT = ["git", "-c", "user.email=test@example.com", "-c", "user.name=test"]


def git(root: Path, *args: str) -> str:
    return subprocess.run([*GIT, "-C", str(root), *args], check=True, capture_output=True,
                          text=True).stdout


def test_the_code_of_a_checkout_with_a_modified_product_file_is_dirty(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.build_id as b

    root = tmp_path / "proj"
    (root / "testbed").mkdir(parents=True)
    (root / "docs").mkdir()
    (root / "pyproject.toml").write_text('[project]\nname = "x"\nversion = "1.2.3"\n')
    (root / "testbed" / "a.py").write_text("A = 1\n")
    (root / "docs" / "a.md").write_text("notes\n")
    git(root, "init", "-q")
    git(root, "add", "-A")
    git(root, "commit", "-qm", "one")
    head = git(root, "rev-parse", "HEAD").strip()
    monkeypatch.setattr(b, "ROOT", root)  # the controller's own checkout, for this test
    code = code_identity()
    assert code["commit"] == head and code["dirty"] is False
    assert code["build"] == f"1.2.3+g{head[:7]}"
    assert code["python"] == platform.python_version()
    assert set(code["libraries"]) >= {"numpy"} and set(code["libraries"]) <= {
        "numpy", "pybullet", "kornia"}
    (root / "docs" / "a.md").write_text("more notes\n")  # not the product: still clean
    assert code_identity()["dirty"] is False
    (root / "testbed" / "a.py").write_text("A = 2\n")
    code = code_identity()
    assert code["commit"] == head and code["dirty"] is True
    assert code["build"].startswith(f"1.2.3+g{head[:7]}.d")


class _Hosts:
    """An in-process double: the contract, and no ``hosts_info``."""

    def __init__(self) -> None:
        self.robot_names = ["h/a"]

    def start(self) -> None: ...

    def observe(self) -> Mapping[str, ArmObservation | Fault]:
        return {}

    def execute(self, pushes: Mapping[str, int], resets: Collection[str]
                ) -> Mapping[str, PushResult | Fault]:
        return {}

    def rest(self) -> None: ...

    def reseed(self, trial_seed: int) -> None: ...

    def close(self) -> None: ...


class _Saying(_Hosts):
    def hosts_info(self) -> dict[str, dict[str, Any]]:
        return {"h": {"backend": "twin", "transport": "local", "build": "b", "arms": ["a"]}}


def test_hosts_say_what_they_are_through_any_wrapper_and_doubles_say_nothing() -> None:
    assert hosts_info_of(_Hosts()) is None
    assert hosts_info_of(HostsWrapper(HostsWrapper(_Hosts()))) is None
    said = _Saying().hosts_info()
    assert hosts_info_of(_Saying()) == said
    assert hosts_info_of(HostsWrapper(HostsWrapper(_Saying()))) == said
