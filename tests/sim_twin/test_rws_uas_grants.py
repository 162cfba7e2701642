"""The twin holds the controller's UAS grants per user (``sim_twin.rws.uas``), as an IRC5
does: the agent's user, with exactly robot/README.md's four grants, runs the driver's
whole push; each of those grants is needed; a hostile PC logged in as the agent cannot
write ``tool_pusher``, restart the controller, switch the motors, load a module, clear
the event log, set the speed ratio or request mastership: each is refused with the
controller's 403 and ``SYS_CTRL_E_UAS_REJECT`` and nothing changes (read back); the
person's user does the same; a stop needs no grant. Driven by the UNCHANGED ABB client
(and the agent's own driver) over HTTP against our RAPID on a real cell.

Without the check in ``sim_twin.rws.rws_service`` every refusal test here fails (the
twin used to check the password alone)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
import requests
from abb_robot_client.rws import ABBException
from twin_rws import PERSON, as_person, client

from drivers.errors import BackendError
from drivers.yumi.credentials import RwsLogin
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from sim_twin.rws import Irc5Controller, RwsServer
from sim_twin.rws import __main__ as rws_main
from sim_twin.rws.digest_auth import DEFAULT_USERS
from sim_twin.rws.mechunits import YUMI_UNITS
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.rws.uas import (
    AGENT_GRANTS,
    DEBUG,
    EXECUTE,
    FACTORY_GRANTS,
    FTP_READ,
    FTP_WRITE,
    PERSON_GRANTS,
    UAS_REJECT,
    grants_of_users,
    parse_grants,
)
from sim_twin.yumi_cell import YumiTwinCell

PUSHER_MM = 184.2
"""The shipped pusher (the twin's and tool_pusher's), as tests/drivers/test_yumi_rws_twin.py."""
AGENT = ("agent", "pushes-only")
NOBODY = ("nobody", "no-grants")
NEEDED = (EXECUTE, DEBUG, FTP_WRITE)
"""The agent's grants a push uses (Read access is the checklist's, not the push's)."""
TOOL = ("tool_pusher", "T_ROB_L/TestbedTask_L")
LEFT, RIGHT = (400.0, 200.0, 100.0), (420.0, -180.0, 100.0)
"""Above the world zones' tb_zone_z (80 mm): a push's place, not its stroke."""


def without(grant: str) -> tuple[str, str]:
    return (f"agent-without-{grant}", "pushes-less")


@dataclass
class Cell:
    """Our RAPID on a real cell, served to the agent, the person, a user with no grant,
    and one agent short of each grant a push needs."""

    url: str
    ctrl: Irc5Controller
    install: TestbedInstall
    yumi: YumiTwinCell
    lock: threading.Lock

    def tcps(self) -> dict[str, tuple[float, float, float]]:
        with self.lock:
            return self.yumi.tcp_xyz()

    def driver(self, login: tuple[str, str]) -> RwsYumiController:
        hook = self.install.hook
        poses = {u.arm: ArmPose(u.task, u.name, tuple(hook.poses.joints(u)),
                                tool_z_mm=PUSHER_MM) for u in YUMI_UNITS}
        return RwsYumiController(self.url, poses, login=RwsLogin(*login),
                                 http_timeout_s=20.0, motion_timeout_s=60.0)


@pytest.fixture
def cell() -> Iterator[Cell]:
    yumi = YumiTwinCell(3, realtime=0.0)
    lock = threading.Lock()
    hook = TestbedRapid(yumi, lock, YUMI_UNITS, pusher_length_mm=PUSHER_MM)
    ctrl = Irc5Controller(units=YUMI_UNITS, poses=hook.poses, on_start=hook)
    install = TestbedInstall(ctrl, hook)
    users = {AGENT[0]: AGENT[1], PERSON[0]: PERSON[1], NOBODY[0]: NOBODY[1],
             **{without(g)[0]: without(g)[1] for g in NEEDED}}
    grants = {AGENT[0]: AGENT_GRANTS, PERSON[0]: PERSON_GRANTS,
              **{without(g)[0]: AGENT_GRANTS - {g} for g in NEEDED}}  # nobody: none given
    server = RwsServer(RwsService(ctrl, program=install, users=users, grants=grants)
                       ).start_thread()
    try:
        yield Cell(server.url, ctrl, install, yumi, lock)
    finally:
        server.stop()
        yumi.close()


def to(xyz: tuple[float, float, float]) -> list[Waypoint]:
    above = (xyz[0], xyz[1], xyz[2] + 40.0)
    return [Waypoint("move_j", above, 150.0, fine=False), Waypoint("move_l", xyz, 100.0)]


def agent_rws(cell: Cell) -> Any:
    return client(cell.url, username=AGENT[0], password=AGENT[1])


# --- the agent's push --------------------------------------------------------------------------
def test_the_agents_grants_are_robot_readmes_four() -> None:
    readme = {"UAS_RAPID_EXECUTE", "UAS_RAPID_DEBUG", "UAS_FTP_WRITE", "UAS_FTP_READ"}
    assert readme == AGENT_GRANTS
    assert not AGENT_GRANTS & {"UAS_RAPID_LOADPROGRAM", "UAS_RAPID_EDIT",
                               "UAS_RAPID_CURRVALUE", "UAS_CFG_WRITE", "UAS_REMOTE_WARMSTART",
                               "UAS_SYSTEM_ADMINISTRATION", "UAS_EVENTLOG_CLEAR"}


def test_the_agents_user_runs_the_drivers_whole_push(cell: Cell) -> None:
    driver = cell.driver(AGENT)
    try:
        driver.execute({"left": to(LEFT), "right": to(RIGHT)})
        got = cell.tcps()
        assert got["left"] == pytest.approx(LEFT, abs=1.0)
        assert got["right"] == pytest.approx(RIGHT, abs=1.0)
    finally:
        driver.close()


@pytest.mark.parametrize("grant", NEEDED)
def test_each_of_the_agents_grants_is_needed_for_a_push(cell: Cell, grant: str) -> None:
    """An agent short of one grant: the driver's push is refused by the controller (403,
    UAS reject, or the upload's Forbidden) and nothing moves, starts or is written."""
    before, newest = cell.tcps(), cell.ctrl.elog.newest
    files = {f["_title"]: cell.ctrl.files.read(f"$TEMP/{f['_title']}")
             for f in cell.ctrl.files.listdir("$TEMP")}
    driver = cell.driver(without(grant))
    try:
        with pytest.raises(BackendError, match=r"SYS_CTRL_E_UAS_REJECT|Forbidden"):
            driver.execute({"left": to(LEFT), "right": to(RIGHT)})
    finally:
        driver.close()
    assert cell.tcps() == before
    assert not [e for e in cell.ctrl.elog.entries() if e.seqnum > (newest or 0)
                and e.title.startswith("Testbed Motion")]
    assert {f["_title"]: cell.ctrl.files.read(f"$TEMP/{f['_title']}")
            for f in cell.ctrl.files.listdir("$TEMP")} == files


# --- what the agent's user may not do, and the person's may -------------------------------------
def _readback(cell: Cell) -> dict[str, Any]:
    c = as_person(cell.url)
    try:
        return {"tool": c.get_rapid_variable(*TOOL), "ctrlstate": c.get_controller_state(),
                "speedratio": c.get_speedratio(), "log": [e.seqnum for e in c.read_event_log()],
                "version": c.get_rapid_variable("TB_RAPID_VERSION", "T_ROB_L/TestbedMotion"),
                "rapid": cell.ctrl.snapshot()}
    finally:
        c.logout()


HOSTILE: dict[str, Callable[[Any], object]] = {
    "tool_pusher": lambda c: c.set_rapid_variable(
        TOOL[0], "[TRUE,[[0,0,120],[1,0,0,0]],[0.272,[7.5,11.5,53.8],[1,0,0,0],0,0,0]]",
        TOOL[1]),
    "restart": lambda c: c._do_post("ctrl?action=restart", {"restart-mode": "restart"}),
    "reset RAPID": lambda c: c._do_post("ctrl?action=restart", {"restart-mode": "pstart"}),
    "motors off": lambda c: c.set_controller_state("motoroff"),
    "module load": lambda c: c._do_post("rw/rapid/tasks/T_ROB_L?action=loadmod",
                                        {"modulepath": "HOME:/Other.mod", "replace": "true"}),
    "event log clear": lambda c: c._do_post("rw/elog/0?action=clear"),
    "speed ratio": lambda c: c.set_speedratio(10),
    "mastership": lambda c: c._do_post("rw/mastership?action=request"),
}
"""What a hostile PC logged in as the agent would send (the ABB client's own calls)."""


@pytest.mark.parametrize("what", sorted(HOSTILE))
def test_the_agents_user_is_refused_with_the_controllers_answer_and_nothing_changes(
        cell: Cell, what: str) -> None:
    before = _readback(cell)
    c = agent_rws(cell)
    try:
        with pytest.raises(ABBException) as refused:
            HOSTILE[what](c)
    finally:
        c.logout()
    assert refused.value.code == UAS_REJECT
    assert "SYS_CTRL_E_UAS_REJECT" in str(refused.value) and "'agent'" in str(refused.value)
    assert _readback(cell) == before


def test_a_refusal_is_http_403_with_the_uas_code(cell: Cell) -> None:
    """The status and body on the wire (the client only raises the code)."""
    auth = requests.auth.HTTPDigestAuth(*AGENT)
    r = requests.post(f"{cell.url}/ctrl?action=restart&json=1", data={"restart-mode": "restart"},
                      auth=auth, timeout=10)
    assert r.status_code == 403
    status = r.json()["_embedded"]["status"]
    assert int(status["code"]) == UAS_REJECT
    assert "UAS_REMOTE_WARMSTART" in status["msg"] and "UAS_RESTORE" in status["msg"]
    r = requests.get(f"{cell.url}/rw/panel/ctrlstate?json=1", auth=auth, timeout=10)
    assert r.status_code == 200  # reading needs no grant


def test_motors_on_is_refused_to_the_agent_and_done_by_the_person(cell: Cell) -> None:
    cell.ctrl.set_state(ctrlstate="motoroff")  # the cabinet
    try:
        c = agent_rws(cell)
        with pytest.raises(ABBException) as refused:
            c.set_controller_state("motoron")
        assert refused.value.code == UAS_REJECT and cell.ctrl.ctrlstate == "motoroff"
        c.logout()
        person = as_person(cell.url)
        person.set_controller_state("motoron")
        person.logout()
        assert cell.ctrl.ctrlstate == "motoron"
    finally:
        cell.ctrl.set_state(ctrlstate="motoron")


def test_the_persons_user_writes_tool_pusher_restarts_and_switches_the_motors(
        cell: Cell) -> None:
    person = as_person(cell.url)
    try:
        old = person.get_rapid_variable(*TOOL)
        new = old.replace("0.272,", "0.3,", 1)
        assert new != old
        person.set_rapid_variable(TOOL[0], new, TOOL[1])
        assert person.get_rapid_variable(*TOOL) == new
        person.set_rapid_variable(TOOL[0], old, TOOL[1])
        assert person.get_rapid_variable(*TOOL) == old
        newest = cell.ctrl.elog.newest or 0
        person._do_post("ctrl?action=restart", {"restart-mode": "restart"})
        assert 10045 in [e.code for e in cell.ctrl.elog.entries() if e.seqnum > newest]
        assert person.get_controller_state() == "motoroff"  # a restart leaves them off
        person.set_controller_state("motoron")
        assert person.get_controller_state() == "motoron"
        # a module load passes the UAS check: the twin's own answer (it serves no loadmod)
        with pytest.raises(ABBException) as load:
            person._do_post("rw/rapid/tasks/T_ROB_L?action=loadmod",
                            {"modulepath": "HOME:/Other.mod", "replace": "true"})
        assert load.value.code != UAS_REJECT
    finally:
        cell.ctrl.set_state(ctrlstate="motoron")
        person.logout()


def test_a_stop_needs_no_grant_a_start_does(cell: Cell) -> None:
    """ABB: "stop is always allowed" (FlexPendant SDK, ExecuteRapid): a user with no grant
    stops a running program; its start is refused."""
    nobody = client(cell.url, username=NOBODY[0], password=NOBODY[1])
    try:
        with pytest.raises(ABBException) as refused:
            nobody.resetpp()
        assert refused.value.code == UAS_REJECT
        cell.ctrl.set_state(execution="running")  # a program started elsewhere
        nobody.stop()
        assert nobody.get_execution_state().ctrlexecstate == "stopped"
        with pytest.raises(ABBException, match="UAS_RAPID_EXECUTE"):
            nobody._do_post("rw/rapid/execution?action=start",
                            {"regain": "continue", "execmode": "continue", "cycle": "once",
                             "condition": "none", "stopatbp": "disabled",
                             "alltaskbytsp": "true"})
        assert nobody.get_execution_state().ctrlexecstate == "stopped"
        with pytest.raises(Exception, match="File not found"):  # no Read access either
            nobody.read_file("$TEMP/testbed_T_ROB_L.bin")
    finally:
        cell.ctrl.set_state(execution="stopped")
        nobody.logout()


# --- who holds what, and the command lines ---------------------------------------------------
def test_default_user_keeps_every_grant_another_user_none_unless_given() -> None:
    got = grants_of_users([*DEFAULT_USERS, "lab"])
    assert got == {"Default User": FACTORY_GRANTS, "lab": frozenset()}
    assert grants_of_users(["Default User"], {"Default User": AGENT_GRANTS}) == {
        "Default User": AGENT_GRANTS}
    with pytest.raises(ValueError, match="no such user"):
        grants_of_users(["lab"], {"lba": AGENT_GRANTS})
    with pytest.raises(ValueError, match="unknown grants"):
        grants_of_users(["lab"], {"lab": {"UAS_EVERYTHING"}})


def test_grants_are_a_role_or_ids() -> None:
    assert parse_grants("agent") == AGENT_GRANTS and parse_grants("none") == frozenset()
    assert parse_grants("person") == PERSON_GRANTS
    assert parse_grants(f"{EXECUTE}, {FTP_READ}") == {EXECUTE, FTP_READ}
    for bad in ("admin", "UAS_RAPID_EXECUTE,UAS_TYPO", ""):
        with pytest.raises(ValueError, match="expected a role"):
            parse_grants(bad)


def test_python_m_sim_twin_rws_gives_an_added_user_the_grants_named(
        capsys: pytest.CaptureFixture[str]) -> None:
    a = rws_main._args(["--user", "lab:pw", "--user", "me:pw", "--grants", "lab=agent"])
    assert a.user_grants == {"Default User": FACTORY_GRANTS, "lab": AGENT_GRANTS,
                             "me": frozenset()}
    for bad in (["--grants", "lab=agent"], ["--user", "lab:pw", "--grants", "lab=root"],
                ["--user", "lab:pw", "--grants", "lab"]):
        with pytest.raises(SystemExit) as e:
            rws_main._args(bad)
        assert e.value.code == 2
        assert "--grants" in capsys.readouterr().err


def test_the_yumi_servers_login_file_user_is_the_agent_unless_told() -> None:
    from sim_twin import yumi_server

    assert yumi_server._args([]).rws_grants == "agent"
    with pytest.raises(SystemExit) as e:
        yumi_server._args(["--rws-grants", "UAS_TYPO"])
    assert e.value.code == 2
