"""Config values take TOML's types strictly: a string where a boolean or a number belongs
is an error naming the field, for EVERY such field of every section (found by walking the
config models, so a field added later is covered without a line here).

pydantic's lax mode would take ``mirror = "yes"`` as true and ``deadline_s = "20"`` as
20.0; ``testbed.core.config.StrictModel`` refuses both, and a boolean where a number belongs.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.backends.twin.twin_host import TwinHost
from drivers.yumi.yumi_host import YumiHost
from testbed.cli import main
from testbed.core import config as c
from testbed.core.host_config import ArmConfig
from testbed.experiments.fleet_config import FleetConfig, TrialConfig, parse_config
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.learning.learning_config import LearningConfig
from testbed.people.people_config import HumansConfig, WebConsoleConfig

YUMI = {"name": "yumi0", "backend": "yumi", "camera": "0",
        "controller_url": "http://192.0.2.1",
        "arms": [{"name": "left", "crop": [0, 0, 300, 300], "calibration": "/c/l.json"}]}
BASE: dict[str, Any] = {"hosts": [{"name": "cell0"}, YUMI]}
SECTIONS: list[tuple[type[Any], tuple[Any, ...]]] = [
    (FleetConfig, ()), (TrialConfig, ("trial",)), (HumansConfig, ("humans",)),
    (WebConsoleConfig, ("humans", "web")), (AlgorithmConfig, ("algorithm",)),
    (LearningConfig, ("learning",)), (TwinHost, ("hosts", 0)), (YumiHost, ("hosts", 1)),
    (ArmConfig, ("hosts", 1, "arms", 0)),
]


def typed_fields() -> Iterator[tuple[str, tuple[Any, ...], type]]:
    for model, where in SECTIONS:
        for name, field in model.model_fields.items():
            kind = c._scalar_kind(field.annotation)
            if kind is not None:
                yield f"{model.__name__}.{name}", (*where, name), kind


CASES = list(typed_fields())


def test_the_walk_finds_the_fields_that_matter() -> None:
    names = {n for n, _, _ in CASES}
    assert {"ArmConfig.mirror", "ArmConfig.crop", "TwinHost.physics", "YumiHost.deadline_s",
            "YumiHost.motion_timeout_s", "TwinHost.port", "LearningConfig.batch_size",
            "AlgorithmConfig.t_R"} <= names
    assert len(CASES) >= 35


def _set(data: dict[str, Any], path: tuple[Any, ...], value: Any) -> None:
    node: Any = data
    for key in path[:-1]:
        if isinstance(key, str) and key not in node:
            node[key] = {}
        node = node[key]
    node[path[-1]] = value


def _spelt(path: tuple[Any, ...]) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


@pytest.mark.parametrize(("name", "path", "kind"), CASES, ids=[n for n, _, _ in CASES])
def test_a_string_for_a_boolean_or_a_number_names_the_field(name: str, path: tuple[Any, ...],
                                                            kind: type) -> None:
    wrong: list[Any] = ["yes"] if kind is bool else ["5", True]
    for value in wrong:
        data = copy.deepcopy(BASE)
        is_list = name == "ArmConfig.crop"
        _set(data, path, ["0", 0, 300, 300] if is_list and value == "5" else
             [True, 0, 300, 300] if is_list else value)
        with pytest.raises(c.ConfigError) as info:
            parse_config(data, "f.toml", check_files=False)
        line = str(info.value)
        assert "\n" not in line
        assert line.startswith(f"f.toml: {_spelt(path)}: must be a TOML "), line


def test_the_right_types_still_load() -> None:
    data = copy.deepcopy(BASE)
    _set(data, ("hosts", 1, "arms", 0, "mirror"), True)
    _set(data, ("hosts", 1, "deadline_s"), 20)  # an integer is a number
    cfg = parse_config(data, "f.toml", check_files=False)
    assert cfg.hosts[1].arms[0].mirror is True and cfg.hosts[1].deadline_s == 20.0


def test_the_command_line_exits_2_with_that_line(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "f.toml"
    f.write_text('[[hosts]]\nname = "cell0"\n[[hosts.arms]]\nname = "left"\nmirror = "yes"\n')
    assert main(["check", "--config", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hosts[0].arms[0].mirror: must be a TOML boolean" in err[0]
