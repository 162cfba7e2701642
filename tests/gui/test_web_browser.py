"""The web console in a real browser: Debian's Chromium, headless, driven by Selenium.

First, pages against a ``WebHumans`` in this process: the page paints the very pixels
the OpenCV console draws, a page without a token shows nothing, a key on one page and a
tap on the other push their own human's arms, and a human with no arm sees that they
wait and the fleet's counters and modes, live, instead of an empty image, under their
own name, with the names of those who hold the arms.

Then end to end, ``testbed trial --humans web`` on the twin: the trial runs in its own
process; two headless Chromium windows open the two humans' URLs and answer as people
would: human 0 (ana, in the config's ``humans.people``, on site) presses ``w`` on the
keyboard (push up, action 0), human 1 (bo, remote: teleop only) clicks face marker 3 on
the image (push right), and a person given a hard-reset frame presses the "Reset done"
button. Midway, human 1's page is closed. The records must show exactly those pushes on
the arms each human held, hard resets completed by the button, every one ana's (bo's
page never shows one, before the trial or in it: issue 44), and after the close: human 1
away, never newly assigned, and the trial going on to its last step; the printed links
and places and the overview name both humans and say where each is.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w
from console_helpers import ActCall, arm_image
from selenium.webdriver.common.keys import Keys

from gui.console_core import OVERVIEW
from gui.desk import Desk
from gui.draw import render_console
from gui.web import WebHumans
from gui.web.browser import (
    browser_missing,
    chromium,
    click_frame_point,
    open_console,
    page_state,
    press_key,
)
from testbed.core.types import FleetStatus, HumanEstimate, Mode, RobotStatus
from testbed.records.steps import read_steps

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[2]
TOKENS = ["human0-token-for-the-browser-test", "human1-token-for-the-browser-test"]
STEPS = 24
CLOSE_AFTER_STEP = 12
PUSH_OF_HUMAN = {0: 0, 1: 3}


@pytest.fixture(scope="module")
def pages() -> Iterator[tuple[Any, Any]]:
    if browser_missing():
        pytest.fail(f"missing {', '.join(browser_missing())}: apt-get install -y chromium "
                    "chromium-driver (scripts/setup.sh --dev does it)")
    with chromium() as a, chromium() as b:
        yield a, b


@pytest.fixture
def web() -> Iterator[WebHumans]:
    with WebHumans(2, port=0, announce=None, away_timeout_s=30.0) as console:
        yield console


@pytest.fixture
def named_web() -> Iterator[WebHumans]:
    """Two humans the config names (``humans.people``): the pages say who is who."""
    with WebHumans(2, names=["ana", "bo"], port=0, announce=None,
                   away_timeout_s=30.0) as console:
        yield console


CANVAS_SHA256 = """
const done = arguments[arguments.length - 1];
const c = document.getElementById(arguments[0]);
const rgba = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
const rgb = new Uint8Array(c.width * c.height * 3);
for (let i = 0, j = 0; i < rgba.length; i += 4, j += 3) {
  rgb[j] = rgba[i]; rgb[j + 1] = rgba[i + 1]; rgb[j + 2] = rgba[i + 2];
}
crypto.subtle.digest("SHA-256", rgb).then((h) => done([c.width, c.height,
  Array.from(new Uint8Array(h)).map((b) => b.toString(16).padStart(2, "0")).join("")]));
"""


def _wait(cond: Any, what: str, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


def test_the_page_paints_the_opencv_consoles_pixels(
    web: WebHumans, pages: tuple[Any, Any], make_request: Any
) -> None:
    page = pages[0]
    open_console(page, web.urls[0])
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 0))
    state = web.wait_for_prompt(0)
    _wait(lambda: page_state(page).get("shownSeq") == state.seq_posted, "frame not shown")
    with web._cond:  # the frame the OpenCV window would show for this view
        view = Desk.with_flags(web._desks[0].view(), **web._flags(0))
        expected = render_console(view, web.layout)
    w, h, digest = page.execute_async_script(CANVAS_SHA256, "frame")
    assert (h, w) == expected.shape[:2]
    assert digest == hashlib.sha256(
        np.ascontiguousarray(expected[:, :, ::-1]).tobytes()).hexdigest()
    press_key(page, "d")
    assert call.join()["cell0/left"].action == 3


def test_no_token_no_page(web: WebHumans, pages: tuple[Any, Any]) -> None:
    from selenium.webdriver.common.by import By

    page = pages[0]
    for url in (web.base_url + "/", web.base_url + "/?token=not-a-token-of-anyone",
                web.base_url + "/overview"):
        page.get(url)
        assert "401" in page.find_element(By.TAG_NAME, "body").text
        assert not page.find_elements(By.TAG_NAME, "canvas")
        assert page.execute_script("return window.consoleState || null") is None
    assert not web.presence().available.any()


def test_a_key_and_a_tap_push_their_own_humans_arms(
    web: WebHumans, pages: tuple[Any, Any], make_request: Any
) -> None:
    from selenium.webdriver.common.by import By

    for h, page in enumerate(pages):
        open_console(page, web.urls[h])
    _wait(lambda: bool(web.presence().available.all()), "both humans present")
    call = ActCall(lambda: web.act([make_request("cell0/left", 0),
                                    make_request("cell1/right", 1)], 0))
    for h in range(2):
        web.wait_for_prompt(h)
    press_key(pages[1], Keys.ARROW_LEFT)  # human 1: push left
    _wait(lambda: web.snapshot(1).phase.value == "sent", "human 1's key was not taken")
    assert web.snapshot(0).phase.value == "choose", "human 1's key reached human 0"
    x, y = web.face_click_point(0, 2)
    click_frame_point(pages[0], x, y, touch=True)  # human 0: a finger taps the down face
    out = call.join()
    assert out["cell1/right"].action == 1
    assert out["cell0/left"].action == 2
    # the overview opens with a human's token; human 0's page left for it, so human 0
    # is away now, and the overview says so
    open_console(pages[0], web.overview_url)
    _wait(lambda: [x["present"] for x in (page_state(pages[0]).get("head") or {})
                   .get("humans", [])] == [False, True], "overview shows who is here")
    assert web.presence().available.tolist() == [False, True]
    who = pages[0].find_element(By.ID, "humans").text  # unnamed humans: "human i"
    assert who.startswith("human 0: away \u00b7 human 1: "), who
    assert web._posted[OVERVIEW] > 0
    # a row per human with what the records say of them (FleetStatus.operators)
    assert not pages[0].find_element(By.ID, "operators").is_displayed()
    web.show(5, FleetStatus(5, 24, operators=[
        HumanEstimate(0, 0.351, 0.01, 5.0, 0.0, 42, 3),
        HumanEstimate(1, 0.126, 0.08, 7.4, 1.9, 17, 2)]))
    _wait(lambda: pages[0].find_element(By.ID, "operators").is_displayed(), "the rows")
    rows = [[td.text for td in tr.find_elements(By.TAG_NAME, "td")] for tr in
            pages[0].find_elements(By.CSS_SELECTOR, "#operators tbody tr")]
    assert rows == [["human 0", "0.35", "0.01", "5.0", "0.0", "42"],
                    ["human 1", "0.13", "0.08", "7.4", "1.9", "17"]], rows


IDLE_PANEL = """
const q = (id) => document.getElementById(id);
const counters = {};
for (const k of ["step", "successes", "hard_resets", "idle_time", "human_actions", "rohe"]) {
  counters[k] = q("f-" + k).textContent;
}
return {idle: !q("idle").hidden, waiting: q("waiting").textContent, counters,
        none: !q("fleet-none").hidden,
        queue: q("fleet-queue").hidden ? null
          : Array.from(q("fleet-queue").children, (li) => li.textContent),
        rows: Array.from(q("fleet-robots").tBodies[0].rows,
                         (tr) => Array.from(tr.cells, (td) => td.textContent))};
"""


def _panel_when(page: Any, cond: Any, what: str) -> dict[str, Any]:
    """The idle panel's contents once ``cond(panel)`` holds."""
    got: dict[str, Any] = {}

    def ready() -> bool:
        got.update(page.execute_script(IDLE_PANEL))
        return bool(cond(got))

    _wait(ready, f"{what}: {got}")
    return got


def test_a_human_without_an_arm_sees_the_wait_and_the_fleet(
    named_web: WebHumans, pages: tuple[Any, Any], make_request: Any
) -> None:
    from selenium.webdriver.common.by import By

    web, page = named_web, pages[0]
    open_console(page, web.urls[0])
    assert page.title == "testbed console - ana (human 0)"
    assert page.find_element(By.ID, "who").text == "ana (human 0)"
    panel = _panel_when(page, lambda p: p["idle"], "no idle panel before the first step")
    assert panel["none"] and panel["rows"] == [] and panel["counters"]["step"] == "-"
    assert page.find_element(By.ID, "waiting").is_displayed()
    assert "Waiting for an arm: nothing needs you right now" in page.find_element(
        By.ID, "idle").text
    assert not page.find_element(By.ID, "frame").is_displayed(), "the empty grey box"
    assert not page.find_element(By.ID, "reset").is_enabled()

    image = arm_image()
    web.show(7, FleetStatus(7, 24, successes=3, hard_resets=1, idle_time=4,
                            human_actions=9, rohe=0.25, robots=[
        RobotStatus("cell0/left", Mode.AUTONOMOUS, image, None, 2),  # queued
        RobotStatus("cell0/right", Mode.TELEOP, image, 1),
        RobotStatus("cell1/left", Mode.IDLE, image, None, 5),
        RobotStatus("cell1/right", Mode.FAULT, None)]))
    panel = _panel_when(page, lambda p: p["counters"]["step"] == "7 of 24", "step 7")
    assert panel["counters"] == {"step": "7 of 24", "successes": "3", "hard_resets": "1",
                                 "idle_time": "4", "human_actions": "9", "rohe": "0.250"}
    assert panel["rows"] == [["cell0/left", "autonomous", "-", "2 steps"],
                             ["cell0/right", "teleop", "bo", "-"],
                             ["cell1/left", "idle", "-", "5 steps"],
                             ["cell1/right", "fault", "-", "-"]]
    assert panel["queue"] == ["cell1/left (idle): waited 5 steps",  # the longest first
                              "cell0/left (autonomous): waited 2 steps"]
    assert not panel["none"]
    text = page.find_element(By.ID, "idle").text  # what is on screen, not only in the DOM
    assert "Waiting for an arm" in text and "cell0/right" in text and "bo" in text

    web.show(8, FleetStatus(8, 24, successes=4, hard_resets=2, idle_time=5,
                            human_actions=10, rohe=0.3, robots=[
        RobotStatus("cell0/left", Mode.AUTONOMOUS, image),
        RobotStatus("cell0/right", Mode.AUTONOMOUS, image),
        RobotStatus("cell1/left", Mode.RESET, image, 1),
        RobotStatus("cell1/right", Mode.AUTONOMOUS, image)]))
    panel = _panel_when(page, lambda p: p["counters"]["step"] == "8 of 24", "live: step 8")
    assert (panel["counters"]["successes"], panel["counters"]["rohe"]) == ("4", "0.300")
    assert panel["rows"][2] == ["cell1/left", "reset", "bo", "-"]
    assert panel["queue"] is None, "nobody waits: no queue"

    # an arm for human 0: the image and its buttons come back; done, the panel again
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 8))
    web.wait_for_prompt(0)
    _panel_when(page, lambda p: not p["idle"], "the arm's image")
    assert page.find_element(By.ID, "frame").is_displayed()
    press_key(page, "w")
    assert call.join()["cell0/left"].action == 0
    web.act([], 9)
    panel = _panel_when(page, lambda p: p["idle"], "idle again")
    assert panel["counters"]["step"] == "8 of 24"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _config(port: int) -> dict[str, Any]:
    return {
        "trial": {"steps": STEPS, "seed": 3},
        # every arm eligible for teleop: the test needs teleops, whatever the policy
        "algorithm": {"u_hat": 0.0},
        "learning": {"ensemble_size": 2, "batch_size": 32, "demos": 40,
                     "critic_transitions": 40, "pretrain_steps": 5},
        "humans": {"count": 2, "kind": "web",
                   "people": [{"name": "ana"}, {"name": "bo", "where": "remote"}],
                   "web": {"port": port, "tokens": TOKENS, "grace_s": 1.0,
                           "away_timeout_s": 0.5}},
    }


class BrowserHuman:
    """A person at one console page: answers each new prompt once, in a thread."""

    def __init__(self, driver: Any, human: int) -> None:
        self.driver = driver
        self.human = human
        self.answers: list[tuple[str, str | None, int]] = []
        """(phase, robot, seq) of every prompt answered."""
        self.errors: list[BaseException] = []
        self._stop = threading.Event()
        self._done: set[int] = set()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> BrowserHuman:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10)

    def _run(self) -> None:
        while not self._stop.wait(0.03):
            try:
                self._answer_once()
            except Exception as exc:  # the page closed under us, or the trial ended
                if not self._stop.is_set():
                    self.errors.append(exc)
                return

    def _answer_once(self) -> None:
        from selenium.webdriver.common.by import By

        st = page_state(self.driver)
        head = st.get("head") or {}
        seq = int(st.get("shownSeq", 0))
        phase = head.get("phase")
        if seq in self._done or phase not in ("choose", "reset") or head.get("paused"):
            return
        if phase == "choose":
            if self.human == 0:
                press_key(self.driver, "w")
            else:
                x, y = head["markers"][PUSH_OF_HUMAN[1]]
                click_frame_point(self.driver, x, y)
        else:
            self.driver.find_element(By.ID, "reset").click()
        self._done.add(seq)
        self.answers.append((phase, head.get("robot"), seq))


def _steps_done(run: Path) -> int:
    try:
        return sum(1 for _ in (run / "steps.jsonl").open())
    except OSError:
        return 0


@pytest.mark.slow
def test_two_humans_in_browsers_run_a_trial(tmp_path: Path) -> None:
    if browser_missing():
        pytest.fail(f"missing {', '.join(browser_missing())}: apt-get install -y chromium "
                    "chromium-driver (scripts/setup.sh --dev does it)")
    port = _free_port()
    (tmp_path / "web.toml").write_text(tomli_w.dumps(_config(port)))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "trial", "--config", "web.toml", "--out", "runs",
         "--name", "web"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    run = tmp_path / "runs" / "web"
    urls = [f"http://127.0.0.1:{port}/?token={tok}" for tok in TOKENS]
    closed_at_step: int | None = None
    try:
        with chromium() as page0, chromium() as page1:
            open_console(page0, urls[0], timeout_s=120)
            open_console(page1, urls[1], timeout_s=120)
            places = [p.find_element("id", "place").text for p in (page0, page1)]
            h0, h1 = BrowserHuman(page0, 0).start(), BrowserHuman(page1, 1).start()
            try:
                deadline = time.monotonic() + 240
                while proc.poll() is None and time.monotonic() < deadline:
                    done = _steps_done(run)
                    if closed_at_step is None and done >= CLOSE_AFTER_STEP:
                        h1.stop()
                        # human 1's page is closed (its socket goes); the same browser
                        # opens the fleet overview, mid-trial
                        page1.get(f"http://127.0.0.1:{port}/overview?token={TOKENS[1]}")
                        closed_at_step = done
                    time.sleep(0.1)
                overview = page_state(page1)
                presence = page1.find_element("id", "humans").text
            finally:
                h0.stop()
                h1.stop()
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert not h0.errors and not h1.errors, (h0.errors, h1.errors)
    assert closed_at_step is not None, "the trial ended before human 1's page was closed"
    assert f"web console: ana (human 0): {urls[0]}" in err, "the URLs, printed at start"
    assert f"web console: bo (human 1): {urls[1]}" in err, "... with each human's name"
    assert "people: ana: on site (teleop and hard resets)\npeople: bo: remote (teleop only)" \
        in err, "each person's place, printed at start"
    assert places == ["You are on site (teleop and hard resets).",
                      "You are remote (teleop only)."]
    # issue 44: the links are kept with the run for a resume, readable by the operator only
    kept = json.loads((run / "web-links.json").read_text())
    assert kept["humans"] == TOKENS
    assert (run / "web-links.json").stat().st_mode & 0o077 == 0
    assert (f"web console: operator (pause and stop; keep it to yourself): "
            f"http://127.0.0.1:{port}/overview?token={kept['operator']}") in err

    steps = read_steps(run / "steps.jsonl")
    assert len(steps) == STEPS
    pushed = {0: 0, 1: 0}
    for row in (r for s in steps for r in s["robots"] if r["mode"] == "teleop"):
        if row["action"] is not None:  # None: an away human's step passed
            assert row["action"] == PUSH_OF_HUMAN[row["human"]], row
            pushed[row["human"]] += 1
    assert pushed[0] > 0 and pushed[1] > 0, f"a human's page pushed nothing: {pushed}"

    # the reset button completed a hard reset: the arm went back to work; the remote
    # person's page never showed one, and no reset in the records is theirs
    assert any(a[0] == "reset" for a in h0.answers), "no reset button pressed"
    assert not [a for a in h1.answers if a[0] == "reset"], h1.answers
    assert all(r["human"] == 0 for s in steps for r in s["robots"] if r["mode"] == "reset")
    completed = 0
    for i in range(len(steps[0]["robots"])):
        modes = [s["robots"][i]["mode"] for s in steps]
        completed += any(a == "reset" and b in ("autonomous", "teleop")
                         for a, b in pairwise(modes))
    assert completed >= 1, "no hard reset was completed by the button"

    # the closed page: human 1 away, never newly assigned, the trial went on
    away_rows = [s for s in steps if 1 in s.get("away", [])]
    assert away_rows, "human 1's closed page was never recorded as away"
    first_away = away_rows[0]["t"]
    assert all(1 in s.get("away", []) for s in steps if s["t"] >= first_away)
    held: set[str] = {r["robot"] for r in steps[first_away - 1]["robots"] if r["human"] == 1}
    for s in steps[first_away:]:
        mine = {r["robot"] for r in s["robots"] if r["human"] == 1}
        assert mine <= held, f"away human 1 newly assigned at t={s['t']}: {mine - held}"
        held = mine
    # the overview, opened mid-trial, got the curve's points so far, then one per step
    points = overview.get("points") or []
    assert [p["t"] for p in points] == list(range(1, STEPS + 1)), points[-3:]
    last = steps[-1]
    assert points[-1]["modes"] == [r["mode"] for r in last["robots"]]
    assert [x["present"] for x in overview["head"]["humans"]] == [True, False]
    assert presence.startswith("ana (human 0), on site: ") and presence.endswith(
        "\u00b7 bo (human 1), remote: away"), presence  # the config's names and places
    released = [x for s in steps for x in s.get("released", [])]
    assert all(x["human"] == 1 and x["why"] == "away" for x in released), released
