"""Our RAPID modules (robot/rapid/*.mod) pass ``rapidchecker`` with no finding, and
agree with the Python sides that read and write what they do: the per-task file names
(the driver uploads to them, the twin reads them), the event log headers, the command
limit, the version (``TB_RAPID_VERSION``), the world zones (``tb_zones``: the boxes the
twin supervises, its default zone = the modules' as shipped) and every symbol the twin
declares as theirs (name, storage, type, and the CONSTs' values). rapidchecker checks
syntax, indentation (2), upper-case keywords and whitespace; it cannot load a module
into a controller, so robot/README.md ends with what to check on the robot."""

from __future__ import annotations

import re
import threading
from pathlib import Path

import pytest
from rapidchecker.cli import check_file

from drivers.yumi import yumi_controller
from sim_twin.rws import testbed_rapid, world_zones

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


def _decl(text: str, name: str) -> tuple[str, str, str]:
    """(storage, type, value) of a module-scope declaration of ``name``."""
    m = re.search(rf"^  ((?:TASK )?PERS|CONST|VAR) (\w+) {name}(?: := (.*))?;$", text, re.M)
    assert m, name
    return m.group(1), m.group(2), (m.group(3) or "").strip('"')


def test_the_world_zones_and_the_version_agree_with_the_twin() -> None:
    shared = (RAPID / "TestbedMotion.mod").read_text()
    assert float(_const(shared, "TB_RAPID_VERSION")) == testbed_rapid.RAPID_VERSION
    assert float(_const(shared, "TB_WZ_FAR")) == world_zones.FAR
    body = shared[shared.index("  PROC tb_zones()"):]
    body = body[:body.index("  ENDPROC")]
    names = re.findall(r"WZLimSup \\Stat, (\w+), shape;", body)
    assert names == [b.name for b in world_zones.ArmZone(0, 0, 1, 1).boxes()]
    assert body.count("WZBoxDef \\Inside, shape, lo, hi;") == len(names)
    for name in names:  # each a task-global VAR, as the manual's examples declare them
        assert _decl(shared, name)[:2] == ("VAR", "wzstationary")
    for side in ("L", "R"):
        text = (RAPID / f"TestbedTask_{side}.mod").read_text()
        lo = [float(v) for v in _decl(text, "tb_zone_lo")[2].strip("[]").split(",")]
        hi = [float(v) for v in _decl(text, "tb_zone_hi")[2].strip("[]").split(",")]
        shipped = world_zones.ArmZone(lo[0], lo[1], hi[0], hi[1],
                                      float(_const(text, "tb_zone_z")),
                                      float(_const(text, "tb_floor_z")))
        # the twin's default zone is the modules' as shipped (a lab edits its own)
        assert shipped == world_zones.default_zone("left" if side == "L" else "right")
        assert _decl(text, "tb_zone_lo")[:2] == _decl(text, "tb_zone_hi")[:2] == (
            "CONST", "pos")


def test_every_symbol_the_twin_declares_is_in_the_modules() -> None:
    from sim_twin.rws import Irc5Controller
    from sim_twin.rws.mechunits import YUMI_UNITS
    from sim_twin.rws.testbed_install import TestbedInstall
    from sim_twin.yumi_cell import YumiTwinCell

    with YumiTwinCell(0) as cell:
        hook = testbed_rapid.TestbedRapid(cell, threading.Lock(), YUMI_UNITS)
        decls = list(TestbedInstall(Irc5Controller(), hook).declarations())
    zone_consts = {"tb_zone_lo", "tb_zone_hi", "tb_zone_z", "tb_floor_z"}  # the CLI's
    for task, (module, name, type_name, value, storage) in decls:
        text = (RAPID / f"{module}.mod").read_text()
        if module != "TestbedMotion":
            assert module == f"TestbedTask_{task[-1]}"
        got = _decl(text, name)
        assert got[:2] == (storage, type_name), (module, name)
        if storage == "CONST" and name not in zone_consts:
            assert got[2] == value.strip('"'), (module, name)


def test_rapidchecker_would_catch_a_broken_zone_routine() -> None:
    text = (RAPID / "TestbedMotion.mod").read_text()
    assert not check_file(text)
    assert check_file(text.replace("WZLimSup \\Stat, tb_wz_floor, shape;",
                                   "WZLimSup \\Stat, tb_wz_floor, shape"))
    assert check_file(text.replace("    z0 := tb_floor_z", "   z0 := tb_floor_z"))
