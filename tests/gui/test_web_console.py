"""The browser console (``gui.web.WebHumans``) with a real server and real clients.

Every test starts the server on loopback and talks to it as pages do: ``urllib`` for
the pages, ``websockets`` for the sockets (``FakePage``: a page minus the pixels; it
reports each frame painted, as the real page does, so ``wait_for_prompt`` works).
What is proven:

* no valid token, no page: 401 with no HTML, a socket refused at the handshake (403)
  and no frame; the token alone says who a page is (``?human=`` changes nothing);
* one human cannot act for another: the server takes the human from the socket's
  token, never from a message, a frame number or a marker's coordinates;
* named humans (``names``): each name beside its index on the printed link, the page's
  title and header (HTML-escaped), the frame headers and the fleet's text; an unnamed
  console's wire is what it was;
* each browser key and each face marker click means its push (w/ArrowLeft/x/d, k);
* an input counts only for the frame that showed the waiting request: an action
  replayed from the step before, or a second answer to one frame, is refused (with
  why) and never applied to the next step;
* the "Reset done" button completes a hard reset (only on a frame that showed it);
  pause / resume / stop-then-yes / stop-then-no from a page;
* time to first action: ``waited_s`` from the frame on the page to the first key or the
  reset button, once per intervention (at least the delay the test waits before it),
  None on the intervention's later answers, restarted by a new intervention;
* presence: a human is available while a page of theirs is open, unavailable at once
  when the last one closes, ``gone`` only after ``grace_s``; ``act`` waits for an away
  human's push at most ``away_timeout_s`` and still waits for a present one;
* malformed messages get an error reply and the socket goes on (one known exception:
  see ``test_a_message_the_parser_chokes_on_gets_an_error_too``);
* the overview socket: who is present, the counters of each ``show``, and the
  history of every point so far for a page that opens late; the human pages' "fleet"
  text (counters, modes, who holds which arm) each step, the latest at once on opening;
* TLS from a certificate and key (https, wss; plain http fails); a taken port is one
  ``ConsoleUnavailable`` line naming host:port.

Every console is closed by a fixture or a ``with`` block, and its server thread is
checked gone; every wait has a deadline.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import socket
import ssl
import struct
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import trustme
from console_helpers import ActCall, RequestFactory, arm_image
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from gui import ConsoleUnavailable, StopRequested
from gui.view import Phase
from gui.web.server import READ_ONLY
from gui.web.web_humans import OPERATOR_ONLY, WebHumans
from testbed.core.types import FleetStatus, HumanEstimate, Mode, RobotStatus

TOKENS = ["human0-token-aaaaaaaaaaaa", "human1-token-bbbbbbbbbbbb"]
OVERVIEW_TOKEN = "overview-token-cccccccccc"
"""The read-only overview's token (to watch)."""
OPERATOR_TOKEN = "operator-token-dddddddddd"
"""The operator's: the overview with pause and stop (issue 44: the operator's alone)."""
GRACE_S = 0.5
AWAY_S = 0.3
WAIT_S = 5.0
"""Deadline of every wait for the server (it answers in milliseconds)."""
OPEN_S = 20.0
"""Deadline of a socket's opening handshake: milliseconds when the machine is idle, but
one CI run under load saw a TLS opening take more than 5 s."""
Header = dict[str, Any]


class PageClosed(AssertionError):
    """The server closed a page's socket while the test waited for a message."""


# ---- clients ------------------------------------------------------------------------------
def ws_base(web: WebHumans) -> str:
    """``ws://host:port`` (``wss://`` with TLS) of a console."""
    return "ws" + web.base_url.removeprefix("http")


def http_get(url: str, context: ssl.SSLContext | None = None) -> tuple[int, str]:
    """Status and body of a GET; no proxy, whatever the environment says."""
    handlers: list[urllib.request.BaseHandler] = [urllib.request.ProxyHandler({})]
    if context is not None:
        handlers.append(urllib.request.HTTPSHandler(context=context))
    opener = urllib.request.build_opener(*handlers)
    try:
        with opener.open(url, timeout=WAIT_S) as resp:
            return resp.status, resp.read().decode()
    except urllib.error.HTTPError as exc:
        with exc:
            return exc.code, exc.read().decode()


class _WakingConnection(ClientConnection):
    """websockets' sync client, whose failed opening cannot hang the test.

    With TLS 1.3 the reader thread can sit inside a blocking ``SSLSocket.recv`` (the
    server's session tickets make the socket readable, no application data follows);
    when the opening handshake then times out, websockets closes the socket and joins
    that thread, and a close() never wakes a read blocked on the same descriptor, so the
    join waits forever (seen in CI: a 300 s pytest timeout instead of a TimeoutError).
    Shutting the TCP connection down first wakes the read with end of file.
    """

    def close_socket(self) -> None:
        with contextlib.suppress(OSError):
            socket.socket.shutdown(self.socket, socket.SHUT_RDWR)  # the TCP socket's own
        super().close_socket()


class FakePage:
    """A console page minus the pixels: one socket, frames read in a thread.

    Keeps every frame's header (``frames``, ``latest``) and every text (``texts``),
    reports each frame painted as the page does, and sends keys, clicks and buttons
    tagged with the seq of the latest frame (as the page tags them with the frame on
    screen) unless told another seq.
    """

    def __init__(self, url: str, *, ssl_context: ssl.SSLContext | None = None) -> None:
        self._stack = contextlib.ExitStack()
        self.ws = self._stack.enter_context(connect(
            url, proxy=None, ssl=ssl_context, open_timeout=OPEN_S, close_timeout=2,
            create_connection=_WakingConnection))
        self._cond = threading.Condition()
        self._send_lock = threading.Lock()
        self._ids = itertools.count(1)
        self.frames: list[Header] = []
        self.pngs: list[bytes] = []
        self.texts: list[dict[str, Any]] = []
        self.kinds: list[str] = []
        """"frame" or "text" per message, in the order they came."""
        self.closed = False
        self._reader = threading.Thread(target=self._read, name="fake-page", daemon=True)
        self._reader.start()
        try:
            self.wait_frame(lambda h: True)  # the server sends the latest frame at once
        except BaseException:
            self.close()
            raise

    def _read(self) -> None:
        try:
            while True:
                msg = self.ws.recv()
                if isinstance(msg, str):
                    with self._cond:
                        self.texts.append(json.loads(msg))
                        self.kinds.append("text")
                        self._cond.notify_all()
                    continue
                (n,) = struct.unpack(">I", msg[:4])
                header = json.loads(msg[4 : 4 + n])
                with self._cond:
                    self.frames.append(header)
                    self.pngs.append(msg[4 + n :])
                    self.kinds.append("frame")
                    self._cond.notify_all()
                self.send_raw(json.dumps({"type": "painted", "seq": header["seq"],
                                          "t_sent": header["t_sent"],
                                          "t_painted": time.time() * 1e3}))
        except ConnectionClosed:
            pass
        finally:
            with self._cond:
                self.closed = True
                self._cond.notify_all()

    # ---- reading -------------------------------------------------------------------
    @property
    def latest(self) -> Header:
        with self._cond:
            return self.frames[-1]

    def _wait(self, found: Callable[[], Any], what: str, timeout: float = WAIT_S) -> Any:
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                got = found()
                if got is not None:
                    return got
                if self.closed:
                    raise PageClosed(f"the server closed the socket; waiting for {what}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no {what} within {timeout} s "
                                         f"(latest frame: {self.frames[-1:]})")
                self._cond.wait(left)

    def wait_frame(self, pred: Callable[[Header], bool], timeout: float = WAIT_S) -> Header:
        """Wait until the latest frame (what the page shows now) satisfies ``pred``."""
        return self._wait(lambda: self.frames[-1] if self.frames and pred(self.frames[-1])
                          else None, "matching frame", timeout)

    # ---- sending -------------------------------------------------------------------
    def send_raw(self, data: str | bytes) -> None:
        with self._send_lock:
            self.ws.send(data)

    def error_for(self, data: str | bytes) -> dict[str, Any]:
        """Send anything; return the error reply it gets."""
        with self._cond:
            start = len(self.texts)
        self.send_raw(data)
        return self._wait(lambda: next((t for t in self.texts[start:]
                                        if t.get("type") == "error"), None), "error reply")

    def send(self, msg: dict[str, Any]) -> dict[str, Any]:
        """Send an input (seq: the latest frame's unless given); return its reply."""
        ident = next(self._ids)
        msg = {"seq": self.latest["seq"]} | msg | {"id": ident}
        with self._cond:
            start = len(self.texts)
        self.send_raw(json.dumps(msg))

        def reply() -> dict[str, Any] | None:
            for text in self.texts[start:]:
                if text.get("type") == "error":
                    raise AssertionError(f"{msg} got an error: {text}")
                if text.get("type") == "input" and text.get("id") == ident:
                    return text
            return None

        return self._wait(reply, f"reply to {msg}")

    def key(self, key: str, seq: int | None = None) -> dict[str, Any]:
        return self.send({"type": "key", "key": key} | ({} if seq is None else {"seq": seq}))

    def click(self, x: float, y: float, seq: int | None = None) -> dict[str, Any]:
        return self.send({"type": "click", "x": x, "y": y}
                         | ({} if seq is None else {"seq": seq}))

    def button(self, name: str, seq: int | None = None) -> dict[str, Any]:
        return self.send({"type": "button", "name": name}
                         | ({} if seq is None else {"seq": seq}))

    def close(self) -> None:
        self._stack.close()
        self._reader.join(WAIT_S)
        assert not self._reader.is_alive(), "the page's reader did not end"

    def __enter__(self) -> FakePage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def wait_until(cond: Callable[[], bool], what: str, timeout: float = WAIT_S) -> float:
    """Poll ``cond``; return the time it became true (``time.monotonic``)."""
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, f"not within {timeout} s: {what}"
        time.sleep(0.01)
    return time.monotonic()


def assert_no_server_thread() -> None:
    alive = [t.name for t in threading.enumerate() if t.name == "web-console"]
    assert not alive, "a web console's server thread outlived close()"


@contextlib.contextmanager
def console(num_humans: int = 2, **kwargs: Any) -> Iterator[WebHumans]:
    args: dict[str, Any] = {"port": 0, "announce": None, "tokens": TOKENS[:num_humans],
                            "overview_token": OVERVIEW_TOKEN, "operator_token": OPERATOR_TOKEN,
                            "grace_s": GRACE_S, "away_timeout_s": AWAY_S}
    humans = WebHumans(num_humans, **(args | kwargs))
    try:
        yield humans
    finally:
        humans.close()
    assert_no_server_thread()


OpenPage = Callable[..., FakePage]


@pytest.fixture
def web() -> Iterator[WebHumans]:
    with console() as humans:
        yield humans


@pytest.fixture
def open_page(web: WebHumans) -> Iterator[OpenPage]:
    """``open_page(h)``: a page with human h's token (``path="/ws/overview"``: overview);
    ``open_page("operator")`` / ``open_page("overview")``: the overview with the
    operator's token / the read-only overview token."""
    pages: list[FakePage] = []

    def open_(human: int | str, *, path: str = "/ws", query: str = "") -> FakePage:
        if isinstance(human, str):
            token = OPERATOR_TOKEN if human == "operator" else OVERVIEW_TOKEN
            path = "/ws/overview"
        else:
            token = TOKENS[human]
        page = FakePage(f"{ws_base(web)}{path}?token={token}{query}")
        pages.append(page)
        return page

    yield open_
    for page in pages:
        page.close()


def choosing(h: Header) -> bool:
    return h.get("phase") == Phase.CHOOSE.value


# ---- 1, 2: tokens ---------------------------------------------------------------------------
@pytest.mark.parametrize("query", [
    "", "?token=", "?token=not-a-token-of-this-console", f"?token={TOKENS[0][:-1]}",
    f"?token={TOKENS[0]}x", f"?token={TOKENS[1].upper()}", f"?human=0&tok={TOKENS[0]}",
], ids=["none", "empty", "wrong", "prefix", "longer", "case", "misnamed"])
def test_no_page_frame_or_socket_without_a_valid_token(web: WebHumans, query: str) -> None:
    for path in ("/", "/overview"):
        status, body = http_get(f"{web.base_url}{path}{query}")
        assert status == 401, path
        assert "<canvas" not in body.lower() and "<script" not in body.lower(), body
        assert "<html" not in body.lower(), body
    for path in ("/ws", "/ws/overview"):
        with pytest.raises(InvalidStatus) as refused, connect(
                f"{ws_base(web)}{path}{query}", proxy=None, open_timeout=WAIT_S) as ws:
            ws.recv(timeout=1.0)  # a frame, were the socket let in
        assert refused.value.response.status_code == 403, path
    assert not web.presence().available.any()


def test_the_token_alone_says_whose_page_it_is(web: WebHumans, open_page: OpenPage) -> None:
    for h in range(2):  # the announced URLs serve their human's page
        status, body = http_get(web.urls[h])
        assert status == 200 and "<canvas" in body
        assert f"<title>testbed console - human {h}</title>" in body
    status, body = http_get(f"{web.base_url}/?token={TOKENS[1]}&human=0")
    assert status == 200
    assert "<title>testbed console - human 1</title>" in body
    assert "human 0" not in body
    status, body = http_get(f"{web.base_url}/overview?token={TOKENS[1]}")
    assert status == 200 and "fleet overview" in body

    page = open_page(1, query="&human=0")
    assert page.latest["human"] == 1
    assert page.pngs[-1].startswith(b"\x89PNG\r\n\x1a\n")
    assert "name" not in page.latest, "an unnamed console's header is what it was"
    assert web.presence().available.tolist() == [False, True]


def test_named_humans_on_their_links_pages_frames_and_the_fleets_text() -> None:
    """Each name beside its index on the printed links and the page's title and header,
    escaped there (a name is text, never markup), and in the frame headers and the
    fleet's text (the waiting page's "held by" column, the overview's presence list);
    ``make_humans(names=...)`` hands them on (a trial passes ``humans.people``'s)."""
    import io

    from testbed.experiments.build import make_humans
    from testbed.people.people_config import WebConsoleConfig

    built = make_humans("web", 2, WebConsoleConfig(port=0), names=["ana", "bo"])
    try:
        assert isinstance(built, WebHumans) and built.names == ("ana", "bo")
    finally:
        built.close()
    out = io.StringIO()
    with console(names=["ana", "<b>bo</b>"], announce=out) as web:
        assert out.getvalue().splitlines()[:2] == [
            f"web console: ana (human 0): {web.urls[0]}",
            f"web console: <b>bo</b> (human 1): {web.urls[1]}"]
        body = http_get(web.urls[0])[1]
        assert "<title>testbed console - ana (human 0)</title>" in body
        assert '<span id="who">ana (human 0)</span>' in body
        body = http_get(web.urls[1])[1]
        assert '<span id="who">&lt;b&gt;bo&lt;/b&gt; (human 1)</span>' in body
        assert "<b>bo</b>" not in body
        assert web.surface_name(0) == "ana (human 0)'s page"
        with (FakePage(f"{ws_base(web)}/ws?token={TOKENS[1]}") as page,
              FakePage(f"{ws_base(web)}/ws/overview?token={TOKENS[0]}") as overview):
            assert (page.latest["human"], page.latest["name"]) == (1, "<b>bo</b>")
            head = overview.wait_frame(lambda h: h["humans"][1]["present"])
            assert [(h["human"], h["name"], h["present"]) for h in head["humans"]] == [
                (0, "ana", False), (1, "<b>bo</b>", True)]
            web.show(3, FleetStatus(3, 10, robots=[
                RobotStatus("cell0/left", Mode.TELEOP, arm_image(), 1),
                RobotStatus("cell0/right", Mode.AUTONOMOUS, arm_image())]))
            with page._cond:
                page._cond.wait_for(lambda: any(x["type"] == "fleet" for x in page.texts),
                                    WAIT_S)
                fleet = next(x for x in page.texts if x["type"] == "fleet")
            assert fleet["robots"] == [
                {"robot": "cell0/left", "mode": "teleop", "human": 1, "waited": None,
                 "name": "<b>bo</b>"},
                {"robot": "cell0/right", "mode": "autonomous", "human": None, "waited": None}]
            # the overview's rows of the humans' estimates, by name
            assert overview.latest["operators"] == []
            web.show(4, FleetStatus(4, 10, operators=[
                HumanEstimate(0, 0.35, 0.01, 5.0, 0.0, 42, 3),
                HumanEstimate(1, 0.125, 0.08, 7.25, 1.9, 17, 2)]))
            head = overview.wait_frame(lambda h: h["operators"] != [])
            assert head["operators"] == [
                {"human": 0, "name": "ana", "skill": 0.35, "violations": 0.01,
                 "reset_steps": 5.0, "latency_steps": 0.0, "pushes": 42, "resets": 3},
                {"human": 1, "name": "<b>bo</b>", "skill": 0.125, "violations": 0.08,
                 "reset_steps": 7.25, "latency_steps": 1.9, "pushes": 17, "resets": 2}]


def test_each_page_says_where_its_person_is_and_the_overview_says_everyones(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Issue 44: built from the config's people (``make_humans``), the operator is told
    each person's place before the console starts; a person's page says what they will
    be given (a remote one: teleop only); the overview's who-is-here has each place."""
    from testbed.experiments.build import make_humans
    from testbed.people.people_config import HumanProfile, WebConsoleConfig

    people = [HumanProfile(name="cleo"), HumanProfile(name="dev", where="remote")]
    web = make_humans("web", 2, WebConsoleConfig(port=0, tokens=TOKENS), people=people,
                      names=["cleo", "dev"])
    try:
        assert isinstance(web, WebHumans) and web.places == ("on_site", "remote")
        err = capsys.readouterr().err.splitlines()
        assert err[:2] == ["people: cleo: on site (teleop and hard resets)",
                           "people: dev: remote (teleop only)"]
        body = http_get(web.urls[1])[1]
        assert '<p class="place" id="place">You are remote (teleop only).</p>' in body
        body = http_get(web.urls[0])[1]
        assert ('<p class="place" id="place">You are on site (teleop and hard resets).'
                '</p>') in body
        with FakePage(f"{ws_base(web)}/ws/overview?token={web.tokens.overview}") as view:
            head = view.wait_frame(lambda h: "humans" in h)
            assert [(h["name"], h["where"]) for h in head["humans"]] == [
                ("cleo", "on_site"), ("dev", "remote")]
    finally:
        web.close()
    with console(names=["ana", "bo"]) as plain:  # not told: the page of before
        assert '<p class="place" id="place"></p>' in http_get(plain.urls[0])[1]


# ---- 3: who acts for whom, and what each input means ----------------------------------------
def test_one_human_cannot_act_for_another(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    p0, p1 = open_page(0), open_page(1)
    reqs = [make_request("cell0/left", 0), make_request("cell1/right", 1)]
    call = ActCall(lambda: web.act(reqs, 0))
    for h in range(2):
        assert web.wait_for_prompt(h).phase is Phase.CHOOSE
    seq1 = p1.wait_frame(choosing)["seq"]
    x1, y1 = web.face_click_point(1, 2)
    assert p1.latest["markers"][2] == [x1, y1]
    assert p1.latest["robot"] == "cell1/right"

    # human 0 aims at human 1's request: its frame, its marker, its name, its token
    forged = {"seq": seq1, "human": 1, "token": TOKENS[1], "robot": "cell1/right"}
    assert not p0.send({"type": "key", "key": "w"} | forged)["taken"]
    assert not p0.send({"type": "click", "x": x1, "y": y1} | forged)["taken"]
    assert not p0.send({"type": "button", "name": "push0"} | forged)["taken"]
    assert web.snapshot(1).phase is Phase.CHOOSE
    assert web.snapshot(0).phase is Phase.CHOOSE  # nor did it count for human 0

    # human 0's own key answers human 0's arm; a click after it answers nothing
    assert p0.key("d")["taken"]
    assert not p0.click(x1, y1)["taken"]
    time.sleep(0.3)
    assert call.waiting, "human 1 has not answered: act() must still wait"
    assert web.snapshot(1).phase is Phase.CHOOSE, "human 0's input reached human 1"
    assert p1.latest["phase"] == Phase.CHOOSE.value

    assert p1.click(x1, y1)["taken"]
    out = call.join()
    assert out["cell0/left"].action == 3
    assert out["cell1/right"].action == 2


def test_each_key_and_each_face_click_means_its_push(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    page = open_page(1)
    inputs: list[tuple[str, int]] = [("w", 0), ("ArrowLeft", 1), ("x", 2), ("d", 3)]
    inputs += [("click", k) for k in range(4)]
    for t, (what, action) in enumerate(inputs):
        img = arm_image(cube_px=(20 + 4 * t, 30))
        call = ActCall(lambda t=t, img=img: web.act(
            [make_request("cell1/left", 1, image=img)], t))
        web.wait_for_prompt(1)
        click = what == "click"
        reply = page.click(*web.face_click_point(1, action)) if click else page.key(what)
        assert reply["taken"], (what, reply)
        assert call.join()["cell1/left"].action == action, what


# ---- 4: the frame rule ----------------------------------------------------------------------
def test_a_stale_or_replayed_action_is_refused(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    page = open_page(0)

    def step(t: int) -> ActCall:
        call = ActCall(lambda: web.act([make_request("cell0/left", 0)], t))
        web.wait_for_prompt(0)
        return call

    call = step(5)
    old_seq = page.latest["seq"]
    old_key = {"type": "key", "key": "w", "seq": old_seq}
    old_click = {"type": "click", "seq": old_seq}
    old_click |= dict(zip("xy", web.face_click_point(0, 1), strict=True))
    assert page.send(old_key)["taken"]
    assert call.join()["cell0/left"].action == 0

    call = step(6)  # the same human, the same arm, the next step
    new_seq = page.wait_frame(choosing)["seq"]
    assert new_seq > old_seq
    for replay in (old_key, old_click):
        reply = page.send(replay)
        assert reply["taken"] is False
        assert "stale" in reply["why"], reply
    time.sleep(0.3)
    assert call.waiting, "a step-5 input answered step 6"
    assert web.snapshot(0).phase is Phase.CHOOSE

    assert page.key("d", seq=new_seq)["taken"]
    second = page.key("a", seq=new_seq)  # a second answer to the same frame
    assert second["taken"] is False and second["why"]
    assert call.join()["cell0/left"].action == 3

    call = step(7)  # neither leaks into the step after
    for replay in (old_key, {"type": "key", "key": "a", "seq": new_seq}):
        assert page.send(replay)["taken"] is False
    time.sleep(0.3)
    assert call.waiting
    assert page.key("x")["taken"]
    assert call.join()["cell0/left"].action == 2


# ---- 5, 6: buttons --------------------------------------------------------------------------
@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_reset_done_by_the_button(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    page = open_page(1)
    idle_seq = page.latest["seq"]
    t0 = time.monotonic()
    out = web.act([make_request("cell1/left", 1, "reset")], 20)
    assert time.monotonic() - t0 < 1.0, "a reset must not make act() wait"
    assert out["cell1/left"].reset_done is False
    assert web.wait_for_prompt(1).phase is Phase.RESET
    shown = page.wait_frame(lambda h: h["phase"] == Phase.RESET.value)
    assert shown["robot"] == "cell1/left" and shown["kind"] == "reset"

    assert not page.button("confirm", seq=idle_seq)["taken"]  # a frame with no reset
    assert page.button("confirm", seq=shown["seq"])["taken"]
    page.wait_frame(lambda h: h["phase"] == Phase.RESET_CONFIRMED.value)
    later = make_request("cell1/left", 1, "reset", served=1)
    assert web.act([later], 21)["cell1/left"].reset_done is True
    assert web.act([later], 22)["cell1/left"].reset_done is False  # used up


def test_pause_and_resume_from_a_page(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    p0, p1, op = open_page(0), open_page(1), open_page("operator")
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 30))
    web.wait_for_prompt(0)
    point = web.face_click_point(0, 3)

    for reply in (p1.button("pause"), p1.key(" ")):  # a human cannot pause the fleet
        assert reply["taken"] is False and reply["why"] == OPERATOR_ONLY, reply
    assert not web.paused
    assert op.button("pause")["taken"]  # the operator pauses the whole fleet
    assert web.paused
    paused = p0.wait_frame(lambda h: h["paused"])
    for reply in (p0.key("d", seq=paused["seq"]), p0.click(*point, seq=paused["seq"])):
        assert reply["taken"] is False and reply["why"] == "paused", reply
    time.sleep(0.3)
    assert call.waiting, "a push while paused answered the request"
    assert web.snapshot(0).phase is Phase.CHOOSE

    assert op.button("pause")["taken"]
    assert not web.paused
    p0.wait_frame(lambda h: not h["paused"] and choosing(h))
    assert p0.key("a")["taken"]
    assert call.join()["cell0/left"].action == 1


def test_stop_then_no_goes_on(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    human, page = open_page(0), open_page("operator")
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 40))
    web.wait_for_prompt(0)
    assert page.button("stop")["taken"]
    page.wait_frame(lambda h: h["confirming_stop"])
    assert page.button("no")["taken"], "no is an answer to the question"
    page.wait_frame(lambda h: not h["confirming_stop"])
    time.sleep(0.3)
    assert call.waiting and not web.stop_requested
    assert human.key("w")["taken"]
    assert call.join()["cell0/left"].action == 0


def test_stop_then_yes_stops(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    p0, p1, op = open_page(0), open_page(1), open_page("operator")
    viewer = open_page("overview")
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 50))
    web.wait_for_prompt(0)
    for page in (p0, p1):  # issue 44: stopping the trial is the operator's alone
        for reply in (page.button("stop"), page.key("Escape")):
            assert reply["taken"] is False and reply["why"] == OPERATOR_ONLY, reply
    for reply in (viewer.button("stop"), viewer.button("pause")):  # the link to share
        assert reply["taken"] is False and reply["why"] == READ_ONLY, reply
    assert op.button("stop")["taken"]
    op.wait_frame(lambda h: h["confirming_stop"])
    assert not viewer.button("yes")["taken"]  # nobody else confirms the operator's question
    assert not p1.button("yes")["taken"]
    time.sleep(0.2)
    assert call.waiting and not web.stop_requested
    assert op.button("yes")["taken"]
    with pytest.raises(StopRequested, match="overview"):
        call.join()
    assert web.stop_requested
    p1.wait_frame(lambda h: h["stop_requested"])  # every page is told


# ---- 6b: time to first action (HumanResponse.waited_s) -------------------------------------
DELAY_S = 0.4
"""How long the test's human looks at a frame before answering it."""
SLACK_S = 2.0
"""More than a loaded machine adds between the page's reports and the test's sleeps."""


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_waited_s_from_the_frame_on_the_page_to_the_first_key(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    page = open_page(0)

    def answer(t: int, served: int, key: str, delay_s: float) -> Any:
        call = ActCall(lambda: web.act([make_request("cell0/left", 0, served=served)], t))
        web.wait_for_prompt(0)  # the page has reported this step's frame painted
        time.sleep(delay_s)
        assert page.key(key)["taken"]
        return call.join()["cell0/left"]

    first = answer(0, 0, "w", DELAY_S)
    assert first.action == 0
    assert first.waited_s is not None and DELAY_S <= first.waited_s < DELAY_S + SLACK_S
    for t in (1, 2):  # the intervention's later steps: pushes, no waited_s
        later = answer(t, t, "d", 0.0)
        assert later.action == 3 and later.waited_s is None
    t_second = time.monotonic()
    second = answer(3, 0, "x", DELAY_S / 2)  # served == 0 again: the clock restarts
    assert second.action == 2 and second.waited_s is not None
    assert DELAY_S / 2 <= second.waited_s <= time.monotonic() - t_second


def test_waited_s_from_the_reset_frame_to_the_reset_done_button(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    page = open_page(1)
    out = web.act([make_request("cell1/left", 1, "reset", served=0)], 40)
    assert out["cell1/left"].waited_s is None  # nothing done yet
    web.wait_for_prompt(1)
    time.sleep(DELAY_S)
    assert page.button("confirm")["taken"]
    done = web.act([make_request("cell1/left", 1, "reset", served=1)], 41)["cell1/left"]
    assert done.reset_done
    assert done.waited_s is not None and DELAY_S <= done.waited_s < DELAY_S + SLACK_S
    held = web.act([make_request("cell1/left", 1, "reset", served=2)], 42)["cell1/left"]
    assert not held.reset_done and held.waited_s is None


# ---- 7: presence ----------------------------------------------------------------------------
def test_presence_follows_the_open_pages(web: WebHumans, open_page: OpenPage) -> None:
    assert web.presence().available.tolist() == [False, False]
    overview = open_page(1, path="/ws/overview")
    assert web.presence().available.tolist() == [False, False]  # not a human's page
    a = open_page(0)
    assert web.presence().available.tolist() == [True, False]
    b = open_page(0)

    web.show(1, FleetStatus(1, 10))
    mark = overview.wait_frame(lambda h: h.get("point", {}).get("t") == 1)["seq"]
    b.close()  # the server redraws the overview when it sees the close
    overview.wait_frame(lambda h: h["seq"] > mark)
    assert web.presence().available.tolist() == [True, False], "one of two pages closed"

    t_closed = time.monotonic()
    a.close()
    t_away = wait_until(lambda: not web.presence().available[0], "human 0 unavailable")
    assert t_away - t_closed < GRACE_S
    assert 0 not in web.presence().gone, "gone before the grace period"
    head = overview.wait_frame(lambda h: not h["humans"][0]["present"])
    assert [h["present"] for h in head["humans"]] == [False, False]
    t_gone = wait_until(lambda: 0 in web.presence().gone, "human 0 gone")
    assert t_gone - t_closed >= GRACE_S
    assert 1 in web.presence().gone  # never came

    open_page(0)  # back: available, not gone
    presence = web.presence()
    assert presence.available.tolist() == [True, False]
    assert 0 not in presence.gone


def test_act_waits_for_an_away_human_only_briefly(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    t0 = time.monotonic()
    call = ActCall(lambda: web.act([make_request("cell1/right", 1)], 0))
    assert call.join()["cell1/right"].action is None  # human 1 never opened a page
    assert call.t_end is not None
    assert AWAY_S - 0.05 <= call.t_end - t0 < AWAY_S + 1.0

    p0 = open_page(0)
    reqs = [make_request("cell0/left", 0), make_request("cell1/right", 1)]
    call = ActCall(lambda: web.act(reqs, 1))
    web.wait_for_prompt(0)
    time.sleep(AWAY_S + 0.4)
    assert call.waiting, "human 0 is here: act() must wait for their push"
    assert p0.key("w")["taken"]
    out = call.join()
    assert out["cell0/left"].action == 0
    assert out["cell1/right"].action is None

    # a human who leaves in the middle of a step is waited for away_timeout_s, no more
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 2))
    web.wait_for_prompt(0)
    t_closed = time.monotonic()
    p0.close()
    assert call.join()["cell0/left"].action is None
    assert call.t_end is not None
    assert AWAY_S - 0.05 <= call.t_end - t_closed < AWAY_S + 1.0

    # back later: the expired request's frame answers nothing
    p0 = open_page(0)
    reply = p0.key("w")
    assert reply["taken"] is False
    assert web.snapshot(0).phase is Phase.SENT


# ---- 8: malformed messages ------------------------------------------------------------------
MALFORMED: list[str | bytes] = [
    "not json", "[1, 2]", "42", '"key"', "null", "{}", '{"type": 7}',
    '{"type": "teleport", "seq": 1}', '{"type": "button", "name": "fly", "seq": 1}',
    '{"type": "key", "seq": 1}', '{"type": "click", "x": 10, "seq": 1}',
    '{"type": "key", "key": "w", "seq": "soon"}', '{"type": "key", "key": "w", "seq": null}',
    '{"type": "click", "x": "left", "y": 3, "seq": 1}', '{"type": "painted", "seq": 1}',
    b"\x00\x01 a binary message",
]


def test_malformed_messages_get_an_error_and_break_nothing(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory
) -> None:
    page = open_page(0)
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 60))
    web.wait_for_prompt(0)
    for raw in MALFORMED:
        reply = page.error_for(raw)
        assert reply["why"], raw
    assert call.waiting and web.snapshot(0).phase is Phase.CHOOSE
    assert web.presence().available[0]
    assert page.key("w")["taken"]
    assert call.join()["cell0/left"].action == 0


@pytest.mark.parametrize("raw", [
    '{"type": "key", "key": "w", "seq": Infinity}',
    '{"type": "click", "x": 1, "y": 1, "seq": -Infinity}',
    "[" * 5000 + "]" * 5000,
], ids=["seq-infinity", "seq-minus-infinity", "deep-nesting"])
def test_a_message_the_parser_chokes_on_gets_an_error_too(
    web: WebHumans, open_page: OpenPage, make_request: RequestFactory, raw: str
) -> None:
    """seq Infinity (OverflowError in int()) and deep nesting (RecursionError in
    json.loads) once escaped the handler and dropped the page's socket."""
    page = open_page(0)
    call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 61))
    web.wait_for_prompt(0)
    assert page.error_for(raw)["why"]
    assert page.key("w")["taken"]
    assert call.join()["cell0/left"].action == 0


# ---- 9: the overview ------------------------------------------------------------------------
def test_overview_socket_who_is_here_counters_and_history(
    web: WebHumans, open_page: OpenPage
) -> None:
    open_page(0)
    overview = open_page(1, path="/ws/overview")  # any human's token opens it
    assert overview.kinds[0] == "text"
    assert overview.texts[0] == {"type": "history", "points": []}
    head = overview.wait_frame(lambda h: "humans" in h)
    assert [(h["human"], h["present"]) for h in head["humans"]] == [(0, True), (1, False)]
    assert "point" not in head

    robots = [RobotStatus("cell0/left", Mode.TELEOP, arm_image(), 0),
              RobotStatus("cell0/right", Mode.AUTONOMOUS, arm_image())]
    web.show(3, FleetStatus(3, 100, successes=2, hard_resets=1, idle_time=4,
                            human_actions=5, rohe=0.25, robots=robots))
    head = overview.wait_frame(lambda h: h.get("point", {}).get("t") == 3)
    point = head["point"]
    assert (point["successes"], point["hard_resets"], point["human_actions"],
            point["idle"], point["rohe"]) == (2, 1, 5, 4, 0.25)
    assert point["modes"] == ["teleop", "autonomous"]
    web.show(4, FleetStatus(4, 100, successes=3, hard_resets=1, human_actions=6,
                            robots=robots))
    overview.wait_frame(lambda h: h.get("point", {}).get("t") == 4)

    late = open_page(0, path="/ws/overview")
    assert late.kinds[0] == "text"
    history = late.texts[0]
    assert history["type"] == "history"
    assert [(p["t"], p["successes"]) for p in history["points"]] == [(3, 2), (4, 3)]
    assert late.latest["point"]["t"] == 4
    assert web.presence().available.tolist() == [True, False]  # overviews are nobody

    assert not overview.key("w")["taken"]  # no arm to push from the overview
    assert overview.button("pause")["why"] == READ_ONLY  # a human's token: only to look
    operator = open_page("operator")
    assert not operator.key("w")["taken"]  # no arm to push from the operator's either
    assert operator.button("pause")["taken"]  # but the operator pauses the fleet
    assert web.paused
    operator.wait_frame(lambda h: h["paused"])
    assert operator.button("pause")["taken"]
    assert not web.paused


def test_human_pages_get_the_fleets_state_each_step_and_the_latest_on_opening(
    web: WebHumans, open_page: OpenPage
) -> None:
    page = open_page(0)
    overview = open_page(1, path="/ws/overview")

    def fleet_texts(p: FakePage) -> list[dict[str, Any]]:
        with p._cond:
            return [x for x in p.texts if x.get("type") == "fleet"]

    assert fleet_texts(page) == [], "no state before the first step"
    robots = [RobotStatus("cell0/left", Mode.TELEOP, arm_image(), 1),
              RobotStatus("cell0/right", Mode.IDLE, None, None, 4)]
    for t in (5, 6):
        web.show(t, FleetStatus(t, 50, successes=t, hard_resets=1, idle_time=2,
                                human_actions=3, rohe=0.125, robots=robots))
        wait_until(lambda t=t: [x["t"] for x in fleet_texts(page)][-1:] == [t], f"step {t}")
    assert fleet_texts(page)[-1] == {
        "type": "fleet", "t": 6, "steps": 50, "successes": 6, "hard_resets": 1,
        "idle_time": 2, "human_actions": 3, "rohe": 0.125, "paused": False,
        "robots": [{"robot": "cell0/left", "mode": "teleop", "human": 1, "waited": None},
                   {"robot": "cell0/right", "mode": "idle", "human": None, "waited": 4}],
        "queue": [{"robot": "cell0/right", "mode": "idle", "waited": 4}],
        "health": "waiting 1 (longest 4 steps)"}
    late = open_page(1)
    wait_until(lambda: [x["t"] for x in fleet_texts(late)] == [6], "the latest, at once")
    overview.wait_frame(lambda h: h.get("point", {}).get("t") == 6)
    assert fleet_texts(overview) == [], "the overview has its own counters"
    # issue 44: a run's health at a glance, on the overview and every page
    robots = [RobotStatus("cell0/left", Mode.FAULT, None, None),
              RobotStatus("cell0/right", Mode.IDLE, None, None, 7)]
    web.show(7, FleetStatus(7, 50, robots=robots, away=[1],
                            last_fault=(6, "cell0/left", "agent on host cell0: motors off")))
    want = ("faulted 1 (cell0/left); waiting 1 (longest 7 steps); away: human 1; last fault "
            "at step 6, cell0/left: agent on host cell0: motors off")
    head = overview.wait_frame(lambda h: h.get("point", {}).get("t") == 7)
    assert head["point"]["health"] == want
    wait_until(lambda: fleet_texts(page)[-1]["health"] == want, "the health, on a page")


# ---- 10, 11: TLS and the port ---------------------------------------------------------------
def test_tls_with_a_certificate(tmp_path: Path) -> None:
    ca = trustme.CA()
    cert = ca.issue_cert("127.0.0.1", "localhost")
    certfile, keyfile = tmp_path / "chain.pem", tmp_path / "key.pem"
    cert.private_key_and_cert_chain_pem.write_to_path(str(certfile))
    cert.private_key_pem.write_to_path(str(keyfile))
    trusted = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ca.configure_trust(trusted)

    with console(1, certfile=str(certfile), keyfile=str(keyfile)) as web:
        assert web.base_url.startswith("https://")
        assert web.urls[0].startswith("https://")
        status, body = http_get(web.urls[0], context=trusted)
        assert status == 200 and "<canvas" in body
        assert ws_base(web).startswith("wss://")
        with FakePage(f"{ws_base(web)}/ws?token={TOKENS[0]}", ssl_context=trusted) as page:
            assert page.latest["human"] == 0
            assert web.presence().available.tolist() == [True]

        plain = f"http://127.0.0.1:{web.port}/?token={TOKENS[0]}"
        with pytest.raises(OSError):
            http_get(plain)
        with pytest.raises(urllib.error.URLError, match="CERTIFICATE_VERIFY_FAILED"):
            http_get(web.urls[0], context=ssl.create_default_context())  # CA not trusted


def test_a_taken_port_is_one_line(web: WebHumans) -> None:
    with pytest.raises(ConsoleUnavailable) as info:
        WebHumans(1, port=web.port, announce=None)
    msg = str(info.value)
    assert "\n" not in msg
    assert f"127.0.0.1:{web.port}" in msg
    assert len([t for t in threading.enumerate() if t.name == "web-console"]) == 1
    assert http_get(web.urls[0])[0] == 200  # the running console is untouched


def test_a_protocols_next_console_keeps_the_urls_and_says_them_once() -> None:
    """Each trial of a protocol opens its own console: without configured tokens, the
    process's random ones are reused, so with a fixed port every URL stays valid (the
    page reconnects by itself), and the URLs are printed once, not once a trial."""
    import io

    with WebHumans(2, port=0, announce=None) as first:
        port = first.port
        urls = list(first.urls)
    out = io.StringIO()
    with WebHumans(2, port=port, announce=out) as second:
        assert second.urls == urls
    with WebHumans(2, port=port, announce=out) as third:
        assert third.urls == urls
    assert out.getvalue().count("web console: human 0:") == 1
    assert len(set(urls)) == 2, "each human has a token of their own"


def test_a_silent_tls_server_fails_the_page_instead_of_hanging_it(tmp_path: Path) -> None:
    """The test client's own guard (``_WakingConnection``): a TLS 1.3 server that never
    answers the upgrade makes the opening time out and raise, in about its timeout, not
    hang in websockets' join of its reader (which the plain client does)."""
    ca = trustme.CA()
    server_ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ca.issue_cert("127.0.0.1").configure_cert(server_ctx)
    client_ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ca.configure_trust(client_ctx)
    listener = socket.create_server(("127.0.0.1", 0))
    release = threading.Event()

    def silent() -> None:
        conn, _ = listener.accept()
        with server_ctx.wrap_socket(conn, server_side=True) as tls:
            tls.recv(4096)  # the upgrade request, never answered
            release.wait(30)

    threading.Thread(target=silent, daemon=True).start()
    outcome: list[BaseException] = []

    def open_() -> None:
        try:
            connect(f"wss://127.0.0.1:{listener.getsockname()[1]}/ws", proxy=None,
                    ssl=client_ctx, open_timeout=1, create_connection=_WakingConnection)
        except BaseException as exc:
            outcome.append(exc)

    opener = threading.Thread(target=open_, daemon=True)
    started = time.monotonic()
    opener.start()
    opener.join(10)
    release.set()
    listener.close()
    assert not opener.is_alive(), "the opening hung past its timeout"
    assert time.monotonic() - started < 5
    assert len(outcome) == 1 and isinstance(outcome[0], TimeoutError)
