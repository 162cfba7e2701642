"""``ConsoleHumans``: the ``Humans`` of the fleet loop, played by people at OpenCV windows.

Threading model (why: one slow human must never freeze another's window, nor the
fleet the screen, nor the screen the fleet)::

    fleet loop thread                 pump thread                    window processes
    -----------------                 -----------                    ----------------
    act(requests, t)  --render-->  post(frame) -> mailbox -> sender thread -> human 0
      waits on the condition                                         -> human 1 ...
      until every teleop has          wait(all pipes) <-- key/click/shown -- each one
      a push (and not paused)         Desk.on_push/on_confirm,
    show(t, status) --render-->       pause, Esc+y; re-render;      -> fleet overview
                                      notify the condition

* Each window is its own process with its own HighGUI thread (``gui.window`` says why).
* The console's state (one ``Desk`` per human, pause, stop) sits behind one lock; the
  pump thread applies inputs the moment they arrive, so a human's Enter, pause or Esc
  shows at once even while the loop is busy executing pushes.
* ``act`` returns as soon as every teleop request has its push; hard resets never make
  it wait (``reset_done`` is False until the human pressed Enter, the loop asks again).
* Pause (p or space, any window) blocks ``act`` and ``show``; Esc then y in any window
  makes ``act`` and ``show`` raise ``StopRequested`` (a ``HumansStopRequested``).

For tests and scripts: ``window_name(h)``, ``overview_name``, ``face_click_point(h, k)``,
``wait_for_prompt(h)``; with ``state_path`` (or ``$TESTBED_CONSOLE_STATE``) the console
writes what each window shows (phase, arm, face-marker points, frame shown) as JSON,
for tests that drive ``testbed trial --humans gui`` from outside with xdotool.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import threading
import time
from collections import defaultdict, deque
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import wait as wait_connections
from pathlib import Path
from typing import Any, Final

from gui.desk import Desk
from gui.display import check_window_system, default_display, explain_window_failure
from gui.errors import ConsoleUnavailable, StopRequested
from gui.keys import Command, decode_key
from gui.layout import ConsoleLayout, Point
from gui.view import ConsoleView, Phase
from gui.window import WindowProcess
from testbed.types import FleetStatus, HumanRequest, HumanResponse, InterventionKind

TELEOP: Final = InterventionKind.TELEOP
OVERVIEW: Final = -1
"""Window id of the fleet overview (humans are 0..M-1)."""
STATE_ENV: Final = "TESTBED_CONSOLE_STATE"
WINDOW_GAP_PX: Final = 12
TITLE_BAR_PX: Final = 40


def window_name(human: int, title: str = "testbed") -> str:
    """The title of human ``human``'s console window (``xdotool search --name`` it)."""
    return f"{title} console - human {human}"


def overview_window_name(title: str = "testbed") -> str:
    return f"{title} console - fleet overview"


@dataclass(frozen=True, slots=True)
class FrameLatency:
    """From ``act`` being called with a request to that request's frame on screen."""

    human: int
    seq: int
    robot: str
    t_act: float
    t_imshow: float
    """``time.monotonic()`` when ``cv2.imshow`` of the frame returned (window process)."""
    t_painted: float
    """... and when the following ``waitKeyEx(1)`` (Qt paints there) returned."""

    @property
    def imshow_ms(self) -> float:
        return (self.t_imshow - self.t_act) * 1e3

    @property
    def painted_ms(self) -> float:
        return (self.t_painted - self.t_act) * 1e3


@dataclass(frozen=True, slots=True)
class WindowState:
    """What one human's window shows, and whether the latest frame is on screen."""

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


class ConsoleHumans:
    """M people, each at a console window, answering the fleet's interventions.

    ``ConsoleHumans(num_humans=2)`` opens one window per human and the overview (on
    ``$DISPLAY``), or raises ``ConsoleUnavailable`` with one line saying what to do.
    Use it as a context manager or call ``close()``.

    ``teleop_timeout_s``: if set, ``act`` gives up waiting for a push after this many
    seconds (paused time not counted) and answers ``action=None`` for that arm.
    ``displays``: one X display per human (default: ``$DISPLAY`` for all); the overview
    opens on the first. Requests for a human index >= ``num_humans`` go to human
    ``index % num_humans`` (queued after that human's own).
    """

    def __init__(
        self,
        num_humans: int,
        *,
        scale: int = 6,
        title: str = "testbed",
        overview: bool = True,
        displays: Sequence[str | None] | None = None,
        teleop_timeout_s: float | None = None,
        start_timeout_s: float = 30.0,
        state_path: str | Path | None = None,
    ) -> None:
        if num_humans < 1:
            raise ValueError(f"num_humans must be >= 1, got {num_humans}")
        self.num_humans = num_humans
        self.title = title
        self.layout = ConsoleLayout(scale=scale)
        self.teleop_timeout_s = teleop_timeout_s
        disp = list(displays) if displays is not None else [default_display()] * num_humans
        if len(disp) != num_humans:
            raise ValueError(f"displays: need {num_humans} entries, got {len(disp)}")
        check_window_system(disp)
        state_env = os.environ.get(STATE_ENV)
        self._state_path = Path(state_path or state_env) if (state_path or state_env) else None

        self._cond = threading.Condition(threading.RLock())
        self._desks = [Desk(h, self.layout) for h in range(num_humans)]
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
        self._log_dir = Path(tempfile.mkdtemp(prefix="testbed-console-"))
        self._windows: dict[int, WindowProcess] = {}
        try:
            self._open_windows(disp, overview, start_timeout_s)
        except BaseException:
            self._close_windows()
            shutil.rmtree(self._log_dir, ignore_errors=True)
            raise
        self._pump = threading.Thread(target=self._pump_loop, name="console-pump", daemon=True)
        self._pump.start()
        with self._cond:
            for h in range(num_humans):
                self._redraw(h)
            if overview:
                self._redraw(OVERVIEW)

    # ---- windows ------------------------------------------------------------------------
    def window_name(self, human: int) -> str:
        return window_name(human, self.title)

    @property
    def overview_name(self) -> str:
        return overview_window_name(self.title)

    def window_position(self, wid: int) -> tuple[int, int]:
        """Where window ``wid`` (a human, or ``OVERVIEW``) is placed: humans side by side,
        the overview below them, so no window hides another (clicks land where aimed)."""
        if wid == OVERVIEW:
            return 0, self.layout.height + TITLE_BAR_PX + WINDOW_GAP_PX
        return wid * (self.layout.width + WINDOW_GAP_PX), 0

    def _open_windows(self, disp: list[str | None], overview: bool, timeout_s: float) -> None:
        wanted: list[tuple[int, str, str | None]] = [
            (h, self.window_name(h), disp[h]) for h in range(self.num_humans)
        ]
        if overview:
            wanted.append((OVERVIEW, self.overview_name, disp[0]))
        for wid, name, display in wanted:
            log = self._log_dir / f"window{wid}.log"
            self._windows[wid] = WindowProcess(
                name, position=self.window_position(wid), display=display, log_path=log
            )
        deadline = time.monotonic() + timeout_s
        for wid, _name, display in wanted:
            win = self._windows[wid]
            problem = win.wait_ready(max(0.1, deadline - time.monotonic()))
            if problem is not None:
                log_tail = _tail(self._log_dir / f"window{wid}.log")
                raise ConsoleUnavailable(explain_window_failure(display, problem, log_tail))

    # ---- Humans protocol -------------------------------------------------------------
    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        """Show each human their request; return when every teleop request has a push."""
        t_act = time.monotonic()
        groups: dict[int, list[HumanRequest]] = defaultdict(list)
        for req in requests:
            groups[req.human % self.num_humans].append(req)
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
            self._wait_for_answers()
            out: dict[str, HumanResponse] = {}
            for desk in self._desks:
                out.update(desk.responses())
            for h, reqs in groups.items():  # timed out: the window must stop asking
                if any(out[r.robot].action is None for r in reqs if r.kind is TELEOP):
                    self._redraw(h)
            return out

    def _wait_for_answers(self) -> None:
        waited = 0.0
        last = time.monotonic()
        while True:
            self._raise_if_stopped()
            now = time.monotonic()
            if not self._paused:
                waited += now - last
            last = now
            if not self._paused:
                if not any(d.needs_input() for d in self._desks):
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

    def close(self) -> None:
        """Close every window; safe to call twice."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        if self._pump.is_alive() and self._pump is not threading.current_thread():
            self._pump.join(2.0)
        self._close_windows()
        shutil.rmtree(self._log_dir, ignore_errors=True)

    def __enter__(self) -> ConsoleHumans:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- state for the loop, tests and the benchmark --------------------------------------
    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def stop_requested(self) -> bool:
        return self._stop_reason is not None

    def set_paused(self, paused: bool) -> None:
        """Pause or resume as if a human pressed p (e.g. from the CLI)."""
        with self._cond:
            if self._paused != paused:
                self._toggle_pause()

    def face_click_point(self, human: int, action: int) -> Point:
        """Window coordinates to click for push ``action`` on the request on screen."""
        with self._cond:
            view = self._desks[human].view()
            if view.phase is not Phase.CHOOSE or not view.markers:
                raise LookupError(f"human {human} has no teleop request to click on")
            return view.markers[action]

    def snapshot(self, human: int) -> WindowState:
        with self._cond:
            view = self._desks[human].view()
            return self._window_state(human, view)

    def wait_for_prompt(self, human: int, timeout_s: float = 10.0) -> WindowState:
        """Block until human ``human``'s window shows a frame that asks for input."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                state = self.snapshot(human)
                if state.on_screen and state.phase in (Phase.CHOOSE, Phase.RESET):
                    return state
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"human {human}'s window shows no prompt: {state}")
                self._cond.wait(min(left, 0.1))

    def frame_latencies(self) -> list[FrameLatency]:
        with self._cond:
            return list(self._latencies)

    # ---- internals (all under self._cond) ------------------------------------------------
    def _raise_if_stopped(self) -> None:
        if self._stop_reason is not None:
            raise StopRequested(self._stop_reason)
        if self._closed:
            raise StopRequested("the console was closed")

    def _window_state(self, human: int, view: ConsoleView) -> WindowState:
        req = view.request
        return WindowState(
            human, self.window_name(human), view.phase,
            req.robot if req else None, req.kind.value if req else None,
            view.markers if view.phase is Phase.CHOOSE else (),
            self._posted[human], self._shown[human],
        )

    def _redraw(self, wid: int) -> int | None:
        """Render window ``wid`` from the current state and post it; returns its seq."""
        from gui import draw  # lazy: cv2 only once a console exists

        win = self._windows.get(wid)
        if win is None:
            return None
        flags = {
            "paused": self._paused,
            "confirming_stop": wid in self._confirming,
            "stop_requested": self._stop_reason is not None,
        }
        self._seq += 1
        seq = self._seq
        if wid == OVERVIEW:
            frame = draw.render_overview(self._status, num_robots=self._num_robots, **flags)
        else:
            desk = self._desks[wid]
            view = Desk.with_flags(desk.view(), **flags)
            frame = draw.render_console(view, self.layout)
            desk.register(seq, view)
        self._posted[wid] = seq
        win.post(seq, frame)
        self._write_state()
        return seq

    def _redraw_all(self) -> None:
        for wid in list(self._windows):
            self._redraw(wid)

    def _toggle_pause(self) -> None:
        self._paused = not self._paused
        self._redraw_all()
        self._cond.notify_all()

    def _on_key(self, wid: int, seq: int, code: int) -> None:
        cmd = decode_key(code)
        if cmd is None:
            return
        if wid in self._confirming:
            self._confirming.discard(wid)
            if cmd.command is Command.YES:
                self._stop_reason = f"stop confirmed in {self._window_title(wid)}"
                self._redraw_all()
            else:
                self._redraw(wid)
            return
        if cmd.command is Command.STOP:
            self._confirming.add(wid)
            self._redraw(wid)
        elif cmd.command is Command.PAUSE:
            self._toggle_pause()
        elif wid != OVERVIEW and not self._paused:
            desk = self._desks[wid]
            changed = False
            if cmd.command is Command.PUSH and cmd.action is not None:
                changed = desk.on_push(cmd.action, seq)
            elif cmd.command is Command.CONFIRM:
                changed = desk.on_confirm(seq)
            if changed:
                self._redraw(wid)

    def _on_click(self, wid: int, seq: int, x: int, y: int) -> None:
        if wid == OVERVIEW or self._paused or wid in self._confirming:
            return
        if self._desks[wid].on_click((x, y), seq):
            self._redraw(wid)

    def _on_shown(self, wid: int, seq: int, t_imshow: float, t_painted: float) -> None:
        self._shown[wid] = max(self._shown[wid], seq)
        pending = self._pending.pop((wid, seq), None)
        if pending is not None:
            t_act, robot = pending
            self._latencies.append(FrameLatency(wid, seq, robot, t_act, t_imshow, t_painted))
        # a frame replaced before it was shown never will be: forget its stamp
        for key in [k for k in self._pending if k[0] == wid and k[1] < seq]:
            del self._pending[key]
        if wid != OVERVIEW:
            self._write_state()

    def _window_title(self, wid: int) -> str:
        return self.overview_name if wid == OVERVIEW else self.window_name(wid)

    def _on_window_lost(self, wid: int) -> None:
        win = self._windows.pop(wid, None)
        if win is None:
            return
        threading.Thread(target=win.close, name="console-reap", daemon=True).start()
        if wid != OVERVIEW and self._stop_reason is None and not self._closed:
            log = self._log_dir / f"window{wid}.log"
            self._stop_reason = (
                f"the console window of human {wid} closed unexpectedly; last log line: "
                f"{_tail(log) or '(none)'}"
            )
            self._redraw_all()

    def _pump_loop(self) -> None:
        from gui import draw  # lazy: cv2 only once a console exists

        # OpenCV 5 loads its fonts once per thread (~25 ms on the first putText): pay
        # that here, not on the first key a human presses.
        draw.render_console(ConsoleView(0, Phase.IDLE), self.layout)
        while True:
            with self._cond:
                if self._closed:
                    return
                conns = {win.conn: wid for wid, win in self._windows.items()}
            if not conns:
                time.sleep(0.1)
                continue
            try:
                ready = wait_connections(list(conns), timeout=0.2)
            except OSError:
                ready = []
            for conn in ready:
                wid = conns[conn]  # type: ignore[index]
                try:
                    msg = conn.recv()  # type: ignore[union-attr]
                except (EOFError, OSError):
                    with self._cond:
                        self._on_window_lost(wid)
                        self._cond.notify_all()
                    continue
                with self._cond:
                    if self._closed:
                        return
                    self._dispatch(wid, msg)
                    self._cond.notify_all()

    def _dispatch(self, wid: int, msg: tuple[Any, ...]) -> None:
        kind = msg[0]
        if kind == "key":
            self._on_key(wid, int(msg[1]), int(msg[2]))
        elif kind == "click":
            self._on_click(wid, int(msg[1]), int(msg[2]), int(msg[3]))
        elif kind == "shown":
            self._on_shown(wid, int(msg[1]), float(msg[2]), float(msg[3]))

    def _write_state(self) -> None:
        if self._state_path is None:
            return
        doc = {
            "windows": [
                self._window_state(h, self._desks[h].view()).as_json()
                for h in range(self.num_humans)
            ],
            "overview": self.overview_name if OVERVIEW in self._windows else None,
            "paused": self._paused,
            "stop_requested": self._stop_reason is not None,
        }
        tmp = self._state_path.with_name(self._state_path.name + ".tmp")
        with contextlib.suppress(OSError):
            tmp.write_text(json.dumps(doc))
            os.replace(tmp, self._state_path)

    def _close_windows(self) -> None:
        windows, self._windows = dict(self._windows), {}
        threads = [threading.Thread(target=w.close, daemon=True) for w in windows.values()]
        for th in threads:
            th.start()
        for th in threads:
            th.join(5.0)


def _tail(path: Path, max_chars: int = 300) -> str:
    """The last meaningful line of a window's log (Qt's noise about focus skipped)."""
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    lines = [
        ln.strip() for ln in text.splitlines()
        if ln.strip() and "XGetInputFocus" not in ln
    ]
    return lines[-1][:max_chars] if lines else ""
