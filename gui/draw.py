"""Drawing the console and overview frames: pure functions from data to BGR arrays.

Nothing here opens a window, so every frame can be built and checked headless (the
tests read overlays back at known pixels) and the window processes only ever show
finished arrays. Works with either OpenCV build: drawing is in both.

Colours are BGR (what ``cv2.imshow`` expects); arm images arrive RGB
(``testbed.core.types``) and are flipped once, here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from gui.keys import ARROW_NAMES, KEY_NAMES
from gui.layout import ConsoleLayout, CubeMarker
from gui.scene import workspace_polygon
from gui.view import ConsoleView, Phase, human_label, place_tag
from testbed.core.humans import REMOTE
from testbed.core.types import (
    SUCCESS_RADIUS,
    FleetStatus,
    HumanEstimate,
    InterventionKind,
    Mode,
    RobotStatus,
)

Frame = npt.NDArray[np.uint8]
Colour = tuple[int, int, int]

BACKGROUND: Final[Colour] = (32, 32, 32)
"""Grey on purpose: frames are filled with one scalar (fast)."""
TEXT: Final[Colour] = (235, 235, 235)
DIM_TEXT: Final[Colour] = (160, 160, 160)
POLYGON: Final[Colour] = (0, 220, 255)
GOAL: Final[Colour] = (255, 0, 255)
CUBE: Final[Colour] = (255, 255, 255)
MARKER: Final[Colour] = (255, 255, 0)
MARKER_SENT: Final[Colour] = (0, 255, 0)
MARKER_DIM: Final[Colour] = (110, 110, 110)
TELEOP_TEXT: Final[Colour] = (255, 170, 60)
RESET_TEXT: Final[Colour] = (0, 160, 255)
BANNER_RESET: Final[Colour] = (0, 110, 210)
BANNER_DONE: Final[Colour] = (40, 140, 40)
BANNER_PAUSE: Final[Colour] = (140, 90, 30)
BANNER_STOP: Final[Colour] = (30, 30, 200)
BANNER_ALPHA: Final = 0.8
MODE_COLOURS: Final[dict[Mode, Colour]] = {
    Mode.AUTONOMOUS: (80, 180, 60),
    Mode.TELEOP: (255, 140, 0),
    Mode.RESET: (0, 140, 255),
    Mode.IDLE: (0, 0, 230),
    Mode.FAULT: (160, 160, 160),
}
DIRECTION_NAMES: Final = ("up", "left", "down", "right")
REASON_WORDS: Final = {"c": "constraint violation", "u": "uncertainty", "r": "risk",
                       "a": "failure alarm", "s": "score"}
SIGNAL_ABBREVIATIONS: Final = {"uncertainty": "unc", "risk": "risk", "goal_risk": "grisk",
                               "alarm_score": "alarm", "alarm_threshold": "thr"}
FONT: Final = cv2.FONT_HERSHEY_SIMPLEX


def _text(
    img: Frame, text: str, org: tuple[int, int], colour: Colour = TEXT, scale: float = 0.45,
    thickness: int = 1,
) -> None:
    cv2.putText(img, text, org, FONT, scale, colour, thickness, cv2.LINE_AA)


def _fit(text: str, width_px: int, scale: float = 0.45, thickness: int = 1) -> str:
    """Cut a line so it fits in ``width_px`` (a margin of 6 px each side)."""
    room = width_px - 12
    if cv2.getTextSize(text, FONT, scale, thickness)[0][0] <= room:
        return text
    while len(text) > 4 and cv2.getTextSize(text + "..", FONT, scale, thickness)[0][0] > room:
        text = text[:-1]
    return text + ".."


def _paste_upscaled(image: npt.NDArray[np.uint8], area: Frame) -> None:
    """RGB ``image`` -> BGR, nearest-neighbour upscaled into ``area`` (a full-width band)."""
    bgr = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2BGR)
    size = (area.shape[1], area.shape[0])
    if area.flags["C_CONTIGUOUS"]:
        cv2.resize(bgr, size, dst=area, interpolation=cv2.INTER_NEAREST)
    else:
        area[:] = cv2.resize(bgr, size, interpolation=cv2.INTER_NEAREST)


def _banner(img: Frame, lines: Sequence[str], colour: Colour, y_centre: int) -> None:
    """A translucent band across the whole width with centred lines of text."""
    line_h = 24
    h = line_h * len(lines) + 14
    y0 = max(0, y_centre - h // 2)
    y1 = min(img.shape[0], y0 + h)
    band = img[y0:y1]  # full width, so contiguous: blended in place
    solid = np.empty_like(band)
    solid[:] = colour
    cv2.addWeighted(band, 1.0 - BANNER_ALPHA, solid, BANNER_ALPHA, 0.0, dst=band)
    for i, line in enumerate(lines):
        (w, _), _ = cv2.getTextSize(line, FONT, 0.6, 2)
        x = max(4, (img.shape[1] - w) // 2)
        _text(img, line, (x, y0 + 24 + i * line_h), TEXT, 0.6, 2)


def _reason_lines(reason: dict[str, float], key: Sequence[float], width: int) -> list[str]:
    short = [(k, v) for k, v in reason.items() if len(k) <= 2]
    long_ = [(k, v) for k, v in reason.items() if len(k) > 2]
    lead = next((k for k, v in short if v > 0), None)
    if lead is not None:
        why = f"why: {lead.upper()} ({REASON_WORDS.get(lead.lower(), lead)})"
    elif short:
        why = "why: no positive priority entry"
    else:
        why = "why: " + (", ".join(f"{v:.2f}" for v in key) if key else "not given")
    values = "  ".join(f"{k.upper()}={v:.2f}" for k, v in short)
    extra = "  ".join(f"{SIGNAL_ABBREVIATIONS.get(k, k[:6])}={v:.2f}" for k, v in long_)
    second = "  ".join(s for s in (values, extra) if s)
    return [_fit(why, width), _fit(second, width)]


def _draw_cube(img: Frame, layout: ConsoleLayout, cube: CubeMarker) -> None:
    if not cube.found:
        return
    cx, cy = layout.to_window(cube.centre)
    half = cube.half * layout.image_px
    c, s = math.cos(cube.yaw), math.sin(cube.yaw)
    corners = [
        (cx + c * dx * half - s * dy * half, cy + s * dx * half + c * dy * half)
        for dx, dy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    pts = np.round(np.array(corners)).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(img, [pts], True, CUBE, 1, cv2.LINE_AA)


def _draw_markers(img: Frame, layout: ConsoleLayout, view: ConsoleView) -> None:
    if not view.markers:
        return
    origin = layout.to_window(view.cube.centre) if view.cube else None
    r = layout.marker_radius
    for k, (mx, my) in enumerate(view.markers):
        if view.phase is Phase.SENT:
            colour = MARKER_SENT if k == view.sent_action else MARKER_DIM
        else:
            colour = MARKER
        if origin is not None:
            cv2.arrowedLine(img, origin, (mx, my), colour, 1, cv2.LINE_AA, tipLength=0.15)
        cv2.circle(img, (mx, my), r, colour, -1, cv2.LINE_AA)
        (w, h), _ = cv2.getTextSize(KEY_NAMES[k], FONT, 0.55, 2)
        _text(img, KEY_NAMES[k], (mx - w // 2, my + h // 2), (0, 0, 0), 0.55, 2)


def _header(img: Frame, layout: ConsoleLayout, view: ConsoleView) -> None:
    w = layout.width
    req = view.request
    host, _, arm = (req.robot.partition("/") if req else ("", "", ""))
    tag = place_tag(view.place)
    who = (human_label(view.human, view.name) + (f", {tag}" if tag else "")
           + (f" | {host} / {arm or host}" if req else ""))
    _text(img, _fit(who, w - 70), (6, 17), TEXT, 0.5, 1)
    if view.t is not None:
        _text(img, f"t={view.t}", (w - 64, 17), DIM_TEXT)
    if req is None:
        idle = "no arm assigned" + (" (remote: teleop only, no resets)"
                                    if view.place == REMOTE else "")
        _text(img, _fit(idle, w), (6, 36), DIM_TEXT)
        return
    teleop = req.kind is InterventionKind.TELEOP
    name = "TELEOP" if teleop else "HARD RESET"
    timer = f"step {req.served + 1}/{req.min_steps} (t_{'T' if teleop else 'R'}={req.min_steps})"
    line = f"{name}  {timer}" + (f"  +{view.queued} queued" if view.queued else "")
    _text(img, _fit(line, w), (6, 36), TELEOP_TEXT if teleop else RESET_TEXT, 0.5, 1)
    for i, text in enumerate(_reason_lines(dict(req.reason), req.key, w)):
        _text(img, text, (6, 54 + 16 * i), DIM_TEXT if i else TEXT, 0.42)


def _footer(img: Frame, layout: ConsoleLayout, view: ConsoleView) -> None:
    y0 = layout.header_h + layout.image_px
    w = layout.width
    instructions = {
        Phase.IDLE: "waiting for the fleet to assign you an arm",
        Phase.CHOOSE: " ".join(
            f"{KEY_NAMES[k]}/{ARROW_NAMES[k]}" for k in range(4)) + ", or click a marker",
        Phase.SENT: (
            f"sent: {DIRECTION_NAMES[view.sent_action]} - waiting for the arm"
            if view.sent_action is not None else "no push in time: the arm waits"),
        Phase.RESET: "put the cube back, then press Enter",
        Phase.RESET_CONFIRMED: "reset confirmed - waiting for the fleet",
    }[view.phase]
    _text(img, _fit(instructions, w), (6, y0 + 18), TEXT)
    state = "PAUSED" if view.paused else "running"
    _text(img, _fit(f"p/space: pause   Esc: stop   [{state}]", w), (6, y0 + 38), DIM_TEXT)


def render_console(view: ConsoleView, layout: ConsoleLayout) -> Frame:
    """The whole console window of one human, BGR, ``(layout.height, layout.width, 3)``."""
    img = np.full((layout.height, layout.width, 3), BACKGROUND[0], dtype=np.uint8)
    x0, y0, x1, y1 = layout.image_rect
    req = view.request
    area = img[y0:y1, x0:x1]
    if req is not None:
        _paste_upscaled(req.observation.image, area)
        poly = np.round(
            [layout.to_window((float(x), float(y))) for x, y in workspace_polygon()]
        ).astype(np.int32)
        cv2.polylines(img, [poly.reshape(-1, 1, 2)], True, POLYGON, 2, cv2.LINE_AA)
        goal = layout.to_window(req.observation.goal)
        cv2.circle(img, goal, round(SUCCESS_RADIUS * layout.image_px), GOAL, 2, cv2.LINE_AA)
        cv2.drawMarker(img, goal, GOAL, cv2.MARKER_CROSS, 10, 1)
        if view.cube is not None:
            _draw_cube(img, layout, view.cube)
        _draw_markers(img, layout, view)
    else:
        area[:] = (48, 48, 48)
    centre_y = (y0 + y1) // 2
    if view.phase is Phase.RESET:
        _banner(img, ["HARD RESET", "put the cube back near the centre",
                      "of the workspace, then press Enter"], BANNER_RESET, centre_y)
    elif view.phase is Phase.RESET_CONFIRMED:
        _banner(img, ["reset confirmed", "waiting for the fleet"], BANNER_DONE, centre_y)
    elif view.phase is Phase.IDLE:
        _banner(img, ["no arm assigned", "please wait"], (70, 70, 70), centre_y)
    if view.paused:
        _banner(img, ["PAUSED", "p or space: resume"], BANNER_PAUSE, y0 + 40)
    if view.stop_requested:
        _banner(img, ["STOPPING THE TRIAL"], BANNER_STOP, y1 - 40)
    elif view.confirming_stop:
        _banner(img, ["stop the trial?", "y: stop   any other key: go on"], BANNER_STOP, y1 - 50)
    _header(img, layout, view)
    _footer(img, layout, view)
    return img


# ---- overview -----------------------------------------------------------------------
OVERVIEW_TILE_SCALE: Final = 3
OVERVIEW_BORDER: Final = 6
OVERVIEW_LABEL_H: Final = 20
OVERVIEW_HEADER_H: Final = 52
OVERVIEW_MIN_WIDTH: Final = 620
OVERVIEW_COLUMNS: Final = 4
OVERVIEW_HUMAN_H: Final = 20
"""Height of one human's line under the tiles (their estimates, ``FleetStatus.operators``)."""
WAIT_BADGE: Final[Colour] = (20, 20, 20)
"""The box behind a waiting arm's "waited N" in its tile: dark, so the count reads on any
table image."""


def overview_tile_rect(index: int, num_robots: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of robot ``index``'s tile, border included, in the overview."""
    del num_robots  # the grid is fixed-width; kept for callers that size windows
    img_px = 64 * OVERVIEW_TILE_SCALE
    tw = img_px + 2 * OVERVIEW_BORDER
    th = tw + OVERVIEW_LABEL_H
    row, col = divmod(index, OVERVIEW_COLUMNS)
    x0 = col * tw
    y0 = OVERVIEW_HEADER_H + row * th
    return x0, y0, x0 + tw, y0 + tw


def overview_size(num_robots: int, num_humans: int = 0) -> tuple[int, int]:
    """(width, height) of the overview for a fleet of this size: the tiles, then one
    line per human (``num_humans``; none: the tiles alone)."""
    n = max(num_robots, 1)
    cols = min(n, OVERVIEW_COLUMNS)
    rows = math.ceil(n / OVERVIEW_COLUMNS)
    tw = 64 * OVERVIEW_TILE_SCALE + 2 * OVERVIEW_BORDER
    lines = num_humans * OVERVIEW_HUMAN_H + (6 if num_humans else 0)
    return (max(cols * tw, OVERVIEW_MIN_WIDTH),
            OVERVIEW_HEADER_H + rows * (tw + OVERVIEW_LABEL_H) + lines)


def human_line(label: str, estimate: HumanEstimate | None) -> str:
    """One human's line of the overview: who, and what their records say so far (the
    web overview's row has the same figures)."""
    if estimate is None:
        return f"{label}: no estimate yet"
    return (f"{label}:  skill {estimate.skill:.2f}   reset {estimate.reset_steps:.1f} steps"
            f"   latency {estimate.latency_steps:.1f} steps   pushes {estimate.pushes}")


def _human_lines(img: Frame, labels: Sequence[str], status: FleetStatus | None,
                 num_robots: int) -> None:
    """Each human's line under the tiles, by index."""
    estimates = {e.human: e for e in status.operators} if status is not None else {}
    _, top = overview_size(num_robots)
    for h, label in enumerate(labels):
        text = _fit(human_line(label, estimates.get(h)), img.shape[1] - 16)
        _text(img, text, (8, top + 6 + (h + 1) * OVERVIEW_HUMAN_H - 5), DIM_TEXT, 0.42)


def wait_label(waited: int | None) -> str | None:
    """A waiting arm's badge: the steps it has waited for a human (``RobotStatus.waited``,
    its row's ``"waited"``; the web page's queue shows the same number); None when it
    does not wait."""
    return None if waited is None else f"waited {int(waited)}"


def wait_badge_rect(index: int, num_robots: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of arm ``index``'s wait badge: the top right of its image, inside
    the mode border, where it hides no part of the label under the tile."""
    _, y0, x1, _ = overview_tile_rect(index, num_robots)
    b = OVERVIEW_BORDER
    return x1 - b - 84, y0 + b, x1 - b, y0 + b + 18


def _tile(img: Frame, index: int, n: int, robot: RobotStatus) -> None:
    x0, y0, x1, y1 = overview_tile_rect(index, n)
    colour = MODE_COLOURS.get(robot.mode, (200, 200, 200))
    img[y0:y1, x0:x1] = colour
    b = OVERVIEW_BORDER
    inner = img[y0 + b : y1 - b, x0 + b : x1 - b]
    if robot.image is not None:
        _paste_upscaled(robot.image, inner)
    else:
        inner[:] = (60, 60, 60)
        _text(img, "no image", (x0 + b + 8, (y0 + y1) // 2), TEXT)
    who = f" h{robot.human}" if robot.human is not None else ""
    label = _fit(f"{robot.robot} {robot.mode.value}{who}", x1 - x0)
    _text(img, label, (x0 + 3, y1 + 15), colour, 0.42)
    badge = wait_label(robot.waited)
    if badge is not None:
        bx0, by0, bx1, by1 = wait_badge_rect(index, n)
        img[by0:by1, bx0:bx1] = WAIT_BADGE
        _text(img, badge, (bx0 + 4, by1 - 5), TEXT, 0.42)


def render_overview(
    status: FleetStatus | None,
    *,
    paused: bool = False,
    confirming_stop: bool = False,
    stop_requested: bool = False,
    num_robots: int | None = None,
    humans: Sequence[str] | None = None,
) -> Frame:
    """The fleet overview: counters, every arm's latest image with a mode border, then
    one line per human with their estimates (``humans``: each human's label, by index;
    None: "human i" for each estimate in ``status.operators``)."""
    robots = list(status.robots) if status is not None else []
    n = num_robots if num_robots is not None else len(robots)
    if humans is None:
        count = len(status.operators) if status is not None else 0
        humans = [human_label(h, None) for h in range(count)]
    width, height = overview_size(n, len(humans))
    img = np.full((height, width, 3), BACKGROUND[0], dtype=np.uint8)
    if status is None:
        _text(img, "fleet overview: waiting for the first step", (8, 22), TEXT, 0.5)
    else:
        line1 = (f"t {status.t}/{status.steps}   successes {status.successes}   "
                 f"hard resets {status.hard_resets}")
        line2 = (f"idle {status.idle_time}   human actions {status.human_actions}   "
                 f"ROHE {status.rohe:.3f}")
        _text(img, _fit(line1, width, 0.5), (8, 20), TEXT, 0.5)
        _text(img, _fit(line2, width, 0.5), (8, 42), TEXT, 0.5)
        for i, robot in enumerate(robots[:n]):
            _tile(img, i, n, robot)
    _human_lines(img, humans, status, n)
    if paused or (status is not None and status.paused):
        _banner(img, ["PAUSED", "p or space: resume"], BANNER_PAUSE, height // 2)
    if stop_requested:
        _banner(img, ["STOPPING THE TRIAL"], BANNER_STOP, height - 30)
    elif confirming_stop:
        _banner(img, ["stop the trial?", "y: stop   any other key: go on"], BANNER_STOP,
                height - 40)
    return img
