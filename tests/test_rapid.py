"""Our RAPID modules (robot/rapid/*.mod) pass ``rapidchecker`` with no finding, and
agree with the Python sides that read and write what they do: the per-task file names
(the driver uploads to them, the twin reads them), the event log headers, the command
limit. rapidchecker checks syntax, indentation (2), upper-case keywords and whitespace;
it cannot load a module into a controller, so robot/README.md ends with what to check
on the robot."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from rapidchecker.cli import check_file

from drivers.yumi import yumi_controller
from sim_twin.rws import testbed_rapid

RAPID = Path(__file__).resolve().parents[1] / "robot" / "rapid"
MODULES = sorted(RAPID.glob("*.mod"))


def test_there_is_a_shared_module_and_one_task_module_per_arm() -> None:
    assert [p.name for p in MODULES] == ["TestbedMotion.mod", "TestbedTask_L.mod",
                                         "TestbedTask_R.mod"]


@pytest.mark.parametrize("path", MODULES, ids=lambda p: p.name)
def test_rapidchecker_finds_nothing(path: Path) -> None:
    errors = check_file(path.read_text())
    assert not errors, f"{path.name}: " + "; ".join(str(e) for e in errors)


def test_rapidchecker_would_catch_a_broken_module() -> None:
    text = (RAPID / "TestbedTask_L.mod").read_text()
    assert check_file(text.replace("  ENDPROC", "  endproc"))  # keyword case
    assert check_file(text.replace("    tb_run;", "   tb_run;"))  # indentation
    assert check_file(text.replace("tb_run;", "tb_run"))  # syntax


def _const(text: str, name: str) -> str:
    m = re.search(rf"CONST (?:string|num) {name} := \"?([^\";]*)\"?;", text)
    assert m, name
    return m.group(1)


def test_the_modules_agree_with_the_driver_and_the_twin() -> None:
    shared = (RAPID / "TestbedMotion.mod").read_text()
    assert _const(shared, "TB_DONE") == yumi_controller.DONE == testbed_rapid.DONE
    assert _const(shared, "TB_FAILED") == yumi_controller.FAILED == testbed_rapid.FAILED
    assert int(_const(shared, "TB_MAX_CMDS")) == testbed_rapid.MAX_COMMANDS
    assert _const(shared, "TB_DIR") == "RAMDISK:"
    for side in ("L", "R"):
        task = f"T_ROB_{side}"
        text = (RAPID / f"TestbedTask_{side}.mod").read_text()
        name = _const(text, "tb_name")
        assert name == yumi_controller.program_file(task)
        assert f"RAMDISK:{name}" == testbed_rapid.testbed_program_file(task)
        assert "TASK PERS tooldata tool_pusher" in text
        assert float(_const(text, "tb_floor_z")) == 0.0  # the twin's default floor
        mass = re.search(r"tool_pusher := \[TRUE,\[\[[^]]*\],\[[^]]*\]\],\[([0-9.]+),", text)
        assert mass and float(mass.group(1)) > 0.001  # a real load, not load0
