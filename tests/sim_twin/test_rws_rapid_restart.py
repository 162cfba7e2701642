"""RAPID's data and module semantics on the twin (issue 29): PP to Main sets VARs back,
"Reset RAPID" removes program modules and keeps system modules, a restart erases the
stationary world zones and the POWER_ON event routine defines them again. Our modules
(robot/rapid/: the zones in the system module TestbedZones, TASK PERS) keep the zones
active and reported through both; the issue-29 layout (VAR zones, everything in program
modules), played on the same twin, reads "zones missing" after PP to Main and loses the
zones at Reset RAPID, as the robot would. Driven by the unchanged ABB client over HTTP."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from twin_rws import LOGINS, as_person, client, program, run

from drivers.yumi.controller_state import RAPID_VERSION, problems, rapid_of_task
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws.irc5 import EVENT_ROUTINE_MISSING
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import ZONES_MODULE, TestbedInstall, task_module
from sim_twin.rws.testbed_rapid import DONE, WORLD_ZONE_CODE, TestbedRapid
from sim_twin.yumi_cell import YumiTwinCell

Made = tuple[Any, Irc5Controller, TestbedInstall]
PAST_THE_BOX = [("J", (400, 300, 80), 500), ("L", (400, 300, 10), 200),
                ("L", (400, 460, 10), 100)]
"""Down inside the left arm's zone box, then a push out past its far face."""
WZ = ("tb_wz_floor", "tb_wz_xlo", "tb_wz_xhi", "tb_wz_ylo", "tb_wz_yhi")


@pytest.fixture
def twin() -> Iterator[Callable[[], Made]]:
    made: list[tuple[RwsServer, YumiTwinCell]] = []

    def make() -> Made:
        cell = YumiTwinCell(3)
        hook = TestbedRapid(cell, threading.Lock(), YUMI_UNITS)
        ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses)
        install = TestbedInstall(ctrl, hook)
        server = RwsServer(RwsService(ctrl, program=install, **LOGINS)).start_thread()
        made.append((server, cell))
        return client(server.url), ctrl, install

    yield make
    for server, cell in made:
        server.stop()
        cell.close()


def zones(c: Any, task: str = "T_ROB_L") -> dict[str, str]:
    """What a lab reads over RWS: each zone's identity and the count tb_zones wrote."""
    out = {n: c.get_rapid_variable(n, f"{task}/{ZONES_MODULE}") for n in WZ}
    out["tb_zones_n"] = c.get_rapid_variable("tb_zones_n", f"{task}/{ZONES_MODULE}")
    return out


def restart(c: Any, mode: str) -> None:
    """``POST ctrl?action=restart`` as a lab's curl line does, as the person (the
    restart grants: robot/README.md), on ``c``'s controller; the motors on again after."""
    person = as_person(c.base_url)
    person._do_post("ctrl?action=restart", {"restart-mode": mode})
    person.set_controller_state("motoron")
    person.logout()


def test_pp_to_main_keeps_the_zones_reported_and_active(twin: Any) -> None:
    c, _, install = twin()
    first = zones(c)
    assert first["tb_zones_n"] == "5" and "[0]" not in first.values()
    assert [e.title for e in run(c, {"T_ROB_L": program([("J", (400, 200, 120), 500)])})] \
        == [DONE]  # the run's resetpp (PP to Main) came first
    c.resetpp()
    assert zones(c) == first  # TASK PERS: kept at PP to Main
    assert install.zones_active == {"left": True, "right": True}
    hit = run(c, {"T_ROB_L": program(PAST_THE_BOX)}, seqno=2)
    assert [e.code for e in hit] == [WORLD_ZONE_CODE]
    rep = {"T_ROB_L": rapid_of_task(c, "T_ROB_L")}
    assert rep["T_ROB_L"]["zones_active"]["n"] == 5.0 and rep["T_ROB_L"]["zones_active"]["at"]


def test_reset_rapid_keeps_the_system_modules_and_the_zones(twin: Any) -> None:
    c, ctrl, install = twin()
    restart(c, "pstart")  # Reset RAPID: TestbedMotion (a program module) is gone
    with pytest.raises(Exception, match="no RAPID symbol"):
        c.get_rapid_variable("TB_RAPID_VERSION", "T_ROB_L/TestbedMotion")
    assert c.get_rapid_variable("tb_zone_z", "T_ROB_L/TestbedTask_L") == "80"
    assert zones(c)["tb_zones_n"] == "5"  # POWER_ON ran tb_zones again: active
    assert install.zones_active == {"left": True, "right": True}
    assert not [e for e in c.read_event_log() if e.code == EVENT_ROUTINE_MISSING]
    install.set_loaded(True)  # the lab loads TestbedMotion.mod again
    assert zones(c)["tb_zones_n"] == "5"  # the system modules kept their values
    hit = run(c, {"T_ROB_L": program(PAST_THE_BOX)})
    assert [e.code for e in hit] == [WORLD_ZONE_CODE]
    restart(c, "restart")
    assert zones(c)["tb_zones_n"] == "5" and ctrl.ctrlstate == "motoron"
    with pytest.raises(Exception, match="the twin models restart, pstart"):
        as_person(c.base_url)._do_post("ctrl?action=restart", {"restart-mode": "xstart"})


def _issue29_layout(ctrl: Irc5Controller, install: TestbedInstall) -> None:
    """Our modules as issue 29 found them: the zones VAR, everything in program modules."""
    for unit in install.hook.units:
        for module in (ZONES_MODULE, task_module(unit.task)):
            ctrl.symbols.declare_module(unit.task, module, system=False)
        for name in WZ:
            ctrl.symbols.declare(unit.task, ZONES_MODULE, name, "wzstationary", "[0]", "VAR")
    ctrl.run_event_routines("POWER_ON")


def test_the_issue_29_layout_fails_on_the_twin_as_on_the_robot(twin: Any) -> None:
    c, ctrl, install = twin()
    _issue29_layout(ctrl, install)
    assert zones(c)["tb_wz_floor"] != "[0]"
    c.resetpp()  # what the driver does before every start
    assert zones(c)["tb_wz_floor"] == "[0]"  # "zones missing" on a healthy robot
    assert install.zones_active["left"]  # ... while the motion system still has them
    restart(c, "pstart")  # Reset RAPID: the event routine's module is gone
    missing = [e for e in c.read_event_log() if e.code == EVENT_ROUTINE_MISSING]
    assert {tuple(e.args[:2]) for e in missing} == {("T_ROB_L", "tb_zones"),
                                                  ("T_ROB_R", "tb_zones")}
    assert install.zones_active == {"left": False, "right": False}
    rep = {"T_ROB_L": rapid_of_task(c, "T_ROB_L")}
    rep["T_ROB_L"]["version"] = RAPID_VERSION  # the layout, not the version, is judged
    faults = problems({"options": ["608-1", "616-1", "623-1", "604-1"],
                       "state": {"opmode": "AUTO", "ctrlstate": "motoron",
                                 "execstate": "stopped"},
                       "tasks": {"T_ROB_L": {}}, "rapid": rep}, ["T_ROB_L"])
    assert any("TestbedZones.sys is not loaded" in f for f in faults), faults
