"""Real windows under Xvfb, driven by xdotool as a person would drive them.

Each human's key goes to that human's arm (per-window attribution), a click on a face
marker pushes that face, Enter completes a hard reset, p pauses, Esc then y stops; the
first key or Enter of an intervention carries its time to first action (``waited_s``).
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from console_helpers import ActCall, RequestFactory, arm_image

from gui import StopRequested
from gui.console import ConsoleHumans
from gui.view import Phase
from gui.xdo import Xvfb, click, find_window, press
from testbed.core.types import FleetStatus, Mode, RobotStatus

pytestmark = pytest.mark.xvfb


def until_taken(send: Callable[[], None], taken: Callable[[], bool], tries: int = 3) -> None:
    """Send an input; send it again (as a person would) if the console has not taken it.

    xdotool's synthetic events were lost about once in 30 full-suite runs (the window got
    no event at all: the first tests of this module, once in CI). A repeated input is
    harmless: it carries the frame's seq, and a frame already answered ignores it.
    """
    for _ in range(tries):
        send()
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            if taken():
                return
            time.sleep(0.02)


@pytest.fixture(scope="module")
def console(xvfb: Xvfb) -> Iterator[ConsoleHumans]:
    with ConsoleHumans(num_humans=2, displays=[xvfb.display] * 2) as c:
        yield c


@pytest.fixture(scope="module")
def windows(console: ConsoleHumans, xvfb: Xvfb) -> list[str]:
    return [find_window(console.window_name(h), display=xvfb.display) for h in range(2)]


def test_keys_and_clicks_reach_the_right_human(
    console: ConsoleHumans, windows: list[str], xvfb: Xvfb, make_request: RequestFactory
) -> None:
    reqs = [make_request("cell0/left", 0), make_request("cell1/right", 1)]
    call = ActCall(lambda: console.act(reqs, 0))
    for h in range(2):
        assert console.wait_for_prompt(h).phase is Phase.CHOOSE
    until_taken(lambda: press(windows[1], "w", display=xvfb.display),
                lambda: console.snapshot(1).phase is Phase.SENT)
    time.sleep(0.3)
    assert call.waiting, "human 0 has not answered: act() must still wait"
    assert console.snapshot(0).phase is Phase.CHOOSE, "human 1's key reached human 0"
    x, y = console.face_click_point(0, 3)
    until_taken(lambda: click(windows[0], x, y, display=xvfb.display),
                lambda: not call.waiting)
    out = call.join()
    assert out["cell1/right"].action == 0
    assert out["cell0/left"].action == 3


def test_arrow_keys(
    console: ConsoleHumans, windows: list[str], xvfb: Xvfb, make_request: RequestFactory
) -> None:
    for t, (key, action) in enumerate([("Left", 1), ("Down", 2), ("x", 2)], start=1):
        call = ActCall(lambda t=t: console.act([make_request("cell0/right", 0)], t))
        console.wait_for_prompt(0)
        until_taken(lambda key=key: press(windows[0], key, display=xvfb.display),
                    lambda call=call: not call.waiting)
        assert call.join()["cell0/right"].action == action


def test_click_on_each_face(
    console: ConsoleHumans, windows: list[str], xvfb: Xvfb, make_request: RequestFactory
) -> None:
    for k in range(4):
        img = arm_image(cube_px=(20 + 4 * k, 30))
        call = ActCall(lambda k=k, img=img: console.act(
            [make_request("cell1/left", 1, image=img)], 10 + k))
        console.wait_for_prompt(1)
        point = console.face_click_point(1, k)
        until_taken(lambda point=point: click(windows[1], *point, display=xvfb.display),
                    lambda call=call: not call.waiting)
        assert call.join()["cell1/left"].action == k


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_enter_completes_a_hard_reset(
    console: ConsoleHumans, windows: list[str], xvfb: Xvfb, make_request: RequestFactory
) -> None:
    req = make_request("cell1/left", 1, "reset")
    t0 = time.monotonic()
    assert console.act([req], 20)["cell1/left"].reset_done is False
    assert time.monotonic() - t0 < 1.0, "a reset must not make act() wait"
    assert console.wait_for_prompt(1).phase is Phase.RESET
    press(windows[1], "Return", display=xvfb.display)
    deadline = time.monotonic() + 5
    while console.snapshot(1).phase is not Phase.RESET_CONFIRMED:
        assert time.monotonic() < deadline, "Enter was not taken"
        time.sleep(0.02)
    later = make_request("cell1/left", 1, "reset", served=1)
    assert console.act([later], 21)["cell1/left"].reset_done is True
    assert console.act([later], 22)["cell1/left"].reset_done is False


DELAY_S = 0.4
"""How long the test's human looks at a window before answering it."""


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_waited_s_from_the_window_to_the_first_key_and_enter(
    console: ConsoleHumans, windows: list[str], xvfb: Xvfb, make_request: RequestFactory
) -> None:
    def teleop(t: int, served: int, delay_s: float) -> Any:
        call = ActCall(lambda: console.act(
            [make_request("cell0/left", 0, served=served)], t))
        console.wait_for_prompt(0)  # the window reported the frame painted
        time.sleep(delay_s)
        until_taken(lambda: press(windows[0], "w", display=xvfb.display),
                    lambda: not call.waiting)
        return call.join()["cell0/left"]

    first = teleop(24, 0, DELAY_S)
    assert first.action == 0
    assert first.waited_s is not None and DELAY_S <= first.waited_s < DELAY_S + 2.0
    later = teleop(25, 1, 0.0)
    assert later.action == 0 and later.waited_s is None

    assert console.act([make_request("cell1/left", 1, "reset")], 26)[
        "cell1/left"].waited_s is None
    console.wait_for_prompt(1)
    time.sleep(DELAY_S)
    until_taken(lambda: press(windows[1], "Return", display=xvfb.display),
                lambda: console.snapshot(1).phase is Phase.RESET_CONFIRMED)
    done = console.act([make_request("cell1/left", 1, "reset", served=1)], 27)["cell1/left"]
    assert done.reset_done
    assert done.waited_s is not None and DELAY_S <= done.waited_s < DELAY_S + 2.0
    held = console.act([make_request("cell1/left", 1, "reset", served=2)], 28)["cell1/left"]
    assert held.waited_s is None


def test_pause_blocks_act_until_resumed(
    console: ConsoleHumans, windows: list[str], xvfb: Xvfb, make_request: RequestFactory
) -> None:
    call = ActCall(lambda: console.act([make_request("cell0/left", 0)], 30))
    console.wait_for_prompt(0)
    press(windows[1], "p", display=xvfb.display)  # any window pauses the whole fleet
    deadline = time.monotonic() + 5
    while not console.paused:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    console.wait_for_prompt(0)  # the paused frame is on screen
    press(windows[0], "d", display=xvfb.display)  # ignored while paused
    time.sleep(0.3)
    assert call.waiting
    press(windows[0], "space", display=xvfb.display)
    deadline = time.monotonic() + 5
    while console.paused:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    console.wait_for_prompt(0)  # the unpaused frame is on screen
    press(windows[0], "a", display=xvfb.display)
    assert call.join()["cell0/left"].action == 1


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_teleop_timeout_answers_none(
    console: ConsoleHumans, make_request: RequestFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(console, "teleop_timeout_s", 0.3)
    t0 = time.monotonic()
    out = console.act([make_request("cell0/left", 0)], 40)
    assert out["cell0/left"].action is None
    assert 0.25 <= time.monotonic() - t0 < 3.0
    assert console.snapshot(0).phase is Phase.SENT


def test_overview_window(console: ConsoleHumans, xvfb: Xvfb) -> None:
    status = FleetStatus(5, 250, 1, 0, 0, 3, 0.2, [
        RobotStatus("cell0/left", Mode.TELEOP, arm_image(), 0),
        RobotStatus("cell0/right", Mode.AUTONOMOUS, arm_image()),
    ])
    console.show(5, status)
    assert find_window(console.overview_name, display=xvfb.display)


def test_esc_then_y_stops(xvfb: Xvfb, make_request: RequestFactory) -> None:
    with ConsoleHumans(num_humans=1, overview=False, displays=[xvfb.display]) as c:
        win = find_window(c.window_name(0), display=xvfb.display)
        call = ActCall(lambda: c.act([make_request()], 0))
        c.wait_for_prompt(0)
        press(win, "Escape", display=xvfb.display)
        press(win, "n", display=xvfb.display)  # any other key: go on
        time.sleep(0.3)
        assert call.waiting and not c.stop_requested
        press(win, "Escape", display=xvfb.display)
        press(win, "y", display=xvfb.display)
        with pytest.raises(StopRequested):
            call.join()
        assert c.stop_requested
        with pytest.raises(StopRequested):
            c.show(1, FleetStatus(1, 10))


def test_a_lost_window_stops_gracefully(xvfb: Xvfb, make_request: RequestFactory) -> None:
    with ConsoleHumans(num_humans=1, overview=False, displays=[xvfb.display]) as c:
        call = ActCall(lambda: c.act([make_request()], 0))
        c.wait_for_prompt(0)
        pid: Any = c._windows[0].pid
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(StopRequested, match="human 0"):
            call.join()
