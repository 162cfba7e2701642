"""Test doubles for the drivers: an agent served in a thread, with hooks that corrupt
the bytes crossing in either direction, and a picture source for the YuMi backend.

Why an in-thread agent: the fuzz tests push a thousand broken frames each way through
the REAL agent loop (``drivers.agent.serve``) and the REAL fleet; a process per case
would take minutes. The pipes are real ``os.pipe`` pairs, so reads, EOF and deadlines
behave as they do with a subprocess.
"""

from __future__ import annotations

import contextlib
import os
import select
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers import wire as p
from drivers.agent import fd_reader, serve
from drivers.backends.base import ArmOutcome, ArmView, HostBackend
from drivers.backends.twin import CannedTwinBackend
from drivers.backends.twin.twin_host import TwinHost
from drivers.errors import DeadlineExceeded
from drivers.testing.sshd import SshServer
from drivers.transport import Transport
from drivers.wire import FrameReader
from drivers.yumi.yumi_host import YumiHost
from testbed.core.host_config import HostConfig

ROOT = Path(__file__).resolve().parents[2]


def local_host(name: str, **kw: Any) -> HostConfig:
    kw.setdefault("deadline_s", 5.0)
    kw.setdefault("connect_timeout_s", 20.0)
    model = YumiHost if kw.get("backend") == "yumi" else TwinHost
    return model(name=name, **kw)


def ssh_host(name: str, server: SshServer, **kw: Any) -> HostConfig:
    kw.setdefault("deadline_s", 5.0)
    kw.setdefault("connect_timeout_s", 20.0)
    return TwinHost(name=name, transport="ssh", address="127.0.0.1", port=server.port,
                      user=server.user, key_file=str(server.client_key),
                      known_hosts=str(server.known_hosts), python=sys.executable,
                      workdir=str(ROOT), **kw)


def wait_until(cond: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.02
               ) -> float:
    """Poll ``cond``; return the seconds it took, fail the test after ``timeout_s``."""
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout_s:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)
    return time.monotonic() - t0


class ExplodingBackend(HostBackend):
    """A backend whose push raises on one arm (as a camera or controller would)."""

    kind = "exploding"

    def __init__(self) -> None:
        self.inner = CannedTwinBackend(0)
        self.rested = 0

    @property
    def arm_names(self) -> tuple[str, ...]:
        return self.inner.arm_names

    @property
    def mirror(self) -> tuple[bool, ...]:
        return self.inner.mirror

    def observe(self) -> dict[str, ArmView]:
        return self.inner.observe()

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        if "right" in faces:
            err = RuntimeError("gripper camera unplugged")
            err.arm = "right"  # type: ignore[attr-defined]
            raise err
        return self.inner.push(faces)

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        return self.inner.reset(arms)

    def rest(self) -> None:
        self.rested += 1

    def close(self) -> None:
        pass


class RecordingBackend(HostBackend):
    """Records every call (the agent's own logic under test: what does it ask the arms
    to do?). ``push_outcomes``/``observe_errors`` script per-arm refusals and errors;
    the optional capabilities answer like a backend that has them."""

    kind = "recording"

    def __init__(self, arms: Sequence[str] = ("left", "right"), *,
                 push_outcomes: Mapping[str, ArmOutcome] | None = None,
                 observe_errors: Mapping[str, str] | None = None,
                 capable: bool = True) -> None:
        self.inner = CannedTwinBackend(0, arms, tuple(a.startswith("right") for a in arms))
        self.calls: list[tuple[str, Any]] = []
        self.push_outcomes = dict(push_outcomes or {})
        self.observe_errors = dict(observe_errors or {})
        self.capable = capable

    MOTION = ("push", "reset", "rest", "move_tcp")

    def motions(self) -> list[tuple[str, Any]]:
        return [c for c in self.calls if c[0] in self.MOTION]

    @property
    def arm_names(self) -> tuple[str, ...]:
        return self.inner.arm_names

    @property
    def mirror(self) -> tuple[bool, ...]:
        return self.inner.mirror

    def observe(self) -> dict[str, ArmView]:
        self.calls.append(("observe", None))
        views: dict[str, Any] = self.inner.observe()
        for arm, why in self.observe_errors.items():
            views[arm] = RuntimeError(why)  # an arm without a view, as the agent allows
        return views

    def push(self, faces: Mapping[str, int]) -> dict[str, ArmOutcome]:
        self.calls.append(("push", dict(faces)))
        out = self.inner.push(faces)
        return {a: self.push_outcomes.get(a, o) for a, o in out.items()}

    def reset(self, arms: Sequence[str]) -> dict[str, bool]:
        self.calls.append(("reset", list(arms)))
        return self.inner.reset(arms)

    def rest(self) -> None:
        self.calls.append(("rest", None))

    def close(self) -> None:
        self.calls.append(("close", None))

    def reseed(self, seed: int) -> None:
        self.calls.append(("reseed", seed))
        if not self.capable:
            super().reseed(seed)
        self.inner.reseed(seed)

    def frame(self) -> np.ndarray:
        self.calls.append(("frame", None))
        if not self.capable:
            return super().frame()
        rng = np.random.default_rng(5)
        return rng.integers(0, 256, (48, 80, 3), dtype=np.uint8)

    def move_tcp(self, arm: str, xyz_mm: Sequence[float]) -> tuple[float, float, float]:
        self.calls.append(("move_tcp", (arm, tuple(xyz_mm))))
        if not self.capable:
            return super().move_tcp(arm, xyz_mm)
        if xyz_mm[2] < 0:
            err = ValueError(f"arm {arm}: {list(xyz_mm)} is below the table")
            err.arm = arm  # type: ignore[attr-defined]
            raise err
        return (float(xyz_mm[0]), float(xyz_mm[1]), float(xyz_mm[2]) + 0.25)

    def save_calibration(self, arm: str, data: Mapping[str, Any]) -> str:
        self.calls.append(("save_calibration", (arm, dict(data))))
        if not self.capable:
            return super().save_calibration(arm, data)
        return f"/calib/{arm}.json"


def _whole_frame(chunk: bytes) -> bool:
    """Is ``chunk`` exactly one well-framed frame (so the agent will answer it)?"""
    if len(chunk) < p.PREFIX_BYTES:
        return False
    magic, hlen, blen, _ = p.PREFIX.unpack(chunk[:p.PREFIX_BYTES])
    return magic == p.MAGIC and len(chunk) == p.PREFIX_BYTES + hlen + blen


def lockstep_serve(chunks: Sequence[bytes], backend: HostBackend, *,
                   tail: Callable[[], bytes] = lambda: b"",
                   write: Callable[[bytes], None] | None = None, **serve_kw: Any
                   ) -> tuple[int, list[bytes]]:
    """The real ``serve`` loop driven by a controller that waits for the reply to each
    request before it sends the next, then gives ``tail()`` (``b""``: EOF; it may raise
    DeadlineExceeded: silence). Why lockstep: the agent reads ahead (protocol 3), and
    once the controller is gone it starts nothing more, so a script written all at once
    and closed would end before its requests ran. Returns the status and the replies
    (each write, as written; ``write`` replaces the recording, its attempts count)."""
    todo = iter(chunks)
    out: list[bytes] = []
    attempts = [0]
    owed = [0]  # replies the agent owes for the chunks given so far

    def record(data: bytes) -> None:
        attempts[0] += 1
        (write or out.append)(data)

    def read(n: int, deadline: float) -> bytes:
        while attempts[0] < owed[0]:  # as a pipe with nothing in it yet
            if time.monotonic() >= deadline:
                raise DeadlineExceeded("lockstep: waiting for the agent's reply")
            time.sleep(0.001)
        chunk = next(todo, None)
        if chunk is None:
            return tail()
        owed[0] += _whole_frame(chunk)
        return chunk

    rc = serve(p.FrameReader(read, "controller"), record, lambda: backend, **serve_kw)
    return rc, out


def frames_of(out: Sequence[bytes]) -> list[p.Frame]:
    """The frames of written replies (one frame per write)."""
    return [p.FrameReader(lambda n, d, b=b: b, "agent").read_frame(1e18) for b in out]


Mutation = Callable[[int, bytes], tuple[bytes, bool]]
"""(index of the frame in its direction, bytes) -> (bytes to send, close the stream
after them?)."""


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            view = view[os.write(fd, view):]
        except BlockingIOError:
            select.select([], [fd], [], 1.0)


class ThreadAgentTransport(Transport):
    """The real agent loop in a thread of this process, over two pipes."""

    def __init__(self, host: HostConfig, *, mutate_request: Mutation | None = None,
                 mutate_reply: Mutation | None = None,
                 backend_factory: Callable[[], HostBackend] | None = None) -> None:
        super().__init__(host)
        arms = tuple(a.name for a in host.arms)
        mirror = tuple(a.mirror for a in host.arms)
        self._factory = backend_factory or (lambda: CannedTwinBackend(0, arms, mirror))
        self._mreq = mutate_request
        self._mrep = mutate_reply
        self._sent = 0
        self._replied = 0
        self._reply_closed = False
        self.rc: int | None = None
        self.crashed: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._req_closed = True  # no streams until open() (a refused open is closed too)
        self._a2c_r = -1

    def open(self, argv: list[str], timeout_s: float) -> None:
        self._c2a_r, self._c2a_w = os.pipe()
        self._a2c_r, self._a2c_w = os.pipe()
        self._req_closed = False
        reader = FrameReader(fd_reader(self._c2a_r), "controller")

        def write(data: bytes) -> None:
            if self._reply_closed:
                raise BrokenPipeError("reply stream closed by the test")
            close = False
            if self._mrep is not None:
                data, close = self._mrep(self._replied, data)
            self._replied += 1
            _write_all(self._a2c_w, data)
            if close:  # as a real agent whose stdout closes: it is exiting
                self._reply_closed = True
                self.rc = -1 if self.rc is None else self.rc
                os.close(self._a2c_w)

        def run() -> None:
            try:
                self.rc = serve(reader, write, self._factory, idle_timeout_s=10.0)
            except BaseException as exc:  # the test asserts this never happens
                self.crashed = exc
            finally:
                if not self._reply_closed:
                    self._reply_closed = True
                    os.close(self._a2c_w)
                os.close(self._c2a_r)

        self._thread = threading.Thread(target=run, daemon=True, name="thread-agent")
        self._thread.start()

    def write(self, data: bytes, deadline: float) -> None:
        if self._req_closed:
            from drivers.errors import LinkClosed

            raise LinkClosed("request stream closed by the test")
        close = False
        if self._mreq is not None:
            data, close = self._mreq(self._sent, data)
        self._sent += 1
        _write_all(self._c2a_w, data)
        if close:
            self._req_closed = True
            os.close(self._c2a_w)

    def read(self, n: int, deadline: float) -> bytes:
        while True:
            timeout = max(deadline - time.monotonic(), 0.0)
            if select.select([self._a2c_r], [], [], timeout)[0]:
                return os.read(self._a2c_r, n)
            if timeout == 0.0:
                raise DeadlineExceeded(f"{self.peer}: no reply within the deadline")

    def exit_status(self) -> int | None:
        return self.rc

    def close(self) -> None:
        if not self._req_closed:
            self._req_closed = True
            with contextlib.suppress(OSError):
                os.close(self._c2a_w)
        if self._thread is not None:
            self._thread.join(5.0)
        with contextlib.suppress(OSError):
            os.close(self._a2c_r)


def write_video(path: Path, frames: list[np.ndarray], fps: float = 10.0) -> Path:
    """Frames (RGB) into a lossless video file for VideoCaptureCamera."""
    import cv2

    h, w = frames[0].shape[:2]
    for fourcc in ("FFV1", "HFYU", "MJPG"):
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
        if writer.isOpened():
            break
    else:
        raise RuntimeError("no usable VideoWriter codec")
    for f in frames:
        writer.write(np.ascontiguousarray(f[..., ::-1]))
    writer.release()
    return path


# --- the YuMi backend against a fake controller and a video-file camera -------------
YUMI_SCALE = 4
"""The twin's cell picture at 4x: 576 x 256 pixels, each workspace 256 x 256."""
YUMI_CROPS: dict[str, tuple[int, int, int, int]] = {"left": (0, 0, 256, 256),
                                                    "right": (320, 0, 576, 256)}
YUMI_HOMOGRAPHY = [[0.0, 1.25, 200.0], [1.25, 0.0, -360.0], [0.0, 0.0, 1.0]]
"""Camera pixel (u, v) -> robot base (x, y) mm: x = 1.25 v + 200, y = 1.25 u - 360."""
YUMI_BOXES = {"left": [210.0, -350.0, 510.0, -50.0], "right": [210.0, 50.0, 510.0, 350.0]}
YUMI_REST = {"left": (100.0, -400.0, 300.0), "right": (100.0, 400.0, 300.0)}
YUMI_IN_VIEW = (360.0, -200.0, 50.0)


def twin_picture(seed: int = 0, cubes: Mapping[str, tuple[float, float]] | None = None
                 ) -> np.ndarray:
    """An overhead picture of a twin cell (RGB), cubes placed at canonical positions."""
    from sim_twin.cell import TwinCell

    with TwinCell(seed, render_scale=YUMI_SCALE) as cell:
        for arm, xy in (cubes or {}).items():
            cell.set_arm_state(arm, xy, 0.0, (0.5, 0.5))
        return cell.picture()


def yumi_calibration(arm: str) -> dict[str, Any]:
    """The fake cell's calibration of ``arm``, with the gate joints ``testbed calibrate``
    would write for it (the driver's model: drivers/yumi/gate.py)."""
    from drivers.yumi.gate import calibration_gate_joints

    cal = {"homography": YUMI_HOMOGRAPHY, "table_box_mm": YUMI_BOXES[arm],
           "z_push_mm": 12.0, "z_travel_mm": 90.0, "max_speed_mm_s": 120.0,
           "push_speed_mm_s": 40.0, "tool_z_mm": 184.2, **_fake_side(arm)}
    return {**cal, "gate_joints_deg": calibration_gate_joints(arm, cal)}


def yumi_joints(arm: str) -> Any:
    """The fake controller's joints for ``arm``'s pusher at a point: the driver's model,
    the pusher down at the arm angle, from the gate joints (as the legs leave them)."""
    from drivers.yumi.arm_calibration import ArmCalibration
    from drivers.yumi.gate import arm_tool

    cal = ArmCalibration.from_dict(yumi_calibration(arm), arm)
    tool = arm_tool(arm, cal)
    assert tool is not None and cal.gate_joints_deg is not None
    seed = tool.model.pose_abb(cal.gate_joints_deg).chain_deg

    def solve(_: str, xyz: Any) -> Any:
        sol = tool.solve(xyz, seed)
        pose = sol.pose if sol.pose is not None else sol.near
        return None if pose is None else pose.abb_deg
    return solve


def _fake_side(arm: str) -> dict[str, Any]:
    """The fake cell's "left" arm works at y < 0 (its table box): on an IRB 14000 that is
    the robot's right arm, T_ROB_R, so its reach and rest are judged with that arm's
    model (the driver checks every target with it, issue 35); and the other way round."""
    right = arm == "left"
    return {"task": "T_ROB_R" if right else "T_ROB_L", "mechunit": "ROB_R" if right else "ROB_L",
            "arm_angle_deg": 40.0 if right else -40.0,
            "rest_joints_deg": [-40 if right else 40, -90, 30, 0, 40, 0, -135 if right else 135]}


def make_yumi(tmp_path: Path, pictures: Sequence[np.ndarray], *, seed: int = 0,
              name: str = "cam") -> tuple[Any, Any]:
    """A YumiBackend on a FakeYumiController and a video file of ``pictures``."""
    import json

    from drivers.cameras.camera import VideoCaptureCamera
    from drivers.testing.fake_yumi import FakeYumiController
    from drivers.yumi.arm_calibration import ArmCalibration
    from drivers.yumi.backend import ArmSetup, YumiBackend

    video = write_video(tmp_path / f"{name}.avi", list(pictures))
    setups = []
    for arm in ("left", "right"):
        cal = tmp_path / f"{name}-{arm}.json"
        cal.write_text(json.dumps(yumi_calibration(arm)))
        setups.append(ArmSetup(arm, YUMI_CROPS[arm], arm == "right",
                               ArmCalibration.load(cal, arm)))
    solvers = {arm: yumi_joints(arm) for arm in ("left", "right")}
    ctrl = FakeYumiController(
        dict(YUMI_REST), in_view_xyz=YUMI_IN_VIEW,
        rest_joints={a: tuple(_fake_side(a)["rest_joints_deg"]) for a in ("left", "right")},
        solve=lambda arm, xyz: solvers[arm](arm, xyz))
    return YumiBackend(setups, VideoCaptureCamera(str(video)), ctrl, seed=seed), ctrl
