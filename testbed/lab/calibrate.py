"""``testbed calibrate``: fit one arm's image-to-table homography with the arm itself.

Why it looks like this: a lab calibrates an arm on day one and after anything moves
(camera bumped, table shifted). The arm's pusher carries an ArUco marker 30 mm above
its TCP; with the TCP at z = 10 mm the marker lies in the cube-top plane, which is the
plane perception measures the cube in. So the command starts that host's agent in
calibration mode (the arm may have no homography yet), moves the TCP over a grid inside
a safe box, takes a full camera frame at each point, and fits pixel -> TCP (x, y) with
RANSAC (``testbed.perception.homography``). It prints the reprojection errors, proposes the crop
box and checks the rest pose is out of view, then writes the calibration file on the
host (atomically, by the agent) keeping every other key of the existing file. Every arm
goes to rest at the end, whatever happens.

    load fleet -> host, arm, existing file (read through the host's own transport)
    -> agent --calibrate ARM -> rest, frame (rest out of view?)
    -> the marker once, over the box's centre (not seen: stop there)
    -> per grid point: move_tcp, frame, marker -> fit -> thresholds
    -> the gate's joints (read at the gate on the way to the first point) -> save -> rest

``calibrate(cfg, opts, say)`` is the calibration itself; ``testbed calibrate``
(``cmd_calibrate``) parses and checks its arguments into ``CalibrateOptions`` and calls
it, and a rehearsal calls it for every arm with ``default_options(host, arm)``.

Over 450 lines, on purpose: ``testbed calibrate`` is one procedure for one arm (drive to
the grid, see the marker, fit, judge, write), with its options and outcome; the
homography's maths is in ``testbed/perception/homography.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from testbed.core.atomic import atomic_write_json
from testbed.core.backend_registry import backend_of
from testbed.core.config import ConfigError
from testbed.core.host_config import HostConfig
from testbed.experiments.fleet_config import FleetConfig
from testbed.perception import homography as cal

CUBE_TOP_MM = 40.0
"""The plane perception sees the cube's centre in (a 40 mm cube's top face)."""
EXIT_FAILED = 1


TABLE_FRAME = "the robot's world frame (wobj0)"
"""The one name of the frame every box, TCP point and table point is in (``--box``,
``table_box_mm``, the homography's output): ABB's world frame of the YuMi, which the
driver's targets and readings use (``wobj0``; robot/README.md, "Frames": not either
arm's base frame). ``testbed calibrate --help`` and the docs say the same words
(tests/testbed/test_calibrate_box.py)."""

GRID_INSET_MM = 10.0
"""How far inside the safe box the calibration's grid lies (its points, not its fit)."""


@dataclass(frozen=True)
class CalibrateOptions:
    """The parsed, validated arguments of one calibration."""

    host: str
    arm: str
    box: cal.Box | None
    grid: tuple[int, int] = (5, 4)
    z_mm: float = 10.0
    marker_above_tcp_mm: float = 30.0
    marker_id: int = 0
    out: Path | None = None
    image: Path | None = None
    max_px: float = 2.0
    max_mm: float = 3.0
    min_markers: int = cal.MIN_MARKERS


@dataclass
class Sighting:
    index: int
    """1-based number of the grid point (as printed)."""
    target_mm: tuple[float, float, float]
    tcp_mm: tuple[float, float, float] | None = None
    pixel: tuple[float, float] | None = None
    note: str = ""


@dataclass
class CalibrationOutcome:
    """What a calibration found (also when it failed: ``error`` says why)."""

    sightings: list[Sighting] = field(default_factory=list)
    used: list[Sighting] = field(default_factory=list)
    """The sightings the fit was given (marker found, TCP reported), in order."""
    fit: cal.HomographyFit | None = None
    box: cal.Box | None = None
    crop: cal.PixelBox | None = None
    frame_size: tuple[int, int] | None = None
    rest_marker: tuple[float, float] | None = None
    """Where the marker was seen with every arm at rest (None: out of view, as it must)."""
    data: dict[str, Any] | None = None
    saved_path: str | None = None
    error: str | None = None
    last_frame: Any = None


# -- arguments ----------------------------------------------------------------------
def calibration_target(cfg: FleetConfig, host_name: str, arm: str) -> HostConfig:
    """The yumi host ``host_name`` of the fleet, checked to have ``arm`` with a
    calibration path; ConfigError (exit 2) naming ``--host`` or ``--arm`` otherwise."""
    hosts = {h.name: h for h in cfg.hosts}
    if host_name not in hosts:
        raise ConfigError(f"--host: no host {host_name!r} in the fleet; it has "
                          f"{', '.join(hosts)}")
    host = hosts[host_name]
    if not backend_of(host).capabilities.calibration:
        raise ConfigError(f"--host: host {host.name} runs the {host.backend} backend, which "
                          "has no calibration (only backends that can move a TCP to a point "
                          "and keep a calibration file are calibrated)")
    arms = {a.name: a for a in host.arms}
    if arm not in arms:
        raise ConfigError(f"--arm: host {host.name} has no arm {arm!r}; it has "
                          f"{', '.join(arms)}")
    if not arms[arm].calibration:
        raise ConfigError(f"--arm: arm {arm} of host {host.name} has no calibration "
                          f"path in the config (arms[].calibration)")
    return host


def default_marker_id(arm: str) -> int:
    """The ArUco id on ``arm``'s pusher when ``--marker-id`` is not given (left 0, right 1)."""
    if arm not in cal.DEFAULT_MARKER_IDS:
        raise ConfigError(f"--marker-id: arm {arm!r} has no default marker id "
                          f"(left 0, right 1); give --marker-id")
    return cal.DEFAULT_MARKER_IDS[arm]


def default_options(host: str, arm: str) -> CalibrateOptions:
    """What ``testbed calibrate --config FILE --host HOST --arm ARM`` runs: every other
    argument at its default (the safe box: the arm's file's table box, else the backend's
    default for the arm; a 5x4 grid, ...)."""
    return CalibrateOptions(host=host, arm=arm, box=None, marker_id=default_marker_id(arm))


def resolve(cfg: FleetConfig, args: argparse.Namespace) -> tuple[HostConfig, CalibrateOptions]:
    """The host and validated options, or ConfigError (exit 2) naming the argument."""
    host = calibration_target(cfg, args.host, args.arm)
    try:
        box = None if args.box is None else cal.parse_box(args.box)
        grid = cal.parse_grid(args.grid)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    for flag, v in (("--z", args.z), ("--marker-above-tcp", args.marker_above_tcp)):
        if not math.isfinite(v) or v < 0:
            raise ConfigError(f"{flag}: must be a finite number >= 0, got {v}")
    for flag, v in (("--max-px", args.max_px), ("--max-mm", args.max_mm)):
        if not math.isfinite(v) or v <= 0:
            raise ConfigError(f"{flag}: must be a finite number > 0, got {v}")
    if grid[0] * grid[1] < cal.MIN_MARKERS:
        raise ConfigError(f"--grid: {args.grid} gives {grid[0] * grid[1]} points; need at "
                          f"least {cal.MIN_MARKERS}")
    marker_id = default_marker_id(args.arm) if args.marker_id is None else args.marker_id
    if not 0 <= marker_id < 50:
        raise ConfigError(f"--marker-id: {marker_id} is not in {cal.MARKER_DICT} (0..49)")
    return host, CalibrateOptions(
        host=host.name, arm=args.arm, box=box, grid=grid, z_mm=float(args.z),
        marker_above_tcp_mm=float(args.marker_above_tcp), marker_id=marker_id,
        out=Path(args.out) if args.out else None, image=Path(args.image) if args.image else None,
        max_px=float(args.max_px), max_mm=float(args.max_mm))


# -- the host's existing file ------------------------------------------------------------
_READ_SCRIPT = (
    "import json, os, sys\n"
    "p = os.path.expanduser(os.path.expandvars(sys.argv[1]))\n"
    "try:\n"
    "    t = open(p, encoding='utf-8').read()\n"
    "except FileNotFoundError:\n"
    "    t = None\n"
    "sys.stdout.write(json.dumps({'path': p, 'text': t}))\n")


def read_host_file(host: HostConfig, path: str, timeout_s: float = 20.0) -> tuple[str, str | None]:
    """(expanded path, text or None if absent) of a file on ``host``.

    Read through the host's own transport (a local subprocess, or one SSH exec channel
    with the same key and known_hosts as the agent), so the lab's rest pose and speeds
    survive a calibration over SSH too. Raises DriverError on a link failure.
    """
    from drivers.errors import TransportError
    from drivers.transport import LocalTransport, make_transport

    python = LocalTransport.python_for(host) if host.transport == "local" else host.python
    t = make_transport(host)
    t.open([python, "-c", _READ_SCRIPT, path], timeout_s)
    buf = bytearray()
    deadline = time.monotonic() + timeout_s
    try:
        while chunk := t.read(65536, deadline):
            buf += chunk
    finally:
        t.close()
    try:
        reply = json.loads(buf.decode("utf-8"))
        return str(reply["path"]), reply["text"]
    except (ValueError, KeyError, TypeError):
        raise TransportError(f"host {host.name}: cannot read {path}: "
                             f"{t.stderr_tail().strip() or 'no answer'}") from None


def existing_calibration(host: HostConfig, arm: str, say: Callable[[str], None]
                         ) -> dict[str, Any] | None:
    """The arm's current calibration file as a dict, None if there is none yet."""
    path = next(a.calibration for a in host.arms if a.name == arm)
    assert path is not None
    where, text = read_host_file(host, path)
    if text is None:
        say(f"no calibration file yet at {where} on host {host.name}: a new one is written")
        return None
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise ConfigError(f"{where} on host {host.name} is not JSON ({exc}); fix or remove "
                          f"it first") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{where} on host {host.name} is not a JSON object")
    return data


# -- the driving loop --------------------------------------------------------------------
def _fmt(v: Any, nd: int = 1) -> str:
    return "(" + ", ".join(f"{float(x):.{nd}f}" for x in v) + ")"


def run_calibration(fleet: Any, opts: CalibrateOptions, box: cal.Box,
                    existing: Mapping[str, Any] | None, say: Callable[[str], None]
                    ) -> CalibrationOutcome:
    """Drive the arm over the grid on a started ``fleet`` and fit; never raises for a
    failure of the calibration itself (``outcome.error``), only for a dead host.

    The caller sends every arm to rest afterwards (whatever happened here).
    """
    from drivers.host_fleet import HostCallError

    out = CalibrationOutcome(box=box)
    fleet.rest()
    frame = fleet.frame(opts.host)
    out.frame_size = (int(frame.shape[1]), int(frame.shape[0]))
    out.rest_marker = cal.find_marker(frame, opts.marker_id)
    out.last_frame = frame
    if not _marker_seen_at_centre(fleet, opts, box, out, say):
        return out  # the arm looked once, over the box's centre, and goes no further
    # 10 mm inside the box: its corners are the edge of the arm's reach with the 184.2 mm
    # pusher (the twin: a joint 0.1-1 deg past its limit near the inner edge)
    points = cal.grid_points(box, opts.grid, inset_mm=GRID_INSET_MM)
    for k, (x, y) in enumerate(points, 1):
        s = Sighting(k, (x, y, opts.z_mm))
        out.sightings.append(s)
        head = f"  point {k:2d}/{len(points)} {_fmt((x, y))} mm"
        try:
            tcp = fleet.move_tcp(opts.host, opts.arm, (x, y, opts.z_mm))
        except HostCallError as exc:
            if not fleet.host_status()[opts.host].connected:
                raise  # the host is gone: no point in trying the other points
            s.note = f"refused: {exc}"  # this point only (outside the host's box?)
            say(f"{head}: {s.note}")
            continue
        s.tcp_mm = (float(tcp[0]), float(tcp[1]), float(tcp[2]))
        frame = fleet.frame(opts.host)
        out.last_frame = frame
        s.pixel = cal.find_marker(frame, opts.marker_id)
        off = math.dist(s.tcp_mm[:2], (x, y))
        reached = f"tcp {_fmt(s.tcp_mm)}" + (f" ({off:.1f} mm off)" if off > 0.5 else "")
        seen = f"marker {_fmt(s.pixel, 2)} px" if s.pixel else "marker NOT FOUND"
        say(f"{head}: {reached}, {seen}")
    good = [s for s in out.sightings if s.pixel is not None and s.tcp_mm is not None]
    out.used = good
    say(f"markers found: {len(good)}/{len(points)}")
    if len(good) < opts.min_markers:
        out.error = (f"only {len(good)} of {len(points)} points showed marker {opts.marker_id}"
                     f" (need {opts.min_markers}); is the pusher's marker in the camera's view "
                     f"over the box? check --box, --marker-id and the light")
        return out
    try:
        out.fit = cal.fit_homography([s.pixel for s in good if s.pixel],
                                     [s.tcp_mm[:2] for s in good if s.tcp_mm],
                                     min_points=opts.min_markers)
    except cal.CalibrationError as exc:
        out.error = str(exc)
        return out
    fit = out.fit
    out.crop = cal.propose_crop(fit.homography, box, out.frame_size)
    out.data = cal.calibration_data(existing, fit, box)
    return out


def _marker_seen_at_centre(fleet: Any, opts: CalibrateOptions, box: cal.Box,
                           out: CalibrationOutcome, say: Callable[[str], None]) -> bool:
    """The marker looked for once, with the pusher over the box's centre, before the arm
    is driven through the grid (issue 44): a marker that is missing, of another id or
    dictionary, hidden by the gripper or unlit fails here in one move, with what to
    check, instead of after twenty. False (``out.error`` set) when it is not seen."""
    from drivers.host_fleet import HostCallError

    centre = ((box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0, opts.z_mm)
    try:
        fleet.move_tcp(opts.host, opts.arm, centre)
    except HostCallError as exc:
        if not fleet.host_status()[opts.host].connected:
            raise
        say(f"  marker check over the box's centre {_fmt(centre[:2])} mm: refused ({exc}); "
            f"the grid follows")
        return True
    frame = fleet.frame(opts.host)
    out.last_frame = frame
    pixel = cal.find_marker(frame, opts.marker_id)
    if pixel is None:
        out.error = (f"marker {opts.marker_id} ({cal.MARKER_DICT}) not seen with the pusher "
                     f"over the box's centre {_fmt(centre[:2])} mm, so the arm did not go "
                     f"through the grid: check that the marker is on the pusher's cap and "
                     f"not hidden by the gripper (robot/README.md, 'The calibration "
                     f"marker'), --marker-id, the light and the camera's view")
        return False
    say(f"  marker {opts.marker_id} seen over the box's centre at {_fmt(pixel, 2)} px: "
        f"the grid follows")
    return True


def report(out: CalibrationOutcome, opts: CalibrateOptions, current_crop: Any,
           say: Callable[[str], None]) -> bool:
    """Print the fit's figures and proposals; True if within the thresholds."""
    fit = out.fit
    assert fit is not None and out.crop is not None and out.frame_size is not None
    s = fit.summary()
    if fit.n_outliers:
        bad = [s.index for s, ok in zip(out.used, fit.inliers, strict=True) if not ok]
        say(f"RANSAC rejected {fit.n_outliers} sighting(s) (points {bad}): a marker seen "
            f"where no other point agrees, or a TCP that did not reach; {fit.n_inliers} kept")
    say(f"reprojection error over {fit.n_inliers} points: median {s['median_px']:.2f} px / "
        f"{s['median_mm']:.2f} mm, max {s['max_px']:.2f} px / {s['max_mm']:.2f} mm")
    cur = "none" if current_crop is None else ",".join(str(v) for v in current_crop)
    say(f"proposed crop for {opts.arm}: {','.join(str(v) for v in out.crop)} "
        f"(config: {cur}) = the square around the box's projection")
    if out.rest_marker is not None:
        say(f"rest pose: IN VIEW (marker {opts.marker_id} seen at {_fmt(out.rest_marker)} px "
            f"with every arm at rest); move the rest pose out of the camera's view")
    else:
        say("rest pose: out of view (marker not seen with every arm at rest)")
    ok = s["max_px"] <= opts.max_px and s["max_mm"] <= opts.max_mm
    if not ok:
        say(f"FAILED: max error {s['max_px']:.2f} px / {s['max_mm']:.2f} mm is over "
            f"--max-px {opts.max_px:g} / --max-mm {opts.max_mm:g}; nothing written")
    return ok


def _overlay(out: CalibrationOutcome, opts: CalibrateOptions, mirror: bool) -> Any:
    from testbed.perception.cube import WORKSPACE_POLYGON

    fit = out.fit
    marks = np.array([s.pixel for s in out.sightings if s.pixel is not None]).reshape(-1, 2)
    arm = cal.ArmOverlay(opts.arm, out.crop, mirror, WORKSPACE_POLYGON,
                         cal.project_box(fit.homography, out.box) if fit is not None
                         and out.box is not None else None, marks)
    return cal.draw_overlays(out.last_frame, [arm])


def _check_inside(box: cal.Box, table_box: cal.Box, whose: str, fix: str) -> None:
    """``--box`` must lie in the table box the host drives the arm in: the host refuses
    TCP points outside it, so say so now rather than at every point."""
    tb = table_box
    if box[0] < tb[0] or box[1] < tb[1] or box[2] > tb[2] or box[3] > tb[3]:
        raise ConfigError(f"--box: {_fmt(box)} leaves the table box {_fmt(tb)}, {whose}, "
                          f"and the host refuses TCP points outside it; give a box inside it "
                          f"or {fix}")


def make_fleet(host: HostConfig, arm: str) -> Any:
    """A one-host fleet whose agent runs every arm of the host in calibration mode.

    All of them, not only ``arm``: on day one the sibling has no homography yet either,
    and calibration mode never observes or pushes, so the sibling loses nothing (it is
    rested, and its file is read only for its box and rest pose).
    """
    from drivers.host_fleet import HostFleet

    arms = [arm, *(a.name for a in host.arms if a.name != arm)]
    return HostFleet([host], trial_seed=0, calibrating={host.name: arms})


def _safe_box(opts: CalibrateOptions, existing: Mapping[str, Any] | None, where: str,
              default: cal.Box | None, backend: str) -> tuple[cal.Box, str]:
    """The box the grid lies in and where it came from (said before anything moves).

    The host drives the arm in its file's ``table_box_mm``, or, when the file has none,
    in the backend's default table box for the arm (``default``: a YuMi's shipped one,
    ``drivers/yumi/arm_calibration.py``), so a first calibration needs no ``--box``.
    ``--box`` must lie inside that box; with neither a file's box nor a default,
    ``--box`` is required (ConfigError naming it)."""
    host_box: cal.Box | None = None
    whose = fix = ""
    if existing is not None and "table_box_mm" in existing:
        try:
            host_box = cal.parse_box(",".join(str(v) for v in existing["table_box_mm"]),
                                     "table_box_mm")
        except ValueError as exc:
            if opts.box is None:
                raise ConfigError(f"{where}: {exc}") from None
            # with --box: the host's provisional calibration says what is wrong with it
        whose = f"the table_box_mm of {where}"
        fix = "widen table_box_mm in that file on the host first"
    elif default is not None:
        host_box = default
        whose = (f"the {backend} backend's default for arm {opts.arm} ({where} has no "
                 f"table_box_mm)")
        fix = "write table_box_mm into that file on the host first"
    if opts.box is not None:
        if host_box is not None:
            _check_inside(opts.box, host_box, whose, fix)
        return opts.box, "--box"
    if host_box is None:
        raise ConfigError(f"--box: required, the arm's calibration ({where}) has no "
                          f"table_box_mm and the {backend} backend has no default box for "
                          f"arm {opts.arm}; give --box x0,y0,x1,y1 (mm, {TABLE_FRAME})")
    if existing is not None and "table_box_mm" in existing:
        return host_box, f"{where}'s table_box_mm; --box for another inside it"
    return host_box, (f"the {backend} backend's default for arm {opts.arm}: {where} has no "
                      f"table_box_mm yet; --box for another inside it")


def _announce(host: str, opts: CalibrateOptions, box: cal.Box, source: str,
              say: Callable[[str], None]) -> None:
    """What is about to move, where, and what the person at the table must keep clear."""
    plane = opts.z_mm + opts.marker_above_tcp_mm
    say(f"calibrate {host}/{opts.arm}: {opts.grid[0]}x{opts.grid[1]} points at z = "
        f"{opts.z_mm:g} mm; marker {cal.MARKER_DICT} id {opts.marker_id} in the plane "
        f"z = {plane:g} mm")
    say(f"box {_fmt(box)} mm (x0, y0, x1, y1 in {TABLE_FRAME}): {source}")
    if abs(plane - CUBE_TOP_MM) > 2.0:
        say(f"warning: the marker plane (z = {plane:g} mm) is not the cube's top face "
            f"(z = {CUBE_TOP_MM:g} mm); pixels of the cube will map with a parallax error")
    say("keep the table clear of cubes under the grid: the pusher goes down to "
        f"z = {opts.z_mm:g} mm at every point")


def with_tool(fleet: Any, host: HostConfig, arm: str, data: Mapping[str, Any],
              say: Callable[[str], None]) -> dict[str, Any]:
    """``data`` with ``tool_z_mm``: the file's when it has one, else the controller's
    ``tool_pusher`` (read through the agent's ``describe``); said either way, and a
    calibration whose tool differs from the controller's by more than 1 mm is said too
    (``testbed check`` fails on it: every program would be refused)."""
    out = dict(data)
    task = str(out.get("task", f"T_ROB_{'L' if arm.startswith('l') else 'R'}"))
    try:
        tool = (fleet.describe(host.name).get("controller", {}).get("rapid", {})
                .get(task, {}).get("tool"))
    except Exception as exc:  # an agent without describe(): the host side fills it
        say(f"tool: the controller's tool_pusher not read ({exc})")
        return out
    if tool is None:
        return out
    z = float(tool["trans"][2])
    if "tool_z_mm" not in out:
        out["tool_z_mm"] = z
        say(f"tool: tool_z_mm {z:g} from the controller's tool_pusher ({task})")
    elif abs(float(out["tool_z_mm"]) - z) > 1.0:
        say(f"FAULT {host.name}: the calibration's tool_z_mm {out['tool_z_mm']} is not the "
            f"controller's tool_pusher z {z:g} ({task}): every program will be refused; "
            f"measure the pusher and write one value into both (robot/README.md, 'The tool "
            f"frame')")
    return out


def with_gate(fleet: Any, host: HostConfig, arm: str, data: Mapping[str, Any],
              say: Callable[[str], None]) -> dict[str, Any]:
    """``data`` with ``gate_joints_deg``: the joints the controller reported with the arm
    at its gate during this calibration (the agent drove it there first and read its
    jointtarget: ``drivers/yumi/backend.py``, ``_measure_gate``), read through the
    agent's ``describe``; said either way. Measured at the gate of the file the agent
    started with: when the new table box (``--box``) moves the default gate elsewhere,
    the measured gate's point is kept as ``gate_xy_mm`` (if it lies in the new box; else
    no joints are written, and ``testbed check`` FAULTs until the arm is calibrated
    again with the new box in its file). A backend without a gate says nothing."""
    from drivers.yumi.paths import gate_xy

    out = dict(data)
    try:
        lay = (fleet.describe(host.name).get("layout") or {}).get(arm) or {}
    except Exception as exc:  # an agent without describe(): nothing measured to write
        say(f"gate: the joints measured at the gate not read ({exc})")
        return out
    if not lay.get("gate_measured"):
        return out
    joints = [float(v) for v in lay["gate_joints_deg"]]
    gx, gy = (float(v) for v in lay["gate_xy_mm"])
    box = [float(v) for v in out["table_box_mm"]]
    fx, fy = gate_xy(box, out.get("gate_xy_mm"))
    if math.dist((fx, fy), (gx, gy)) > 1.0:
        if not (box[0] <= gx <= box[2] and box[1] <= gy <= box[3]):
            say(f"FAULT {host.name}: the gate's joints were measured at ({gx:.0f}, {gy:.0f}) "
                f"mm, outside the new table box {_fmt(box, 0)}: no gate_joints_deg written; "
                f"calibrate {arm} again (its file now has the new box)")
            out.pop("gate_joints_deg", None)
            return out
        out["gate_xy_mm"] = [gx, gy]
        say(f"gate: gate_xy_mm ({gx:.0f}, {gy:.0f}) kept where its joints were measured "
            f"(the new table box's default gate is ({fx:.0f}, {fy:.0f}))")
    out["gate_joints_deg"] = joints
    shown = ", ".join(f"{v:g}" for v in joints)
    say(f"gate: gate_joints_deg [{shown}] read from the controller with the arm at its gate "
        f"({gx:.0f}, {gy:.0f}, {float(lay.get('z_clear_mm', 0.0)):g}) mm")
    return out


def verify_layout(fleet: Any, host: HostConfig, opts: CalibrateOptions,
                  out: CalibrationOutcome, say: Callable[[str], None]) -> bool:
    """The new calibration's layout, with the other arms' files, through the backend's
    kinematics (a YuMi: every table box corner reachable with the pusher down, the rest
    pose above the world zone, out of view, clear of the other arm; ``testbed check``
    judges the same): its lines and one FAULT line each. The fit is still written (it is
    right about the camera); the FAULT lines say what to change before a trial, which
    ``testbed check`` then fails on. False on a FAULT. Another arm not calibrated yet (its
    file has no gate joints: a lab calibrates one arm after the other) is one line saying
    so, not a FAULT of this arm's calibration; ``testbed check`` FAULTs it until then."""
    from drivers.errors import DriverError

    assert out.data is not None
    cals: dict[str, Any] = {opts.arm: {**out.data, "homography": out.fit.homography.tolist()
                                       if out.fit is not None else out.data.get("homography")}}
    for a in host.arms:
        if a.name != opts.arm and a.calibration:
            try:
                _, text = read_host_file(host, a.calibration)
                cals[a.name] = json.loads(text) if text else None
            except (DriverError, ValueError):
                cals[a.name] = None
    info: dict[str, Any] = {"camera": {"size": list(out.frame_size or ())}}
    try:
        info.update(fleet.describe(host.name))
        info["camera"] = {"size": list(out.frame_size or ())}
    except Exception as exc:  # the zones stay unknown: their comparison is skipped
        say(f"layout: the controller's zones not read ({exc})")
    lines, faults = backend_of(host).layout_report(
        host, {a: c for a, c in cals.items() if isinstance(c, dict)}, info)
    for line in lines:
        say(line.strip())
    later = {a for a, c in cals.items()
             if a != opts.arm and isinstance(c, dict) and "gate_joints_deg" not in c}
    for a in sorted(later):
        say(f"layout: arm {a} is not calibrated yet (no gate joints): testbed calibrate "
            f"--arm {a} next; testbed check FAULTs until then")
    faults = [f for f in faults
              if not any(f.startswith(f"arm {a}: its calibration has no 'gate_joints_deg'")
                         for a in later)]
    for why in faults:
        say(f"FAULT {host.name}: {why}")
    return not faults


def _fit_and_save(fleet: Any, host: HostConfig, opts: CalibrateOptions, box: cal.Box,
                  existing: Mapping[str, Any] | None, say: Callable[[str], None]) -> int:
    """On the started ``fleet``: drive, fit, report, and write the file if it is good."""
    arm_cfg = next(a for a in host.arms if a.name == opts.arm)
    out = run_calibration(fleet, opts, box, existing, say)
    if out.error is not None:
        say(f"FAILED: {out.error}; nothing written")
        return EXIT_FAILED
    ok = report(out, opts, arm_cfg.crop, say)
    if out.data is not None:
        out.data = with_tool(fleet, host, opts.arm, out.data, say)
        out.data = with_gate(fleet, host, opts.arm, out.data, say)
        verify_layout(fleet, host, opts, out, say)
    if opts.image is not None and out.last_frame is not None:
        import cv2

        opts.image.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(opts.image), _overlay(out, opts, arm_cfg.mirror))
        say(f"picture -> {opts.image}")
    if not ok:
        return EXIT_FAILED
    assert out.data is not None
    out.saved_path = str(fleet.save_calibration(opts.host, opts.arm, out.data))
    say(f"calibration -> {out.saved_path} (on host {opts.host})")
    if opts.out is not None:
        atomic_write_json(opts.out, out.data)
        say(f"copy -> {opts.out}")
    return 0


def calibrate(cfg: FleetConfig, opts: CalibrateOptions,
              say: Callable[[str], None] = print) -> int:
    """Calibrate arm ``opts.arm`` of host ``opts.host`` of ``cfg`` (see the module doc),
    every line to ``say``: 0 when the file was written on the host, ``EXIT_FAILED``
    when the calibration failed (nothing written); ConfigError (exit 2) for a host, an
    arm, a box or an existing file that cannot be calibrated with. Every arm of the host
    goes to rest at the end, whatever happens.

    ``testbed calibrate`` (``cmd_calibrate``) and a rehearsal's first morning
    (``testbed.lab.rehearsal``) both run this.
    """
    from drivers.errors import DriverError

    host = calibration_target(cfg, opts.host, opts.arm)
    arm_cfg = next(a for a in host.arms if a.name == opts.arm)
    try:
        existing = existing_calibration(host, opts.arm, say)
    except DriverError as exc:  # unreachable: one line naming it, as testbed check's
        say(f"FAULT {host.name}: cannot read its calibration file: {exc}")
        return EXIT_FAILED
    backend = backend_of(host)
    box, source = _safe_box(opts, existing, str(arm_cfg.calibration),
                            backend.default_table_box(opts.arm, existing), backend.name)
    _announce(host.name, opts, box, source, say)
    fleet = make_fleet(host, opts.arm)
    try:
        fleet.start()
        status = fleet.host_status()[host.name]
        if not status.connected:
            say(f"FAILED: host {host.name} did not start: {status.error}")
            return EXIT_FAILED
        return _fit_and_save(fleet, host, opts, box, existing, say)
    except DriverError as exc:
        say(f"FAILED: {exc}")
        return EXIT_FAILED
    finally:
        try:
            fleet.rest()  # every arm, whatever happened
        finally:
            fleet.close()


def cmd_calibrate(args: argparse.Namespace) -> int:
    """``testbed calibrate``: the parsed arguments checked, then :func:`calibrate`."""
    from testbed.experiments.fleet_config import load_fleet

    cfg = load_fleet(args.config)
    _, opts = resolve(cfg, args)
    return calibrate(cfg, opts, print)
