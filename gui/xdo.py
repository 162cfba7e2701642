"""Drive real console windows from outside: a private Xvfb and xdotool, for tests and benchmarks.

The console's promises (a key in *this* window pushes *that* arm, Enter completes a
reset, a frame is on screen within 50 ms) hold only for real windows, so the tests
open real ones on a virtual X server and act on them as a person would: find the
window by its title, send it a key, click a point in it. Debian packages: ``xvfb``,
``xauth``, ``xdotool``.

    with Xvfb() as x:                      # DISPLAY of this process set to x.display
        wid = find_window(window_name(0))  # "testbed console - human 0"
        press(wid, "w")                    # or "Up", "Return", "Escape", "space"
        click(wid, *console.face_click_point(0, 3))
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import subprocess
import threading
import time
from collections.abc import Callable
from types import TracebackType

XVFB_SCREEN = "1600x1200x24"


def tools_missing() -> list[str]:
    """The X tools this module needs that are not on PATH."""
    return [t for t in ("Xvfb", "xdotool") if shutil.which(t) is None]


class Xvfb:
    """A private Xvfb on a free display number; ``DISPLAY`` points at it while open."""

    def __init__(self, screen: str = XVFB_SCREEN, *, set_env: bool = True) -> None:
        self.screen = screen
        self.set_env = set_env
        self.display = ""
        self._proc: subprocess.Popen[bytes] | None = None
        self._old_display: str | None = None

    def start(self, timeout_s: float = 10.0) -> str:
        if tools_missing():
            raise RuntimeError(
                f"missing {', '.join(tools_missing())}: apt-get install -y xvfb xauth xdotool"
            )
        read_fd, write_fd = os.pipe()
        try:
            # -displayfd: Xvfb picks a free display and writes its number when ready.
            self._proc = subprocess.Popen(
                ["Xvfb", "-displayfd", str(write_fd), "-screen", "0", self.screen,
                 "-nolisten", "tcp"],
                pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )
        finally:
            os.close(write_fd)
        try:
            number = b""
            deadline = time.monotonic() + timeout_s
            while not number.endswith(b"\n"):
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([read_fd], [], [], left)[0]:
                    raise RuntimeError("Xvfb did not start")
                chunk = os.read(read_fd, 16)
                if not chunk:
                    raise RuntimeError("Xvfb exited at start")
                number += chunk
        except BaseException:
            self.stop()
            raise
        finally:
            os.close(read_fd)
        self.display = f":{int(number)}"
        if self.set_env:
            self._old_display = os.environ.get("DISPLAY")
            os.environ["DISPLAY"] = self.display
        return self.display

    def stop(self) -> None:
        if self.set_env and self.display:
            if self._old_display is None:
                os.environ.pop("DISPLAY", None)
            else:
                os.environ["DISPLAY"] = self._old_display
        if self._proc is not None:
            self._proc.terminate()
            try:
                self._proc.wait(5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(5)
            self._proc = None

    def __enter__(self) -> Xvfb:
        self.start()
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def _xdotool(*args: str, display: str | None = None) -> str:
    env = dict(os.environ)
    if display is not None:
        env["DISPLAY"] = display
    done = subprocess.run(
        ["xdotool", *args], env=env, capture_output=True, text=True, timeout=10
    )
    return done.stdout


def find_window(name: str, *, display: str | None = None, timeout_s: float = 10.0) -> str:
    """The X id of the visible window titled exactly ``name`` (waits for it to appear)."""
    pattern = "^" + re.sub(r"([.\[\]{}()\\*+?^$|])", r"\\\1", name) + "$"  # POSIX ERE
    deadline = time.monotonic() + timeout_s
    while True:
        ids = _xdotool("search", "--onlyvisible", "--name", pattern, display=display).split()
        if ids:
            return ids[-1]
        if time.monotonic() > deadline:
            raise LookupError(f"no visible window named {name!r}")
        time.sleep(0.05)


def press(window: str, key: str, *, display: str | None = None) -> None:
    """Send one key (an X keysym name: w, Up, Return, Escape, space) to a window."""
    _xdotool("key", "--window", window, key, display=display)


def click(window: str, x: int, y: int, *, display: str | None = None) -> None:
    """Left click at window coordinates (x, y): move the pointer there, then click.

    (Not ``mousemove --sync``: it waits for a motion event, and when the pointer is
    already there, a second click on the same marker, none comes: xdotool hung.)
    """
    _xdotool("mousemove", "--window", window, str(x), str(y), "click", "1", display=display)


# ---- driving a console in another process (``testbed trial --humans gui``) ----------
def read_console_state(path: str | os.PathLike[str]) -> dict[str, object] | None:
    """The console's state file (``$TESTBED_CONSOLE_STATE``), or None if not there yet."""
    try:
        with open(path, encoding="utf-8") as f:
            doc: dict[str, object] = json.load(f)
    except (OSError, ValueError):
        return None
    return doc


Answer = tuple[str, "int | str"]
"""("key", keysym) or ("click", action): how the autopilot answers a teleop prompt."""


class Autopilot:
    """Answers every prompt of a console in another process, as people would.

    Reads the console's state file; when a human's window shows a teleop prompt (its
    latest frame on screen), answers with ``teleop(human)``: ``("key", "w")`` presses a
    key, ``("click", k)`` clicks face marker k; when it shows a hard-reset banner,
    presses Return. Each frame is answered once, and again (its window looked up anew)
    if the prompt is still there ``retry_s`` later: an X event can be lost on a loaded
    machine, and a person whose key did nothing presses it again. A prompt the console
    took leaves its phase (``sent``, ``reset_confirmed``) or its frame, so an answer
    never lands twice. For end-to-end tests:

        TESTBED_CONSOLE_STATE=state.json xvfb-run testbed trial --humans gui ...
        Autopilot("state.json", display, lambda h: ("key", "w") if h == 0 else ("click", 3))
    """

    def __init__(
        self, state_path: str | os.PathLike[str], display: str | None,
        teleop: Callable[[int], Answer], period_s: float = 0.02, retry_s: float = 2.0,
    ) -> None:
        self.state_path = state_path
        self.display = display
        self.teleop = teleop
        self.period_s = period_s
        self.retry_s = retry_s
        self.answers: list[tuple[int, str, str, Answer]] = []
        """(human, robot, phase, answer) of every prompt answered, in order."""
        self.retries = 0
        """Answers sent again because the prompt was still on screen ``retry_s`` later."""
        self._done: dict[tuple[int, int], float] = {}
        """(human, seq) of each frame answered -> when (monotonic)."""
        self._ids: dict[str, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="autopilot", daemon=True)

    def start(self) -> Autopilot:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def __enter__(self) -> Autopilot:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _window(self, name: str) -> str:
        if name not in self._ids:
            self._ids[name] = find_window(name, display=self.display)
        return self._ids[name]

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self._answer_prompts()
            except (subprocess.SubprocessError, OSError, LookupError):
                continue  # xdotool hung or a window is not up yet: a person tries again

    def _answer_prompts(self) -> None:
        """Answer each prompt on screen not answered yet (one pass)."""
        doc = read_console_state(self.state_path)
        windows = doc.get("windows") if doc else None
        if not isinstance(windows, list) or (doc or {}).get("paused"):
            return
        for w in windows:
            human, seq = int(w["human"]), int(w["seq_shown"])
            if not w.get("on_screen"):
                continue
            answered = self._done.get((human, seq))
            if answered is not None:  # again only if still waiting retry_s later: lost
                if (time.monotonic() - answered < self.retry_s
                        or w["phase"] not in ("choose", "reset")):
                    continue
                self._ids.pop(str(w["window"]), None)
                self.retries += 1
            if w["phase"] == "choose":
                answer = self.teleop(human)
                wid = self._window(w["window"])
                if answer[0] == "click":
                    x, y = w["markers"][int(answer[1])]
                    click(wid, int(x), int(y), display=self.display)
                else:
                    press(wid, str(answer[1]), display=self.display)
            elif w["phase"] == "reset":
                answer = ("key", "Return")
                press(self._window(w["window"]), "Return", display=self.display)
            else:
                continue
            self._done[(human, seq)] = time.monotonic()
            self.answers.append((human, str(w["robot"]), str(w["phase"]), answer))
