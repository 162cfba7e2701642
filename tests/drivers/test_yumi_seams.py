"""The YuMi backend's two seams with real parts: the camera as a lab IP camera (an HTTP
MJPEG stream through cv2.VideoCapture/FFmpeg), and the controller client built from the
controller URL; then the backend, unchanged, against the hardware twin server
(``python -m sim_twin.yumi_server``: PyBullet, its camera stream, its controller's Robot
Web Services with our RAPID's semantics), through the one real controller client.
"""

from __future__ import annotations

import json
import math
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from driver_fakes import twin_picture, write_video
from mjpeg_fixture import MjpegCamera, frame_number

from drivers.cameras.camera import VideoCaptureCamera
from drivers.errors import BackendError
from drivers.yumi.arm_calibration import ArmCalibration
from drivers.yumi.controllers import make_controller
from drivers.yumi.credentials import FACTORY_DEFAULT, FACTORY_LOGIN
from drivers.yumi.gate import calibration_gate_joints
from drivers.yumi.rws_controller import RwsYumiController
from drivers.yumi.yumi_controller import ArmPose, Waypoint
from testbed.lab.camera_model import arm_facts

pytestmark = pytest.mark.alone  # wall-clock bounds (tests/conftest.py)

# --- the camera seam: a network camera ------------------------------------------------


def test_stream_read_returns_a_frame_made_after_the_call() -> None:
    with MjpegCamera(fps=15) as server:
        raw = cv2.VideoCapture(server.url, cv2.CAP_FFMPEG)  # what a plain read gives
        assert raw.isOpened()
        raw.read()
        time.sleep(0.6)  # the client looks away (a push): frames queue in the sockets
        t0 = time.monotonic()
        ok, stale = raw.read()
        assert ok and server.produced[frame_number(stale)] < t0 - 0.3  # the queue is real
        raw.release()

        cam = VideoCaptureCamera(server.url, fps=15, open_timeout_s=3, read_timeout_s=3)
        assert cam.size == (320, 240)
        latencies = []
        for pause in (0.6, 0.0, 1.0, 0.1):
            time.sleep(pause)
            t0 = time.monotonic()
            frame = cam.read()
            latencies.append(time.monotonic() - t0)
            assert server.produced[frame_number(frame)] > t0, (pause, cam.drained)
        cam.close()
        # about one frame interval (67 ms): never seconds
        assert max(latencies) < 0.5, latencies


def _hog(stop_at: float) -> None:
    while time.monotonic() < stop_at:
        pass


@pytest.mark.slow
def test_stream_frames_stay_fresh_with_every_core_busy() -> None:
    """The rehearsal caught it: a camera drained only when asked returned a frame queued
    before a push when the machine was loaded (a slow decode looked like a wait)."""
    import multiprocessing as mp

    with MjpegCamera(fps=15, size=(640, 480)) as server:
        cam = VideoCaptureCamera(server.url, open_timeout_s=3, read_timeout_s=3)
        stop_at = time.monotonic() + 30
        hogs = [mp.get_context("fork").Process(target=_hog, args=(stop_at,), daemon=True)
                for _ in range(4 * (os.cpu_count() or 2))]
        for h in hogs:
            h.start()
        try:
            rng = np.random.default_rng(0)
            for _ in range(12):
                time.sleep(float(rng.uniform(0.0, 0.8)))  # a push, a training step...
                t0 = time.monotonic()
                frame = cam.read()
                assert server.produced[frame_number(frame)] > t0
        finally:
            for h in hogs:
                h.kill()
            cam.close()


def test_a_dead_camera_is_an_error_not_a_hang() -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    with pytest.raises(BackendError, match=rf"camera http://127.0.0.1:{port}/c.mjpg: cannot "
                                           r"open the stream .*unreachable"):
        VideoCaptureCamera(f"http://127.0.0.1:{port}/c.mjpg", open_timeout_s=1)
    with MjpegCamera() as server:
        server.mute = True  # accepts, never answers
        with pytest.raises(BackendError, match=r"cannot open the stream within 1 s") as e:
            VideoCaptureCamera(server.url, open_timeout_s=1)
        assert "\n" not in str(e.value)
    assert time.monotonic() - t0 < 8


def test_a_busy_camera_says_so_and_a_stalled_one_times_out() -> None:
    with MjpegCamera() as server:
        server.busy = True
        with pytest.raises(BackendError, match="HTTP 503: camera busy: another client"):
            VideoCaptureCamera(server.url, open_timeout_s=2)
        server.busy = False
        cam = VideoCaptureCamera(server.url, open_timeout_s=2, read_timeout_s=1)
        cam.read()
        server.stall.set()
        t0 = time.monotonic()
        with pytest.raises(BackendError, match=r"gave no frame within 1 s"):
            cam.read()
        assert time.monotonic() - t0 < 4
        cam.close()


def test_file_paths_expand_home_and_variables(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    write_video(tmp_path / "cam.avi", [twin_picture(0)])
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("CAMS", str(tmp_path))
    for src in ("~/cam.avi", "$CAMS/cam.avi", "${CAMS}/cam.avi"):
        cam = VideoCaptureCamera(src)
        assert cam.size == (576, 256) and cam.read().shape == (256, 576, 3)
        cam.close()
    monkeypatch.delenv("CAMS")
    with pytest.raises(BackendError, match="environment variable CAMS is not set"):
        VideoCaptureCamera("$CAMS/cam.avi")


# --- the controller seam: one client, built from the URL and the login file -------------
def test_make_controller_builds_the_rws_client(tmp_path: Path) -> None:
    pose = ArmPose("T_ROB_L", "ROB_L", (40, -90, 30, 0, 40, 0, 135), tool_z_mm=184.2)
    ctrl = make_controller("http://127.0.0.1:1", {"left": pose},
                           credentials_file=FACTORY_DEFAULT)  # the twin's: loopback
    assert isinstance(ctrl, RwsYumiController)
    with pytest.raises(BackendError, match=r"cannot read the arms' positions \(tool_pusher "
                                           r"in wobj0\) from the YuMi controller: .*refused"):
        ctrl.tcp_xyz()
    with pytest.raises(BackendError, match=r"arm right: .*'rest_joints_deg'.*every arm's "
                                           r"rest pose, also while calibrating"):
        make_controller("https://yumi.lab", {"left": pose, "right": None})
    for url in ("rws://yumi", "twin+http://127.0.0.1:4101"):
        with pytest.raises(BackendError, match=r"^controller_url: .* is not a controller URL"):
            make_controller(url, {"left": pose})
    login = tmp_path / "rws.login"
    login.write_text("lab:secret\n")
    login.chmod(0o644)
    with pytest.raises(BackendError, match=r"credentials_file .*mode 0644"):
        make_controller("http://127.0.0.1:1", {"left": pose}, credentials_file=str(login))


# --- the backend, unchanged, on the hardware twin ----------------------------------------
ROOT = Path(__file__).resolve().parents[2]
SPEEDS = {"z_push_mm": 10.0, "z_travel_mm": 80.0, "max_speed_mm_s": 150.0,
          "push_speed_mm_s": 100.0}


class Twin:
    """One ``python -m sim_twin.yumi_server`` process and its published camera model."""

    def __init__(self, port: int, rws_port: int) -> None:
        self.base = f"http://127.0.0.1:{port}"
        self.camera_url = f"{self.base}/camera.mjpg"
        self.controller_url = f"http://127.0.0.1:{rws_port}"
        self.model: dict[str, Any] = self.get("/lab/camera")

    def get(self, path: str, body: Any = None) -> Any:
        import urllib.request

        req = urllib.request.Request(self.base + path, method="GET" if body is None else "POST",
                                     data=None if body is None else json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=60) as resp:
            return json.loads(resp.read())

    def truth(self) -> dict[str, Any]:
        return self.get("/lab/truth")["arms"]

    def tcp(self) -> dict[str, list[float]]:
        """Where each pusher truly is (the lab's eyes, not the controller's word)."""
        return {a: t["tcp_mm"] for a, t in self.truth().items()}

    def project(self, xyz: Any) -> np.ndarray:
        m = self.model
        pts = np.asarray(xyz, np.float64).reshape(-1, 3)
        rvec = np.asarray(m["rvec"], np.float64) if "rvec" in m else \
            cv2.Rodrigues(np.asarray(m["R"], np.float64))[0]
        tvec = np.asarray(m.get("tvec", m.get("t")), np.float64)
        uv, _ = cv2.projectPoints(pts, rvec, tvec, np.asarray(m["K"], np.float64),
                                  np.asarray(m["dist"], np.float64))
        return uv.reshape(-1, 2)

    def calibration(self, arm: str) -> dict[str, Any]:
        """What a calibration finds: image -> table homography in the cube-top plane."""
        x0, y0, x1, y1 = self.model["workspaces_mm"][arm]
        xy = np.array([(x, y) for x in np.linspace(x0, x1, 9) for y in np.linspace(y0, y1, 9)])
        uv = self.project(np.c_[xy, np.full(len(xy), 40.0)])
        h, _ = cv2.findHomography(uv, xy)
        cal = {"homography": h.tolist(), "table_box_mm": [x0, y0, x1, y1], **SPEEDS,
               **rest_pose(arm)}
        return {**cal, "gate_joints_deg": calibration_gate_joints(arm, cal)}  # issue 43

    def canonical(self, arm: str) -> np.ndarray:
        """The cube's true centre in the arm's canonical crop frame."""
        u, v = self.truth()[arm]["cube_px"]
        x0, y0, x1, y1 = self.model["crops"][arm]
        c = np.array([(u + 0.5 - x0) / (x1 - x0), (v + 0.5 - y0) / (y1 - y0)])
        if self.model["mirror"][arm]:
            c[0] = 1.0 - c[0]
        return c

    def client(self) -> RwsYumiController:
        """The agent's controller client on this twin's RWS."""
        poses = {a: ArmCalibration.from_dict(self.calibration(a), a).pose for a in ARMS}
        return RwsYumiController(self.controller_url, poses,  # type: ignore[arg-type]
                                 login=FACTORY_LOGIN)

    def fresh(self) -> None:
        """Both cubes back near their centres, both arms at rest (the lab hand)."""
        ctrl = self.client()
        try:
            ctrl.execute({a: [Waypoint("rest", None, SPEEDS["max_speed_mm_s"])] for a in ARMS})
        finally:
            ctrl.close()
        for arm in ARMS:
            self.get("/lab/reset", {"arm": arm})


ARMS = ("left", "right")


def rest_pose(arm: str) -> dict[str, Any]:
    """The twin's rest pose in a calibration file (the joints its RWS reports)."""
    return arm_facts(arm)


@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Twin]:
    import subprocess

    if not (ROOT / "sim_twin" / "yumi_server.py").exists():
        pytest.fail("sim_twin/yumi_server.py (the hardware twin, Part S) is missing")
    d = tmp_path_factory.mktemp("twin")
    port_file, rws_file = d / "port", d / "rws.port"
    with open(d / "server.log", "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "sim_twin.yumi_server", "--arms",
                                 "left,right", "--seed", "3", "--port", "0", "--port-file",
                                 str(port_file), "--rws-port-file", str(rws_file),
                                 "--fps", "15"], cwd=ROOT, stdout=log,
                                stderr=subprocess.STDOUT)
    try:
        t0 = time.monotonic()
        while not (port_file.exists() and port_file.read_text().strip()):
            if proc.poll() is not None or time.monotonic() - t0 > 60:
                pytest.fail(f"twin server did not start: {(d / 'server.log').read_text()}")
            time.sleep(0.05)
        yield Twin(int(port_file.read_text()), int(rws_file.read_text()))
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def open_retrying(make: Any) -> Any:
    """The camera takes one client; the previous test's may take a frame to be noticed."""
    t0 = time.monotonic()
    while True:
        try:
            return make()
        except BackendError as exc:
            if "busy" not in str(exc) or time.monotonic() - t0 > 3:
                raise
            time.sleep(0.1)


def cal_files(twin: Twin, d: Path, **override: dict[str, Any]) -> dict[str, str]:
    out = {}
    for arm in ("left", "right"):
        (d / f"{arm}.json").write_text(json.dumps(override.get(arm, twin.calibration(arm))))
        out[arm] = str(d / f"{arm}.json")
    return out


def test_backend_observes_and_pushes_the_twin(twin: Twin, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from drivers.yumi.backend import build_yumi_backend
    from testbed.core.types import FACE_DIRECTIONS
    from testbed.perception import cube as perception

    twin.fresh()
    cal_files(twin, tmp_path)
    monkeypatch.setenv("CALDIR", str(tmp_path))  # a host path with a variable in it
    crops = {a: tuple(twin.model["crops"][a]) for a in ("left", "right")}
    backend = open_retrying(lambda: build_yumi_backend(
        ["left", "right"], [False, True], crops, {a: f"$CALDIR/{a}.json" for a in crops},
        twin.camera_url, twin.controller_url, seed=1, credentials_file=FACTORY_DEFAULT))
    try:
        views = backend.observe()
        for arm, v in views.items():
            pose = perception.find_cube(v.image)
            assert not v.violating and pose is not None
            assert math.dist(pose.centre, twin.canonical(arm)) < 1.0 / 64, arm
        faces = {"left": 3, "right": 2}
        before = {a: twin.canonical(a) for a in faces}
        t0 = time.monotonic()
        out = backend.push(faces)
        wall = time.monotonic() - t0
        for arm, face in faces.items():
            assert not out[arm].violation and out[arm].refused is None, out[arm]
            assert out[arm].error is None and set(out[arm].readings) == {"push_s"}
            assert 0.0 < out[arm].readings["push_s"] <= wall  # the motion, timed on the host
            moved = twin.canonical(arm) - before[arm]
            d = FACE_DIRECTIONS[face]
            along, across = moved @ d, moved[0] * d[1] - moved[1] * d[0]
            assert along > 0.02 and abs(across) < along, (arm, moved)
        rest = twin.model["rest_mm"]
        assert all(math.dist(twin.tcp()[a], rest[a]) < 1.0 for a in faces)  # out of view
        for arm, v in backend.observe().items():  # the picture after the push: moved cube
            pose = perception.find_cube(v.image)
            assert pose is not None and math.dist(pose.centre, twin.canonical(arm)) < 1 / 64
        goals = backend.observe()
        backend.reseed(11)
        first = {a: v.goal for a, v in backend.observe().items()}
        backend.reseed(11)
        assert {a: v.goal for a, v in backend.observe().items()} == first
        assert first != {a: v.goal for a, v in goals.items()}
        print(f"push on the twin over RWS: {wall:.2f} s wall "
              f"({backend._controller.timing})")
    finally:
        backend.close()


def test_refused_and_per_arm_errors_leave_the_sibling_pushing(twin: Twin,
                                                              tmp_path: Path) -> None:
    from drivers.yumi.backend import ArmSetup, YumiBackend

    class JammedSetup(ArmSetup):  # one arm's planning fails (as a bad pose or model would)
        def canonical_to_table(self, c: Any) -> tuple[float, float]:
            raise RuntimeError("inverse kinematics failed")

    twin.fresh()
    model = twin.model
    left = ArmSetup("left", tuple(model["crops"]["left"]), False,
                    ArmCalibration.from_dict(twin.calibration("left"), "left"))
    right_cal = ArmCalibration.from_dict(twin.calibration("right"), "right")
    for right, expect in [
        (ArmSetup("right", (0, 0, 64, 64), True, right_cal), "refused"),  # crop: no cube
        (JammedSetup("right", tuple(model["crops"]["right"]), True, right_cal), "error"),
    ]:
        backend = open_retrying(lambda r=right: YumiBackend(  # type: ignore[misc]
            [left, r], VideoCaptureCamera(twin.camera_url),
            twin.client(), seed=2))
        try:
            backend.observe()
            truth = twin.truth()
            out = backend.push({"left": 2, "right": 0})
            after = twin.truth()
            assert out["left"].refused is None and out["left"].error is None
            assert math.dist(truth["left"]["cube_mm"], after["left"]["cube_mm"]) > 5  # pushed
            assert math.dist(truth["right"]["cube_mm"], after["right"]["cube_mm"]) < 1
            r = out["right"]
            assert not r.success and not r.violation
            if expect == "refused":
                assert r.refused == "cube not found" and r.error is None
            else:
                assert r.refused is None and r.error is not None
                assert "cannot plan the push: RuntimeError: inverse kinematics" in r.error
        finally:
            backend.close()


def test_calibration_mode_moves_the_tcp_shows_the_marker_and_saves(
        twin: Twin, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from drivers.backends import make_backend
    from drivers.yumi.arm_calibration import ArmCalibration

    twin.fresh()
    box = twin.model["workspaces_mm"]["left"]
    files = cal_files(twin, tmp_path, left={"table_box_mm": box, **SPEEDS,  # no homography
                                            **rest_pose("left")})
    monkeypatch.setenv("HOME", str(tmp_path))
    backend = open_retrying(lambda: make_backend(
        "yumi", arms=["left", "right"], mirror=[False, True], seed=0,
        crops={a: tuple(twin.model["crops"][a]) for a in ("left", "right")},
        calibrations={"left": "~/left.json", "right": files["right"]},
        camera=twin.camera_url, controller_url=twin.controller_url, calibrating=["left"],
        credentials_file=FACTORY_DEFAULT))
    try:
        with pytest.raises(BackendError, match="arm left is being calibrated") as e:
            backend.observe()
        assert e.value.arm == "left"  # type: ignore[attr-defined]
        detector = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
        for target in [(box[0] + 60, box[1] + 70, 10.0), (box[2] - 50, box[3] - 90, 10.0)]:
            tcp = backend.move_tcp("left", target)
            assert math.dist(tcp, target) < 1.0
            corners, ids, _ = detector.detectMarkers(backend.frame())
            assert ids is not None and 0 in ids.ravel()
            centre = corners[list(ids.ravel()).index(0)].reshape(4, 2).mean(axis=0)
            assert math.dist(centre, twin.project([tcp[0], tcp[1], tcp[2] + 30])[0]) < 1.0
        with pytest.raises(ValueError, match=r"arm left: .* outside its table box"):
            backend.move_tcp("left", (box[2] + 5, box[1] + 10, 10))
        assert math.dist(twin.tcp()["left"], tcp) < 1.0  # refused: nothing moved
        backend.rest()
        _, ids, _ = detector.detectMarkers(backend.frame())
        assert ids is None or 0 not in ids.ravel()  # at rest: out of view

        path = Path(files["left"])
        old = path.read_text()
        with pytest.raises(ValueError, match="invertible"):
            backend.save_calibration("left", {**twin.calibration("left"),
                                              "homography": [[0] * 3] * 3})

        def disk_full(fd: int) -> None:
            raise OSError(28, "No space left on device")

        with monkeypatch.context() as m:
            m.setattr(os, "fsync", disk_full)
            with pytest.raises(OSError, match="No space left"):
                backend.save_calibration("left", twin.calibration("left"))
        assert path.read_text() == old and sorted(os.listdir(tmp_path)) == [
            "left.json", "right.json"]  # the old file whole, no temp file left
        new = twin.calibration("left")
        assert backend.save_calibration("left", new) == str(path)
        assert json.loads(path.read_text()) == new
        assert sorted(os.listdir(tmp_path)) == ["left.json", "right.json"]
        ArmCalibration.load(path, "left")
    finally:
        backend.close()


def test_a_frozen_camera_is_an_error_naming_it_and_a_restarted_one_reads_again() -> None:
    """An encoder that hung sends its last picture again and again, at the frame rate:
    every frame decodes, so only their sameness tells (drivers/cameras/frozen_frames.py).
    The stamped frames are noiseless, yet a live stream's frames all differ."""
    from drivers.cameras.frozen_frames import FROZEN_S

    with MjpegCamera(fps=15) as server:
        cam = VideoCaptureCamera(server.url, fps=15, open_timeout_s=3, read_timeout_s=3)
        try:
            for _ in range(3):
                cam.read()
            server.frozen.set()
            time.sleep(FROZEN_S + 0.3)
            with pytest.raises(BackendError, match=r"is frozen: its frames have been "
                                                   r"identical for \d") as e:
                cam.read()
            assert "\n" not in str(e.value) and server.url in str(e.value)
            server.frozen.clear()
            t0 = time.monotonic()
            frame = cam.read()
            assert server.produced[frame_number(frame)] >= t0 - 0.1  # fresh again
        finally:
            cam.close()
