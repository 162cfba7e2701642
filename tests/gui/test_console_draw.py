"""Console and overview frames as arrays: the overlays are where the layout says."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from console_helpers import CUBE_RGB, TABLE_RGB, RequestFactory, arm_image

from gui import draw
from gui.desk import Desk
from gui.layout import ConsoleLayout, CubeMarker
from gui.view import ConsoleView, Phase
from testbed.core.types import SUCCESS_RADIUS, FleetStatus, HumanEstimate, Mode, RobotStatus

LAYOUT = ConsoleLayout(scale=6)
CUBE = CubeMarker((28 / 64, 36 / 64), 0.0, 4 / 64)  # arm_image()'s cube


def bgr(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    return rgb[2], rgb[1], rgb[0]


def near(frame: np.ndarray, point: tuple[int, int], colour: tuple[int, int, int],
         radius: int = 1, tol: int = 40) -> bool:
    """Some pixel within ``radius`` of ``point`` is within ``tol`` of ``colour``."""
    x, y = point
    patch = frame[y - radius : y + radius + 1, x - radius : x + radius + 1].astype(int)
    return bool((np.abs(patch - np.array(colour)).max(axis=-1) <= tol).any())


def view_of(make_request: RequestFactory, kind: str = "teleop", **flags: bool) -> ConsoleView:
    desk = Desk(0, LAYOUT, locate=lambda _img: CUBE)
    desk.assign([make_request(kind=kind)], t=7, serial=1)
    return Desk.with_flags(desk.view(), paused=flags.get("paused", False),
                           confirming_stop=flags.get("confirming_stop", False),
                           stop_requested=flags.get("stop_requested", False))


def test_teleop_frame_overlays(make_request: RequestFactory) -> None:
    view = view_of(make_request)
    assert view.phase is Phase.CHOOSE
    frame = draw.render_console(view, LAYOUT)
    assert frame.shape == (LAYOUT.height, LAYOUT.width, 3) and frame.dtype == np.uint8
    # the arm image, upscaled nearest and turned BGR
    assert tuple(frame[LAYOUT.to_window((0.8, 0.3))[::-1]]) == bgr(TABLE_RGB)
    assert tuple(frame[LAYOUT.to_window((25.5 / 64, 33.5 / 64))[::-1]]) == bgr(CUBE_RGB)
    # workspace polygon: its top edge, and a cut corner's diagonal
    assert near(frame, LAYOUT.to_window((0.6, 0.075)), draw.POLYGON)
    assert near(frame, LAYOUT.to_window((0.175, 0.175)), draw.POLYGON)
    assert not near(frame, LAYOUT.to_window((0.6, 0.4)), draw.POLYGON, radius=3)
    # goal ring of the success radius around the goal (0.7, 0.7)
    gx, gy = LAYOUT.to_window((0.7, 0.7))
    r = round(SUCCESS_RADIUS * LAYOUT.image_px)
    for point in ((gx + r, gy), (gx - r, gy), (gx, gy + r), (gx, gy - r)):
        assert near(frame, point, draw.GOAL)
    # four face markers, filled, at the layout's points
    assert view.markers == LAYOUT.face_points(CUBE)
    yy, xx = np.mgrid[0 : frame.shape[0], 0 : frame.shape[1]]
    for mx, my in view.markers:
        disc = (xx - mx) ** 2 + (yy - my) ** 2 <= 12**2
        share = (np.abs(frame[disc].astype(int) - draw.MARKER).max(axis=-1) == 0).mean()
        assert share > 0.6
    # header and footer carry text
    assert (frame[: LAYOUT.header_h] != draw.BACKGROUND[0]).any(axis=-1).sum() > 500
    assert (frame[LAYOUT.header_h + LAYOUT.image_px :] != draw.BACKGROUND[0]).any(
        axis=-1).sum() > 500


def test_reset_frame_has_banner_and_no_markers(make_request: RequestFactory) -> None:
    view = view_of(make_request, kind="reset")
    assert view.phase is Phase.RESET and view.markers == ()
    frame = draw.render_console(view, LAYOUT)
    y_mid = LAYOUT.header_h + LAYOUT.image_px // 2
    expected = np.array(draw.BANNER_RESET) * draw.BANNER_ALPHA + np.array(
        bgr(TABLE_RGB)) * (1 - draw.BANNER_ALPHA)
    assert np.abs(frame[y_mid, 3].astype(int) - expected).max() <= 2
    for point in LAYOUT.face_points(CUBE):
        assert not near(frame, point, draw.MARKER, radius=2, tol=0)


def test_sent_frame_highlights_the_push(make_request: RequestFactory) -> None:
    desk = Desk(0, LAYOUT, locate=lambda _img: CUBE)
    desk.assign([make_request()], t=7, serial=1)
    desk.register(1, desk.view())
    assert desk.on_push(2, 1)
    view = desk.view()
    assert view.phase is Phase.SENT and view.sent_action == 2
    frame = draw.render_console(view, LAYOUT)
    for k, (mx, my) in enumerate(view.markers):
        colour = draw.MARKER_SENT if k == 2 else draw.MARKER_DIM
        assert tuple(frame[my - 10, mx]) == colour


@pytest.mark.parametrize(
    ("flag", "colour", "row"),
    [("paused", draw.BANNER_PAUSE, LAYOUT.header_h + 40),
     ("confirming_stop", draw.BANNER_STOP, LAYOUT.header_h + LAYOUT.image_px - 50)],
)
def test_pause_and_stop_banners(
    make_request: RequestFactory, flag: str, colour: tuple[int, int, int], row: int
) -> None:
    plain = draw.render_console(view_of(make_request), LAYOUT)
    frame = draw.render_console(view_of(make_request, **{flag: True}), LAYOUT)
    expected = np.array(colour) * draw.BANNER_ALPHA + plain[row, 2] * (1 - draw.BANNER_ALPHA)
    assert np.abs(frame[row, 2].astype(int) - expected).max() <= 2


def test_idle_frame() -> None:
    frame = draw.render_console(ConsoleView(1, Phase.IDLE), LAYOUT)
    x0, y0, _, _ = LAYOUT.image_rect
    assert tuple(frame[y0 + 5, x0 + 5]) == (48, 48, 48)


def test_overview_mosaic_borders_and_counters() -> None:
    modes = [Mode.TELEOP, Mode.AUTONOMOUS, Mode.RESET, Mode.IDLE, Mode.FAULT]
    robots = [
        RobotStatus(f"cell{i // 2}/arm{i % 2}", m, None if m is Mode.FAULT else arm_image(),
                    0 if m is Mode.TELEOP else None)
        for i, m in enumerate(modes)
    ]
    status = FleetStatus(12, 250, 3, 1, 4, 20, 0.125, robots)
    frame = draw.render_overview(status)
    assert frame.shape[:2][::-1] == draw.overview_size(5)
    for i, mode in enumerate(modes):
        x0, y0, x1, y1 = draw.overview_tile_rect(i, 5)
        assert tuple(frame[y0 + 2, x0 + 2]) == draw.MODE_COLOURS[mode]
        assert tuple(frame[y1 - 2, x1 - 2]) == draw.MODE_COLOURS[mode]
        inner = frame[y0 + draw.OVERVIEW_BORDER + 3, x0 + draw.OVERVIEW_BORDER + 3]
        if mode is Mode.FAULT:
            assert tuple(inner) == (60, 60, 60)
        else:
            assert tuple(inner) == bgr(TABLE_RGB)
    # the counters are drawn in the header band
    assert (frame[: draw.OVERVIEW_HEADER_H] != draw.BACKGROUND[0]).any(axis=-1).sum() > 800
    paused = draw.render_overview(status, paused=True)
    assert (paused != frame).any()


def test_the_overview_has_a_line_per_human_with_their_estimates(
    monkeypatch: pytest.MonkeyPatch
) -> None:
    """Under the tiles, one line per human by label: skill, reset time, latency and the
    pushes behind them (``FleetStatus.operators``); a human without one says so."""
    drawn: list[tuple[str, tuple[int, int]]] = []
    put_text = draw._text

    def recording(img: np.ndarray, text: str, org: tuple[int, int], *args: Any,
                  **kwargs: Any) -> None:
        drawn.append((text, org))
        put_text(img, text, org, *args, **kwargs)

    monkeypatch.setattr(draw, "_text", recording)
    robots = [RobotStatus(f"cell0/arm{i}", Mode.AUTONOMOUS, arm_image()) for i in range(3)]
    ops = [HumanEstimate(0, 0.351, 0.01, 5.0, 0.0, 42, 3),
           HumanEstimate(1, 0.125, 0.08, 7.25, 1.9, 17, 2)]
    status = FleetStatus(12, 250, 3, 1, 4, 20, 0.125, robots, operators=ops)
    labels = ["ana (human 0)", "bo (human 1)", "human 2"]
    frame = draw.render_overview(status, humans=labels)
    assert frame.shape[:2][::-1] == draw.overview_size(3, 3)
    assert draw.overview_size(3, 3)[1] > draw.overview_size(3)[1] + 3 * 19
    lines = [(text, org) for text, org in drawn if text.startswith(tuple(labels))]
    assert [t for t, _ in lines] == [
        "ana (human 0):  skill 0.35   reset 5.0 steps   latency 0.0 steps   pushes 42",
        "bo (human 1):  skill 0.12   reset 7.2 steps   latency 1.9 steps   pushes 17",
        "human 2: no estimate yet"]
    _, tiles_end = draw.overview_size(3)
    assert all(tiles_end < y < frame.shape[0] for _, (_, y) in lines)
    band = frame[tiles_end:]
    assert (band != draw.BACKGROUND[0]).any(axis=-1).sum() > 600  # the text is there
    # without labels: "human i" for each estimate; with neither, the overview of before
    drawn.clear()
    plain = draw.render_overview(status)
    assert [t.split(":")[0] for t, _ in drawn if t.startswith("human ")] == [
        "human 0", "human 1"]
    assert plain.shape[:2][::-1] == draw.overview_size(3, 2)
    before = draw.render_overview(FleetStatus(12, 250, robots=robots))
    assert before.shape[:2][::-1] == draw.overview_size(3)


def test_a_waiting_arms_tile_says_how_long_it_has_waited() -> None:
    """A badge in the tile's top right ("waited N", ``RobotStatus.waited``); none on an
    arm that does not wait, so the tiles of a calm fleet are what they were."""
    robots = [RobotStatus("cell0/left", Mode.IDLE, arm_image(), None, 7),
              RobotStatus("cell0/right", Mode.AUTONOMOUS, arm_image())]
    frame = draw.render_overview(FleetStatus(3, 10, robots=robots))
    calm = draw.render_overview(FleetStatus(3, 10, robots=[
        RobotStatus("cell0/left", Mode.IDLE, arm_image()), robots[1]]))
    assert draw.wait_label(7) == "waited 7" and draw.wait_label(None) is None
    x0, y0, x1, y1 = draw.wait_badge_rect(0, 2)
    assert tuple(frame[y0 + 1, x0 + 1]) == draw.WAIT_BADGE
    assert (frame[y0:y1, x0:x1].min(axis=-1) > 120).sum() > 20  # the text, bright on dark
    x1_tile = draw.overview_tile_rect(0, 2)[2]
    assert (frame[:, :x1_tile] != calm[:, :x1_tile]).any()
    assert (frame[:, x1_tile:] == calm[:, x1_tile:]).all(), "no badge on the calm arm"


def test_overview_before_the_first_step() -> None:
    frame = draw.render_overview(None)
    assert frame.ndim == 3 and frame.shape[1] >= draw.OVERVIEW_MIN_WIDTH


def test_the_header_and_the_window_title_name_the_human(
    make_request: RequestFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The person's name, with the index the step rows count by; unnamed: "human i"."""
    from gui.console import window_name

    drawn: list[str] = []
    put_text = draw._text

    def recording(img: np.ndarray, text: str, *args: Any, **kwargs: Any) -> None:
        drawn.append(text)
        put_text(img, text, *args, **kwargs)

    monkeypatch.setattr(draw, "_text", recording)
    desk = Desk(0, LAYOUT, locate=lambda _img: CUBE, name="ana")
    desk.assign([make_request()], t=7, serial=1)
    named = draw.render_console(desk.view(), LAYOUT)
    assert [t for t in drawn if "human" in t] == ["ana (human 0) | cell0 / left"]
    drawn.clear()
    plain = draw.render_console(view_of(make_request), LAYOUT)
    assert [t for t in drawn if "human" in t] == ["human 0 | cell0 / left"]
    assert (named[:20] != plain[:20]).any(), "the name is in the header's pixels"
    drawn.clear()
    draw.render_console(ConsoleView(1, Phase.IDLE, name="bo"), LAYOUT)
    assert [t for t in drawn if "human" in t] == ["bo (human 1)"]
    assert window_name(0, name="ana") == "testbed console - ana (human 0)"
    assert window_name(1) == "testbed console - human 1"


def test_the_header_says_where_the_human_is(
    make_request: RequestFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 44: the place beside the name; a remote person with no arm reads why no
    reset comes to them; the overview's line has the label it is given."""
    drawn: list[str] = []
    put_text = draw._text

    def recording(img: np.ndarray, text: str, *args: Any, **kwargs: Any) -> None:
        drawn.append(text)
        put_text(img, text, *args, **kwargs)

    monkeypatch.setattr(draw, "_text", recording)
    desk = Desk(1, LAYOUT, locate=lambda _img: CUBE, name="bo", place="remote")
    desk.assign([make_request(human=1)], t=7, serial=1)
    remote = draw.render_console(desk.view(), LAYOUT)
    assert [t for t in drawn if "human" in t] == ["bo (human 1), remote | cell0 / left"]
    drawn.clear()
    draw.render_console(ConsoleView(0, Phase.IDLE, name="ana", place="on_site"), LAYOUT)
    assert {"ana (human 0), on site", "no arm assigned"} <= set(drawn)
    drawn.clear()
    draw.render_console(ConsoleView(1, Phase.IDLE, name="bo", place="remote"), LAYOUT)
    assert {"bo (human 1), remote",
            "no arm assigned (remote: teleop only, no resets)"} <= set(drawn)
    desk = Desk(1, LAYOUT, locate=lambda _img: CUBE, name="bo")
    desk.assign([make_request(human=1)], t=7, serial=1)
    assert (draw.render_console(desk.view(), LAYOUT)[:20] != remote[:20]).any()
    drawn.clear()
    draw.render_overview(FleetStatus(3, 10), humans=["ana (human 0), on site",
                                                     "bo (human 1), remote"])
    assert [t for t in drawn if "(human" in t] == [
        "ana (human 0), on site: no estimate yet", "bo (human 1), remote: no estimate yet"]


def test_why_this_arm_asked_names_the_failure_alarm_and_its_threshold() -> None:
    """Issue 36, item 4: an arm the monitor algorithm called shows the alarm as the
    reason, with the score and the threshold it passed (both consoles draw these lines)."""
    reason = {"c": 0.0, "a": 1.0, "s": 0.7, "u": 0.0, "r": 0.0, "alarm_score": 0.7,
              "alarm_threshold": 0.5, "uncertainty": 0.1, "risk": 0.2}
    why, values = draw._reason_lines(reason, (0.0, 1.0, 0.7, 0.0, 0.0), 400)
    assert why == "why: A (failure alarm)"
    assert "alarm=0.70" in values and "thr=0.50" in values
