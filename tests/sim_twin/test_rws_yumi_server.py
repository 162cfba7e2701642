"""The hardware twin's controller: a real ``python -m sim_twin.yumi_server`` process serves
RWS 1.0 on a second port beside its camera, and the UNCHANGED ABB client drives our RAPID
on the twin's cell through it: the RWS port file, an extra login from a file only its
owner reads (a wrong password is the controller's 401; a file others can read stops the
twin with exit 2), the request log, the command line's zones (read over RWS, supervised),
``--no-rapid``, the lab side channel loading, versioning and de-optioning the
controller, a stop at real time that halts the pusher within a sample, and the camera's
frames published during a paced motion and once at its end."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from twin_rws import UNDER_SHOULDER_DEG, client, program, run, start

from sim_twin.rws.testbed_rapid import DONE, RAPID_VERSION, WORLD_ZONE_CODE
from sim_twin.yumi_arms import rest_tip
from sim_twin.yumi_cell import YumiTwinCell

REST_TIP = {side: rest_tip(side) for side in ("left", "right")}
"""Where the twin's arms rest the pusher's tip (their rest joints, its 100 mm tool)."""

ROOT = Path(__file__).resolve().parents[2]
LOGIN = ("lab user", "s3cret:with colon")
ZONE = (250.0, 60.0, 550.0, 330.0)


class Twin:
    """One ``python -m sim_twin.yumi_server`` and its two ports."""

    def __init__(self, tmp: Path, *args: str) -> None:
        self.port_file, self.rws_port_file = tmp / "cam.port", tmp / "rws.port"
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "sim_twin.yumi_server", "--seed", "5", "--port", "0",
             "--port-file", str(self.port_file), "--rws-port-file", str(self.rws_port_file),
             *args], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 60
        while not self.port_file.exists():  # written after the RWS port file
            assert self.proc.poll() is None and time.monotonic() < deadline, "no twin"
            time.sleep(0.05)
        self.url = f"http://127.0.0.1:{int(self.port_file.read_text())}"
        self.rws_url = f"http://127.0.0.1:{int(self.rws_port_file.read_text())}"

    def get(self, url: str) -> Any:
        with urllib.request.urlopen(url, timeout=20) as r:
            return json.loads(r.read())

    def lab(self, body: dict[str, Any] | None = None) -> Any:
        """The RWS port's side channel, ``/lab/controller``."""
        req = urllib.request.Request(self.rws_url + "/lab/controller",
                                     data=None if body is None else json.dumps(body).encode())
        with urllib.request.urlopen(req, timeout=20) as r:
            return json.loads(r.read())

    def tcp(self, arm: str) -> list[float]:
        return self.get(self.url + "/lab/truth")["arms"][arm]["tcp_mm"]  # type: ignore[no-any-return]

    def close(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise


@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Twin]:
    tmp = tmp_path_factory.mktemp("yumi_rws")
    login = tmp / "login"
    login.write_text(f"# the rehearsal's login\n{LOGIN[0]}:{LOGIN[1]}\n")
    login.chmod(0o600)
    t = Twin(tmp, "--rws-credentials", str(login), "--rws-log", str(tmp / "rws.jsonl"),
             "--zone", "left=" + ",".join(f"{v:g}" for v in ZONE), "--zone-z", "70")
    t.log_path = tmp / "rws.jsonl"  # type: ignore[attr-defined]
    yield t
    assert t.close() == 0


def test_rws_on_its_own_port_with_the_files_login_and_the_factorys(twin: Twin) -> None:
    assert twin.rws_url != twin.url
    c = client(twin.rws_url, username=LOGIN[0], password=LOGIN[1])
    assert c.get_execution_state().ctrlexecstate == "stopped"
    assert client(twin.rws_url).get_controller_state() == "motoron"  # Default User
    with pytest.raises(Exception, match="HTTP error 401"):
        client(twin.rws_url, username=LOGIN[0], password="wrong").get_operation_mode()
    c.logout()


def test_the_files_login_holds_the_agents_grants_only(twin: Twin) -> None:
    """The rehearsal's login is the agent's: ``--rws-grants`` defaults to robot/README.md's
    four (sim_twin.rws.uas), so it resets the PP but its restart is the controller's 403
    (``SYS_CTRL_E_UAS_REJECT``) and nothing restarts; the factory login may."""
    from abb_robot_client.rws import ABBException

    from sim_twin.rws.uas import UAS_REJECT

    c = client(twin.rws_url, username=LOGIN[0], password=LOGIN[1])
    c.resetpp()  # Execute program
    newest = [e.seqnum for e in c.read_event_log()][:1]
    with pytest.raises(ABBException) as refused:
        c._do_post("ctrl?action=restart", {"restart-mode": "restart"})
    assert refused.value.code == UAS_REJECT and "'lab user'" in str(refused.value)
    assert [e.seqnum for e in c.read_event_log()][:1] == newest  # no restart entry
    assert c.get_controller_state() == "motoron"
    c.logout()


def test_every_request_is_one_json_line_without_secrets(twin: Twin) -> None:
    client(twin.rws_url, username=LOGIN[0], password=LOGIN[1]).get_speedratio()
    wanted = {("GET", "/rw/panel/speedratio?json=1", 401),
              ("GET", "/rw/panel/speedratio?json=1", 200)}
    deadline = time.monotonic() + 5.0  # the server writes its line once the answer is sent:
    while True:                        # under load the client may read the log first
        text = twin.log_path.read_text()  # type: ignore[attr-defined]
        lines = [json.loads(line) for line in text.split("\n")[:-1]]  # whole lines only
        seen = {(e["method"], e["path"], e["status"]) for e in lines}
        if seen >= wanted or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert lines and all(set(e) == {"t", "method", "path", "status", "ms"} for e in lines)
    assert seen >= wanted
    assert all(e["ms"] >= 0 and abs(e["t"] - time.time()) < 600 for e in lines)
    for secret in (LOGIN[1], "Digest", "-http-session-", "ABBCX"):
        assert secret not in text


def test_the_command_lines_zone_is_read_over_rws_and_supervised(twin: Twin) -> None:
    c = client(twin.rws_url)
    assert c.get_rapid_variable("tb_zone_lo", "T_ROB_L/TestbedTask_L") == "[250,60,0]"
    assert c.get_rapid_variable("tb_zone_hi", "T_ROB_L/TestbedTask_L") == "[550,330,0]"
    assert c.get_rapid_variable("tb_zone_z", "T_ROB_R/TestbedTask_R") == "70"
    assert c.get_rapid_variable("tb_zone_hi", "T_ROB_R/TestbedTask_R") == "[495,-25,0]"
    assert c.get_rapid_variable("TB_RAPID_VERSION", "T_ROB_L/TestbedMotion") == str(
        RAPID_VERSION)
    # one arm angle under the shoulder: the driver's plan for the line down turns it across
    # the shoulder's singularity (twin_rws.UNDER_SHOULDER_DEG), and from the face up too
    under = UNDER_SHOULDER_DEG["left"]
    entries = run(c, {"T_ROB_L": program([("J", (400, 200, 100), 800, under),
                                          ("L", (400, 200, 20), 200, under),
                                          ("L", (200, 200, 20), 200, under)])})
    assert [(e.code, e.args[1]) for e in entries] == [(WORLD_ZONE_CODE, "tb_wz_xlo")]
    assert twin.tcp("left") == pytest.approx([ZONE[0], 200, 20], abs=1.0)
    back = run(c, {"T_ROB_L": program([("L", (ZONE[0], 200, 100), 300, under),
                                       ("R", "left", 800)])}, seqno=2)
    assert [e.title for e in back] == [DONE]


def test_the_lab_side_unloads_and_versions_our_rapid_and_drops_an_option(twin: Twin) -> None:
    c = client(twin.rws_url)
    state = twin.lab()
    assert state["rapid"]["loaded"] and state["rapid"]["version"] == RAPID_VERSION
    assert "608-1 World Zones" in state["options"]
    twin.lab({"rapid": "none"})  # as if our modules were never loaded
    with pytest.raises(Exception, match=r"no RAPID symbol"):
        c.get_rapid_variable("tb_zone_lo", "T_ROB_L/TestbedTask_L")
    entries = run(c, {"T_ROB_L": program([("J", (400, 200, 100), 800)])})
    assert entries == [] and twin.tcp("left") == pytest.approx(list(REST_TIP["left"]), abs=1)
    twin.lab({"rapid": "testbed", "rapid_version": 1})  # an older version loaded
    assert c.get_rapid_variable("TB_RAPID_VERSION", "T_ROB_R/TestbedMotion") == "1"
    assert twin.lab()["rapid"] == {**state["rapid"], "version": 1}
    twin.lab({"remove_option": "608-1"})
    opts = [o["option"] for o in c._do_get("rw/system/options")["_embedded"]["_state"]]
    assert "608-1 World Zones" not in opts and "616-1 PC Interface" in opts
    for bad in ({"rapid": "maybe"}, {"remove_option": "608-1"}, {"rapid_version": -1},
                {"options": "608-1"}):
        with pytest.raises(urllib.error.HTTPError) as e:
            twin.lab(bad)
        assert e.value.code == 400
    twin.lab({"options": state["options"], "rapid_version": RAPID_VERSION})
    assert twin.lab()["options"] == state["options"]


def _said(out: subprocess.CompletedProcess[str]) -> list[str]:
    """The twin's stderr lines (less PyBullet's banner, printed on import)."""
    return [s for s in out.stderr.strip().splitlines() if not s.startswith("pybullet build")]


def _twin_exit(tmp: Path, args: Sequence[str]) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "sim_twin.yumi_server", "--port-file",
                           str(tmp / "p"), *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=60)


def test_a_login_file_others_can_read_or_a_bad_zone_is_refused(tmp_path: Path) -> None:
    login = tmp_path / "login"
    login.write_text(f"{LOGIN[0]}:{LOGIN[1]}\n")
    login.chmod(0o644)
    bad = _twin_exit(tmp_path, ["--rws-credentials", str(login)])
    assert bad.returncode == 2 and "chmod 600" in bad.stderr
    assert len(_said(bad)) == 1 and LOGIN[1] not in bad.stderr
    assert not (tmp_path / "p").exists()
    for args in (["--zone", "middle=0,0,1,1"], ["--zone", "left=500,0,200,300"],
                 ["--zone-z", "-5"]):
        out = _twin_exit(tmp_path, args)
        assert out.returncode == 2 and len(_said(out)) == 1, (args, out.stderr)


def test_no_rapid_declares_none_of_our_symbols_and_a_start_runs_nothing(tmp_path: Path) -> None:
    t = Twin(tmp_path, "--no-rapid", "--arms", "left")
    try:
        c = client(t.rws_url)
        with pytest.raises(Exception, match=r"no RAPID symbol"):
            c.get_rapid_variable("TB_RAPID_VERSION", "T_ROB_L/TestbedMotion")
        assert run(c, {"T_ROB_L": program([("J", (400, 200, 100), 800)])}) == []
        assert t.tcp("left") == pytest.approx(list(REST_TIP["left"]), abs=1.0)
        assert t.lab()["rapid"]["loaded"] is False
        t.lab({"rapid": "testbed"})  # loaded later (the lab's switch)
        assert run(c, {"T_ROB_L": program([("J", (400, 200, 100), 800)])}, seqno=2)[0].title \
            == DONE
    finally:
        assert t.close() == 0


def test_omit_motiontask_lists_no_motion_task_and_a_one_arm_start_starts_both(
        tmp_path: Path) -> None:
    """``--omit-motiontask`` (abb_motion_program_exec issue 4): the ABB client reads no
    motion task, so its start of T_ROB_L alone starts T_ROB_R too, which re-runs its file."""
    t = Twin(tmp_path, "--omit-motiontask")
    try:
        c = client(t.rws_url)
        assert not any(s.motiontask for s in c.get_tasks().values())
        assert t.lab()["omit_motiontask"] is True
        first = run(c, {"T_ROB_L": program([("J", (400, 200, 120), 800)]),
                        "T_ROB_R": program([("J", (400, -200, 120), 800)])})
        assert [e.args[1] for e in first] == ["T_ROB_L", "T_ROB_R"]
        again = run(c, {"T_ROB_L": program([("J", (380, 180, 120), 800)])}, seqno=2)
        assert [(e.args[1], e.args[2]) for e in again] == [("T_ROB_L", "seqno 2"),
                                                           ("T_ROB_R", "seqno 1")]
    finally:
        assert t.close() == 0


def test_a_stop_at_real_time_halts_the_pusher_within_a_sample(tmp_path: Path) -> None:
    t = Twin(tmp_path, "--realtime", "1", "--arms", "left")
    try:
        c = client(t.rws_url)
        begin, target = REST_TIP["left"], (400.0, 200.0, 150.0)
        start(c, {"T_ROB_L": program([("L", target, 60)])})  # ~6 s at real time
        deadline = time.monotonic() + 5.0
        while True:  # under way (under load the start itself can take a while)
            seen = c.get_robtarget("ROB_L", tool="tool_pusher").trans.tolist()  # latest sample
            if math.dist(seen, begin) > 10.0 or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        t_stop = time.monotonic()
        c.stop()
        assert c.get_execution_state().ctrlexecstate == "stopped"
        held = t.tcp("left")  # blocks until the motion let go of the cell
        assert time.monotonic() - t_stop < 0.1 + 0.2  # (the truth request's own time)
        assert math.dist(held, seen) < 60.0 * 0.1 + 1.0  # moved at most 0.1 s further
        along, total = math.dist(held, begin), math.dist(begin, target)
        assert 5.0 < along < total - 100.0
        time.sleep(0.3)
        assert t.tcp("left") == pytest.approx(held, abs=0.05)  # and stays there
    finally:
        assert t.close() == 0


def test_a_paced_motion_publishes_camera_frames_as_it_goes_and_the_end_state() -> None:
    from sim_twin import yumi_server  # in-process: the same parts main() wires

    a = yumi_server._args(["--arms", "left", "--realtime", "4", "--fps", "15"])
    cell = YumiTwinCell(5, ("left",), realtime=4.0)
    server = yumi_server.TwinServer(cell)
    rws = yumi_server.RwsSide(server, a, yumi_server._zones(a, cell.arms, cell.sides),
                              yumi_server._users(a))
    rws.server.start_thread()
    try:
        before = server.frames.published
        c = client(rws.server.url)
        t0 = time.monotonic()  # ~2 s of motion at 4x real time: ~0.5 s, a frame per 1/15 s
        assert [e.title for e in run(c, {"T_ROB_L": program([("J", (400, 200, 150), 200)])})
                ] == [DONE]
        frames = server.frames.published - before
        assert 5 <= frames <= (time.monotonic() - t0) * 15 + 2
        with server.cell_lock:  # the last frame shown is the state the motion ended in
            assert np.array_equal(server.frames._clean, cell.render(noise=False))
            assert cell.tcp_xyz()["left"] == pytest.approx((400, 200, 150), abs=1.0)
    finally:
        rws.close()
        server.server_close()
        cell.close()
