"""``testbed check``: before a trial, is every host, agent, camera and arm ready?

A lab operator runs it before the 250-step trial: it reaches each host, lets the
handshake check the agent's protocol version, looks at every arm, reports each arm's
state in one line, and writes a mosaic PNG of all arms' images so a glance shows a
camera that is dark, a crop that is off, or a cube out of its workspace: each tile is
labelled with its robot's name and has the arm's workspace outlined on it (the
violation check's polygon, in the crop's canonical frame), so the glance also says
which arm it is and how far the cube is from leaving its workspace.

It never moves an arm (issue 43). A host whose backend has the ``controller``
capability (a YuMi) is only asked read-only calls: ``describe`` (the controller's
report, below; it moves nothing, an arm in the camera's view is a FAULT naming the fix:
``drivers/yumi/backend.py``) and ``frame`` (the full camera frame, whose crops the
check cuts here as the agent does); it is never observed (a YuMi's picture step sends
an arm in view to rest) nor rested, and an agent asked nothing that moves an arm does
not rest one at bye (``drivers/agent/agent_session.py`` ``MAY_MOVE``). Other hosts (a
simulated cell) are observed once, in a fleet of their own.

A YuMi host's controller reports itself (RobotWare version and options, serial, operating
mode, controller and RAPID state, speed ratio, tasks, our RAPID modules' version against
this checkout's and their world zones); anything that would refuse a push or stop an arm
(manual mode, motors off, a guard stop, a program running, a task stopped by a RAPID
error, a missing option or module, a table box wider than its world zone, an arm in the
camera's view) is a FAULT line naming what to fix, and the check fails. Issue 35 adds,
per task: the controller's ``tool_pusher`` beside the calibration's ``tool_z_mm`` (more
than 1 mm apart: a FAULT, our RAPID would refuse every program), the world zones known
active since the last restart (a "Testbed Zones Active" entry newer than the last
restart), and the layout through the arm's model: each table box corner's reach, the
rest pose, and the pusher's tip and the links along the paths the driver commands
(``drivers/yumi/paths.py``) against the world zones, a FAULT with the worst point when a
joint move comes within 20 mm of them. That report is the part every trial runs first
(``testbed.experiments.controller_gate``): its FAULT lines refuse the trial.

A host with a real camera (yumi) also has its FULL frame written as
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
from testbed.core.types import IMAGE_SIZE, ArmObservation, Fault
from testbed.experiments.controller_gate import controller_hosts, controller_report
from testbed.experiments.fleet_config import FleetConfig

Say = Callable[[str], None]


def preflight(cfg: FleetConfig, mosaic_path: Path, print_line: Say) -> bool:
    """Check every host and arm of ``cfg`` (see the module doc), write the mosaic to
    ``mosaic_path`` (and each camera host's full frame beside it); False on any FAULT."""
    import cv2

    for line in backend_lines():
        print_line(line)
    looked_at = controller_hosts(cfg.hosts)
    named = {h.name for h in looked_at}
    observed = [h for h in cfg.hosts if h.name not in named]
    tiles: dict[str, np.ndarray] = {}
    ok = True
    if observed:
        ok = _observe(cfg, observed, tiles, print_line) and ok
    if looked_at:
        ok = _look(cfg, looked_at, tiles, mosaic_path.parent, print_line) and ok
    names = [r for r in (f"{h.name}/{a.name}" for h in cfg.hosts for a in h.arms)
             if r in tiles]
    if names:
        picture = mosaic([tiles[r] for r in names], names)
        cv2.imwrite(str(mosaic_path), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
        print_line(f"mosaic of {len(names)} arms -> {mosaic_path}")
    return ok


def _observe(cfg: FleetConfig, hosts_cfg: Sequence[HostConfig], tiles: dict[str, np.ndarray],
             print_line: Say) -> bool:
    """Hosts without a controller capability (a simulated cell): one observation of
    every arm, each arm's line and image; False if an arm has none."""
    from testbed.experiments.build import build_hosts

    hosts = build_hosts(cfg, cfg.trial.seed, hosts=hosts_cfg)
    ok = True
    try:
        hosts.start()
        obs = hosts.observe()
        for robot in hosts.robot_names:
            o = obs.get(robot)
            if isinstance(o, ArmObservation):
                print_line(_arm_line(robot, o.image, o.violating))
                tiles[robot] = o.image
            else:
                ok = False
                reason = o.reason if isinstance(o, Fault) else "no answer"
                print_line(f"FAULT {robot}: {reason}")
    finally:
        hosts.close()
    return ok


def _look(cfg: FleetConfig, hosts_cfg: Sequence[HostConfig], tiles: dict[str, np.ndarray],
          folder: Path, print_line: Say) -> bool:
    """Controller hosts, read-only: each one's report and FAULT lines
    (``controller_report``), then its full frame and its arms' crops cut from it
    (:func:`full_frame`); False on any FAULT."""
    from testbed.experiments.build import build_hosts

    hosts = build_hosts(cfg, cfg.trial.seed, hosts=hosts_cfg)
    ok = True
    try:
        hosts.start()
        for host in hosts_cfg:
            faults = controller_report(hosts, host, print_line)
            for line in faults:
                print_line(line)
            ok = not faults and ok
            ok = full_frame(hosts, host, folder, print_line, tiles) and ok
    finally:
        hosts.close()  # bye: asked nothing that moves an arm, the agents rest none
    return ok


def _arm_line(robot: str, image: np.ndarray, violating: bool) -> str:
    state = "VIOLATING (needs a hard reset)" if violating else "ready"
    dark = " DARK IMAGE?" if float(image.mean()) < 10 else ""
    return f"ok    {robot}: frame {image.shape}, {state}{dark}"


def arm_crop(frame: np.ndarray, crop: tuple[int, int, int, int], mirror: bool) -> np.ndarray:
    """An arm's canonical RGB image from its host's full BGR frame, as the agent cuts it
    (``drivers/yumi/backend.py`` ``_crop``: the crop box, resized to ``IMAGE_SIZE`` with
    area averaging, mirrored left-right for a mirrored arm)."""
    import cv2

    x0, y0, x1, y1 = crop
    img = cv2.resize(frame[y0:y1, x0:x1], (IMAGE_SIZE, IMAGE_SIZE),
                     interpolation=cv2.INTER_AREA)
    img = img[:, ::-1, ::-1] if mirror else img[:, :, ::-1]
    return np.ascontiguousarray(img)


def _violating(image: np.ndarray) -> bool:
    """The agent's own judgement of a first picture: no cube found, or a cube out of
    its workspace (``testbed.perception.cube``)."""
    from testbed.perception.cube import find_cube, is_violation

    pose = find_cube(image)
    return pose is None or bool(is_violation(pose))


def full_frame(hosts: Any, host: HostConfig, folder: Path, print_line: Say,
               tiles: dict[str, np.ndarray] | None = None) -> bool:
    """Write ``folder/check-<host>.png`` (full frame, crops, workspaces); False on a fault.
    ``tiles``: each arm's canonical crop cut from the frame (:func:`arm_crop`), with its
    line, for the mosaic.

    Only hosts whose backend has the ``camera_frame`` capability are asked; a host that is
    down was already reported by its controller's check, so it is not reported twice.
    """
    import cv2

    from drivers.host_fleet import HostCallError
    from testbed.perception import homography as cal

    if not backend_of(host).capabilities.camera_frame:
        print_line(f"      {host.name}: no full camera frame (its backend has none): no "
                   f"images of its arms")
        return True
    if not hosts.host_status()[host.name].connected:
        return True  # its controller's check said so
    try:
        frame = hosts.frame(host.name)
    except HostCallError as exc:
        print_line(f"FAULT {host.name}: no full camera frame: {exc}")
        return False
    size = (int(frame.shape[1]), int(frame.shape[0]))
    ok = True
    overlays = []
    for arm in host.arms:
        box_px, note = _table_box_px(host, arm.name, arm.calibration)
        overlays.append(cal.ArmOverlay(arm.name, arm.crop, arm.mirror,
                                       _workspace(), box_px))
        crop = "no crop" if arm.crop is None else f"crop {','.join(map(str, arm.crop))}"
        outside = arm.crop is not None and (arm.crop[2] > size[0] or arm.crop[3] > size[1])
        if outside:
            crop += f" OUTSIDE the {size[0]}x{size[1]} frame"
        print_line(f"      {host.name}/{arm.name}: {crop}; {note}")
        robot = f"{host.name}/{arm.name}"
        if outside:
            ok = False
            print_line(f"FAULT {robot}: {crop}: fix the host's crop box")
        elif arm.crop is not None and tiles is not None:
            tiles[robot] = arm_crop(frame, arm.crop, arm.mirror)
            print_line(_arm_line(robot, tiles[robot], _violating(tiles[robot])))
    path = folder / f"check-{host.name}.png"
    cv2.imwrite(str(path), cal.draw_overlays(frame, overlays))
    print_line(f"full frame {size[0]}x{size[1]} of host {host.name} with crops and "
               f"workspaces -> {path}")
    return ok


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
