"""The YuMi hardware twin: contact physics, MultiMove, rest pose, lab hand, perception and
markers against the true camera, and the server process with a real cv2.VideoCapture on
its camera and the unchanged ABB RWS client on its controller."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest
import twin_rws
from abb_motion_program_exec import abb_motion_program_exec_client as mpe

from sim_twin.yumi_arms import ArmModel, abb_to_chain
from sim_twin.yumi_cell import RESET_NOISE, YumiTwinCell
from sim_twin.yumi_geometry import WORKSPACE_MM, workspace_mm
from testbed.perception.cube import find_cube

Waypoint = dict[str, Any]
ROOT = Path(__file__).resolve().parents[2]


def wp(kind: str, xyz: list[float] | None, v: float, fine: bool = True) -> Waypoint:
    return {"kind": kind, "xyz_mm": xyz, "speed_mm_s": v, "fine": fine}


def push_x(cube: list[float], dy: float = 0.0, stroke: float = 60.0) -> list[Waypoint]:
    """From rest: above a point 20 mm before the cube's near (-x) face, down, a stroke
    along +x (``dy`` sideways), up, back to rest: the shape of YumiBackend's pushes."""
    sx, y = cube[0] - 20.0 - 12.0 - 20.0, cube[1] + dy
    return [wp("move_j", [sx, y, 80], 150, False), wp("move_l", [sx, y, 10], 100),
            wp("move_l", [sx + stroke, y, 10], 50), wp("move_l", [sx + stroke, y, 80], 100, False),
            wp("rest", None, 150)]


def crop(frame: npt.NDArray[np.uint8], box: tuple[int, int, int, int], mirror: bool
         ) -> npt.NDArray[np.uint8]:
    """As drivers/yumi/backend.py ``_crop``: INTER_AREA to 64x64, RGB, mirrored."""
    x0, y0, x1, y1 = box
    img = cv2.resize(frame[y0:y1, x0:x1], (64, 64), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img[:, ::-1, ::-1] if mirror else img[:, :, ::-1])


def crop_error(cell: YumiTwinCell, frame: npt.NDArray[np.uint8], arm: str) -> float:
    """Distance (crop pixels of 64) between find_cube and the truth mapped into the crop
    (pixel centres at integers: crop pixel k covers [x0 + k s - 1/2, x0 + (k+1) s - 1/2))."""
    box = cell.crops[arm]
    pose = find_cube(crop(frame, box, cell.mirror[arm]))
    assert pose is not None, arm
    u, v = cell.truth()[arm]["cube_px"]
    w = box[2] - box[0]
    cx, cy = (u + 0.5 - box[0]) / w, (v + 0.5 - box[1]) / w
    return math.dist(pose.centre, (1.0 - cx if cell.mirror[arm] else cx, cy)) * 64


@pytest.fixture
def cell() -> Iterator[YumiTwinCell]:
    with YumiTwinCell(11) as c:
        yield c


def test_push_moves_the_cube_by_contact(cell: YumiTwinCell) -> None:
    before = cell.truth()["left"]["cube_mm"]
    cell.execute({"left": push_x(before, dy=60.0)})  # the line misses the cube: nothing moves
    assert math.dist(cell.truth()["left"]["cube_mm"], before) < 0.5
    sim_s = cell.execute({"left": push_x(before)})
    after = cell.truth()["left"]["cube_mm"]
    assert 20.0 < after[0] - before[0] < 60.0 and abs(after[1] - before[1]) < 10.0
    assert 5.0 < sim_s < 20.0
    assert math.dist(cell.tcp_xyz()["left"], (100.0, 450.0, 150.0)) < 1.0


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_both_arms_move_at_once(cell: YumiTwinCell) -> None:
    t0 = cell.truth()
    one = YumiTwinCell(11)
    try:
        alone = one.execute({"left": push_x(t0["left"]["cube_mm"])})
    finally:
        one.close()
    both = cell.execute({a: push_x(t0[a]["cube_mm"]) for a in cell.arms})
    assert both < 1.2 * alone  # in parallel, not one after the other
    t1 = cell.truth()
    assert all(t1[a]["cube_mm"][0] - t0[a]["cube_mm"][0] > 20.0 for a in cell.arms)


def test_bad_programs_are_refused_before_anything_moves(cell: YumiTwinCell) -> None:
    tcp = cell.tcp_xyz()
    good = [wp("move_l", [400, 200, 10], 100)]
    for bad in ({"left": good, "middle": good}, {"left": good, "right": [wp("move_l", [400,
                -200, -1], 100)]}, {"left": [wp("move_l", [400, 200, 10], 0)]},
                {"left": [wp("move_l", [math.nan, 200, 10], 100)]},
                {"left": [wp("jump", [400, 200, 10], 100)]}):
        with pytest.raises(ValueError):
            cell.execute(bad)
    assert cell.tcp_xyz() == tcp


def _pusher_pixels(frame: npt.NDArray[np.uint8]) -> int:
    """Pixels that are neither table (grey ~146) nor cube (saturated): caps, markers,
    pusher cylinders."""
    hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
    grey = hsv[..., 1] < 60
    return int((grey & (np.abs(hsv[..., 2].astype(int) - 150) > 25)).sum())


def test_rest_pose_is_out_of_view(cell: YumiTwinCell) -> None:
    cell.execute({a: [wp("rest", None, 200)] for a in cell.arms})
    assert _pusher_pixels(cell.render(noise=False)) == 0
    for u, v in (cell.project(p) for p in cell.tcp_xyz().values()):
        assert not (0 <= u < 640 and 0 <= v < 480)
    cell.execute({"right": [wp("move_j", [450, -200, 80], 300)]})
    assert _pusher_pixels(cell.render(noise=False)) > 500  # the check sees a pusher


def test_lab_reset_puts_the_cube_back_near_the_centre(cell: YumiTwinCell) -> None:
    cell.place_cube("right", (650.0, -420.0), 0.3)  # anywhere: the hand fetches it
    x0, y0, x1, y1 = workspace_mm("right")
    for _ in range(5):
        cell.lab_reset("right")
        t = cell.truth()["right"]
        assert t["on_table"]
        for c, lo, hi in ((t["cube_mm"][0], x0, x1), (t["cube_mm"][1], y0, y1)):
            assert abs(c - (lo + hi) / 2) <= RESET_NOISE * WORKSPACE_MM + 1.0
    with pytest.raises(ValueError, match="unknown arm"):
        cell.lab_reset("middle")


def test_a_cube_pushed_off_the_table_falls(cell: YumiTwinCell) -> None:
    cell.place_cube("left", (745.0, 200.0), 0.0)
    cell.execute({"left": [wp("move_j", [700, 200, 10], 300), wp("move_l", [790, 200, 10],
                                                                    200)]})
    assert not cell.truth()["left"]["on_table"]


def test_perception_finds_the_cube_where_the_truth_says(cell: YumiTwinCell) -> None:
    rng = np.random.default_rng(3)
    errors = []
    for _ in range(12):
        for a in cell.arms:
            x0, y0, x1, y1 = workspace_mm(cell.sides[a])
            cell.place_cube(a, (rng.uniform(x0 + 30, x1 - 30), rng.uniform(y0 + 30, y1 - 30)),
                            rng.uniform(0, 2 * math.pi))
        frame = cell.render()
        errors += [crop_error(cell, frame, a) for a in cell.arms]
    assert max(errors) < 0.5, errors


def test_marker_is_found_where_the_tcp_projects(cell: YumiTwinCell) -> None:
    targets = {"left": [330.0, 260.0, 10.0], "right": [500.0, -120.0, 10.0]}
    cell.execute({a: [wp("move_j", [*p[:2], 80.0], 300), wp("move_l", p, 100)]
                  for a, p in targets.items()})
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50),
                                  params)
    corners, ids, _ = det.detectMarkers(cell.render())
    assert ids is not None and sorted(ids.ravel().tolist()) == [0, 1]
    ids_of = cell.camera_model["marker"]["ids"]
    for c, i in zip(corners, ids.ravel(), strict=True):
        arm = next(a for a, k in ids_of.items() if k == i)
        tcp = cell.tcp_xyz()[arm]
        expected = cell.project((tcp[0], tcp[1], tcp[2] + 30.0))
        assert math.dist(c.reshape(4, 2).mean(0), expected) < 0.5


# --- the server process ------------------------------------------------------------------------
class Server:
    def __init__(self, tmp: Path) -> None:
        port_file, rws_port_file = tmp / "port", tmp / "rws.port"
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "sim_twin.yumi_server", "--seed", "5", "--port", "0",
             "--port-file", str(port_file), "--rws-port-file", str(rws_port_file),
             "--fps", "15"], cwd=ROOT, env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 30
        while not port_file.exists():
            assert self.proc.poll() is None and time.monotonic() < deadline, "server did not start"
            time.sleep(0.05)
        self.url = f"http://127.0.0.1:{int(port_file.read_text())}"
        self.rws_url = f"http://127.0.0.1:{int(rws_port_file.read_text())}"

    def get(self, path: str) -> Any:
        with urllib.request.urlopen(self.url + path, timeout=10) as r:
            return json.loads(r.read())

    def post(self, path: str, body: Mapping[str, Any]) -> Any:
        req = urllib.request.Request(self.url + path, data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=30) as r:
            return json.loads(r.read())


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Server]:
    s = Server(tmp_path)
    yield s
    if s.proc.poll() is None:
        s.proc.kill()
        s.proc.wait()


def _fresh(cap: cv2.VideoCapture, fps: float = 15.0) -> npt.NDArray[np.uint8]:
    """Drain frames queued in the sockets (grab until a grab waits for the camera)."""
    for _ in range(200):
        t = time.monotonic()
        assert cap.grab()
        if time.monotonic() - t > 0.5 / fps:
            break
    ok, frame = cap.retrieve()
    assert ok
    return frame


def rapid_push(c: Any, cube: list[float]) -> Any:
    """``push_x`` as our RAPID's program (the driver's shape): stop points, the rest pose
    as a MoveAbsJ to the joints the controller reports."""
    p = twin_rws.program([("J" if w["kind"] == "move_j" else "L", w["xyz_mm"],
                           w["speed_mm_s"]) for w in push_x(cube) if w["kind"] != "rest"])
    j = c.get_jointtarget("ROB_L")
    p.MoveAbsJ(mpe.jointtarget(j.robax.tolist(), j.extax.tolist()),
               mpe.speeddata(150, 100, 1000, 100), mpe.fine)  # within the caps
    return p


def _cube_seen(frame: npt.NDArray[np.uint8], cam: Mapping[str, Any], truth: Mapping[str, Any]
               ) -> float:
    """Crop pixels between the cube perception finds in ``frame`` and the truth's."""
    box = tuple(cam["crops"]["left"])
    pose = find_cube(crop(frame, box, False))
    w = box[2] - box[0]
    u, v = truth["cube_px"]
    assert pose is not None
    return math.dist(pose.centre, ((u + 0.5 - box[0]) / w, (v + 0.5 - box[1]) / w)) * 64


def test_server_stream_controller_and_lab(server: Server) -> None:
    cam = server.get("/lab/camera")
    assert (cam["width"], cam["height"]) == (640, 480) and cam["mirror"] == {
        "left": False, "right": True}
    c = twin_rws.client(server.rws_url)  # the controller: RWS, the unchanged ABB client
    cap = cv2.VideoCapture(server.url + "/camera.mjpg", cv2.CAP_FFMPEG)
    try:
        assert cap.isOpened()
        ok, frame = cap.read()
        assert ok and frame.shape == (480, 640, 3)
        with pytest.raises(urllib.error.HTTPError) as busy:  # one client, like a V4L2 device
            urllib.request.urlopen(server.url + "/camera.mjpg", timeout=10)
        assert busy.value.code == 503 and b"camera busy" in busy.value.read()

        below = twin_rws.run(c, {"T_ROB_L": twin_rws.program([("L", (400, 200, -5), 100)])})
        assert [(e.code, e.args[1]) for e in below] == [(80001, "Target below the table")]
        t0 = server.get("/lab/truth")["arms"]["left"]
        done = twin_rws.run(c, {"T_ROB_L": rapid_push(c, t0["cube_mm"])}, seqno=2)
        assert [e.title for e in done] == ["Testbed Motion Done"]
        with urllib.request.urlopen(server.url + "/camera.jpg", timeout=10) as r:
            jpg = cv2.imdecode(np.frombuffer(r.read(), np.uint8), cv2.IMREAD_COLOR)
        t1 = server.get("/lab/truth")["arms"]["left"]
        assert t1["cube_mm"][0] - t0["cube_mm"][0] > 20.0
        assert t1["tcp_mm"] == pytest.approx(cam["rest_mm"]["left"], abs=1.0)  # its arm's rest
        rest = ArmModel("left").pose(abb_to_chain(cam["rest_joints_deg"]["left"])).flange
        assert c.get_robtarget("ROB_L").trans.tolist() == pytest.approx(  # tool0: the flange
            rest[:3, 3].tolist(), abs=1.0)
        assert _cube_seen(jpg, cam, t1) < 0.6  # shown by the time execution read stopped
        assert _cube_seen(_fresh(cap), cam, t1) < 0.6  # and on the stream
    finally:
        cap.release()
    for gone in ("/controller/execute", "/controller/tcp"):  # the private API is retired
        with pytest.raises(urllib.error.HTTPError) as e:
            server.post(gone, {"programs": {}}) if "execute" in gone else server.get(gone)
        assert e.value.code == 404
    assert server.post("/lab/reset", {"arm": "left"}) == {"ok": True}
    with urllib.request.urlopen(server.url + "/camera.jpg", timeout=10) as r:
        jpg = cv2.imdecode(np.frombuffer(r.read(), np.uint8), cv2.IMREAD_COLOR)
    assert jpg.shape == (480, 640, 3)
    assert server.get("/lab/health") == {"ok": True}
    c.logout()
    server.proc.send_signal(signal.SIGTERM)
    assert server.proc.wait(timeout=10) == 0
