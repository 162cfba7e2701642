"""``ConsoleCore``: what every operator console does, whatever shows its frames.

Two consoles face the humans: OpenCV windows on the controller's desktop
(``gui.console.ConsoleHumans``) and pages in each human's own browser
(``gui.web.WebHumans``). They differ only in how a frame reaches a person and how a
key or click comes back, so everything else lives here, once:

* the ``Humans`` protocol: ``act`` (wait until every teleop request has its push, never
  for a hard reset), ``show`` (the overview), pause and the confirmed graceful stop;
* one ``Desk`` per human (``gui.desk``: which input counts for which frame), the frame
  sequence numbers, what is on screen, and the allocation-to-paint latencies;
* rendering with ``gui.draw`` (the same pixels in a window and in a page) and input
  meaning with ``gui.keys`` (``KeyCommand``: a key, a button or a click all end there).

A subclass owns its surfaces: it implements ``_has_surface(wid)`` and
``_post(wid, seq, frame)``, calls ``_on_command`` / ``_on_click`` / ``_on_shown`` with
``self._cond`` held when an input or a paint report arrives, and may override
``_gave_up`` (stop waiting for a human: the web console's away humans) and
``_changed`` (after any redraw: the OpenCV console's state file). Window ids: humans
are ``0..M-1``, the fleet overview is ``OVERVIEW``.

Time to first action (``HumanResponse.waited_s``): each ``Desk`` times an intervention
from the moment a frame showing it was first on that human's screen to the key, click
or button that first pushed or confirmed the reset. Both ends are stamped on this
process's ``time.monotonic()`` clock and each surface says which moment it can honestly
stamp: the ``at`` of ``_on_command`` / ``_on_click`` (the input) and the ``seen_at`` of
``_on_shown`` (the frame on screen). The OpenCV windows stamp both themselves (same
machine, system-wide monotonic clock): the key or click as HighGUI delivered it, the
frame when the ``waitKeyEx`` that lets Qt paint it returned. The browser console stamps
both as its page's reports arrive at the server (``gui.web.web_humans``).
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from gui.desk import Desk
from gui.errors import StopRequested
from gui.keys import Command, KeyCommand
from gui.layout import ConsoleLayout, Point
from gui.view import ConsoleView, Phase, check_places, human_label, place_tag
from testbed.core.humans import reset_taker
from testbed.core.types import FleetStatus, HumanRequest, HumanResponse, InterventionKind

TELEOP: Final = InterventionKind.TELEOP
OVERVIEW: Final = -1
"""Window id of the fleet overview (humans are 0..M-1)."""

Frame = npt.NDArray[np.uint8]


def check_names(names: Sequence[str], num_humans: int) -> tuple[str, ...]:
    """The humans' names as a console shows them, or a ValueError saying what is wrong.

    Why checked here and not only in the config: a console built by a script or a test
    gets no config, and a name is put in window titles and pages, where an empty one, a
    line break or a twin would name the wrong person (or nobody).
    """
    given = tuple(names)
    if not given:
        return ()
    if len(given) != num_humans:
        raise ValueError(f"names: need {num_humans} (one per human), got {len(given)}")
    for i, name in enumerate(given):
        if not isinstance(name, str) or not name.strip() or not name.isprintable():
            raise ValueError(f"names[{i}]: {name!r} is not a name to show")
        if name in given[:i]:
            raise ValueError(f"names[{i}]: {name!r} twice; each human needs their own")
    return given


@dataclass(frozen=True, slots=True)
class FrameLatency:
    """From ``act`` being called with a request to that request's frame on screen."""

    human: int
    seq: int
    robot: str
    t_act: float
    t_imshow: float
    """``time.monotonic()`` when the frame left for the screen (window: ``cv2.imshow``
    returned; page: the server sent it)."""
    t_painted: float
    """... and when it was painted (window: the next ``waitKeyEx(1)`` returned, where Qt
    paints; page: the browser's animation frame after drawing it, by the page's clock)."""

    @property
    def imshow_ms(self) -> float:
        return (self.t_imshow - self.t_act) * 1e3

    @property
    def painted_ms(self) -> float:
        return (self.t_painted - self.t_act) * 1e3


@dataclass(frozen=True, slots=True)
class WindowState:
    """What one human's surface shows, and whether the latest frame is on screen."""

    human: int
    window: str
    phase: Phase
    robot: str | None
    kind: str | None
    markers: tuple[Point, ...]
    seq_posted: int
    seq_shown: int

    @property
    def on_screen(self) -> bool:
        return self.seq_shown >= self.seq_posted > 0

    def as_json(self) -> dict[str, Any]:
        return {
            "human": self.human, "window": self.window, "phase": self.phase.value,
            "robot": self.robot, "kind": self.kind,
            "markers": [list(p) for p in self.markers],
            "seq_posted": self.seq_posted, "seq_shown": self.seq_shown,
            "on_screen": self.on_screen,
        }


class ConsoleCore:
    """The console logic shared by the OpenCV and the browser consoles (see module doc).

    ``teleop_timeout_s``: if set, ``act`` gives up waiting for a push after this many
    seconds (paused time not counted) and answers ``action=None`` for that arm.
    Requests for a human index >= ``num_humans`` go to human ``index % num_humans``.
    ``names``: each human's name, by index (the config's ``humans.people``), shown on
    every surface beside the index (``gui.view.human_label``); empty: "human i".
    ``places``: each human's place, by index (``"on_site"`` / ``"remote"``), shown beside
    the name on their surface and the overview's (``gui.view.place_tag``); empty: none.
    """

    def __init__(self, num_humans: int, *, names: Sequence[str] = (),
                 places: Sequence[str] = (), scale: int = 6,
                 teleop_timeout_s: float | None = None) -> None:
        if num_humans < 1:
            raise ValueError(f"num_humans must be >= 1, got {num_humans}")
        self.num_humans = num_humans
        self.names = check_names(names, num_humans)
        self.places = check_places(places, num_humans)
        self.layout = ConsoleLayout(scale=scale)
        self.teleop_timeout_s = teleop_timeout_s
        self._cond = threading.Condition(threading.RLock())
        self._desks = [Desk(h, self.layout, name=self.human_name(h),
                            place=self.human_place(h))
                       for h in range(num_humans)]
        self._seq = 0
        self._serial = 0
        self._posted: dict[int, int] = defaultdict(int)
        self._shown: dict[int, int] = defaultdict(int)
        self._paused = False
        self._stop_reason: str | None = None
        self._confirming: set[int] = set()
        self._status: FleetStatus | None = None
        self._num_robots: int | None = None
        self._pending: dict[tuple[int, int], tuple[float, str]] = {}
        self._latencies: deque[FrameLatency] = deque(maxlen=10_000)
        self._closed = False
        self.on_stop: Callable[[], None] | None = None
        """Called, in a thread of its own, when a human confirms Stop: the trial sets it
        to stop the motions in flight (a push of seconds would otherwise run to its end
        before ``act``/``show`` can raise)."""

    # ---- for subclasses -------------------------------------------------------------
    def _has_surface(self, wid: int) -> bool:
        raise NotImplementedError

    def _post(self, wid: int, seq: int, frame: Frame) -> None:
        """Hand frame ``seq`` to surface ``wid``; must never block on a person."""
        raise NotImplementedError

    def _gave_up(self, human: int, t_act: float, now: float) -> bool:
        """True to stop waiting for ``human``'s push in the current ``act`` call."""
        return False

    def _changed(self) -> None:
        """Called after each redraw and paint report (under the lock)."""

    def surface_name(self, wid: int) -> str:
        return "fleet overview" if wid == OVERVIEW else self.human_label(wid)

    def human_name(self, human: int) -> str | None:
        """Human ``human``'s name, or None when the console was given no names."""
        return self.names[human] if self.names else None

    def human_place(self, human: int) -> str | None:
        """Human ``human``'s place, or None when the console was given no places."""
        return self.places[human] if self.places else None

    def overview_label(self, human: int) -> str:
        """``"ana (human 0), remote"``: the label, and the place when told."""
        tag = place_tag(self.human_place(human))
        return self.human_label(human) + (f", {tag}" if tag else "")

    def human_label(self, human: int) -> str:
        """``"ana (human 0)"`` (or ``"human 0"``): what every surface calls this human."""
        return human_label(human, self.human_name(human))

    def _mark_closed(self) -> bool:
        """Mark the console closed (``act``/``show`` raise from now on); False if it
        already was, so a subclass's ``close`` is safe to call twice."""
        with self._cond:
            if self._closed:
                return False
            self._closed = True
            self._cond.notify_all()
            return True

    # ---- Humans protocol -------------------------------------------------------------
    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        """Show each human their request; return when every teleop request has a push."""
        t_act = time.monotonic()
        groups: dict[int, list[HumanRequest]] = defaultdict(list)
        for req in requests:  # a reset for a remote person goes to one on site
            h = req.human % self.num_humans
            groups[h if req.kind is TELEOP else reset_taker(h, self.places)].append(req)
        with self._cond:
            self._raise_if_stopped()
            self._serial += 1
            went_idle = []
            for h, desk in enumerate(self._desks):
                if desk.has_request() and h not in groups:
                    went_idle.append(h)
                desk.assign(groups.get(h, []), t, self._serial)
            for h in groups:  # the humans with work first: they are waited for
                seq = self._redraw(h)
                if seq is not None:
                    self._pending[(h, seq)] = (t_act, groups[h][0].robot)
            for h in went_idle:
                self._redraw(h)
            self._wait_for_answers(t_act)
            out: dict[str, HumanResponse] = {}
            for desk in self._desks:
                out.update(desk.responses())
            for h, reqs in groups.items():  # timed out: the page must stop asking
                if any(out[r.robot].action is None for r in reqs if r.kind is TELEOP):
                    self._redraw(h)
            return out

    def _wait_for_answers(self, t_act: float) -> None:
        waited = 0.0
        last = time.monotonic()
        while True:
            self._raise_if_stopped()
            now = time.monotonic()
            if not self._paused:
                waited += now - last
            last = now
            if not self._paused:
                if not any(d.needs_input() and not self._gave_up(h, t_act, now)
                           for h, d in enumerate(self._desks)):
                    return
                if self.teleop_timeout_s is not None and waited >= self.teleop_timeout_s:
                    return
            self._cond.wait(0.1)

    def show(self, t: int, status: FleetStatus) -> None:
        """Update the overview; blocks while paused; raises ``StopRequested`` if asked."""
        with self._cond:
            self._status = status
            if self._num_robots is None or len(status.robots) > self._num_robots:
                self._num_robots = len(status.robots)
            self._redraw(OVERVIEW)
            while self._paused and self._stop_reason is None:
                self._cond.wait(0.1)
            self._raise_if_stopped()

    # ---- state for the loop, tests and the benchmark --------------------------------
    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def stop_requested(self) -> bool:
        return self._stop_reason is not None

    def face_click_point(self, human: int, action: int) -> Point:
        """Frame coordinates to click for push ``action`` on the request on screen."""
        with self._cond:
            view = self._desks[human].view()
            if view.phase is not Phase.CHOOSE or not view.markers:
                raise LookupError(f"human {human} has no teleop request to click on")
            return view.markers[action]

    def snapshot(self, human: int) -> WindowState:
        with self._cond:
            return self._window_state(human, self._desks[human].view())

    def wait_for_prompt(self, human: int, timeout_s: float = 10.0) -> WindowState:
        """Block until human ``human``'s surface shows a frame that asks for input."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                state = self.snapshot(human)
                if state.on_screen and state.phase in (Phase.CHOOSE, Phase.RESET):
                    return state
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"human {human}'s console shows no prompt: {state}")
                self._cond.wait(min(left, 0.1))

    def frame_latencies(self) -> list[FrameLatency]:
        with self._cond:
            return list(self._latencies)

    # ---- internals (all under self._cond) ----------------------------------------------
    def _raise_if_stopped(self) -> None:
        if self._stop_reason is not None:
            raise StopRequested(self._stop_reason)
        if self._closed:
            raise StopRequested("the console was closed")

    def _window_state(self, human: int, view: ConsoleView) -> WindowState:
        req = view.request
        return WindowState(
            human, self.surface_name(human), view.phase,
            req.robot if req else None, req.kind.value if req else None,
            view.markers if view.phase is Phase.CHOOSE else (),
            self._posted[human], self._shown[human],
        )

    def _flags(self, wid: int) -> dict[str, bool]:
        return {
            "paused": self._paused,
            "confirming_stop": wid in self._confirming,
            "stop_requested": self._stop_reason is not None,
        }

    def _redraw(self, wid: int) -> int | None:
        """Render surface ``wid`` from the current state and post it; returns its seq."""
        from gui import draw  # lazy: cv2 only once a console exists

        if not self._has_surface(wid):
            return None
        self._seq += 1
        seq = self._seq
        if wid == OVERVIEW:
            frame = draw.render_overview(self._status, num_robots=self._num_robots,
                                         humans=[self.overview_label(h)
                                                 for h in range(self.num_humans)],
                                         **self._flags(wid))
        else:
            desk = self._desks[wid]
            view = Desk.with_flags(desk.view(), **self._flags(wid))
            frame = draw.render_console(view, self.layout)
            desk.register(seq, view, time.monotonic())
        self._posted[wid] = seq
        self._post(wid, seq, frame)
        self._changed()
        return seq

    def _redraw_all(self) -> None:
        for wid in [*range(self.num_humans), OVERVIEW]:
            self._redraw(wid)

    def _toggle_pause(self) -> None:
        self._paused = not self._paused
        self._redraw_all()
        self._cond.notify_all()

    def _on_command(self, wid: int, seq: int, cmd: KeyCommand | None,
                    at: float | None = None) -> bool:
        """A key or a button on surface ``wid`` whose frame ``seq`` was on screen, made
        at ``at`` (``time.monotonic()``; default: now, as it arrives).

        Returns True if it was taken (a push or a reset confirmation that counted, a
        pause, a stop step), False if it was refused (stale frame, paused, no request).
        """
        at = time.monotonic() if at is None else at
        if cmd is None:
            return False
        taken = False
        if wid in self._confirming:
            self._confirming.discard(wid)
            if cmd.command is Command.YES:
                self._stop_reason = f"stop confirmed by {self.surface_name(wid)}"
                if self.on_stop is not None:  # never under our lock, never blocking input
                    threading.Thread(target=self.on_stop, name="console-stop",
                                     daemon=True).start()
                self._redraw_all()
            else:  # "go on": the question is answered all the same
                self._redraw(wid)
            taken = True
        elif cmd.command is Command.STOP:
            self._confirming.add(wid)
            self._redraw(wid)
            taken = True
        elif cmd.command is Command.PAUSE:
            self._toggle_pause()
            taken = True
        elif wid != OVERVIEW and not self._paused:
            desk = self._desks[wid]
            if cmd.command is Command.PUSH and cmd.action is not None:
                taken = desk.on_push(cmd.action, seq, at)
            elif cmd.command is Command.CONFIRM:
                taken = desk.on_confirm(seq, at)
            if taken:
                self._redraw(wid)
        self._cond.notify_all()
        return taken

    def _on_click(self, wid: int, seq: int, x: float, y: float,
                  at: float | None = None) -> bool:
        """A click at frame pixel (x, y) on frame ``seq``, made at ``at`` (default now)."""
        if wid == OVERVIEW or self._paused or wid in self._confirming:
            return False
        at = time.monotonic() if at is None else at
        taken = self._desks[wid].on_click((x, y), seq, at)
        if taken:
            self._redraw(wid)
            self._cond.notify_all()
        return taken

    def _on_shown(self, wid: int, seq: int, t_imshow: float, t_painted: float,
                  seen_at: float | None = None) -> None:
        """Frame ``seq`` of surface ``wid`` is on screen; ``seen_at`` (default
        ``t_painted``) is the moment that starts an intervention's time to first action."""
        self._shown[wid] = max(self._shown[wid], seq)
        if wid != OVERVIEW:
            self._desks[wid].on_shown(seq, t_painted if seen_at is None else seen_at)
        pending = self._pending.pop((wid, seq), None)
        if pending is not None:
            t_act, robot = pending
            self._latencies.append(FrameLatency(wid, seq, robot, t_act, t_imshow, t_painted))
        # a frame replaced before it was shown never will be: forget its stamp
        for key in [k for k in self._pending if k[0] == wid and k[1] < seq]:
            del self._pending[key]
        if wid != OVERVIEW:
            self._changed()
        self._cond.notify_all()
