"""The YuMi host's camera as labs have them: a V4L2 device by index, path or card name,
its driver queue drained so a picture is never older than the call, its settings set
and read back; and the picture-quality figures ``testbed check`` prints.

A kernel camera device cannot exist on a CI machine, so the device is stood in for AT
THE cv2.VideoCapture SEAM: ``v4l2_fakes.FakeDevice.capture`` is handed to
``VideoCaptureCamera(capture=...)``, where the camera constructs its
``cv2.VideoCapture(index, cv2.CAP_V4L2)``. The fake keeps OpenCV's V4L2 queue (4 driver
buffers filled at the frame rate while free, new frames dropped when full, ``grab``
takes the oldest) and its controls (some refused, some read back as another value);
``/dev`` and ``/sys/class/video4linux`` are a temp folder (``V4l2Devices`` takes both
roots), and where the kernel would answer an ioctl about a node a probe function
stands in. The MJPEG URL and video-file cameras keep their tests in
test_yumi_seams.py.
"""

from __future__ import annotations

import json
import logging
import os
import statistics
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from driver_fakes import twin_picture, write_video, yumi_calibration
from mjpeg_fixture import frame_number
from v4l2_fakes import FakeDevice, FakeNode, fake_tree, link, uvc_controls

from drivers.cameras.camera import VideoCaptureCamera
from drivers.cameras.capture_settings import CaptureSettings
from drivers.cameras.picture_quality import camera_report, sharpness_and_exposure
from drivers.cameras.v4l2_devices import NodeFacts, V4l2Devices, kind_of, query_node
from drivers.errors import BackendError

C920 = "HD Pro Webcam C920"
REALSENSE = "Intel(R) RealSense(TM) Depth Ca"
"""A stock kernel's name for every node of a D435 (the card name is 31 characters)."""
SELECT_TIMEOUT = "OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT"


@pytest.fixture(autouse=True)
def _v4l2_select_timeout(monkeypatch: pytest.MonkeyPatch) -> None:
    """The camera sets OpenCV's V4L2 wait (a process-wide variable) if unset: undone
    after each test."""
    monkeypatch.setenv(SELECT_TIMEOUT, "10")
    monkeypatch.delenv(SELECT_TIMEOUT)


def webcam_tree(tmp_path: Path, number: int = 0) -> V4l2Devices:
    """One UVC webcam: its capture node and its metadata node, one card name."""
    dev, sysfs = fake_tree(tmp_path, [FakeNode(number, C920, 0, "1-2"),
                                      FakeNode(number + 1, C920, 1, "1-2")])
    return V4l2Devices(str(dev), str(sysfs))


def open_camera(devices: V4l2Devices, device: FakeDevice, source: str = "0",
                **kw: Any) -> VideoCaptureCamera:
    return VideoCaptureCamera(source, capture=device.capture, devices=devices, **kw)


# --- the frame after a push is never older than the push ------------------------------
def _age_after_pause(read: Any, device: FakeDevice, pause: float) -> tuple[float, float]:
    """(frame age at the call, read latency) for a read after ``pause`` s away."""
    time.sleep(pause)
    t0 = time.monotonic()
    frame = read()
    return t0 - device.taken[frame_number(frame)], time.monotonic() - t0


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
@pytest.mark.slow
def test_a_read_after_a_push_is_a_frame_taken_after_the_call(tmp_path: Path) -> None:
    device = FakeDevice()
    raw = device.capture(0, cv2.CAP_V4L2)  # what OpenCV alone gives: the queue is real
    raw.read()
    raw_age, _ = _age_after_pause(lambda: raw.read()[1], device, 1.0)
    assert raw_age > 0.8, raw_age  # one of the frames queued right after the previous read
    raw.release()
    old = open_camera(webcam_tree(tmp_path / "a"), device, flush_frames=2)  # the old rule
    old.read()
    old_age, _ = _age_after_pause(old.read, device, 1.0)
    assert old_age > 0.8, old_age
    old.close()

    cam = open_camera(webcam_tree(tmp_path / "b"), device)
    cap = device.captures[-1]
    cam.read()
    ages, latencies = [], []
    for pause in (1.0, 0.0, 0.3, 0.05, 1.0, 0.5):  # a push, back-to-back reads, a step
        decoded = cap.decoded
        age, latency = _age_after_pause(cam.read, device, pause)
        ages.append(age)
        latencies.append(latency)
        assert age <= 0.0, (pause, age, cam.drained)  # taken at or after the call
        assert cap.decoded == decoded + 1  # the stale frames were grabbed, not decoded
    assert max(latencies) < 0.25, latencies  # 30 fps: the next frame and its transfer
    assert cam.describe()["fresh"].startswith("frame timestamps")
    cam.close()
    print(f"30 fps, 4 buffers, after a 1 s pause: OpenCV read {raw_age * 1000:.0f} ms old, "
          f"the old drop-2 rule {old_age * 1000:.0f} ms old; this camera: taken "
          f"{-max(ages) * 1000:.0f}..{-min(ages) * 1000:.0f} ms after the call, latency "
          f"median {statistics.median(latencies) * 1000:.0f} ms, max "
          f"{max(latencies) * 1000:.0f} ms")


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
@pytest.mark.parametrize("stamps", ["none", "realtime", "relative"])
def test_without_usable_timestamps_a_read_drains_buffers_plus_one(
        tmp_path: Path, stamps: str, caplog: pytest.LogCaptureFixture) -> None:
    device = FakeDevice(stamps=stamps)  # type: ignore[arg-type]
    with caplog.at_level(logging.INFO, logger="drivers.cameras.camera"):
        cam = open_camera(webcam_tree(tmp_path), device)
        cam.read()  # the first read finds the stamps out ("relative": 7 grabs)
        for pause in (0.0, 1.0, 0.2, 1.0):
            age, latency = _age_after_pause(cam.read, device, pause)
            assert age <= 0.0, (stamps, pause, age)
            assert latency < 6 / 30 + 0.1, latency  # at most buffers + 1 frames
    said = [r.getMessage() for r in caplog.records if "timestamps are not" in r.getMessage()]
    assert len(said) == 1 and "drains 5 frames" in said[0], said
    assert cam.describe()["fresh"] == "count: 5 grabs per read"
    cam.close()


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_a_camera_that_stops_sending_is_an_error_within_the_read_timeout(
        tmp_path: Path) -> None:
    device = FakeDevice()
    cam = open_camera(webcam_tree(tmp_path), device, read_timeout_s=1.0)
    cam.read()
    device.stalled = True
    t0 = time.monotonic()
    with pytest.raises(BackendError, match=r"camera 0 = .*video0 .* gave no frame within 1 s"):
        cam.read()
    assert time.monotonic() - t0 < 2.5
    assert os.environ[SELECT_TIMEOUT] == "1"  # OpenCV's V4L2 wait, bounded by ours
    cam.close()


# --- settings: set, read back, logged, each refusal one warning ----------------------
def test_settings_are_read_back_and_each_one_not_taken_is_one_warning(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    device = FakeDevice(controls=uvc_controls(focus=False), rates=(30, 15))  # no focus
    asked = {"width": 1280, "height": 720, "fourcc": "MJPG", "fps": 60, "exposure": 156,
             "white_balance": 7000, "focus": 0}
    with caplog.at_level(logging.INFO, logger="drivers.cameras.capture_settings"):
        cam = open_camera(webcam_tree(tmp_path), device, settings=asked)
    got = {"width": 1280, "height": 720, "fourcc": "MJPG", "fps": 30.0, "exposure": 156,
           "white_balance": 6500, "focus": None, "buffers": 4}
    assert cam.settings() == got
    # exposure was taken only because auto exposure went off first (the fake, as a UVC
    # camera, refuses a manual value while the automatic mode is on)
    assert device.controls[cv2.CAP_PROP_AUTO_EXPOSURE].value == 1
    info = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert len(info) == 1 and json.dumps(CaptureSettings.parse(asked).asked()) in info[0]
    assert json.dumps(got) in info[0]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 3, warned
    assert any("did not take fps: asked 60, got 30.0" in w for w in warned)
    assert any("did not take white_balance: asked manual 7000, got manual 6500" in w
               for w in warned)
    assert any("did not take focus: asked manual 0, got nothing (the device has no such "
               "control)" in w for w in warned)
    assert all(w.startswith("camera 0 = ") and "video0 ('HD Pro Webcam C920')" in w
               for w in warned)
    d = cam.describe()
    assert set(d["refused"]) == {"fps", "white_balance", "focus"}
    assert d["asked"]["fourcc"] == "MJPG" and d["settings"] == got
    assert cam.size == (1280, 720) and cam.read().shape == (720, 1280, 3)
    cam.close()


def test_auto_turns_automatic_modes_back_on_and_a_missing_format_is_named(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    device = FakeDevice()
    for prop, value in ((cv2.CAP_PROP_AUTO_EXPOSURE, 1), (cv2.CAP_PROP_AUTO_WB, 0),
                        (cv2.CAP_PROP_AUTOFOCUS, 0)):  # as a previous program left it
        device.controls[prop].value = value
    with caplog.at_level(logging.WARNING):
        cam = open_camera(webcam_tree(tmp_path), device, settings={
            "exposure": "auto", "white_balance": "auto", "focus": "auto", "fourcc": "H264"})
    s = cam.settings()
    assert (s["exposure"], s["white_balance"], s["focus"]) == ("auto", "auto", "auto")
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "did not take fourcc: asked 'H264', got 'YUYV'" in warned[0]
    cam.close()


def test_settings_are_for_a_device_a_url_refuses_them_a_file_ignores_them(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with pytest.raises(BackendError, match="camera_settings are for a V4L2 device"):
        VideoCaptureCamera("http://127.0.0.1:1/c.mjpg", settings={"fps": 30})
    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    with caplog.at_level(logging.WARNING):
        cam = VideoCaptureCamera(str(video), settings={"fps": 30})
    assert "camera_settings ignored: a video file" in caplog.text
    assert cam.read().shape == (256, 576, 3)
    assert cam.settings() == {"width": 576, "height": 256, "fps": 10.0}
    cam.close()
    for bad, word in (({"gain": 3}, "unknown key"), ({"width": 640}, "together"),
                      ({"exposure": True}, "exposure"), ('{"fps": 30', "not JSON")):
        with pytest.raises(BackendError, match=word):
            CaptureSettings.parse(bad)  # type: ignore[arg-type]


# --- which node: by path, by card name; RealSense ---------------------------------------
def test_a_by_id_or_by_path_link_opens_the_node_it_points_to(tmp_path: Path) -> None:
    devices = webcam_tree(tmp_path, number=4)
    dev = Path(devices.dev_root)
    by_id = link(dev, "by-id", "usb-046d_HD_Pro_Webcam_C920_8F3A1B2C-video-index0", 4)
    by_path = link(dev, "by-path", "pci-0000:00:14.0-usb-0:2:1.0-video-index0", 4)
    for source in (by_id, by_path, dev / "video4"):
        device = FakeDevice()
        cam = open_camera(devices, device, str(source))
        assert device.opens == [(4, cv2.CAP_V4L2)]
        d = cam.describe()
        assert d["node"] == str(dev / "video4") and d["card"] == C920
        assert d["links"] == [str(by_id), str(by_path)]
        cam.read()
        cam.close()
    with pytest.raises(BackendError, match=r"by-id/usb-gone-video-index0: no such device "
                                           r"\(unplugged\?\); .*by-id has: usb-046d"):
        open_camera(devices, FakeDevice(), str(dev / "v4l" / "by-id" / "usb-gone-video-index0"))
    (dev / "mem").write_bytes(b"")
    with pytest.raises(BackendError, match="not a V4L2 video node"):
        open_camera(devices, FakeDevice(), str(dev / "mem"))


def test_a_card_name_chooses_the_capture_node_of_its_device(tmp_path: Path) -> None:
    dev, sysfs = fake_tree(tmp_path, [
        FakeNode(0, "Integrated Camera: Integrated C", 0, "3-1"),
        FakeNode(1, "Integrated Camera: Integrated C", 1, "3-1"),
        FakeNode(2, C920, 0, "1-2"), FakeNode(3, C920, 1, "1-2")])
    devices = V4l2Devices(str(dev), str(sysfs))
    for name, number in ((C920, 2), ("  hd pro webcam c920 ", 2), ("C920", 2),
                         ("Integrated Camera", 0)):
        device = FakeDevice()
        open_camera(devices, device, name).close()
        assert device.opens == [(number, cv2.CAP_V4L2)], name
    with pytest.raises(BackendError, match=r"camera 'Logitech BRIO': no such video file, "
                                           r"and no V4L2 device has that card name \(video0 "
                                           r"'Integrated Camera: Integrated C' unknown, "):
        open_camera(devices, FakeDevice(), "Logitech BRIO")
    with pytest.raises(BackendError, match=r"video file '.*missing\.avi' does not exist"):
        open_camera(devices, FakeDevice(), "missing.avi")


def test_two_identical_cameras_by_name_are_an_error_naming_their_links(
        tmp_path: Path) -> None:
    dev, sysfs = fake_tree(tmp_path, [FakeNode(0, C920, 0, "1-2"), FakeNode(1, C920, 1, "1-2"),
                                      FakeNode(2, C920, 0, "1-3"), FakeNode(3, C920, 1, "1-3")])
    a = link(dev, "by-path", "pci-0000:00:14.0-usb-0:2:1.0-video-index0", 0)
    b = link(dev, "by-path", "pci-0000:00:14.0-usb-0:3:1.0-video-index0", 2)
    with pytest.raises(BackendError, match=rf"2 devices have that name; .*{a}.*{b}"):
        open_camera(V4l2Devices(str(dev), str(sysfs)), FakeDevice(), C920)


def _realsense(tmp_path: Path, names: list[str]) -> tuple[Path, Path]:
    """A D435 on USB 2-1: depth, infrared, colour, each with its metadata node."""
    return fake_tree(tmp_path, [FakeNode(i, names[i], i, "2-1", interface=i // 2 * 2)
                                for i in range(6)])


def test_a_realsense_named_by_stream_gives_its_colour_node(tmp_path: Path) -> None:
    """A driver that names its streams: the name's words decide (no kernel to ask)."""
    base = "Intel(R) RealSense(TM) Depth Camera 435i"
    names = [f"{base} Depth"] * 2 + [f"{base} Infrared"] * 2 + [f"{base} RGB"] * 2
    dev, sysfs = _realsense(tmp_path, names)
    device = FakeDevice()
    open_camera(V4l2Devices(str(dev), str(sysfs)), device, "RealSense(TM) Depth Camera").close()
    assert device.opens == [(4, cv2.CAP_V4L2)]


def test_a_stock_realsense_is_told_apart_by_the_kernels_formats(tmp_path: Path) -> None:
    """All six nodes are "Intel(R) RealSense(TM) Depth Ca"; what the kernel lists for each
    (QUERYCAP, ENUM_FMT) is stood in by the probe seam."""
    dev, sysfs = _realsense(tmp_path, [REALSENSE] * 6)
    facts = {0: NodeFacts(True, ("Z16 ",)), 2: NodeFacts(True, ("GREY", "Y8I ", "Y12I")),
             4: NodeFacts(True, ("YUYV", "RGB3", "BGR3"))}

    def probe(path: str) -> NodeFacts | None:
        n = int(Path(path).name.removeprefix("video"))
        return facts.get(n, NodeFacts(False, ()))  # odd nodes: metadata

    devices = V4l2Devices(str(dev), str(sysfs), probe=probe)
    device = FakeDevice()
    cam = open_camera(devices, device, REALSENSE)
    assert device.opens == [(4, cv2.CAP_V4L2)]
    assert cam.describe()["node_kind"] == "colour"
    cam.close()
    depth_link = link(dev, "by-id", "usb-Intel_R__RealSense_TM__Depth_Camera_435i-video-index0",
                      0)
    for source in ("0", str(depth_link)):
        with pytest.raises(BackendError, match=r"video0 .* is a depth stream \(formats Z16\), "
                                               r"not a colour picture; its device's colour "
                                               r"stream is .*/video4"):
            open_camera(devices, FakeDevice(), source)
    with pytest.raises(BackendError, match="is a grey stream"):
        open_camera(devices, FakeDevice(), "2")
    with pytest.raises(BackendError, match="is a metadata stream"):
        open_camera(devices, FakeDevice(), "5")


def test_the_node_rules_and_a_node_that_answers_no_ioctl(tmp_path: Path) -> None:
    assert kind_of(None, "Intel(R) RealSense(TM) Depth Camera 435i RGB")[0] == "colour"
    assert kind_of(None, "Intel(R) RealSense(TM) Depth Camera 435i Depth")[0] == "depth"
    assert kind_of(None, "Integrated IR Camera")[0] == "grey"
    assert kind_of(None, REALSENSE)[0] == "unknown"
    assert kind_of(NodeFacts(True, ("MJPG", "YUYV")), "Integrated IR Camera")[0] == "colour"
    assert kind_of(NodeFacts(False, ()), C920)[0] == "metadata"
    plain = tmp_path / "video0"
    plain.write_bytes(b"")
    assert query_node(str(plain)) is None and query_node(str(tmp_path / "nope")) is None
    # no sysfs at all (a container, this machine): an index opens as given
    device = FakeDevice()
    open_camera(V4l2Devices(str(tmp_path / "dev"), str(tmp_path / "sys")), device).close()
    assert device.opens == [(0, cv2.CAP_V4L2)]


# --- picture quality ------------------------------------------------------------------
def test_sharpness_and_exposure_tell_blur_dark_and_clipping() -> None:
    rng = np.random.default_rng(0)
    sharp = np.kron((np.indices((16, 16)).sum(0) % 2) * 160 + 40, np.ones((8, 8)))
    sharp = np.repeat(sharp[..., None], 3, axis=2).astype(np.uint8)
    blurred = cv2.GaussianBlur(sharp, (0, 0), 4)
    s, b = sharpness_and_exposure(sharp), sharpness_and_exposure(blurred)
    assert s["sharpness"] > 10 * b["sharpness"] and s["clipped"] == 0.0
    assert s["luma_p1"] == pytest.approx(40, abs=1) and s["luma_p99"] == pytest.approx(200,
                                                                                      abs=1)
    dark = (rng.integers(0, 12, (64, 64, 3))).astype(np.uint8)
    assert sharpness_and_exposure(dark)["luma_mean"] < 10
    half = np.full((10, 10, 3), 120, np.uint8)
    half[:5, :, 2] = 255  # one channel saturated: the red of a cube clips
    half[5:7] = 0
    q = sharpness_and_exposure(half)
    assert (q["clipped_high"], q["clipped_low"], q["clipped"]) == (0.5, 0.2, 0.7)
    assert q["pixels"] == 100
    with pytest.raises(ValueError, match="non-empty uint8"):
        sharpness_and_exposure(np.zeros((0, 4, 3), np.uint8))


def test_camera_report_has_the_cameras_account_and_each_crops_figures(
        tmp_path: Path) -> None:
    device = FakeDevice()
    cam = open_camera(webcam_tree(tmp_path), device, settings={"exposure": 200})
    report = camera_report(cam, {"left": (0, 0, 320, 240), "right": (320, 0, 700, 240)})
    json.dumps(report)  # it travels in a describe answer
    assert report["size"] == [640, 480] and report["camera"]["settings"]["exposure"] == 200
    assert report["camera"]["card"] == C920 and report["picture"]["pixels"] == 640 * 480
    assert report["crops"]["left"]["pixels"] == 320 * 240
    assert "outside the 640x480 picture" in report["crops"]["right"]["error"]
    assert isinstance(report["read_ms"], float) and report["read_ms"] < 1000
    given = np.zeros((100, 200, 3), np.uint8)  # a picture the backend already took
    again = camera_report(cam, {"left": (0, 0, 50, 50)}, frame=given)
    assert again["size"] == [200, 100] and again["read_ms"] is None
    assert again["crops"]["left"]["clipped_low"] == 1.0
    cam.close()


# --- from the config to the camera ---------------------------------------------------
def test_camera_settings_go_from_the_config_through_the_agent_to_the_camera(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import tomllib

    from drivers import agent
    from drivers.transport import agent_argv
    from drivers.yumi.backend import build_yumi_backend
    from testbed.core.config import ConfigError
    from testbed.experiments.fleet_config import parse_config

    toml = ('[[hosts]]\nname = "yumi0"\nbackend = "yumi"\n'
            'camera = "/dev/v4l/by-id/usb-046d_HD_Pro_Webcam_C920_8F3A1B2C-video-index0"\n'
            'controller_url = "http://192.0.2.1"\n'
            'arms = [{name = "left", crop = [0, 0, 300, 300], calibration = "/c/l.json"}]\n'
            '[hosts.camera_settings]\nwidth = 1280\nheight = 720\nfourcc = "MJPG"\n'
            'fps = 30\nexposure = 156\nwhite_balance = 4600\nfocus = "auto"\n')
    host = parse_config(tomllib.loads(toml)).hosts[0]
    argv = agent_argv(host, seed=0, python="python3", idle_timeout_s=10.0)
    text = argv[argv.index("--camera-settings") + 1]
    assert json.loads(text) == {"width": 1280, "height": 720, "fourcc": "MJPG", "fps": 30,
                                "exposure": 156, "white_balance": 4600, "focus": "auto"}
    kwargs = agent._backend_kwargs(agent.parse_args(argv[3:]))
    assert isinstance(kwargs, dict) and kwargs["camera_settings"] == text
    assert CaptureSettings.parse(text) == CaptureSettings(1280, 720, "MJPG", 30, 156, 4600,
                                                          "auto")
    for bad, field in (('exposure = "manual"', "camera_settings.exposure"),
                       ("width = 640", "camera_settings.height"),
                       ("fps = 30.0", "camera_settings.fps")):
        with pytest.raises(ConfigError, match=field):
            parse_config(tomllib.loads(toml.split("[hosts.camera_settings]")[0]
                                       + f"[hosts.camera_settings]\n{bad}\n"))
    with pytest.raises(ConfigError, match="camera_settings: a network camera takes no"):
        parse_config(tomllib.loads(toml.replace(host.camera, "http://cam.lab/video.mjpg")))

    video = write_video(tmp_path / "cam.avi", [twin_picture(0)])
    cal = tmp_path / "left.json"
    cal.write_text(json.dumps(yumi_calibration("left")))
    with caplog.at_level(logging.WARNING, logger="drivers.cameras.camera"):
        backend = build_yumi_backend(["left"], [False], {"left": (0, 0, 256, 256)},
                                     {"left": str(cal)}, str(video), "http://127.0.0.1:1",
                                     camera_settings=text, credentials_file="factory-default")
    backend.close()
    assert "camera_settings ignored: a video file" in caplog.text  # it reached the camera
