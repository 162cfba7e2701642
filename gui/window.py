"""One OpenCV window in a process of its own, and the handle the console drives it by.

Why a process per window rather than one GUI thread for all of them:

* ``cv2.waitKeyEx`` returns a key without saying which window had the focus. With two
  humans' windows in one HighGUI, a ``w`` could not be given to the right human. A
  process per window has its own HighGUI, so every key and click belongs to exactly one
  window. (HighGUI calls still stay on one thread: each process's main thread.)
* One human's window can never freeze another's: a window busy (being dragged, a slow
  X server, a remote DISPLAY) stalls only its own process; the console hands frames to
  each window through a latest-only mailbox and never blocks on a window.
* A bad display cannot kill the trial: the Qt build ``abort()``s the process when it
  cannot open its display. It does so in the window process, and the console turns it
  into one ``ConsoleUnavailable`` line.
* Each human may sit at a different X display (``ssh -X``): one DISPLAY per process.

Wire (pickled ``multiprocessing.connection`` messages over two pipes)::

    console --> window   ("frame", seq, bgr_array)  |  ("close",)
    window --> console   ("ready", pid) | ("error", text) | ("key", seq, code, t)
                         ("click", seq, x, y, t) | ("shown", seq, t_imshow, t_painted)

``seq`` tags every input with the frame that was on screen (see ``gui.desk``);
``shown`` and the inputs' ``t`` carry ``time.monotonic()`` stamps (system-wide on
Linux), taken here as HighGUI hands over the key or click, for the latency benchmark
and the human's time to first action (a pipe and a pump thread later is not the press).

Run as ``python -m gui.window --in-fd R --out-fd W --name NAME [--x X --y Y]``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

POLL_MS = 5
"""waitKeyEx period: the window's event loop turn, and the worst added frame latency."""
VISIBILITY_CHECK_S = 0.5


# ---- the window process --------------------------------------------------------------
def _first_error_line(text: str) -> str:
    lines = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    return lines[-1] if lines else str(text)


def _child(inbox: Connection, outbox: Connection, name: str, x: int, y: int) -> int:
    try:
        import cv2  # lazy: only the window process needs HighGUI
    except ImportError as exc:
        outbox.send(("error", f"cannot import cv2: {exc}"))
        return 1
    flags = cv2.WINDOW_AUTOSIZE | cv2.WINDOW_GUI_NORMAL  # no Qt toolbar: clicks 1:1
    shown = {"seq": -1}
    last: list[npt.NDArray[np.uint8]] = [np.zeros((64, 64, 3), np.uint8)]

    def on_mouse(event: int, mx: int, my: int, _flags: int, _param: Any) -> None:
        if event == cv2.EVENT_LBUTTONDOWN:
            outbox.send(("click", shown["seq"], int(mx), int(my), time.monotonic()))

    def open_window() -> None:
        cv2.namedWindow(name, flags)
        cv2.moveWindow(name, x, y)
        cv2.imshow(name, last[0])
        cv2.setMouseCallback(name, on_mouse)
        cv2.waitKeyEx(1)

    try:
        open_window()
    except cv2.error as exc:
        outbox.send(("error", _first_error_line(str(exc))))
        return 1
    outbox.send(("ready", os.getpid()))
    next_check = time.monotonic() + VISIBILITY_CHECK_S
    while True:
        frame: tuple[Any, ...] | None = None
        while inbox.poll():
            msg = inbox.recv()
            if msg[0] == "close":
                cv2.destroyAllWindows()
                return 0
            frame = msg  # only the latest frame matters
        if frame is not None:
            # Inputs made on the old frame were collected by the last waitKeyEx, at most
            # a pipe read ago, and keep the old seq; no extra flush (it costs 2 ms).
            _, seq, image = frame
            last[0] = image
            cv2.imshow(name, image)
            t_imshow = time.monotonic()
            shown["seq"] = seq
            key = cv2.waitKeyEx(1)  # lets Qt paint it
            outbox.send(("shown", seq, t_imshow, time.monotonic()))
        else:
            key = cv2.waitKeyEx(POLL_MS)
        if key != -1:
            outbox.send(("key", shown["seq"], key, time.monotonic()))
        now = time.monotonic()
        if now >= next_check:
            next_check = now + VISIBILITY_CHECK_S
            # The window manager's close button must not lose a human's console.
            if cv2.getWindowProperty(name, cv2.WND_PROP_VISIBLE) < 1:
                open_window()


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="one operator-console window (internal)")
    p.add_argument("--in-fd", type=int, required=True)
    p.add_argument("--out-fd", type=int, required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--x", type=int, default=0)
    p.add_argument("--y", type=int, default=0)
    args = p.parse_args(argv)
    # Ctrl-C is the controller's to handle; a window goes when its pipe closes.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    inbox = Connection(args.in_fd, writable=False)
    outbox = Connection(args.out_fd, readable=False)
    try:
        return _child(inbox, outbox, args.name, args.x, args.y)
    except (EOFError, BrokenPipeError, ConnectionResetError):
        return 0  # the console is gone


# ---- the console's handle -----------------------------------------------------------
class WindowProcess:
    """Starts one window process and feeds it frames without ever blocking the caller."""

    def __init__(
        self, name: str, *, position: tuple[int, int] = (0, 0), display: str | None = None,
        log_path: Path | None = None,
    ) -> None:
        self.name = name
        self.display = display
        self.log_path = log_path
        self.pid: int | None = None
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        env = dict(os.environ)
        if display is not None:
            env["DISPLAY"] = display
        root = str(Path(__file__).resolve().parent.parent)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        cmd = [
            sys.executable, "-m", "gui.window", "--in-fd", str(to_child_r),
            "--out-fd", str(from_child_w), "--name", name,
            "--x", str(position[0]), "--y", str(position[1]),
        ]
        log = open(log_path, "ab") if log_path is not None else subprocess.DEVNULL  # noqa: SIM115
        try:
            self._proc = subprocess.Popen(
                cmd, pass_fds=(to_child_r, from_child_w), env=env,
                stdin=subprocess.DEVNULL, stdout=log, stderr=log,
            )
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
            if log is not subprocess.DEVNULL:
                log.close()
        self.conn = Connection(from_child_r, writable=False)
        """Events from the window; the console's pump thread reads it."""
        self._out = Connection(to_child_w, readable=False)
        self._mailbox: tuple[Any, ...] | None = None
        self._closing = False
        self._cond = threading.Condition()
        self._sender = threading.Thread(
            target=self._send_loop, name=f"console-send[{name}]", daemon=True
        )
        self._sender.start()

    def wait_ready(self, timeout_s: float) -> str | None:
        """None once the window is up, else why it is not (one line)."""
        if not self.conn.poll(timeout_s):
            return f"no answer within {timeout_s:.0f} s"
        try:
            msg = self.conn.recv()
        except (EOFError, OSError):
            self._proc.wait(timeout=5)
            return f"the window process exited with status {self._proc.returncode}"
        if msg[0] == "ready":
            self.pid = int(msg[1])
            return None
        return str(msg[1])

    def post(self, seq: int, frame: npt.NDArray[np.uint8]) -> None:
        """Hand a frame to the window; an older frame not yet sent is dropped."""
        with self._cond:
            if not self._closing:
                self._mailbox = ("frame", seq, frame)
                self._cond.notify()

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while self._mailbox is None and not self._closing:
                    self._cond.wait()
                msg, self._mailbox = self._mailbox, None
                closing = self._closing
            try:
                if msg is not None:
                    self._out.send(msg)
                if closing:
                    self._out.send(("close",))
                    return
            except OSError:
                return  # the window died; the pump thread sees its EOF

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    def close(self, timeout_s: float = 2.0) -> None:
        with self._cond:
            self._closing = True
            self._mailbox = None
            self._cond.notify()
        self._sender.join(timeout_s)
        try:
            self._proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(timeout=timeout_s)
        for conn in (self._out, self.conn):
            with contextlib.suppress(OSError):
                conn.close()


if __name__ == "__main__":
    raise SystemExit(main())
