"""The RWS 1.0 twin of the YuMi's IRC5, driven by the UNCHANGED ABB clients over HTTP:
digest auth and sessions (and their limit), every resource the clients read, the
controller states answered as the twin assumes a controller does, the RAPID error in the
event log, and abb_motion_program_exec's whole round trip through the start-hook seam."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import requests
from abb_motion_program_exec import abb_motion_program_exec_client as mpe
from abb_robot_client.rws import RWS, ABBException

from sim_twin.rws import Irc5Controller, ProgramRun, RapidError, RwsServer, serve
from sim_twin.rws import errors as codes
from sim_twin.rws.cell_link import CellPoses
from sim_twin.rws.digest_auth import DigestAuthority, SessionLimitReached, SessionTable
from sim_twin.rws.mechunits import YUMI_UNITS

ROOT = Path(__file__).resolve().parents[2]
PUSHER = "[TRUE,[[0,0,100],[1,0,0,0]],[0.2,[0,0,50],[1,0,0,0],0,0,0]]"
TABLE = '[FALSE,TRUE,"",[[300,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]]'


def client(url: str, **kw: Any) -> RWS:
    """The unchanged ABB client, with a timeout on its requests (it sets none)."""
    c = RWS(url, **kw)
    plain = c._session.request
    c._session.request = lambda m, u, **k: plain(m, u, **{"timeout": 10, **k})  # type: ignore[method-assign]
    return c


@pytest.fixture
def twin() -> Iterator[Callable[..., tuple[RwsServer, Irc5Controller]]]:
    servers: list[RwsServer] = []

    def make(controller: Irc5Controller | None = None, **kw: Any
             ) -> tuple[RwsServer, Irc5Controller]:
        c = controller or Irc5Controller()
        s = serve(c, **kw)
        servers.append(s)
        return s, c

    yield make
    for s in servers:
        s.stop()


def lab(server: RwsServer, body: dict[str, Any] | None = None) -> dict[str, Any]:
    req = urllib.request.Request(server.url + "/lab/controller",
                                 data=None if body is None else json.dumps(body).encode())
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read())  # type: ignore[no-any-return]


def raw(server: RwsServer, c: RWS, method: str, path: str, **kw: Any) -> requests.Response:
    """A request on the client's own session (its cookies, its digest state)."""
    return c._session.request(method, f"{server.url}/{path}", auth=c.auth, timeout=10, **kw)


# --- authentication and sessions --------------------------------------------------------------
def test_a_bad_password_or_user_is_refused_with_a_digest_challenge(twin: Any) -> None:
    s, _ = twin()
    for kw in ({"password": "nope"}, {"username": "Someone", "password": "robotics"}):
        with pytest.raises(Exception, match="HTTP error 401"):
            client(s.url, **kw).get_execution_state()
    r = requests.get(s.url + "/rw/rapid/execution?json=1", timeout=10)
    assert r.status_code == 401
    challenge = r.headers["WWW-Authenticate"]
    assert challenge.startswith("Digest ") and 'qop="auth"' in challenge
    assert 'realm="validusers@robapi.abb"' in challenge
    assert lab(s)["sessions"] == []


def test_one_session_per_client_carried_by_its_cookies(twin: Any) -> None:
    s, _ = twin(users={"Default User": "robotics", "lab": "secret"})
    c = client(s.url)
    for _ in range(5):
        assert c.get_execution_state().ctrlexecstate == "stopped"
    assert set(c._session.cookies.keys()) == {"-http-session-", "ABBCX"}
    sessions = lab(s)["sessions"]
    assert len(sessions) == 1 and sessions[0]["requests"] == 5
    # the cookie alone is the session (no Authorization header at all)
    r = requests.get(s.url + "/rw/panel/opmode?json=1", cookies=c._session.cookies, timeout=10)
    assert r.status_code == 200 and r.json()["_embedded"]["_state"][0]["opmode"] == "AUTO"
    assert client(s.url, username="lab", password="secret").get_operation_mode() == "AUTO"
    assert len(lab(s)["sessions"]) == 2


def test_the_session_limit_shows_a_client_that_never_logs_out(twin: Any) -> None:
    s, _ = twin(max_sessions=3)
    leaked = [client(s.url) for _ in range(3)]
    for c in leaked:
        c.get_controller_state()
    late = client(s.url)
    with pytest.raises(Exception, match="500"):  # the library's words for a 503 (its bug)
        late.get_controller_state()
    r = raw(s, client(s.url), "GET", "rw/panel/ctrlstate?json=1")
    assert r.status_code == 503 and "too many sessions" in r.json()["_embedded"]["status"]["msg"]
    assert lab(s)["refused_logins"] == 2
    leaked[0].logout()  # frees one slot
    assert len(lab(s)["sessions"]) == 2
    assert "-http-session-" not in leaked[0]._session.cookies
    assert late.get_controller_state() == "motoron"
    assert len(lab(s)["sessions"]) == 3


def test_a_logged_out_cookie_is_no_session(twin: Any) -> None:
    s, _ = twin()
    c = client(s.url)
    c.get_speedratio()
    jar = requests.cookies.RequestsCookieJar()
    jar.update(c._session.cookies)
    c.logout()
    assert lab(s)["sessions"] == []
    r = requests.get(s.url + "/rw/panel/speedratio?json=1", cookies=jar, timeout=10)
    assert r.status_code == 401


def test_digest_nonces_expire_and_are_not_replayed() -> None:
    now = [0.0]
    auth = DigestAuthority(nonce_lifetime_s=10.0, clock=lambda: now[0])
    nonce = auth.challenge().split('nonce="')[1].split('"')[0]
    prep = requests.Request("GET", "http://127.0.0.1/rw/panel/opmode?json=1").prepare()
    d = requests.auth.HTTPDigestAuth("Default User", "robotics")
    d.init_per_thread_state()
    d._thread_local.chal = {"realm": auth.realm, "nonce": nonce, "qop": "auth",
                            "algorithm": "MD5", "opaque": "x"}
    header = d.build_digest_header("GET", prep.url)
    assert auth.verify("GET", "/rw/panel/opmode?json=1", header) == ("Default User", False)
    assert auth.verify("GET", "/rw/panel/opmode?json=1", header) == (None, False)  # replay
    assert auth.verify("GET", "/rw/panel/ctrlstate?json=1", d.build_digest_header(
        "GET", prep.url)) == (None, False)  # uri does not match the request
    now[0] = 11.0
    assert auth.verify("GET", "/rw/panel/opmode?json=1", d.build_digest_header(
        "GET", prep.url)) == (None, True)  # stale: the client retries with a new nonce


def test_idle_sessions_expire() -> None:
    now = [0.0]
    table = SessionTable(max_sessions=1, idle_timeout_s=30.0, clock=lambda: now[0])
    s = table.open("Default User")
    with pytest.raises(SessionLimitReached):
        table.open("Default User")
    now[0] = 31.0
    assert table.lookup({"-http-session-": s.sid, "ABBCX": s.abbcx}) is None
    assert table.open("Default User").user == "Default User"


# --- resources ---------------------------------------------------------------------------------
def test_panel_execution_ramdisk_identity_and_system(twin: Any) -> None:
    s, _ = twin()
    c = client(s.url)
    state = c.get_execution_state()
    assert (state.ctrlexecstate, state.cycle) == ("stopped", "forever")
    assert (c.get_controller_state(), c.get_operation_mode()) == ("motoron", "AUTO")
    assert c.get_speedratio() == 100.0
    c.set_speedratio(40)
    assert c.get_speedratio() == 40.0
    assert c.get_ramdisk_path() == "$TEMP"
    ident = c._do_get("ctrl/identity")["_embedded"]["_state"][0]
    assert ident["_type"] == "ctrl-identity-info" and ident["ctrl-name"] == "YUMI_TWIN"
    system, options = c._do_get("rw/system")["_embedded"]["_state"]
    assert system["_type"] == "sys-system-li" and system["rwversion"].startswith("6.")
    assert "623-1 Multitasking" in [o["option"] for o in options["options"]]
    opts = c._do_get("rw/system/options")["_embedded"]["_state"]
    assert opts[0] == {"_type": "sys-option-li", "_title": "0", "option": "RobotWare Base"}


def test_json_is_exactly_rws_shape_and_the_default_is_xhtml(twin: Any) -> None:
    s, _ = twin()
    c = client(s.url)
    r = raw(s, c, "GET", "rw/rapid/execution?json=1")
    assert r.status_code == 200 and r.headers["Content-Type"] == "application/json"
    assert r.json() == {"_links": {"base": {"href": f"{s.url}/rw/rapid/"}},
                        "_embedded": {"_state": [{"_type": "rap-execution",
                                                  "_title": "execution",
                                                  "ctrlexecstate": "stopped",
                                                  "cycle": "forever"}]}}
    x = raw(s, c, "GET", "rw/rapid/execution")
    assert x.headers["Content-Type"].startswith("application/xhtml+xml")
    assert '<li class="rap-execution" title="execution">' in x.text
    assert '<span class="ctrlexecstate">stopped</span>' in x.text
    err = raw(s, c, "GET", "rw/no/such?json=1")
    assert err.status_code == 404 and int(err.json()["_embedded"]["status"]["code"]) < 0
    assert raw(s, c, "DELETE", "rw/rapid/execution?json=1").status_code == 405
    form = raw(s, c, "POST", "rw/rapid/execution?action=resetpp&json=1", json={"x": 1})
    assert form.status_code == 415


def test_fileservice_upload_read_list_delete(twin: Any) -> None:
    s, ctrl = twin()
    c = client(s.url)
    assert raw(s, c, "PUT", "fileservice/$TEMP/a.bin", data=b"\x00\x01").status_code == 201
    assert raw(s, c, "PUT", "fileservice/$temp/a.bin", data=b"\x02" * 3).status_code == 200
    c.upload_file("$HOME/prog.mod", b"MODULE x\nENDMODULE\n")
    assert c.read_file("$TEMP/a.bin") == b"\x02\x02\x02"
    assert ctrl.files.read("RAMDISK:a.bin") == b"\x02\x02\x02"  # RAPID's device, same folder
    assert c.list_files("$TEMP") == ["a.bin"]
    listing = c._do_get("fileservice/$HOME")["_embedded"]["_state"]
    assert listing[0]["_type"] == "fs-file" and listing[0]["fs-size"] == "19"
    c.delete_file("$TEMP/a.bin")
    assert c.list_files("$TEMP") == []
    with pytest.raises(Exception, match="File not found"):
        c.read_file("$TEMP/a.bin")
    with pytest.raises(Exception, match="Not Found"):
        c.upload_file("$TEMP/no/such/dir/x.bin", b"x")
    assert raw(s, c, "DELETE", "fileservice/$TEMP/a.bin").status_code == 404


def test_rapid_symbols_get_and_set(twin: Any) -> None:
    s, ctrl = twin()
    ctrl.symbols.declare("T_ROB_L", "user", "reg1", "num", "0", storage="VAR")
    ctrl.symbols.declare("T_ROB_L", "user", "limit", "num", "5", storage="CONST")
    c = client(s.url)
    assert c.get_rapid_variable("tool0", "T_ROB_L").startswith("[TRUE,[[0,0,0],[1,0,0,0]]")
    c.set_rapid_variable_num("reg1", 10.5, "T_ROB_L")
    assert c.get_rapid_variable_num("reg1", "T_ROB_L") == 10.5
    assert c.get_rapid_variable("user/reg1", "T_ROB_L") == "10.5"  # with the module
    item = c._do_get("rw/rapid/symbol/data/RAPID/T_ROB_L/user/reg1")["_embedded"]["_state"][0]
    assert item == {"_type": "rap-data", "_title": "RAPID/T_ROB_L/user/reg1", "value": "10.5"}
    with pytest.raises(ABBException) as e:
        c.set_rapid_variable("reg1", "[1,2", "T_ROB_L")
    assert e.value.code == codes.GENERIC
    with pytest.raises(ABBException):
        c.set_rapid_variable("tool0", "[TRUE,[[0,0,1]]]", "T_ROB_L")  # not a tooldata
    with pytest.raises(ABBException):
        c.set_rapid_variable("limit", "6", "T_ROB_L")  # a CONST
    with pytest.raises(ABBException) as e:
        c.get_rapid_variable("nothing", "T_ROB_L")
    assert e.value.code == codes.NO_SUCH_SYMBOL


def test_robtarget_is_the_named_tool_in_the_named_frame(twin: Any) -> None:
    s, ctrl = twin()
    ctrl.symbols.declare("T_ROB_L", "user", "pusher", "tooldata", PUSHER)
    ctrl.symbols.declare("T_ROB_L", "user", "table", "wobjdata", TABLE)
    c = client(s.url)
    flange = c.get_robtarget("ROB_L")  # tool0 = the flange (100, 450, 150), tool down
    assert flange.trans.tolist() == [100.0, 450.0, 150.0]
    assert flange.rot.tolist() == [0.0, 0.0, 1.0, 0.0]
    tip = c.get_robtarget("ROB_L", tool="pusher")
    assert tip.trans.tolist() == [100.0, 450.0, 50.0]  # 100 mm along the down-pointing z
    in_table = c.get_robtarget("ROB_L", tool="pusher", wobj="table", coordinate="Wobj")
    assert in_table.trans.tolist() == [-200.0, 450.0, 50.0]
    assert c.get_robtarget("ROB_R").trans.tolist() == [100.0, -450.0, 150.0]
    with pytest.raises(ABBException):
        c.get_robtarget("ROB_R", tool="pusher")  # declared in T_ROB_L only
    with pytest.raises(ABBException):
        c.get_robtarget("ROB_1")  # not a YuMi unit
    j = c.get_jointtarget("ROB_L")
    assert j.robax.tolist() == [0.0, -130.0, 30.0, 0.0, 40.0, 0.0]
    assert j.extax[0] == 135.0 and j.extax[1] == 9e9  # axis 7 is eax_a on an IRB 14000
    # ... and a robtarget's eaxa is ABB's arm angle of those joints, not axis 7 (issue 43;
    # docs/notes/rws.md, "What eax_a means on a YuMi")
    from sim_twin.sew_angle import arm_angle
    from sim_twin.yumi_arms import ArmModel, abb_to_chain

    angle = arm_angle(ArmModel("left").pose(abb_to_chain([*j.robax.tolist(), j.extax[0]])))
    assert tip.extax[0] == pytest.approx(angle, abs=1e-4)
    assert abs(tip.extax[0] - 135.0) > 30.0 and tip.extax[1] == 9e9


def test_robtarget_follows_the_cell() -> None:
    class Cell:
        def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
            return {"left": (400.0, 200.0, 10.0), "right": (300.0, -150.0, 80.0)}

    ctrl = Irc5Controller(poses=CellPoses(Cell(), threading.Lock(), YUMI_UNITS, 100.0))
    ctrl.symbols.declare("T_ROB_L", "user", "pusher", "tooldata", PUSHER)
    assert ctrl.robtarget("ROB_L", "tool0", "wobj0", "Base")["z"] == "110"
    tip = ctrl.robtarget("ROB_L", "pusher", "wobj0", "Base")
    assert (tip["x"], tip["y"], tip["z"]) == ("400", "200", "10")


def test_robtarget_follows_a_real_yumi_twin_cell() -> None:
    from sim_twin.yumi_cell import YumiTwinCell

    lock = threading.Lock()
    with YumiTwinCell(3) as cell:
        ctrl = Irc5Controller(poses=CellPoses(cell, lock, YUMI_UNITS, 100.0))
        ctrl.symbols.declare("T_ROB_L", "user", "pusher", "tooldata", PUSHER)
        with lock:
            cell.execute({"left": [{"kind": "move_l", "xyz_mm": [400, 200, 50],
                                    "speed_mm_s": 500, "fine": True}]})
            tcp = cell.tcp_xyz()["left"]
        tip = ctrl.robtarget("ROB_L", "pusher", "wobj0", "Base")
        assert [float(tip[k]) for k in "xyz"] == pytest.approx(list(tcp), abs=1e-6)
        assert abs(tcp[0] - 400.0) < 1.0 and abs(tcp[2] - 50.0) < 1.0
        assert float(ctrl.robtarget("ROB_L", "tool0", "wobj0", "Base")["z"]) == \
            pytest.approx(tcp[2] + 100.0)


def test_signals_list_get_and_set(twin: Any) -> None:
    s, ctrl = twin()
    c = client(s.url)
    names = [x["name"] for x in c._do_get("rw/iosystem/signals")["_embedded"]["_state"]]
    assert "motion_program_log_motion" in names and "motion_program_preempt" in names
    m = mpe.MotionProgramExecClient(abb_client=c)
    assert not m.get_motion_logging_enabled()
    m.enable_motion_logging()
    assert m.get_motion_logging_enabled() and ctrl.signals.value("motion_program_log_motion")
    c.set_analog_io("motion_program_preempt_cmd_num", 17)
    assert c.get_analog_io("motion_program_preempt_cmd_num") == 17.0
    ctrl.signals.write("motion_program_current_cmd_num", 4)  # RAPID's SetAO
    assert m.get_current_cmdnum() == 4.0
    one = c._do_get("rw/iosystem/signals/Local/DRV_1/motion_program_log_motion")
    assert one["_embedded"]["_state"][0]["_type"] == "ios-signal"
    with pytest.raises(ABBException):
        c._do_post("rw/iosystem/signals/Local/DRV_1/motion_program_log_motion?action=set",
                   {"lvalue": "2"})
    with pytest.raises(ABBException):
        c.get_digital_io("no_such_signal")


# --- RAPID execution, tasks, states ---------------------------------------------------------
def gated_hook(runs: list[ProgramRun], go: threading.Event) -> Callable[[ProgramRun], None]:
    def hook(run: ProgramRun) -> None:
        runs.append(run)
        assert go.wait(10)
    return hook


def test_start_runs_the_hook_and_execution_reads_running_until_it_returns(twin: Any) -> None:
    runs: list[ProgramRun] = []
    go = threading.Event()
    s, ctrl = twin(Irc5Controller(on_start=gated_hook(runs, go)))
    c = client(s.url)
    c.resetpp()
    assert [e.code for e in c.read_event_log()[:2]] == [10002, 10002]
    c.start(cycle="once", tasks=["T_ROB_L", "T_ROB_R"])
    assert c.get_execution_state().ctrlexecstate == "running"
    assert {t.excstate for t in c.get_tasks().values()} == {"started"}
    for call in (c.resetpp, lambda: c.start(tasks=["T_ROB_L", "T_ROB_R"]),
                 lambda: c.deactivate_task("T_ROB_R")):
        with pytest.raises(ABBException) as e:
            call()
        assert e.value.code == codes.EXEC_STATE
    go.set()
    assert ctrl.wait_stopped(10)
    assert c.get_execution_state() == ("stopped", "oncedone")
    assert runs[0].tasks == ("T_ROB_L", "T_ROB_R") and runs[0].cycle == "once"


def test_stop_ends_the_run_at_once_and_tells_the_hook(twin: Any) -> None:
    runs: list[ProgramRun] = []
    go = threading.Event()
    s, _ = twin(Irc5Controller(on_start=gated_hook(runs, go)))
    c = client(s.url)
    c.start(cycle="forever", tasks=["T_ROB_L", "T_ROB_R"])
    c.stop()
    assert c.get_execution_state() == ("stopped", "forever")
    assert runs[0].stop_requested.is_set()
    go.set()


def test_tasks_activate_and_deactivate(twin: Any) -> None:
    runs: list[ProgramRun] = []
    go = threading.Event()
    go.set()
    s, ctrl = twin(Irc5Controller(on_start=gated_hook(runs, go)))
    c = client(s.url)
    c.start(tasks=["T_ROB_L"])  # the library deactivates T_ROB_R first
    assert ctrl.wait_stopped(10) and runs[0].tasks == ("T_ROB_L",)
    assert not c.get_tasks()["T_ROB_R"].active
    c.activate_task("T_ROB_R")
    assert c.get_tasks()["T_ROB_R"].active
    one = c._do_get("rw/rapid/tasks/T_ROB_L")["_embedded"]["_state"][0]
    assert one["_type"] == "rap-task" and one["motiontask"] == "TRUE"
    with pytest.raises(ABBException):
        c.activate_task("T_ROB1")


@pytest.mark.parametrize(("state", "code"), [
    ({"opmode": "MANR"}, codes.GENERIC),
    ({"opmode": "MANR", "ctrlstate": "motoron"}, codes.GENERIC),
    ({"ctrlstate": "motoroff"}, codes.GENERIC),
    ({"ctrlstate": "guardstop"}, codes.GENERIC),
    ({"ctrlstate": "emergencystop"}, codes.GENERIC),
])
def test_start_is_refused_when_the_controller_cannot_run(twin: Any, state: dict[str, str],
                                                         code: int) -> None:
    s, ctrl = twin()
    lab(s, state)
    c = client(s.url)
    with pytest.raises(ABBException) as e:
        c.start(tasks=["T_ROB_L", "T_ROB_R"])
    assert e.value.code == code
    assert c.get_execution_state().ctrlexecstate == "stopped"
    if "opmode" in state:
        assert "mastership" in str(e.value) and c.get_operation_mode() == "MANR"
        with pytest.raises(ABBException):
            c.resetpp()
        with pytest.raises(ABBException):
            c.set_rapid_variable("tool0", ctrl.symbols.find(["T_ROB_L", "tool0"]).value,
                                 "T_ROB_L")
    else:
        assert c.get_controller_state() == state["ctrlstate"]
    m = mpe.MotionProgramExecClient(abb_client=c)
    mp = mpe.MotionProgram()
    mp.WaitTime(0.1)
    with pytest.raises(Exception, match=r"must be motoron|mastership"):
        m.execute_motion_program(mp, task="T_ROB_L")


def test_a_mode_change_turns_the_motors_off_and_a_guard_stop_stops_the_program(
        twin: Any) -> None:
    runs: list[ProgramRun] = []
    go = threading.Event()
    s, _ = twin(Irc5Controller(on_start=gated_hook(runs, go)))
    c = client(s.url)
    c.start(tasks=["T_ROB_L", "T_ROB_R"])
    assert lab(s, {"ctrlstate": "guardstop"})["state"]["execution"] == "stopped"
    assert runs[0].stop_requested.is_set()
    assert c.read_event_log()[0].code == 10012
    with pytest.raises(ABBException):
        c.set_controller_state("motoron")  # software cannot close the safety chain
    go.set()
    lab(s, {"opmode": "MANR"})
    assert (c.get_operation_mode(), c.get_controller_state()) == ("MANR", "motoroff")
    assert [e.code for e in c.read_event_log()[:2]] == [10010, 10015]
    with pytest.raises(ABBException):
        c.set_speedratio(50)  # AUTO only
    lab(s, {"opmode": "AUTO"})
    c.set_controller_state("motoron")  # in AUTO a remote client may turn the motors on
    assert c.get_controller_state() == "motoron"


def test_a_program_already_running_is_not_started_again(twin: Any) -> None:
    s, _ = twin()
    lab(s, {"execution": "running"})
    c = client(s.url)
    assert c.get_execution_state().ctrlexecstate == "running"
    m = mpe.MotionProgramExecClient(abb_client=c)
    mp = mpe.MotionProgram()
    mp.WaitTime(0.1)
    with pytest.raises(Exception, match="must be stopped"):
        m.execute_motion_program(mp, task="T_ROB_L")
    assert m.is_motion_program_running()
    lab(s, {"execution": "stopped"})
    assert not m.is_motion_program_running()


def test_the_lab_side_refuses_an_impossible_state(twin: Any) -> None:
    s, _ = twin()
    for body in ({"opmode": "TURBO"}, {"execution": "running", "ctrlstate": "motoroff"},
                 {"task_error": {"task": "T_ROB_L"}}, {"colour": "red"}):
        with pytest.raises(urllib.error.HTTPError) as e:
            lab(s, body)
        assert e.value.code == 400
    assert lab(s)["state"]["ctrlstate"] == "motoron"


def test_the_lab_side_sets_the_options_listed(twin: Any) -> None:
    s, ctrl = twin()
    c = client(s.url)

    def listed() -> list[str]:
        return [o["option"] for o in c._do_get("rw/system/options")["_embedded"]["_state"]]

    every = listed()
    assert lab(s, {"remove_option": "608-1"})["options"] == [o for o in every
                                                             if not o.startswith("608-1")]
    assert "608-1 World Zones" not in listed()
    assert lab(s, {"options": ["RobotWare Base", "616-1 PC Interface"]})["options"] == [
        "RobotWare Base", "616-1 PC Interface"]
    assert listed() == ["RobotWare Base", "616-1 PC Interface"]
    for body in ({"remove_option": "623-1"}, {"options": [""]}, {"rapid": "none"},
                 {"rapid_version": 1}):  # not listed; empty; no RAPID of ours on this twin
        with pytest.raises(urllib.error.HTTPError) as e:
            lab(s, body)
        assert e.value.code == 400
    assert lab(s)["rapid"] is None and ctrl.identity.options == tuple(listed())


def test_a_rapid_error_stops_the_task_and_shows_in_the_elog(twin: Any) -> None:
    s, _ = twin()
    c = client(s.url)
    lab(s, {"execution": "running"})
    lab(s, {"task_error": {"task": "T_ROB_R", "code": 41617, "title": "Too intense frequency",
                           "desc": "Write instructions too often.", "args": ["T_ROB_R"]}})
    newest = c.read_event_log()[0]
    assert (newest.code, newest.msgtype, newest.title) == (41617, 3, "Too intense frequency")
    assert newest.desc == "Write instructions too often." and newest.args == ["T_ROB_R"]
    assert c.get_execution_state().ctrlexecstate == "stopped"
    assert c.get_tasks()["T_ROB_R"].excstate == "stopped"
    program = c._do_get("rw/elog/4/?lang=en")["_embedded"]["_state"]  # the program domain
    assert [e["code"] for e in program] == ["41617"]
    bare = c._do_get(f"rw/elog/0/{newest.seqnum}")["_embedded"]["_state"][0]
    assert "title" not in bare and bare["code"] == "41617"  # texts only with lang=


# --- abb_motion_program_exec end to end ----------------------------------------------------------
def fake_rapid(seen: dict[str, Any]) -> Callable[[ProgramRun], None]:
    """What the RAPID module does, as far as the client can tell: read the program from
    RAMDISK:, write a joint log next to it and say so in the event log (code 80003)."""
    def hook(run: ProgramRun) -> None:
        files, elog = run.controller.files, run.controller.elog
        seen["program"] = files.read("RAMDISK:motion_program.bin")
        name = "log-2026-01-02-03-04-05.bin"
        header = b"timestamp,cmdnum,J1,J2"  # 22 chars: pad to a float boundary
        body = struct.pack("<f", 10011) + struct.pack("<f", 4) + b"2026" + \
            struct.pack("<f", len(header) + 2) + header + b",x" + \
            struct.pack("<5f", 0.0, 1.0, 0.5, 0.25, 0.125)
        files.put(f"RAMDISK:{name}", body)
        elog.write(80003, 1, "Motion Program Log",
                   args=("Motion Program Log File Opened", f"RAMDISK:{name}", "", "", ""))
        elog.write(80003, 1, "Motion Program Log",
                   args=("Motion Program Log File Closed", "", "", "", ""))
    return hook


def test_execute_motion_program_round_trip_through_the_hook(twin: Any) -> None:
    seen: dict[str, Any] = {}
    s, ctrl = twin(Irc5Controller(on_start=fake_rapid(seen)))
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    mp = mpe.MotionProgram()
    mp.MoveAbsJ(mpe.jointtarget([0, 0, 0, 0, 30, 0], [0] * 6), mpe.v100, mpe.fine)
    log = m.execute_motion_program(mp, task="T_ROB_L")
    assert seen["program"] == mp.get_program_bytes()  # the very bytes the client uploaded
    assert log.timestamp == "2026" and log.column_headers[-1] == "x"
    assert log.data.tolist() == [[0.0, 1.0, 0.5, 0.25, 0.125]]
    assert [f["_title"] for f in ctrl.files.listdir("$TEMP")] == ["motion_program.bin"]


def test_a_rapid_error_fails_the_motion_program(twin: Any) -> None:
    def hook(run: ProgramRun) -> None:
        raise RapidError(40223, "Execution error", task="T_ROB_L", desc="Division by zero.")

    s, _ = twin(Irc5Controller(on_start=hook))
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    mp = mpe.MotionProgram()
    mp.WaitTime(0.1)
    with pytest.raises(Exception, match="Motion Program Failed"):
        m.execute_motion_program(mp, task="T_ROB_L")
    assert m.abb_client.read_event_log()[0].code == 40223


def test_multimove_with_yumi_task_names_writes_both_programs_to_one_file(twin: Any) -> None:
    """The library names a task's file after the task's trailing digits: T_ROB_L and
    T_ROB_R have none, so both arms' programs go to motion_program.bin and the second
    overwrites the first. The RAPID work (and drivers/yumi) must deal with this."""
    seen: list[list[str]] = []
    s, ctrl = twin(Irc5Controller(on_start=lambda run: seen.append(
        [f["_title"] for f in run.controller.files.listdir("$TEMP")])))
    m = mpe.MotionProgramExecClient(abb_client=client(s.url))
    mps = []
    for x in (10.0, 20.0):
        mp = mpe.MotionProgram()
        mp.MoveAbsJ(mpe.jointtarget([x] * 6, [0] * 6), mpe.v100, mpe.fine)
        mps.append(mp)
    m.execute_multimove_motion_program(mps, ["T_ROB_L", "T_ROB_R"], wait=False)
    assert ctrl.wait_stopped(10)
    assert seen == [["motion_program.bin"]]
    assert ctrl.files.read("$TEMP/motion_program.bin") == mps[1].get_program_bytes()


# --- the process -------------------------------------------------------------------------------
def test_python_m_sim_twin_rws_serves_until_sigterm(tmp_path: Path) -> None:
    port_file = tmp_path / "port"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    bad = subprocess.run([sys.executable, "-m", "sim_twin.rws", "--host", "10.1.2.3"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "loopback" in bad.stderr
    proc = subprocess.Popen([sys.executable, "-m", "sim_twin.rws", "--port", "0",
                             "--port-file", str(port_file), "--max-sessions", "1",
                             "--user", "lab:secret", "--opmode", "MANR",
                             "--ctrlstate", "motoroff"], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 30
        while not port_file.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "twin did not start"
            time.sleep(0.05)
        url = f"http://127.0.0.1:{int(port_file.read_text())}"
        c = client(url, username="lab", password="secret")
        assert (c.get_operation_mode(), c.get_controller_state()) == ("MANR", "motoroff")
        with pytest.raises(Exception, match="500"):  # one session, and it is taken
            client(url).get_operation_mode()
        c.logout()
        assert client(url).get_operation_mode() == "MANR"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
