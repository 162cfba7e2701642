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
from collections.abc import Sequence
from multiprocessing.connection import wait as wait_connections
from pathlib import Path
from typing import Any, Final

from gui.console_core import OVERVIEW, ConsoleCore, Frame, FrameLatency, WindowState
from gui.display import check_window_system, default_display, explain_window_failure
from gui.errors import ConsoleUnavailable
from gui.keys import decode_key
from gui.view import ConsoleView, Phase, human_label
from gui.window import WindowProcess

__all__ = ["OVERVIEW", "ConsoleHumans", "FrameLatency", "WindowState", "window_name"]
STATE_ENV: Final = "TESTBED_CONSOLE_STATE"
WINDOW_GAP_PX: Final = 12
TITLE_BAR_PX: Final = 40


def window_name(human: int, title: str = "testbed", name: str | None = None) -> str:
    """The title of human ``human``'s console window (``xdotool search --name`` it):
    ``"testbed console - ana (human 0)"``, or ``"... - human 0"`` when unnamed."""
    return f"{title} console - {human_label(human, name)}"


def overview_window_name(title: str = "testbed") -> str:
    return f"{title} console - fleet overview"


class ConsoleHumans(ConsoleCore):
    """M people, each at a console window, answering the fleet's interventions.

    ``ConsoleHumans(num_humans=2)`` opens one window per human and the overview (on
    ``$DISPLAY``), or raises ``ConsoleUnavailable`` with one line saying what to do.
    Use it as a context manager or call ``close()``.

    ``teleop_timeout_s``: if set, ``act`` gives up waiting for a push after this many
    seconds (paused time not counted) and answers ``action=None`` for that arm.
    ``displays``: one X display per human (default: ``$DISPLAY`` for all); the overview
    opens on the first. Requests for a human index >= ``num_humans`` go to human
    ``index % num_humans`` (queued after that human's own). ``names``: each human's
    name, in their window's title and header (empty: "human i"). ``places``: each
    human's place (``"on_site"`` / ``"remote"``), beside the name in their header and
    the overview's lines (empty: not shown).
    """

    def __init__(
        self,
        num_humans: int,
        *,
        names: Sequence[str] = (),
        places: Sequence[str] = (),
        scale: int = 6,
        title: str = "testbed",
        overview: bool = True,
        displays: Sequence[str | None] | None = None,
        teleop_timeout_s: float | None = None,
        start_timeout_s: float = 30.0,
        state_path: str | Path | None = None,
    ) -> None:
        super().__init__(num_humans, names=names, places=places, scale=scale,
                         teleop_timeout_s=teleop_timeout_s)
        self.title = title
        disp = list(displays) if displays is not None else [default_display()] * num_humans
        if len(disp) != num_humans:
            raise ValueError(f"displays: need {num_humans} entries, got {len(disp)}")
        check_window_system(disp)
        state_env = os.environ.get(STATE_ENV)
        self._state_path = Path(state_path or state_env) if (state_path or state_env) else None
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
        return window_name(human, self.title, self.human_name(human))

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

    def close(self) -> None:
        """Close every window; safe to call twice."""
        if not self._mark_closed():
            return
        if self._pump.is_alive() and self._pump is not threading.current_thread():
            self._pump.join(2.0)
        self._close_windows()
        shutil.rmtree(self._log_dir, ignore_errors=True)

    def __enter__(self) -> ConsoleHumans:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- ConsoleCore's surfaces: the window processes ---------------------------------
    def surface_name(self, wid: int) -> str:
        """A window's title (what ``xdotool search --name`` finds)."""
        return self.overview_name if wid == OVERVIEW else self.window_name(wid)

    def _has_surface(self, wid: int) -> bool:
        return wid in self._windows

    def _post(self, wid: int, seq: int, frame: Frame) -> None:
        self._windows[wid].post(seq, frame)

    def _changed(self) -> None:
        self._write_state()

    def _on_window_lost(self, wid: int) -> None:
        win = self._windows.pop(wid, None)
        if win is None:
            return
        threading.Thread(target=win.close, name="console-reap", daemon=True).start()
        if wid != OVERVIEW and self._stop_reason is None and not self._closed:
            log = self._log_dir / f"window{wid}.log"
            self._stop_reason = (
                f"the console window of {self.human_label(wid)} closed unexpectedly; "
                f"last log line: {_tail(log) or '(none)'}"
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
            at = float(msg[3]) if len(msg) > 3 else None  # the window's own stamp
            self._on_command(wid, int(msg[1]), decode_key(int(msg[2])), at)
        elif kind == "click":
            at = float(msg[4]) if len(msg) > 4 else None
            self._on_click(wid, int(msg[1]), int(msg[2]), int(msg[3]), at)
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
