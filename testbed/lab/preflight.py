"""``testbed check``: before a trial, is every host, agent, camera and arm ready?

A lab operator runs it before the 250-step trial: it reaches each host, lets the
handshake check the agent's protocol version, takes one frame of every arm, reports
each arm's state in one line, and writes a mosaic PNG of all arms' images so a glance
shows a camera that is dark, a crop that is off, or a cube out of its workspace: each
tile is labelled with its robot's name and has the arm's workspace outlined on it (the
violation check's polygon, in the crop's canonical frame), so the glance also says
which arm it is and how far the cube is from leaving its workspace.

A YuMi host's controller reports itself (RobotWare version and options, serial, operating
mode, controller and RAPID state, speed ratio, tasks, our RAPID modules' version against
this checkout's and their world zones); anything that would refuse a push or stop an arm
(manual mode, motors off, a guard stop, a program running, a task stopped by a RAPID
error, a missing option or module, a table box wider than its world zone) is a FAULT
line naming what to fix, and the check fails. Issue 35 adds, per task: the controller's
``tool_pusher`` beside the calibration's ``tool_z_mm`` (more than 1 mm apart: a FAULT, our
RAPID would refuse every program), the world zones known active since the last restart
(a "Testbed Zones Active" entry newer than the last 10045), and the layout through the
arm's model: each table box corner's reach, the rest pose, and the pusher's tip and the
links along the paths the driver commands (rest by joints to the gate at clear height,
straight everywhere else: ``drivers/yumi/paths.py``) against the world zones, a FAULT
with the worst point when a joint move comes within 20 mm of them. The check ends with
every arm at rest; an arm with nothing to do runs the driver's "stay" program, so no
task replays the file its RAM disk still holds.

A host with a real camera (yumi) also sends its FULL frame, written as
``check-<host>.png`` beside the mosaic with each arm's crop box, its workspace (the
task's canonical polygon mapped back through crop and mirror) and, when the arm's
calibration file has a homography, its table box projected through it: a crop that
does not sit on the calibrated table box is a bad crop or a stale calibration. Backends
without a camera frame (the twin) are skipped with a line, not failed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from testbed.core.backend_registry import backend_lines, backend_of
from testbed.core.host_config import HostConfig
from testbed.core.types import ArmObservation, Fault
from testbed.experiments.fleet_config import FleetConfig


def preflight(cfg: FleetConfig, mosaic_path: Path, print_line: Callable[[str], None]) -> bool:
    import cv2

    from testbed.experiments.build import build_hosts

    for line in backend_lines():
        print_line(line)
    hosts = build_hosts(cfg, cfg.trial.seed)
    ok = True
    images: list[np.ndarray] = []
    names: list[str] = []
    try:
        hosts.start()
        obs = hosts.observe()
        for robot in hosts.robot_names:
            o = obs.get(robot)
            if isinstance(o, ArmObservation):
                state = "VIOLATING (needs a hard reset)" if o.violating else "ready"
                mean = float(o.image.mean())
                dark = " DARK IMAGE?" if mean < 10 else ""
                print_line(f"ok    {robot}: frame {o.image.shape}, {state}{dark}")
                images.append(o.image)
                names.append(robot)
            else:
                ok = False
                reason = o.reason if isinstance(o, Fault) else "no answer"
                print_line(f"FAULT {robot}: {reason}")
        hosts.rest()
        for host in cfg.hosts:
            ok = controller_report(hosts, host, print_line) and ok
            ok = full_frame(hosts, host, mosaic_path.parent, print_line) and ok
    finally:
        hosts.close()
    if images:
        picture = mosaic(images, names)
        cv2.imwrite(str(mosaic_path), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
        print_line(f"mosaic of {len(images)} arms -> {mosaic_path}")
    return ok


def full_frame(hosts: Any, host: HostConfig, folder: Path,
               print_line: Callable[[str], None]) -> bool:
    """Write ``folder/check-<host>.png`` (full frame, crops, workspaces); False on a fault.

    Only hosts whose backend has the ``camera_frame`` capability are asked; a host that is down
    was already reported by the observation, so it is not reported twice.
    """
    import cv2

    from drivers.host_fleet import HostCallError
    from testbed.perception import homography as cal

    if not backend_of(host).capabilities.camera_frame:
        return True
    if not hosts.host_status()[host.name].connected:
        return True  # its arms are already FAULT lines
    try:
        frame = hosts.frame(host.name)
    except HostCallError as exc:
        print_line(f"FAULT {host.name}: no full camera frame: {exc}")
        return False
    size = (int(frame.shape[1]), int(frame.shape[0]))
    overlays = []
    for arm in host.arms:
        box_px, note = _table_box_px(host, arm.name, arm.calibration)
        overlays.append(cal.ArmOverlay(arm.name, arm.crop, arm.mirror,
                                       _workspace(), box_px))
        crop = "no crop" if arm.crop is None else f"crop {','.join(map(str, arm.crop))}"
        if arm.crop is not None and (arm.crop[2] > size[0] or arm.crop[3] > size[1]):
            crop += f" OUTSIDE the {size[0]}x{size[1]} frame"
        print_line(f"      {host.name}/{arm.name}: {crop}; {note}")
    path = folder / f"check-{host.name}.png"
    cv2.imwrite(str(path), cal.draw_overlays(frame, overlays))
    print_line(f"full frame {size[0]}x{size[1]} of host {host.name} with crops and "
               f"workspaces -> {path}")
    return True


def controller_report(hosts: Any, host: HostConfig, print_line: Callable[[str], None]
                      ) -> bool:
    """Print what a host's controller says of itself and one FAULT line for each thing to
    fix first; False if there is one. Only backends with the ``controller`` capability
    are asked (a YuMi: RobotWare, options, serial, mode and state, tasks, our RAPID and
    its world zones: ``drivers/yumi/check_report.py``); the backend words its report."""
    from drivers.host_fleet import HostCallError

    plugin = backend_of(host)
    if not plugin.capabilities.controller or not hosts.host_status()[host.name].connected:
        return True
    try:
        info = hosts.describe(host.name)
    except HostCallError as exc:
        print_line(f"FAULT {host.name}: cannot read the controller's state: {exc}")
        return False
    lines, faults = plugin.controller_report(host, info)
    for line in lines:
        print_line(line)
    for why in faults:
        print_line(f"FAULT {host.name}: {why}")
    return not faults


def _workspace() -> Any:
    from testbed.perception.cube import WORKSPACE_POLYGON

    return WORKSPACE_POLYGON


def _table_box_px(host: HostConfig, arm: str, path: str | None) -> tuple[Any, str]:
    """The arm's calibrated table box in the picture, read from its file on the host
    (through the host's own transport); (None, why not) when there is none."""
    import json

    import numpy as np

    from drivers.errors import DriverError
    from testbed.lab.calibrate import read_host_file
    from testbed.perception import homography as cal

    if path is None:
        return None, "no calibration path"
    try:
        where, text = read_host_file(host, path)
    except DriverError as exc:
        return None, f"calibration not read: {exc}"
    if text is None:
        return None, f"no calibration at {where}: run testbed calibrate"
    try:
        d = json.loads(text)
        h = np.asarray(d["homography"], dtype=np.float64).reshape(3, 3)
        box = cal.parse_box(",".join(str(v) for v in d["table_box_mm"]), "table_box_mm")
        return cal.project_box(h, box), f"calibrated table box drawn ({where})"
    except (ValueError, KeyError, TypeError, np.linalg.LinAlgError) as exc:
        return None, f"calibration {where} has no usable homography/table_box_mm ({exc})"


MOSAIC_LABEL_H: Final = 22
"""Pixels of the strip above each tile that carries its robot's name."""
MOSAIC_GAP: Final = 4
"""Background pixels between tiles, so that two arms' crops never read as one."""
MOSAIC_BACKGROUND: Final = (32, 32, 32)
MOSAIC_TEXT: Final = (235, 235, 235)
MOSAIC_OUTLINE: Final = (255, 220, 0)
"""RGB of the workspace outline: the consoles' colour for it (``gui.draw.POLYGON``)."""


def mosaic_size(count: int, image_px: int = 64, cols: int = 4, scale: int = 4
                ) -> tuple[int, int]:
    """(height, width) of the mosaic of ``count`` arms' ``image_px`` crops."""
    rows, used = (count + cols - 1) // cols, min(cols, count)
    side = image_px * scale
    return (rows * (MOSAIC_LABEL_H + side) + (rows - 1) * MOSAIC_GAP,
            used * side + (used - 1) * MOSAIC_GAP)


def mosaic(images: Sequence[np.ndarray], names: Sequence[str], cols: int = 4,
           scale: int = 4) -> np.ndarray:
    """Tile arm images (RGB, upscaled) into one RGB picture for ``testbed check``.

    Each tile sits under a strip with its robot's name (``cell0/left``), and the arm's
    workspace polygon is drawn on it: the crop is in the canonical frame (a mirrored
    arm's too), where the polygon is one for every arm, so a cube near or over the line
    is an arm about to need, or needing, a hard reset.
    """
    if len(names) != len(images):
        raise ValueError(f"mosaic: {len(images)} images but {len(names)} names")
    if not images:
        return np.zeros((64 * scale, 64 * scale, 3), np.uint8)
    side_h, side_w = images[0].shape[0] * scale, images[0].shape[1] * scale
    height, width = mosaic_size(len(images), images[0].shape[0], cols, scale)
    out = np.empty((height, width, 3), np.uint8)
    out[:] = MOSAIC_BACKGROUND
    for k, (img, name) in enumerate(zip(images, names, strict=True)):
        r, c = divmod(k, cols)
        y0 = r * (MOSAIC_LABEL_H + side_h + MOSAIC_GAP)
        x0 = c * (side_w + MOSAIC_GAP)
        _label(out[y0 : y0 + MOSAIC_LABEL_H, x0 : x0 + side_w], name)
        tile = out[y0 + MOSAIC_LABEL_H : y0 + MOSAIC_LABEL_H + side_h, x0 : x0 + side_w]
        tile[:] = np.kron(img[..., :3], np.ones((scale, scale, 1), np.uint8))
        _outline_workspace(tile, thickness=max(1, scale // 2))
    return out


def _label(strip: np.ndarray, text: str) -> None:
    """``text`` in ``strip`` (a view into the mosaic), cut to fit its width."""
    import cv2

    font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.5
    room = strip.shape[1] - 8
    while len(text) > 4 and cv2.getTextSize(text, font, size, 1)[0][0] > room:
        text = text[:-3] + ".."
    canvas = np.ascontiguousarray(strip)
    cv2.putText(canvas, text, (4, MOSAIC_LABEL_H - 7), font, size, MOSAIC_TEXT, 1,
                cv2.LINE_AA)
    strip[:] = canvas


def _outline_workspace(tile: np.ndarray, thickness: int) -> None:
    """The workspace polygon (canonical units) drawn on an upscaled canonical crop."""
    import cv2

    h, w = tile.shape[:2]
    pts = np.round(np.asarray(_workspace()) * (w, h)).astype(np.int32).reshape(-1, 1, 2)
    canvas = np.ascontiguousarray(tile)
    cv2.polylines(canvas, [pts], True, MOSAIC_OUTLINE, thickness, cv2.LINE_AA)
    tile[:] = canvas
