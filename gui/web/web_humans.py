"""``WebHumans``: the fleet's humans, each at a console page on their own device.

Why a browser console beside the OpenCV one: the paper's robots stand half a mile
apart. A hard reset needs a person at that robot, a teleop only a screen anywhere, so
every human needs a console on their own phone or laptop, not a window on the
controller's desktop. The page shows the very frames the OpenCV window shows (rendered
here by ``gui.draw`` through ``gui.console_core.ConsoleCore``) and its keys, clicks, taps and
buttons mean what they mean there (``gui.keys``).

::

    fleet loop thread            ConsoleCore (lock)            server thread (asyncio)
    act / show  --render, PNG-->  FrameHub.post  --wake-->  send loop --> each page
    presence()  <-- who is connected, since when <-- connect / close of a page
                <-- handle(key, click, button, painted) <-- page (worker thread)

Humans come and go. A human with no open page is away: ``presence()`` marks them
unavailable, so the allocator gives them nothing new; ``act`` waits for an away
human's push at most ``away_timeout_s`` (then the arm's step passes with no push); a
held intervention goes on through ``grace_s`` (a reload, a dropped Wi-Fi) and then
``presence().gone`` tells the loop to end it, which the step row records.

Security: the server listens on loopback unless ``host`` says otherwise; every page,
frame and input needs its human's token (``gui.web.tokens``); TLS when a certificate
and key are given.
"""

from __future__ import annotations

import functools
import html
import sys
import time
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from gui.console_core import OVERVIEW, ConsoleCore, Frame
from gui.keys import BUTTONS, Command, decode_browser_key
from gui.view import Phase
from gui.web.links import link_base, link_lines
from gui.web.server import FrameHub, WebServer, build_app
from gui.web.tls import certificate_fingerprint, console_certificate
from gui.web.tokens import TokenBook
from testbed.core.humans import Presence, place_words
from testbed.core.types import FleetStatus

if TYPE_CHECKING:
    from testbed.people.people_config import WebConsoleConfig

_ANNOUNCED: set[tuple[str, ...]] = set()
"""The URLs printed so far by this process (each set once)."""
OPERATOR_COMMANDS = (Command.PAUSE, Command.STOP)
"""What only the operator's overview may do (issue 44): one person's pause or stop would
hold or end the trial for everybody."""
OPERATOR_ONLY = ("pause and stop are the operator's (their overview link, or Ctrl-C where "
                 "the trial runs)")


HISTORY_MAX = 100_000
"""Overview curve points kept for a page that opens mid-trial (one per step)."""


def _encode_png(frame: Frame) -> bytes:
    """Lossless, so the page shows the OpenCV window's very pixels (the tests compare).

    Run-length deflate: 5 ms for a console frame against 7 ms at the default strategy
    (JPEG would take 0.6 ms but blurs the 1-pixel overlays; PNG decodes off the page's
    main thread in ``createImageBitmap``). About 30 KB a frame.
    """
    import cv2  # either OpenCV build: encoding is in both

    ok, buf = cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, 1,
                                           cv2.IMWRITE_PNG_STRATEGY,
                                           cv2.IMWRITE_PNG_STRATEGY_RLE])
    if not ok:
        raise RuntimeError("PNG encoding of a console frame failed")
    return buf.tobytes()


def fleet_doc(status: FleetStatus, names: Sequence[str] = ()) -> dict[str, Any]:
    """The ``"fleet"`` text of the human pages: counters, and each arm's mode and human.

    Text, not a frame: a page with no arm shows it as HTML (readable on a phone, found by
    its words), and one text serves every page without rendering a frame per human.
    With ``names`` (by human index), an arm held by a named human also has its ``name``,
    so the page says who holds it; unnamed, the text is what it always was.
    Each arm has ``waited`` (the steps it has waited for a human, its row's ``"waited"``;
    null when not waiting), and ``queue`` lists the waiting arms, longest wait first
    (ties in the fleet's order): who needs a person most, read without a frame.
    """
    counters = ("t", "steps", "successes", "hard_resets", "idle_time", "human_actions")
    robots = [_robot_doc(r.robot, r.mode.value, r.human, names, r.waited)
              for r in status.robots]
    return {  # int(): a loop may count in numpy integers, which JSON does not take
        "type": "fleet", **{k: int(getattr(status, k)) for k in counters},
        "rohe": round(float(status.rohe), 5), "paused": bool(status.paused),
        "robots": robots, "health": status.health(names),
        "queue": [{"robot": r["robot"], "mode": r["mode"], "waited": r["waited"]}
                  for r in sorted((r for r in robots if r["waited"] is not None),
                                  key=lambda r: -r["waited"])],
    }


def operators_doc(status: FleetStatus | None,
                  name_of: Callable[[int], dict[str, str]]) -> list[dict[str, Any]]:
    """The overview's rows of the humans' estimates (``FleetStatus.operators``), by
    index, each with its ``name`` when the human has one: text the page shows as a
    table, so a reader finds a person's figures by their name."""
    if status is None:
        return []
    return [{"human": int(e.human), **name_of(e.human), "skill": float(e.skill),
             "violations": float(e.violations), "reset_steps": float(e.reset_steps),
             "latency_steps": float(e.latency_steps), "pushes": int(e.pushes),
             "resets": int(e.resets)} for e in status.operators]


def _robot_doc(robot: str, mode: str, human: int | None, names: Sequence[str],
               waited: int | None = None) -> dict[str, Any]:
    """One arm of the ``"fleet"`` text; ``name`` only when its human has one."""
    doc: dict[str, Any] = {"robot": robot, "mode": mode,
                           "human": None if human is None else int(human),
                           "waited": None if waited is None else int(waited)}
    if human is not None and 0 <= human < len(names):
        doc["name"] = names[human]
    return doc


@functools.cache
def _page_template(overview: bool) -> str:
    """A page with its script and style inlined (so nothing is served without a token),
    read from the package once."""
    static = resources.files("gui.web").joinpath("static")
    html = static.joinpath("overview.html" if overview else "human.html").read_text()
    return (html.replace("/*CONSOLE_JS*/", static.joinpath("console.js").read_text())
            .replace("/*CONSOLE_CSS*/", static.joinpath("console.css").read_text()))


class WebHumans(ConsoleCore):
    """M people answering the fleet's interventions from console pages in browsers.

    ``WebHumans(2)`` starts the server and prints each human's URL once (to
    ``announce``, stderr by default); ``urls`` has them too. Use it as a context
    manager or call ``close()``. Without ``tokens``, every console of this process uses
    the same random ones, so a protocol's trials keep their URLs (a fixed ``port``
    too: the pages reconnect by themselves between trials). ``names``: each human's
    name, on their printed link, their page and the fleet's pages (empty: "human i").
    ``places``: each human's place (``"on_site"`` / ``"remote"``), on their page (what
    they will be given) and beside their name on the overview (empty: not shown).
    """

    def __init__(
        self,
        num_humans: int,
        *,
        names: Sequence[str] = (),
        places: Sequence[str] = (),
        host: str = "127.0.0.1",
        port: int = 0,
        tokens: list[str] | None = None,
        overview_token: str | None = None,
        operator_token: str | None = None,
        public_url: str | None = None,
        resumed_at: int | None = None,
        tls: str = "auto",
        tls_dir: Path | None = None,
        certfile: str | None = None,
        keyfile: str | None = None,
        grace_s: float = 10.0,
        away_timeout_s: float = 5.0,
        teleop_timeout_s: float | None = None,
        scale: int = 6,
        announce: TextIO | None = sys.stderr,
    ) -> None:
        super().__init__(num_humans, names=names, places=places, scale=scale,
                         teleop_timeout_s=teleop_timeout_s)
        certfile, keyfile, self_signed_here = console_certificate(host, tls, tls_dir,
                                                                  certfile, keyfile)
        self.fingerprint = None if certfile is None else certificate_fingerprint(certfile)
        """The certificate's SHA-256 fingerprint when the console serves https."""
        self.tokens = TokenBook(tokens, overview_token, operator_token) if tokens else \
            TokenBook.for_session(num_humans)
        self.resumed_at = resumed_at
        if len(self.tokens) != num_humans:
            raise ValueError(f"humans.web.tokens: need {num_humans} tokens (one per human), "
                             f"got {len(self.tokens)}")
        self.grace_s = grace_s
        self.away_timeout_s = away_timeout_s
        now = time.monotonic()
        self._pages = [0] * num_humans
        self._away_since: list[float] = [now] * num_humans
        """Per human: when their last page closed (start: never opened yet)."""
        self._overview_pages = 0
        self._history: list[dict[str, Any]] = []
        self._hub = FrameHub()
        self._server = WebServer(build_app(self, self._hub), host, port,
                                 certfile=certfile, keyfile=keyfile)
        self._server.start()
        self.link_base = link_base(self.base_url, public_url)
        self.urls = [f"{self.link_base}/?token={self.tokens.token(h)}"
                     for h in range(num_humans)]
        self.overview_url = f"{self.link_base}/overview?token={self.tokens.overview}"
        """The read-only overview (a link to share with whoever should watch)."""
        self.operator_url = f"{self.link_base}/overview?token={self.tokens.operator}"
        """The operator's overview: pause and stop (for the operator alone)."""
        if announce is not None and (self.base_url, *self.urls) not in _ANNOUNCED:
            _ANNOUNCED.add((self.base_url, *self.urls))  # once: a protocol's next trial
            lines = link_lines([self.human_label(h) for h in range(num_humans)], self.urls,
                               self.overview_url, self.operator_url, self.fingerprint,
                               self_signed_here, resumed_at)
            print("\n".join(lines), file=announce, flush=True)
        with self._cond:
            self._redraw_all()

    @classmethod
    def from_config(cls, count: int, cfg: WebConsoleConfig | None = None, *,
                    names: Sequence[str] = (), places: Sequence[str] = (),
                    resumed_at: int | None = None) -> WebHumans:
        """Built from ``[humans.web]`` (``testbed.people.people_config.WebConsoleConfig``) and the
        humans' ``names`` and ``places`` (``humans.people``; empty: "human i", untold)."""
        if cfg is None:
            from testbed.people.people_config import WebConsoleConfig

            cfg = WebConsoleConfig()
        return cls(
            count, names=names, places=places, host=cfg.host, port=cfg.port,
            tokens=list(cfg.tokens) or None,
            overview_token=cfg.overview_token, operator_token=cfg.operator_token,
            public_url=cfg.public_url, resumed_at=resumed_at, tls=cfg.tls,
            certfile=cfg.certfile,
            keyfile=cfg.keyfile, grace_s=cfg.grace_s,
            away_timeout_s=cfg.away_timeout_s, teleop_timeout_s=cfg.teleop_timeout_s,
        )

    @property
    def base_url(self) -> str:
        return self._server.base_url

    @property
    def port(self) -> int:
        return self._server.port

    # ---- who is here -------------------------------------------------------------------
    def presence(self) -> Presence:
        """Humans with a page open are available; away past ``grace_s``: gone."""
        with self._cond:
            now = time.monotonic()
            here = np.array([n > 0 for n in self._pages], dtype=bool)
            gone = frozenset(h for h in range(self.num_humans)
                             if not here[h] and now - self._away_since[h] >= self.grace_s)
            return Presence(here, gone)

    def present(self, human: int) -> bool:
        with self._cond:
            return self._pages[human] > 0

    def _gave_up(self, human: int, t_act: float, now: float) -> bool:
        if self._pages[human] > 0:
            return False
        return now - max(self._away_since[human], t_act) >= self.away_timeout_s

    # ---- ConsoleCore's surfaces: pages -------------------------------------------------
    def surface_name(self, wid: int) -> str:
        return ("the fleet overview page" if wid == OVERVIEW
                else f"{self.human_label(wid)}'s page")

    def _has_surface(self, wid: int) -> bool:
        return not self._closed

    def _post(self, wid: int, seq: int, frame: Frame) -> None:
        header: dict[str, Any] = {"seq": seq, "paused": self._paused,
                                  "confirming_stop": wid in self._confirming,
                                  "stop_requested": self._stop_reason is not None}
        if wid == OVERVIEW:
            header["humans"] = [{"human": h, "present": self._pages[h] > 0,
                                 "phase": self._desks[h].view().phase.value,
                                 **self._name_of(h)}
                                for h in range(self.num_humans)]
            header["operators"] = operators_doc(self._status, self._name_of)
            if self._history:
                header["point"] = self._history[-1]
        else:
            view = self._desks[wid].view()
            req = view.request
            header |= {"human": wid, **self._name_of(wid), "phase": view.phase.value,
                       "robot": req.robot if req else None,
                       "kind": req.kind.value if req else None,
                       "markers": [list(p) for p in view.markers]
                       if view.phase is Phase.CHOOSE else []}
        self._hub.post(wid, _encode_png(frame), header)

    def _name_of(self, human: int) -> dict[str, str]:
        """``{"name": ...}`` for a named human, and ``"where"`` (``on_site``, ``remote``)
        when the console knows it; ``{}`` otherwise: an unnamed console's headers stay
        what they were, and a page falls back to "human i" without it."""
        name, place = self.human_name(human), self.human_place(human)
        return ({} if name is None else {"name": name}) | (
            {} if place is None else {"where": place})

    def show(self, t: int, status: FleetStatus) -> None:
        """The overview's frame and curve point, and the fleet's state on every human's
        page (what a human with no arm sees instead of an empty image)."""
        with self._cond:
            self._history.append({
                "t": status.t, "successes": status.successes,
                "hard_resets": status.hard_resets, "human_actions": status.human_actions,
                "idle": status.idle_time, "rohe": round(status.rohe, 5),
                "modes": [str(r.mode) for r in status.robots],
                "health": status.health(self.names),
            })
            del self._history[:-HISTORY_MAX]
            self._hub.post_fleet(fleet_doc(status, self.names))
        super().show(t, status)

    # ---- the server's calls (worker threads) -------------------------------------------
    def human_of(self, token: str | None) -> int | None:
        return self.tokens.human_of(token)

    def overview_role(self, token: str | None) -> str | None:
        return self.tokens.overview_role(token)

    def page(self, wid: int, controls: bool = False) -> str:
        """The page of surface ``wid``; a human's is headed with their label, escaped
        (a name is text, never markup, whatever a script passed as one). Pause and stop
        are shown with the operator's ``controls`` only; a resumed trial says so."""
        overview = wid == OVERVIEW
        label = "" if overview else html.escape(self.human_label(wid))
        text = _page_template(overview).replace("HUMAN_LABEL", label)
        text = text.replace("<!--NOTICE-->", html.escape(self.resume_notice()))
        place = None if overview else self.human_place(wid)
        text = text.replace("<!--PLACE-->", "" if place is None else
                            html.escape(f"You are {place_words(place)}."))
        if not controls:
            text = text.replace('<button id="pause"', '<button id="pause" hidden').replace(
                '<button class="stop" id="stop"', '<button class="stop" id="stop" hidden')
        return text

    def resume_notice(self) -> str:
        """What every page says of a resumed trial ("" for one that was not): on a page
        loaded now, and on one left open through the crash, which finds the console
        again by itself and is told on its new socket (``connected``)."""
        if self.resumed_at is None:
            return ""
        return (f"This trial was resumed at step {self.resumed_at}; your link is the one "
                f"given at its start.")

    def connected(self, wid: int) -> list[dict[str, Any]]:
        session = ([{"type": "session", "notice": self.resume_notice()}]
                   if self.resumed_at is not None else [])
        with self._cond:
            if wid == OVERVIEW:
                self._overview_pages += 1
                return [{"type": "history", "points": list(self._history)}, *session]
            self._pages[wid] += 1
            self._redraw(OVERVIEW)  # the overview shows who is here
            self._cond.notify_all()
            return session

    def disconnected(self, wid: int) -> None:
        with self._cond:
            if wid == OVERVIEW:
                self._overview_pages -= 1
                return
            self._pages[wid] -= 1
            if self._pages[wid] == 0:
                self._away_since[wid] = time.monotonic()
            if not self._closed:
                self._redraw(OVERVIEW)
            self._cond.notify_all()

    def handle(self, wid: int, msg: Any) -> dict[str, Any] | None:
        """One message from a page; the reply says whether an input was taken.

        Its arrival is the moment stamped on it for the time to first action: the
        page's own clock may be another device's, set seconds apart, while arrival is
        on this process's clock and late by the same uplink delay for the paint report
        that starts the wait as for the key, click or button that ends it.
        """
        arrived = time.monotonic()
        if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
            return {"type": "error", "why": "not a console message"}
        kind = msg["type"]
        try:
            seq = int(msg.get("seq", -1))
            if kind == "painted":
                self._painted(wid, seq, float(msg["t_sent"]), float(msg["t_painted"]),
                              arrived)
                return None
            cmd = decode_browser_key(str(msg["key"])) if kind == "key" else \
                BUTTONS.get(str(msg.get("name"))) if kind == "button" else None
            if wid != OVERVIEW and cmd is not None and cmd.command in OPERATOR_COMMANDS:
                return {"type": "input", "seq": seq, "taken": False, "why": OPERATOR_ONLY,
                        "id": msg.get("id")}
            with self._cond:
                if kind == "key" or (kind == "button" and cmd is not None):
                    taken = self._on_command(wid, seq, cmd, arrived)
                elif kind == "click":
                    taken = self._on_click(wid, seq, float(msg["x"]), float(msg["y"]),
                                           arrived)
                else:
                    return {"type": "error", "why": f"unknown message {kind!r}"}
                why = None if taken else self._why_refused(wid, seq)
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            return {"type": "error", "why": f"malformed {kind!r} message ({exc})"}
        return {"type": "input", "seq": seq, "taken": taken, "why": why,
                "id": msg.get("id")}

    def _why_refused(self, wid: int, seq: int) -> str:
        if self._stop_reason is not None:
            return "the trial is stopping"
        if self._paused:
            return "paused"
        if wid != OVERVIEW and seq < self._posted[wid]:
            return "stale: that frame's request is over"
        return "nothing to answer on that frame"

    def _painted(self, wid: int, seq: int, t_sent_ms: float, t_painted_ms: float,
                 arrived: float) -> None:
        """The page's own clock (epoch ms) -> this process's monotonic clock, for the
        latencies; the report's ``arrived`` starts a time to first action (``handle``)."""
        offset = time.time() - time.monotonic()
        with self._cond:
            if seq > self._posted[wid]:
                return  # a page cannot report a frame not yet sent
            self._on_shown(wid, seq, t_sent_ms / 1e3 - offset, t_painted_ms / 1e3 - offset,
                           seen_at=arrived)

    def close(self) -> None:
        """Stop the server (every page sees the socket close); safe to call twice."""
        if self._mark_closed():
            self._server.stop()

    def __enter__(self) -> WebHumans:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
