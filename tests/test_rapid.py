"""Our RAPID modules (robot/rapid/*.mod) pass ``rapidchecker`` with no finding, and
agree with the Python sides that read and write what they do: the per-task file names
(the driver uploads to them, the twin reads them), the event log headers, the command
limit, the version (``TB_RAPID_VERSION``), the world zones (``tb_zones``: the boxes the
twin supervises, its default zone = the modules' as shipped) and every symbol the twin
declares as theirs (name, storage, type, and the CONSTs' values). rapidchecker checks
syntax, indentation (2), upper-case keywords and whitespace; it cannot load a module
into a controller, so robot/README.md ends with what to check on the robot.

rapidchecker passes modules that RobotWare would run wrongly, so the semantic rules of
issue 29 are checked here on the parsed text (each check also on a planted copy of the
defect, and each fails on the issue-29 modules): every ``wzstationary`` is TASK PERS in
a system module; the POWER_ON event routine and everything it reads are in system
modules; ``main`` is in the program module; no ``Close`` without the opened flag; the
RAM disk path as the manual writes it ("RAMDISK:/<name>"); the tool load is the gripper
and the pusher, as robot/README.md derives it."""

from __future__ import annotations

import math
import random
import re
import struct
import threading
from collections import Counter
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from rapidchecker.cli import check_file

from drivers.yumi import yumi_controller
from sim_twin.rws import testbed_file, testbed_install, testbed_rapid, world_zones

RAPID = Path(__file__).resolve().parents[1] / "robot" / "rapid"
MODULES = sorted([*RAPID.glob("*.mod"), *RAPID.glob("*.sys")])


def _file(module: str) -> Path:
    return next(p for p in MODULES if p.stem == module)


def test_there_is_a_shared_module_and_one_task_module_per_arm() -> None:
    assert [p.name for p in MODULES] == ["TestbedMotion.mod", "TestbedTask_L.mod",
                                         "TestbedTask_R.mod", "TestbedZones.sys"]


@pytest.mark.parametrize("path", MODULES, ids=lambda p: p.name)
def test_rapidchecker_finds_nothing(path: Path) -> None:
    errors = check_file(path.read_text())
    assert not errors, f"{path.name}: " + "; ".join(str(e) for e in errors)


def test_rapidchecker_would_catch_a_broken_module() -> None:
    text = (RAPID / "TestbedMotion.mod").read_text()
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
    assert "tb_path := TB_DIR + \"/\" + tb_name;" in shared
    for side in ("L", "R"):
        task = f"T_ROB_{side}"
        text = (RAPID / f"TestbedTask_{side}.mod").read_text()
        name = _const(text, "tb_name")
        assert name == yumi_controller.program_file(task)
        assert f"RAMDISK:/{name}" == testbed_rapid.testbed_program_file(task)
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
    zones = (RAPID / "TestbedZones.sys").read_text()
    assert float(_const(zones, "TB_WZ_FAR")) == world_zones.FAR
    body = zones[zones.index("  PROC tb_zones()"):]
    body = body[:body.index("  ENDPROC")]
    names = re.findall(r"WZLimSup \\Stat, (\w+), shape;", body)
    assert names == [b.name for b in world_zones.ArmZone(0, 0, 1, 1).boxes()]
    assert body.count("WZBoxDef \\Inside, shape, lo, hi;") == len(names)
    assert float(_const(zones, "TB_WZ_COUNT")) == len(names)
    assert body.count("tb_zones_n := tb_zones_n + 1;") == len(names)
    for name in names:  # each TASK PERS: kept at PP to Main, one per task
        assert _decl(zones, name)[:2] == ("TASK PERS", "wzstationary")
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
        text = _file(module).read_text()
        if module not in ("TestbedMotion", "TestbedZones"):
            assert module == f"TestbedTask_{task[-1]}"
        got = _decl(text, name)
        assert got[:2] == (storage, type_name), (module, name)
        if storage == "CONST" and name not in zone_consts:
            assert got[2] == value.strip('"'), (module, name)


def test_rapidchecker_would_catch_a_broken_zone_routine() -> None:
    text = (RAPID / "TestbedZones.sys").read_text()
    assert not check_file(text)
    assert check_file(text.replace("WZLimSup \\Stat, tb_wz_floor, shape;",
                                   "WZLimSup \\Stat, tb_wz_floor, shape"))
    assert check_file(text.replace("    z0 := tb_floor_z", "   z0 := tb_floor_z"))


# --- the semantics rapidchecker cannot see (issue 29) ----------------------------------------
Texts = dict[str, str]
"""module name -> its text (one task's modules: the shared ones and that task's)."""
DECL = re.compile(r"^  (?:LOCAL )?(TASK PERS|PERS|CONST|VAR) (\w+) (\w+)(?:\{[^}]*\})?"
                  r"(?: := (.*))?;$", re.M)
EVENT_ROUTINES = ("tb_zones",)
"""The routines robot/README.md makes POWER_ON event routines."""


def _texts(side: str) -> Texts:
    """The modules one task (``T_ROB_<side>``) loads."""
    return {p.stem: p.read_text() for p in MODULES
            if not p.stem.startswith("TestbedTask_") or p.stem.endswith(side)}


def _is_system(text: str) -> bool:
    """``MODULE name(SYSMODULE, ...)``: RAPID's system module attribute."""
    m = re.match(r"MODULE \w+(?:\(([^)]*)\))?", text)
    return bool(m and m.group(1) and "SYSMODULE" in m.group(1).replace(" ", "").split(","))


def _declared(texts: Texts) -> dict[str, tuple[str, str, str, str]]:
    """Module-scope name -> (module, storage, type, value)."""
    return {m.group(3): (mod, m.group(1), m.group(2), m.group(4) or "")
            for mod, text in texts.items() for m in DECL.finditer(text)}


def _routine(texts: Texts, name: str) -> tuple[str, str]:
    """(module, body) of PROC ``name``."""
    for mod, text in texts.items():
        m = re.search(rf"^  PROC {name}\(\)\n(.*?)^  ENDPROC", text, re.M | re.S)
        if m:
            return mod, m.group(1)
    raise AssertionError(f"no PROC {name}")


def wzstationary_problems(texts: Texts) -> list[str]:
    """Every wzstationary must be TASK PERS (kept at PP to Main, one per task) in a system
    module (kept at Reset RAPID)."""
    return [f"{name} is {storage} in {mod}"
            for name, (mod, storage, type_name, _) in _declared(texts).items()
            if type_name == "wzstationary"
            and (storage != "TASK PERS" or not _is_system(texts[mod]))]


def event_routine_problems(texts: Texts) -> list[str]:
    """An event routine, and every module-scope name it reads, must be in a system
    module: Reset RAPID removes program modules while the event stays configured."""
    out, decls = [], _declared(texts)
    for routine in EVENT_ROUTINES:
        mod, body = _routine(texts, routine)
        if not _is_system(texts[mod]):
            out.append(f"{routine} is in the program module {mod}")
        code = re.sub(r"!.*", "", body)
        for name in sorted(set(re.findall(r"\b[A-Za-z_]\w*\b", code)) & set(decls)):
            if not _is_system(texts[decls[name][0]]):
                out.append(f"{routine} reads {name} of the program module {decls[name][0]}")
    return out


def main_problems(texts: Texts) -> list[str]:
    """One ``main`` per task, in a program module."""
    mains = [mod for mod, text in texts.items() if re.search(r"^  PROC main\(\)", text, re.M)]
    if len(mains) != 1:
        return [f"main in {mains or 'no module'}"]
    return [f"main is in the system module {mains[0]}"] if _is_system(texts[mains[0]]) else []


def close_problems(texts: Texts) -> list[str]:
    """Every ``Close dev`` sits under ``IF flag THEN`` where ``flag := TRUE`` follows the
    ``Open ... dev``: an error handler must not close a device that was never opened."""
    out = []
    for mod, text in texts.items():
        lines = [ln.strip() for ln in text.splitlines()]
        for i, line in enumerate(lines):
            m = re.fullmatch(r"Close (\w+);", line)
            if not m:
                continue
            guard = next((re.fullmatch(r"IF (\w+) THEN", lines[j]) for j in range(i - 1,
                          max(i - 3, -1), -1) if re.fullmatch(r"IF \w+ THEN", lines[j])), None)
            opened = guard is not None and any(
                re.match(rf"Open .*, {m.group(1)}\b", lines[j]) and
                lines[j + 1] == f"{guard.group(1)} := TRUE;" for j in range(len(lines) - 1))
            if not opened:
                out.append(f"{mod} line {i + 1}: {line} without an opened-flag guard")
    return out


def _string(expr: str, texts: Texts) -> str:
    """The value of a string expression of literals, CONSTs and a VAR assigned once."""
    decls, out = _declared(texts), ""
    for term in (s.strip() for s in expr.split("+")):
        if term.startswith('"'):
            out += term.strip('"')
        elif decls.get(term, ("", ""))[1] == "CONST":
            out += decls[term][3].strip('"')
        else:
            sets = [m.group(1) for text in texts.values()
                    for m in re.finditer(rf"^\s*{term} := (.*);$", text, re.M)]
            assert len(sets) == 1, f"{term} is set {len(sets)} times"
            out += _string(sets[0], texts)
    return out


def path_problems(texts: Texts) -> list[str]:
    """FileSize takes one path, in the manual's form: the device, a slash, the name."""
    out = []
    for text in texts.values():
        for expr in re.findall(r"FileSize\((.+?)\)", text):
            path = _string(expr, texts)
            if not re.fullmatch(r"[A-Z]+:/[^/:]+", path):
                out.append(f"FileSize({expr}) is {path!r}, not DEVICE:/name")
    return out


SEMANTICS = (wzstationary_problems, event_routine_problems, main_problems, close_problems,
             path_problems)


@pytest.mark.parametrize("side", ["L", "R"])
@pytest.mark.parametrize("check", SEMANTICS, ids=lambda f: f.__name__)
def test_the_modules_keep_robotwares_semantics(check: object, side: str) -> None:
    assert check(_texts(side)) == []  # type: ignore[operator]


PLANTED = {
    wzstationary_problems: ("TestbedZones", "TASK PERS wzstationary tb_wz_xlo",
                            "VAR wzstationary tb_wz_xlo"),
    event_routine_problems: ("TestbedZones", "MODULE TestbedZones(SYSMODULE, NOSTEPIN)",
                             "MODULE TestbedZones"),
    main_problems: ("TestbedMotion", "  PROC main()\n    tb_run;\n  ENDPROC\n", ""),
    close_problems: ("TestbedMotion", "    IF tb_open THEN\n      tb_open := FALSE;\n"
                     "      Close tb_dev;\n    ENDIF\n", "    Close tb_dev;\n"),
    path_problems: ("TestbedMotion", 'tb_path := TB_DIR + "/" + tb_name;',
                    "tb_path := TB_DIR + tb_name;"),
}


@pytest.mark.parametrize("check", SEMANTICS, ids=lambda f: f.__name__)
def test_each_semantic_check_catches_its_planted_defect(check: object) -> None:
    module, good, bad = PLANTED[check]  # type: ignore[index]
    texts = _texts("L")
    assert good in texts[module]
    texts[module] = texts[module].replace(good, bad)
    assert check(texts), "the planted defect was not caught"  # type: ignore[operator]
    event_problem = event_routine_problems({**_texts("L"), "TestbedTask_L": _texts("L")[
        "TestbedTask_L"].replace("MODULE TestbedTask_L(SYSMODULE)", "MODULE TestbedTask_L")})
    assert event_problem == [f"tb_zones reads {n} of the program module TestbedTask_L"
                             for n in ("tb_floor_z", "tb_zone_hi", "tb_zone_lo", "tb_zone_z")]


def test_the_readme_makes_tb_zones_the_power_on_routine() -> None:
    readme = (RAPID.parent / "README.md").read_text()
    for task in ("T_ROB_L", "T_ROB_R"):
        assert f"Event `POWER_ON`, Routine `tb_zones`, Task `{task}`" in readme
        assert f"File `HOME:/TestbedZones.sys`, Task `{task}`" in readme


GRIPPER = (0.262, (7.8, 11.9, 50.7), (0.00022, 0.00024, 0.00009))
"""The YuMi SmartGripper (servo, camera, vacuum) load: ABB's SmartGripper load table, the
numbers of the lab's published YuMi RAPID (issue 29); kg, mm, kg m^2 about its CoG."""
PUSHER = (0.010, (0.0, 0.0, 134.0), 100.0, 5.0)
"""The pusher, an estimate until weighed (robot/README.md): kg, its CoG (mm), a rod of
that length and radius (mm) along the tool's z axis."""


def _combined() -> tuple[float, list[float], list[float]]:
    """Mass, CoG and inertia (about the joint CoG, tool0 axes) of gripper + pusher."""
    (mg, cg, ig), (mp, cp, length, r) = GRIPPER, PUSHER
    mass = mg + mp
    cog = [(mg * a + mp * b) / mass for a, b in zip(cg, cp, strict=True)]
    rod = [mp * (3 * r * r + length * length) / 12e6] * 2 + [mp * r * r / 2e6]

    def shift(m: float, c: tuple[float, ...]) -> list[float]:
        d = [(c[k] - cog[k]) / 1000 for k in range(3)]
        return [m * (d[(k + 1) % 3] ** 2 + d[(k + 2) % 3] ** 2) for k in range(3)]

    inertia = [ig[k] + rod[k] + shift(mg, cg)[k] + shift(mp, cp)[k] for k in range(3)]
    return mass, cog, inertia


@pytest.mark.parametrize("side", ["L", "R"])
def test_the_tool_load_is_the_gripper_and_the_pusher(side: str) -> None:
    text = (RAPID / f"TestbedTask_{side}.mod").read_text()
    load = _decl(text, "tool_pusher")[2]
    nums = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?(?:E-?\d+)?", load)]
    mass, cog, aom, inertia = nums[7], nums[8:11], nums[11:15], nums[15:18]
    want_mass, want_cog, want_inertia = _combined()
    assert mass == pytest.approx(want_mass, abs=0.0005) and mass > GRIPPER[0]
    assert cog == pytest.approx(want_cog, abs=0.05)
    assert aom == [1, 0, 0, 0]
    assert inertia == pytest.approx(want_inertia, abs=0.000006)
    assert all(v > 0 for v in inertia)


# --- the tool frame is the controller's; zones active in the event log (issue 35) ------------
PUSHER_TCP_MM = 114.2 + 70.0
"""The pusher's tip down the flange's z: the SmartGripper fingers' TCP (ABB's gripper
tooldata, 114.2 mm) and the 100 mm rod's 70 mm beyond them (30 mm held inside);
robot/README.md, "The tool frame"."""


@pytest.mark.parametrize("side", ["L", "R"])
def test_tool_pusher_ships_the_pushers_measured_frame(side: str) -> None:
    text = (RAPID / f"TestbedTask_{side}.mod").read_text()
    storage, type_name, value = _decl(text, "tool_pusher")
    assert (storage, type_name) == ("TASK PERS", "tooldata")
    assert value.startswith("[TRUE,[[0,0,184.2],[1,0,0,0]],[0.272,")
    assert float(value.split(",")[3].rstrip("]")) == pytest.approx(PUSHER_TCP_MM)


def test_the_twins_pusher_is_the_shipped_tool_pusher() -> None:
    """The twin's default pusher (its tool_pusher as declared) is the shipped frame."""
    from sim_twin.yumi_arms import DEFAULT_TOOL_MM

    assert abs(DEFAULT_TOOL_MM - PUSHER_TCP_MM) < 1e-9, DEFAULT_TOOL_MM


def test_no_program_sets_the_tool_frame_and_the_header_checks_it() -> None:
    """tb_header reads the file's tframe and hands it to tb_tool, which compares it with
    tool_pusher's; nothing assigns tool_pusher (it was ``tool_pusher.tframe := tb_pose()``)."""
    texts = _texts("L")
    for mod, text in texts.items():
        code = re.sub(r"!.*", "", text)
        assert not re.search(r"^ {4,}tool_pusher\b[.\w]*\s*:=", code, re.M), mod
    shared = texts["TestbedMotion"]
    _, header = _routine({"TestbedMotion": shared}, "tb_header")
    steps = [ln.strip() for ln in header.splitlines() if not ln.strip().startswith("!")]
    i = steps.index("frame := tb_pose();")
    assert steps[i + 1] == "tb_tool frame;"  # right after the frame: before any command
    assert float(_const(shared, "TB_TOOL_MM")) == testbed_rapid.TOOL_MM
    assert float(_const(shared, "TB_TOOL_DEG")) == testbed_rapid.TOOL_DEG
    assert _const(shared, "TB_TOOL_DIFFERS") == testbed_rapid.TOOL_DIFFERS
    body = re.search(r"^  PROC tb_tool\(pose file\)\n(.*?)^  ENDPROC", shared, re.M | re.S)
    assert body and "IF dist > TB_TOOL_MM OR angle > TB_TOOL_DEG THEN" in body.group(1)
    assert "tb_fail TB_TOOL_DIFFERS," in body.group(1)


def _rapid_func(text: str, name: str) -> Any:
    """A RAPID FUNC of plain arithmetic (``:=``, compact ``IF``, ``RETURN``, Sqrt, Pow,
    ASin, ACos, Abs) as a Python function of the same parameters (records: attributes)."""
    m = re.search(rf"^  FUNC num {name}\(([^)]*)\)\n(.*?)^  ENDFUNC", text, re.M | re.S)
    assert m, name
    params = [p.split()[-1] for p in m.group(1).split(",")]
    code = " ".join(ln.strip() for ln in m.group(2).splitlines()
                    if not ln.strip().startswith("!"))
    out = [f"def {name}({', '.join(params)}):"]
    for stmt in (s.strip() for s in code.split(";") if s.strip()):
        stmt = re.sub(r"^VAR num (\w+)$", r"\1 = None", stmt)
        stmt = re.sub(r"^VAR num ", "", stmt)
        cond = re.match(r"IF (.*?) (RETURN .*|\w+ := .*)$", stmt)
        if cond:
            test = re.sub(r"(?<![<>:])=", "==", cond.group(1))
            stmt = f"if {test}: {cond.group(2)}"
        out.append("    " + stmt.replace(":=", "=").replace("RETURN", "return")
                   .replace(" OR ", " or ").replace(" AND ", " and "))
    env = {"Sqrt": math.sqrt, "Pow": pow, "Abs": abs,
           "ASin": lambda x: math.degrees(math.asin(x)),
           "ACos": lambda x: math.degrees(math.acos(x))}
    exec("\n".join(out), env)  # our own module's text, in a test
    return env[name]


def test_tb_angle_is_the_angle_between_two_orientations() -> None:
    """The RAPID of tb_angle, evaluated: 2 acos(|a.b|) of the normalised quaternions (q
    and -q alike), exact for small angles, 180 for a zero quaternion; as the twin's."""
    tb_angle = _rapid_func((RAPID / "TestbedMotion.mod").read_text(), "tb_angle")
    rng = random.Random(3)

    def orient(q: list[float]) -> SimpleNamespace:
        return SimpleNamespace(q1=q[0], q2=q[1], q3=q[2], q4=q[3])

    for _ in range(300):
        a = [rng.gauss(0, 1) for _ in range(4)]
        b = [rng.gauss(0, 1) for _ in range(4)]
        dot = abs(sum(x * y for x, y in zip(a, b, strict=True))) / (
            math.hypot(*a) * math.hypot(*b))
        want = math.degrees(2 * math.acos(min(dot, 1.0)))
        assert tb_angle(orient(a), orient(b)) == pytest.approx(want, abs=1e-6)
        assert tb_angle(orient(a), orient(b)) == pytest.approx(testbed_rapid.angle_deg(a, b))
        assert tb_angle(orient(a), orient([-v for v in a])) == pytest.approx(0, abs=1e-6)
    half = math.radians(0.3) / 2
    assert tb_angle(orient([1, 0, 0, 0]), orient([math.cos(half), 0, math.sin(half), 0])) \
        == pytest.approx(0.3, rel=1e-9)
    assert tb_angle(orient([0, 0, 0, 0]), orient([1, 0, 0, 0])) == 180


def test_tb_zones_writes_zones_active_when_all_are_on() -> None:
    zones = (RAPID / "TestbedZones.sys").read_text()
    assert _const(zones, "TB_ZONES_ACTIVE") == testbed_install.ZONES_ACTIVE
    _, body = _routine({"TestbedZones": zones}, "tb_zones")
    code = [ln.strip() for ln in body.splitlines() if not ln.strip().startswith("!")]
    last = " ".join(code[-2:])
    assert last == ('ErrWrite \\I, TB_ZONES_ACTIVE, GetTaskName() \\RL2:="zones " + '
                    'NumToStr(tb_zones_n, 0) \\RL3:=tb_zones_at;')
    assert code[-3] == 'tb_zones_at := CDate() + " " + CTime();'  # after every WZLimSup


def test_rapidchecker_would_catch_a_broken_tool_check() -> None:
    text = (RAPID / "TestbedMotion.mod").read_text()
    assert check_file(text.replace("    IF d > 1 d := 1;", "    IF d > 1 d := 1"))
    assert check_file(text.replace("    tb_tool frame;", "   tb_tool frame;"))


# --- every field a file can set has a limit the controller holds (issue 43) ------------------
def _reasons(shared: str) -> set[str]:
    """Every reason (a refusal's first line) TestbedMotion writes: ``tb_fail``'s and
    ``tb_over``'s first argument, the error handler's ``tb_reason``, CONSTs resolved."""
    code = re.sub(r"!.*", "", shared)
    names = re.findall(r"\btb_fail (\"[^\"]*\"|\w+),", code)
    names += re.findall(r"\btb_over (\w+),", code)
    names += re.findall(r"\btb_reason := (\"[^\"]*\");", code)
    # tb_over hands its parameter on: its callers' reasons are counted above
    return {n.strip('"') if n.startswith('"') else _const(shared, n) for n in names
            if n not in ("reason", "\"\"")}


def test_every_refusal_of_the_module_is_the_twins() -> None:
    """The twin refuses with exactly the module's reasons (sim_twin/rws/testbed_file.py
    REASONS), the issue-43 ones as the module's CONSTs."""
    shared = (RAPID / "TestbedMotion.mod").read_text()
    assert _reasons(shared) == set(testbed_file.REASONS)
    for name, text in testbed_install.LIMIT_REASONS.items():
        assert _const(shared, name) == text
    planted = shared.replace('tb_fail TB_WAIT_OVER, tb_clip', 'tb_fail "Wait too long", tb_clip')
    assert _reasons(planted) != set(testbed_file.REASONS)


def test_the_limits_are_the_twins_and_let_the_drivers_files_pass() -> None:
    """The module's caps and the task modules' (as shipped) are the twin's; the driver's
    speeds (drivers/yumi/rws_controller.py) and its zones (fine, z10) pass them."""
    from drivers.yumi import rws_controller

    shared = (RAPID / "TestbedMotion.mod").read_text()
    assert float(_const(shared, "TB_WAIT_MAX")) == testbed_file.WAIT_MAX == 2
    assert float(_const(shared, "TB_V_LEAX_MAX")) == testbed_file.V_LEAX_MAX
    for name, cap in testbed_file.ZONE_MAX.values():
        assert float(_const(shared, name)) == cap
    z10 = [10, 15, 15, 1.5, 15, 1.5]  # abb_motion_program_exec's z10 (RAPID's)
    assert [cap for _, cap in testbed_file.ZONE_MAX.values()] == z10
    for side in ("L", "R"):
        text = (RAPID / f"TestbedTask_{side}.mod").read_text()
        caps = {n: float(_const(text, n)) for n in testbed_rapid.CAPS}
        assert caps == {"tb_v_tcp_max": testbed_file.V_TCP_MAX,
                        "tb_v_ori_max": testbed_file.V_ORI_MAX,
                        "tb_v_reax_max": testbed_file.V_REAX_MAX}
        assert all(_decl(text, n)[:2] == ("CONST", "num") for n in caps)
        assert caps["tb_v_tcp_max"] >= 150.0  # the calibration's default max_speed_mm_s
        assert caps["tb_v_ori_max"] >= rws_controller.V_ORI_DEG_S
        assert caps["tb_v_reax_max"] >= rws_controller.V_REAX_DEG_S
    assert rws_controller.V_LEAX_MM_S <= testbed_file.V_LEAX_MAX


def _calls(shared: str, routine: str, callee: str) -> list[list[str]]:
    """The argument lists of every ``callee`` call in FUNC or PROC ``routine``."""
    m = re.search(rf"^  (?:FUNC \w+|PROC) {routine}\([^)]*\)\n(.*?)^  END(?:FUNC|PROC)", shared,
                  re.M | re.S)
    assert m, routine
    code = re.sub(r"\n\s+", " ", re.sub(r"!.*", "", m.group(1)))
    return [[a.strip() for a in args.split(",")]
            for args in re.findall(rf"\b{callee} ([^;]*);", code)]


def limit_problems(shared: str) -> list[str]:
    """Each speed and zone field is checked against its cap, VelSet caps the TCP before
    the moves, the moves run in wobj0 with the file's speeds (none replaced), every
    WaitTime is checked against TB_WAIT_MAX and both frames of the work object."""
    out = []
    speeds = [(c[1].strip('"'), c[3].strip('"'), c[4]) for c in
              _calls(shared, "tb_speeddata", "tb_speed_limit")]
    if speeds != [("v_tcp", "tb_v_tcp_max", "tb_v_tcp_max"), ("v_ori", "tb_v_ori_max",
                  "tb_v_ori_max"), ("v_leax", "TB_V_LEAX_MAX", "TB_V_LEAX_MAX"),
                  ("v_reax", "tb_v_reax_max", "tb_v_reax_max")]:
        out.append(f"tb_speeddata checks {speeds}")
    zones = [(c[1].strip('"'), c[4]) for c in _calls(shared, "tb_zonedata", "tb_zone_limit")]
    if zones != [(f, name) for f, (name, _) in testbed_file.ZONE_MAX.items()]:
        out.append(f"tb_zonedata checks {zones}")
    _, execute = _routine({"TestbedMotion": shared}, "tb_execute")
    steps = [ln.strip() for ln in execute.splitlines() if not ln.strip().startswith("!")]
    if "VelSet 100, tb_v_tcp_max;" not in steps or steps.index(
            "VelSet 100, tb_v_tcp_max;") > steps.index("FOR i FROM 1 TO tb_n DO"):
        out.append("no VelSet 100, tb_v_tcp_max before the moves")
    moves = [s for s in steps if s.startswith(("MoveJ ", "MoveL "))]
    if not moves or any(not s.endswith("tool_pusher \\WObj:=wobj0;") for s in moves):
        out.append(f"a move not in wobj0: {moves}")
    code = re.sub(r"!.*", "", shared)
    if re.search(r"\bs\.v_\w+ := (?!tb_num\(\))", code):
        out.append("a speed of the file is replaced")
    if "tb_wait{tb_n} > TB_WAIT_MAX" not in code:
        out.append("WaitTime not checked against TB_WAIT_MAX")
    if [c[0].strip('"') for c in _calls(shared, "tb_header", "tb_identity")] != [
            "uframe", "oframe"]:
        out.append("the work object's frames are not both checked")
    return out


def test_every_field_has_its_limit_in_the_module() -> None:
    shared = (RAPID / "TestbedMotion.mod").read_text()
    assert limit_problems(shared) == []
    planted = {
        "VelSet": shared.replace("    VelSet 100, tb_v_tcp_max;\n", ""),
        "v_ori": shared.replace('    tb_speed_limit what, "v_ori", s.v_ori, "tb_v_ori_max", '
                                'tb_v_ori_max;\n', ""),
        "zone": shared.replace('"TB_ZONE_ORI_MAX", TB_ZONE_ORI_MAX', '"TB_ZONE_ORI_MAX", 90'),
        "wobj": shared.replace("tool_pusher \\WObj:=wobj0;", "tool_pusher \\WObj:=tb_wobj;"),
        "replaced": shared.replace("    RETURN s;", "    s.v_ori := 500;\n    RETURN s;"),
        "frame": shared.replace('    tb_identity "oframe", file_wobj.oframe;\n', ""),
    }
    for name, text in planted.items():
        assert text != shared and limit_problems(text), name


def test_tb_num_refuses_every_inf_and_nan_before_unpacking_it() -> None:
    """The bit test of tb_num (the float32's exponent all ones), evaluated on the bytes
    of finite numbers (the largest, the smallest, subnormal, zero, random) and of every
    kind of inf and NaN: refused exactly when the number is not finite; and before the
    value is unpacked."""
    shared = (RAPID / "TestbedMotion.mod").read_text()
    _, body = re.search(r"^  FUNC num (tb_num)\(\)\n(.*?)^  ENDFUNC", shared,
                        re.M | re.S).groups()  # type: ignore[union-attr]
    steps = [ln.strip() for ln in body.splitlines() if not ln.strip().startswith("!")]
    at = {m.group(2): int(m.group(1)) for s in steps
          for m in [re.fullmatch(r"UnpackRawBytes tb_raw, (\d), (hi|lo) \\IntX:=USINT;", s)] if m}
    check = next(i for i, s in enumerate(steps) if "tb_fail TB_NOT_FINITE" in s)
    assert check < steps.index("UnpackRawBytes tb_raw, 1, v \\Float4;")
    cond = re.fullmatch(r"IF (.*) tb_fail TB_NOT_FINITE, .*;", steps[check]).group(1)  # type: ignore[union-attr]
    expr = cond.replace(" MOD ", " % ").replace(" AND ", " and ").replace(" = ", " == ")
    rng = random.Random(43)
    finite = [3.4028234e38, -3.4028234e38, 1.4e-45, -1.4e-45, 0.0, -0.0, 1.0, 150.0]
    finite += [rng.uniform(-1e6, 1e6) for _ in range(500)]
    bits = [struct.pack("<f", v) for v in finite]
    odd = [struct.pack("<I", s | 0x7F800000 | m) for s in (0, 1 << 31)
           for m in (0, 1, 0x400000, 0x7FFFFF, rng.randrange(1, 1 << 23))]
    for raw in bits + odd:
        v = struct.unpack("<f", raw)[0]
        refused = eval(expr, {}, {"hi": raw[at["hi"] - 1], "lo": raw[at["lo"] - 1]})
        assert refused == (not math.isfinite(v)), (raw.hex(), v)


ROUTINE = re.compile(r"^  (?:LOCAL )?(?:PROC|TRAP|FUNC \w+) (\w+)\(", re.M)


def name_problems(texts: Texts) -> list[str]:
    """Every module-scope name of a task (data and routines, its modules together) is
    declared once; RAPID's names are not case-sensitive, so neither is this. rapidchecker
    passed a PROC ``tb_speed`` beside the array ``tb_speed{}``, which a controller does
    not load."""
    seen: Counter[str] = Counter()
    for text in texts.values():
        seen.update(m.group(3).lower() for m in DECL.finditer(text))
        seen.update(m.group(1).lower() for m in ROUTINE.finditer(text))
    return [f"{name} is declared {n} times" for name, n in sorted(seen.items()) if n > 1]


@pytest.mark.parametrize("side", ["L", "R"])
def test_no_name_is_declared_twice_in_a_task(side: str) -> None:
    texts = _texts(side)
    assert name_problems(texts) == []
    shared = texts["TestbedMotion"]
    planted = shared.replace("PROC tb_speed_limit(", "PROC tb_speed(")
    assert planted != shared
    assert name_problems({**texts, "TestbedMotion": planted}) == ["tb_speed is declared 2 times"]
