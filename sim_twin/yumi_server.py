"""The YuMi hardware twin as a process: camera stream, the controller's RWS, lab side channel.

Why a process with HTTP: the physical path (agent -> YumiBackend -> camera seam and
controller seam) must run unchanged against the twin, over the same kinds of channel as
in the lab: an IP camera's MJPEG stream that ``cv2.VideoCapture`` opens, and the IRC5's
Robot Web Services 1.0 that the UNCHANGED ABB client (``abb_robot_client.rws.RWS``)
speaks, behind which the twin plays OUR RAPID (``robot/rapid/``: one program file per
task, the event-log entries, the world zones). The lab side channels (``/lab/*`` on both
ports) are what the rehearsal's humans, truth recorder and fault drills use; the backend
never sees them.

Usage::

    python -m sim_twin.yumi_server --arms left,right --seed 7 --port 0 \\
        --port-file /tmp/twin.port [--fps 15] [--realtime 0] [--host 127.0.0.1] \\
        [--rws-port-file /tmp/twin.rws.port] [--rws-credentials FILE] [--rws-grants agent] \\
        [--rws-log FILE] \\
        [--zone ARM=x0,y0,x1,y1 ...] [--zone-z 80] [--floor-z 0] [--max-sessions 70] \\
        [--pusher-length-mm 0] [--no-rapid] [--verbose]

It listens on HOST:PORT (port 0: any free port) for the camera and the lab, and on a
second loopback port (always 127.0.0.1, any free port) for RWS; it writes the RWS port to
``--rws-port-file`` and THEN the camera port to ``--port-file`` (each a decimal line,
atomically), so a parent that sees the camera's port file can use both. It serves until
SIGTERM/SIGINT and exits 0; 2 (one line on stderr) on a bad argument, a zone that does
not fit, or a credentials file others can read.

The camera port (JSON unless said otherwise; errors are ``{"error": "..."}`` with
400/404/503):

- ``GET /camera.mjpg``: ``multipart/x-mixed-replace; boundary=frame``, one JPEG part per
  frame at ``--fps`` (each part: ``--frame``, ``Content-Type: image/jpeg``,
  ``Content-Length``). One client at a time, like a V4L2 device: a second one gets 503
  with the text ``camera busy: another client is streaming``. The world is rendered
  once per state (after a motion or a reset; during a motion at ``--realtime`` > 0 also
  at ``--fps`` of wall time as it goes); every frame gets fresh sensor noise. The socket's
  send buffer is kept small so few stale frames queue. After a motion the new state is
  published before RWS reads execution ``stopped``.
- ``GET /camera.jpg``: one JPEG of the current state (not a stream client).
- ``POST /lab/reset`` ``{"arm": "left"}`` -> ``{"ok": true}``: the lab hand puts the
  arm's cube back near its workspace centre.
- ``POST /lab/place`` ``{"arm", "xy_mm": [x, y], "yaw"}`` -> ``{"ok": true}``: a person puts
  the cube somewhere (fault drills, tests).
- ``POST /lab/jog`` ``{"arm", "xyz_mm": [x, y, z]}`` -> ``{"ok": true, "tcp_mm"}``: a
  person jogs the arm's TCP to a point on the FlexPendant (tests: an arm left in the
  camera's view, which ``testbed check`` must FAULT without moving it).
- ``GET /lab/truth`` -> ``{"arms": {arm: {"cube_mm", "on_table", "cube_px", "yaw_px",
  "tcp_mm"}}}`` (``tcp_mm``: the pusher's actual TCP, world mm).
- ``GET /lab/tcp`` -> ``{"tcp_mm": {arm: [x, y, z]}}``: the pushers now, ALSO while a
  motion runs (``/lab/truth`` waits for the cell, so for the motion's end): the latest
  sample of the running program, what a person sees of a moving arm.
- ``GET /lab/camera`` -> the true camera model and the cell's layout (K, dist, R/t and
  rvec/tvec world mm -> camera, crops, mirror, workspaces_mm, rest_mm, marker, ...).
- ``GET /lab/health`` -> ``{"ok": true}``.
- ``POST /lab/fault`` ``{"kind", "arm"?}`` -> ``{"ok", "kind", "arm", "shows"}``: something
  goes wrong in the cell (``kind``: guard_stop, motors_off, rapid_error, zone_stop,
  camera_frozen; ``arm`` names the task of a RAPID error or a zone stop); 400 if that kind
  is already active. ``POST /lab/clear`` ``{"kind"}`` -> ``{"ok", "kind", "arm",
  "actions"}``: a person clears it as in the lab (``sim_twin.lab_faults``: reset the
  guard and press Motors On, PP to Main, jog out of the zone, restart the camera).
  ``GET /lab/faults`` -> ``{"active": {kind: arm}}``.

The RWS port (``sim_twin.rws``; docs/notes/rws.md): RWS 1.0 as RobotWare 6 answers it,
digest login as ``Default User``/``robotics`` or the ``--rws-credentials`` file's
``USER:PASSWORD`` (the format of the agent's ``credentials_file``: one line, ``#``
comments; mode 0600 or 0400), at most ``--max-sessions`` sessions. The UAS grants
(``sim_twin.rws.uas``): ``Default User`` every grant; the file's user, the agent's login
in a rehearsal, ``--rws-grants`` (default ``agent``: exactly robot/README.md's four, so a
request the agent's user may not make is refused with the controller's 403; ``person``,
``factory``, ``none`` or ``UAS_...`` ids separated by commas). A RAPID start runs
``TestbedRapid`` on this process's cell (under the same lock as the camera and the lab):
our modules' semantics, the task modules' symbols readable (``tb_zone_lo``,
``tb_zone_hi``, ``tb_zone_z``, ``tb_floor_z``, ``tool_pusher``, ``TB_RAPID_VERSION``, ...),
and the stationary world zones, per arm the ``--zone`` box (world mm; default: the arm's
workspace grown by 25 mm) below ``--zone-z`` and nothing below ``--floor-z``. With
``--no-rapid`` our modules are not loaded: no such symbols, a start runs nothing. Its
``/lab/controller`` side channel sets the controller's states, RAPID errors, the
options listed, and loads/unloads our modules (``sim_twin.rws.rws_service``).
``--rws-log`` appends one JSON line per RWS request served: ``{"t", "method", "path",
"status", "ms"}`` (never a header, cookie or body).

The geometry, camera model and physics are documented in ``sim_twin.yumi_geometry`` and
``sim_twin.yumi_cell``.

Over 450 lines, on purpose: the twin as a process: its HTTP routes (the camera stream,
RWS, the lab's side channel) over one cell, and the command line that starts it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import select
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sim_twin.lab_faults import KINDS as FAULT_KINDS
from sim_twin.lab_faults import TwinFaults
from sim_twin.port_file import write_port
from sim_twin.rws.digest_auth import DEFAULT_USERS
from sim_twin.rws.irc5 import Identity, Irc5Controller
from sim_twin.rws.login_file import read_login_file
from sim_twin.rws.mechunits import MechUnit
from sim_twin.rws.request_log import RequestLog
from sim_twin.rws.rws_server import RwsServer
from sim_twin.rws.rws_service import RwsService
from sim_twin.rws.testbed_install import TestbedInstall
from sim_twin.rws.testbed_rapid import TestbedRapid
from sim_twin.rws.uas import parse_grants
from sim_twin.rws.world_zones import ArmZone, default_zone, parse_zone
from sim_twin.yumi_arms import DEFAULT_TOOL_MM
from sim_twin.yumi_cell import YumiTwinCell
from sim_twin.yumi_geometry import arm_side

BUSY_TEXT = "camera busy: another client is streaming"
JPEG_QUALITY = 90
VARIANTS = 4
"""Noisy JPEGs kept per world state (the stream cycles through them)."""
SNDBUF_BYTES = 16384
MAX_BODY_BYTES = 1 << 20


class FrameCache:
    """The newest clean picture and a few noisy JPEGs of it. The clean picture is
    published under the cell lock; JPEGs are made on demand by whoever needs one."""

    def __init__(self, cell: YumiTwinCell) -> None:
        self._cell = cell
        self._lock = threading.Lock()
        self._clean: np.ndarray | None = None
        self._jpegs: list[bytes] = []
        self._next = 0
        self.published = 0
        self._frozen: bytes | None = None
        """A frozen camera's one JPEG (``sim_twin.lab_faults``): sent again and again."""

    def publish(self) -> None:
        """Render the cell's current state (call with the cell lock held)."""
        clean = self._cell.render(noise=False)
        with self._lock:
            self._clean, self._jpegs, self._next = clean, [], 0
            self.published += 1

    def freeze(self, on: bool) -> None:
        """A camera whose picture stopped updating (``on``) or restarted: frozen, every
        frame is the byte-identical JPEG of the moment it froze, whatever the cell does."""
        frame = self.jpeg() if on else None
        with self._lock:
            self._frozen = frame

    def jpeg(self) -> bytes:
        with self._lock:
            if self._frozen is not None:
                return self._frozen
            clean, jpegs = self._clean, self._jpegs
            if clean is None:
                raise RuntimeError("no picture published yet")
            if len(jpegs) >= VARIANTS:
                self._next = (self._next + 1) % len(jpegs)
                return jpegs[self._next]
            noisy = self._cell.add_noise(clean)
        ok, buf = cv2.imencode(".jpg", noisy, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        data = buf.tobytes()
        with self._lock:
            if self._jpegs is jpegs:  # not replaced by a newer state meanwhile
                jpegs.append(data)
        return data


class TwinServer(ThreadingHTTPServer):
    """The HTTP server around one cell (threads per request, one lock for the cell)."""

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, cell: YumiTwinCell, host: str = "127.0.0.1", port: int = 0,
                 fps: float = 15.0, verbose: bool = False) -> None:
        self.cell = cell
        self.fps = float(fps)
        self.verbose = verbose
        self.cell_lock = threading.Lock()
        self.stream_slot = threading.Lock()
        self.stopping = threading.Event()
        self.frames = FrameCache(cell)
        self.tcp_source: Callable[[], dict[str, tuple[float, float, float]]] | None = None
        """Where ``GET /lab/tcp`` reads the pushers without waiting for a motion to end
        (the controller's start hook keeps the latest sample); set by :class:`RwsSide`."""
        self.arm_facts: dict[str, Any] = {}
        """What the twin's arms add to ``GET /lab/camera``: the tool's length below the
        flange (``tool_z_mm``) and each arm's rest joints (``rest_joints_deg``, ABB's
        order), which a lab measures on its robot and writes into the calibration."""
        self.faults: TwinFaults | None = None
        """The faults a lab injects and a person clears (``/lab/fault``, ``/lab/clear``);
        set by :func:`main` once the controller exists."""
        self._streams: set[socket.socket] = set()
        self._streams_lock = threading.Lock()
        with self.cell_lock:
            self.frames.publish()
        super().__init__((host, port), Handler)

    @property
    def port(self) -> int:
        return int(self.server_address[1])

    def track(self, sock: socket.socket, on: bool) -> None:
        with self._streams_lock:
            (self._streams.add if on else self._streams.discard)(sock)

    def stop(self) -> None:
        """End serve_forever (from another thread) and unblock the stream's writes."""
        self.stopping.set()
        with self._streams_lock:
            for s in self._streams:
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
        self.shutdown()


class Handler(BaseHTTPRequestHandler):
    server: TwinServer
    server_version = "YumiTwin/1"

    def log_message(self, format: str, *args: Any) -> None:
        if self.server.verbose:
            super().log_message(format, *args)

    # --- replies ------------------------------------------------------------------------
    def _send(self, status: int, body: bytes, ctype: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, status: int, obj: Any) -> None:
        self._send(status, json.dumps(obj).encode(), "application/json")

    def _body(self) -> Any:
        n = int(self.headers.get("Content-Length") or 0)
        if not 0 < n <= MAX_BODY_BYTES:
            raise ValueError("expected a JSON body")
        try:
            return json.loads(self.rfile.read(n))
        except ValueError as exc:
            raise ValueError(f"bad JSON: {exc}") from None

    # --- routes ---------------------------------------------------------------------------
    def do_GET(self) -> None:
        path = self.path.split("?", 1)[0]
        srv, cell = self.server, self.server.cell
        if path == "/camera.mjpg":
            self._stream()
        elif path == "/camera.jpg":
            self._send(200, srv.frames.jpeg(), "image/jpeg")
        elif path == "/lab/truth":
            with srv.cell_lock:
                truth, tcp = cell.truth(), cell.tcp_xyz()
            for arm, t in truth.items():
                t["tcp_mm"] = list(tcp[arm])
            self._json(200, {"arms": truth})
        elif path == "/lab/tcp":
            self._json(200, {"tcp_mm": self._tcp_now()})
        elif path == "/lab/camera":
            self._json(200, {**cell.camera_model, **srv.arm_facts})
        elif path == "/lab/health":
            self._json(200, {"ok": True})
        elif path == "/lab/faults" and srv.faults is not None:
            self._json(200, srv.faults.state())
        else:
            self._json(404, {"error": f"no such endpoint: GET {path}"})

    def _tcp_now(self) -> dict[str, list[float]]:
        """Each pusher's actual TCP (world mm) now, also mid-motion: from the motion's
        latest sample (every ``frame_every_s`` of simulated time) while one runs."""
        srv = self.server
        if srv.tcp_source is not None:
            tcp = srv.tcp_source()
        else:
            with srv.cell_lock:
                tcp = srv.cell.tcp_xyz()
        return {a: [round(float(v), 3) for v in xyz] for a, xyz in tcp.items()}

    def do_POST(self) -> None:
        path = self.path.split("?", 1)[0]
        routes: dict[str, Callable[[Any], dict[str, Any]]] = {
            "/lab/reset": self._reset, "/lab/place": self._place, "/lab/jog": self._jog,
            "/lab/fault": self._fault, "/lab/clear": self._clear}
        if path not in routes:
            self._json(404, {"error": f"no such endpoint: POST {path}"})
            return
        try:
            reply = routes[path](self._body())
        except ValueError as exc:
            self._json(400, {"error": str(exc)})
            return
        self._json(200, reply)

    def _reset(self, body: Any) -> dict[str, Any]:
        if not isinstance(body, dict) or not isinstance(body.get("arm"), str):
            raise ValueError('expected {"arm": NAME}')
        srv = self.server
        with srv.cell_lock:
            srv.cell.lab_reset(body["arm"])
            srv.frames.publish()
        return {"ok": True}

    def _jog(self, body: Any) -> dict[str, Any]:
        """A person jogs an arm's TCP to a point (the cell's stop-at-a-point, as a zone
        stop's clearing jogs it); the controller then reports it there, the camera shows
        it there."""
        xyz = body.get("xyz_mm") if isinstance(body, dict) else None
        if (not isinstance(body, dict) or not isinstance(body.get("arm"), str)
                or not isinstance(xyz, list) or len(xyz) != 3
                or not all(isinstance(v, int | float) and math.isfinite(v) for v in xyz)):
            raise ValueError('expected {"arm": NAME, "xyz_mm": [x, y, z]} (finite mm)')
        srv = self.server
        if body["arm"] not in srv.cell.arms:
            raise ValueError(f"unknown arm {body['arm']!r} (this cell has {list(srv.cell.arms)})")
        with srv.cell_lock:
            srv.cell.halt({body["arm"]: tuple(float(v) for v in xyz)})
            srv.frames.publish()
            tcp = srv.cell.tcp_xyz()[body["arm"]]
        return {"ok": True, "tcp_mm": [float(v) for v in tcp]}

    def _place(self, body: Any) -> dict[str, Any]:
        """A person in the lab puts a cube somewhere (fault drills, tests): anywhere on
        the table, in a neighbour's workspace or beyond the camera's view."""
        if not isinstance(body, dict) or not isinstance(body.get("arm"), str):
            raise ValueError('expected {"arm": NAME, "xy_mm": [x, y], "yaw": rad}')
        xy = body.get("xy_mm")
        yaw = body.get("yaw", 0.0)
        if (not isinstance(xy, list) or len(xy) != 2
                or not all(isinstance(v, int | float) and math.isfinite(v) for v in xy)
                or not isinstance(yaw, int | float) or not math.isfinite(yaw)):
            raise ValueError("xy_mm must be [x, y] (finite mm) and yaw a finite number")
        srv = self.server
        if body["arm"] not in srv.cell.arms:
            raise ValueError(f"unknown arm {body['arm']!r} (this cell has {list(srv.cell.arms)})")
        with srv.cell_lock:
            srv.cell.place_cube(body["arm"], (float(xy[0]), float(xy[1])), float(yaw))
            srv.frames.publish()
        return {"ok": True}

    def _fault(self, body: Any) -> dict[str, Any]:
        """The lab makes something go wrong (``sim_twin.lab_faults``: a guard stop, ...)."""
        faults = self._faults(body)
        arm = body.get("arm")
        if arm is not None and not isinstance(arm, str):
            raise ValueError("arm must be an arm's name")
        return {"ok": True, **faults.inject(body["kind"], arm)}

    def _clear(self, body: Any) -> dict[str, Any]:
        """A person clears a fault as in the lab (the actions: ``sim_twin.lab_faults``)."""
        return {"ok": True, **self._faults(body).clear(body["kind"])}

    def _faults(self, body: Any) -> TwinFaults:
        if not isinstance(body, dict) or not isinstance(body.get("kind"), str):
            raise ValueError(f'expected {{"kind": one of {list(FAULT_KINDS)}, "arm"?: NAME}}')
        if self.server.faults is None:
            raise ValueError("this twin has no controller to fault")
        return self.server.faults

    def _stream(self) -> None:
        srv = self.server
        if not srv.stream_slot.acquire(blocking=False):
            self._send(503, BUSY_TEXT.encode(), "text/plain; charset=utf-8")
            return
        sock = self.connection
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SNDBUF_BYTES)
            srv.track(sock, True)
            self.send_response(200)
            self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
            self.send_header("Cache-Control", "no-store")
            self.send_header("Connection", "close")
            self.end_headers()
            period, due = 1.0 / srv.fps, time.monotonic()
            while not srv.stopping.is_set():
                # A client that stopped reading (a paused VideoCapture) fills the socket:
                # wait until it reads again and then send the NEWEST frame, rather than
                # blocking on a frame that is stale by the time it goes out.
                if not select.select([], [sock], [], 0.5)[1]:
                    continue
                data = srv.frames.jpeg()
                self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                 + str(len(data)).encode() + b"\r\n\r\n" + data + b"\r\n")
                self.wfile.flush()
                due = max(due + period, time.monotonic())  # a blocked client: no burst
                srv.stopping.wait(max(due - time.monotonic(), 0.0))
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass  # the client went away
        finally:
            srv.track(sock, False)
            self.close_connection = True
            srv.stream_slot.release()


def _args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m sim_twin.yumi_server",
                                description="The YuMi hardware twin: camera, RWS, lab side.")
    p.add_argument("--arms", default="left,right", help="comma-separated arm names")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--host", default="127.0.0.1", help="the camera's and the lab's address")
    p.add_argument("--port", type=int, default=0, help="0: any free port")
    p.add_argument("--port-file", type=Path, default=None)
    p.add_argument("--fps", type=float, default=15.0)
    p.add_argument("--realtime", type=float, default=0.0,
                   help="real-time factor of motions (sim s per wall s); 0: fast as possible")
    p.add_argument("--rws-port-file", type=Path, default=None,
                   help="where the RWS port goes (RWS is always served, on 127.0.0.1)")
    p.add_argument("--rws-credentials", type=Path, default=None, metavar="FILE",
                   help="one line USER:PASSWORD, mode 0600/0400: a login besides the factory's")
    p.add_argument("--rws-grants", default="agent", metavar="GRANTS",
                   help="the --rws-credentials user's UAS grants: a role (agent, person, "
                        "factory, none) or UAS_... ids separated by commas (default agent)")
    p.add_argument("--rws-log", type=Path, default=None, metavar="FILE",
                   help="append one JSON line per RWS request served")
    p.add_argument("--zone", action="append", default=[], metavar="ARM=x0,y0,x1,y1",
                   help="an arm's world-zone box (world mm; default: workspace + 25 mm)")
    p.add_argument("--zone-z", type=float, default=80.0, metavar="MM",
                   help="below this the TCP must stay in its zone box")
    p.add_argument("--floor-z", type=float, default=0.0, metavar="MM",
                   help="no TCP below this, anywhere")
    p.add_argument("--max-sessions", type=int, default=70)
    p.add_argument("--serial", default=None,
                   help="the controller's serial (ctrl/identity's ctrl-id; default "
                        "14000-500000): robot locks are keyed on it, so twins beside each "
                        "other need their own")
    p.add_argument("--pusher-length-mm", type=float, default=DEFAULT_TOOL_MM,
                   help="the flange above the pusher's tip (RWS tool0 = flange); the arms' "
                        "gripper and pusher (default %(default)g)")
    p.add_argument("--no-rapid", action="store_true",
                   help="our RAPID modules not loaded: no testbed symbols, a start runs nothing")
    p.add_argument("--omit-motiontask", action="store_true",
                   help="GET rw/rapid/tasks leaves the motiontask field out, as some "
                        "controllers do (abb_motion_program_exec issue 4): the ABB "
                        "client's start() then (de)activates no task")
    p.add_argument("--verbose", action="store_true", help="log every request to stderr")
    a = p.parse_args(argv)
    if not (math.isfinite(a.fps) and 0 < a.fps <= 60):
        p.error("--fps must be in (0, 60]")
    if not (math.isfinite(a.realtime) and a.realtime >= 0):
        p.error("--realtime must be >= 0")
    if a.max_sessions < 1:
        p.error("--max-sessions must be >= 1")
    try:
        parse_grants(a.rws_grants)
    except ValueError as exc:
        p.error(f"--rws-grants: {exc}")
    if not all(math.isfinite(v) for v in (a.zone_z, a.floor_z, a.pusher_length_mm)):
        p.error("--zone-z, --floor-z and --pusher-length-mm must be finite")
    return a


def _zones(a: argparse.Namespace, cell_arms: Sequence[str], sides: dict[str, str]
           ) -> dict[str, ArmZone]:
    """Every arm's zone from ``--zone`` (default: its workspace grown), ``--zone-z`` and
    ``--floor-z``; ``ValueError`` naming the argument."""
    boxes: dict[str, tuple[float, float, float, float]] = {}
    for text in a.zone:
        arm, box = parse_zone(text)
        if arm not in cell_arms:
            raise ValueError(f"--zone {text!r}: no arm {arm!r} (this cell has "
                             f"{','.join(cell_arms)})")
        boxes[arm] = box
    out = {}
    for arm in cell_arms:
        d = default_zone(sides[arm], zone_z=a.zone_z, floor_z=a.floor_z)
        try:
            out[arm] = ArmZone(*boxes.get(arm, d.box), zone_z=a.zone_z, floor_z=a.floor_z)
        except ValueError as exc:
            raise ValueError(f"--zone for {arm}: {exc}") from None
    return out


class RwsSide:
    """The controller beside the camera: an RWS server on the same cell and cell lock,
    our RAPID (or none) installed, and its request log."""

    def __init__(self, server: TwinServer, a: argparse.Namespace,
                 zones: dict[str, ArmZone], users: dict[str, str],
                 grants: Mapping[str, frozenset[str]] | None = None) -> None:
        cell = server.cell
        units = tuple(MechUnit(f"ROB_{cell.sides[arm][0].upper()}",
                               f"T_ROB_{cell.sides[arm][0].upper()}", arm) for arm in cell.arms)
        live = cell.realtime > 0  # a paced motion shows on the stream as it happens
        self.motion = TestbedRapid(cell, server.cell_lock, units,
                                   pusher_length_mm=a.pusher_length_mm, floor_z_mm=a.floor_z,
                                   zones=zones, on_frame=server.frames.publish,
                                   on_frame_every_s=cell.realtime / server.fps if live
                                   else math.inf)
        identity = Identity() if a.serial is None else Identity(ctrl_id=a.serial)
        self.controller = Irc5Controller(units=units, poses=self.motion.poses,
                                         identity=identity,
                                         omit_motiontask=a.omit_motiontask)
        self.install = TestbedInstall(self.controller, self.motion, loaded=not a.no_rapid)
        self.log = RequestLog(a.rws_log) if a.rws_log is not None else None
        service = RwsService(self.controller, users=users, max_sessions=a.max_sessions,
                             program=self.install, grants=grants)
        self.server = RwsServer(service, "127.0.0.1", 0, verbose=a.verbose,
                                request_log=self.log)

    def close(self) -> None:
        self.server.stop()
        if self.log is not None:
            self.log.close()


def _users(a: argparse.Namespace) -> dict[str, str]:
    return _logins(a)[0]


def _logins(a: argparse.Namespace) -> tuple[dict[str, str], dict[str, frozenset[str]]]:
    """The logins (the factory's, the ``--rws-credentials`` file's) and the UAS grants
    given: the file's user ``--rws-grants``; ``ValueError`` for a bad file."""
    users = dict(DEFAULT_USERS)
    grants: dict[str, frozenset[str]] = {}
    if a.rws_credentials is not None:
        user, password = read_login_file(a.rws_credentials)
        users[user] = password
        grants[user] = parse_grants(a.rws_grants)
    return users, grants


def main(argv: Sequence[str] | None = None) -> int:
    a = _args(argv)
    arms = tuple(s.strip() for s in a.arms.split(",") if s.strip())
    try:
        users, grants = _logins(a)
        zones = _zones(a, arms, arm_side(arms))
        cell = YumiTwinCell(a.seed, arms, realtime=a.realtime)
    except ValueError as exc:
        print(f"yumi_server: {exc}", file=sys.stderr)
        return 2
    server = TwinServer(cell, a.host, a.port, a.fps, a.verbose)
    rws = RwsSide(server, a, zones, users, grants)
    server.tcp_source = rws.motion.tcp_xyz
    server.arm_facts = {"tool_z_mm": a.pusher_length_mm,
                        "rest_joints_deg": {arm: list(rws.motion.arms.rest_joints(arm))
                                            for arm in arms}}
    server.faults = TwinFaults(rws.controller, server.frames, cell, server.cell_lock,
                               {u.arm: u.task for u in rws.controller.units.values()},
                               {arm: z.zone_z for arm, z in zones.items()},
                               server.frames.publish)

    def on_signal(signum: int, frame: object) -> None:
        threading.Thread(target=server.stop, daemon=True).start()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    rws.server.start_thread()
    if a.rws_port_file is not None:
        write_port(a.rws_port_file, rws.server.port)
    if a.port_file is not None:
        write_port(a.port_file, server.port)
    print(f"yumi_server: arms {','.join(arms)} seed {a.seed} on http://{a.host}:{server.port}"
          f", RWS on {rws.server.url} (our RAPID {'not ' if a.no_rapid else ''}loaded)",
          file=sys.stderr, flush=True)
    try:
        server.serve_forever(poll_interval=0.2)
    finally:
        gap, where = rws.motion.arms.closest
        if where:
            print(f"yumi_server: the arms came within {gap:.0f} mm of each other ({where})",
                  file=sys.stderr, flush=True)
        rws.close()
        server.server_close()
        with server.cell_lock:
            cell.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
