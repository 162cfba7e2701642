"""Can this machine show the console? Answer before any window is tried, in one line.

The two OpenCV wheels own the same ``cv2/`` folder and cannot coexist
(measured: docs/notes/gui.md), so the project installs exactly one on purpose: the GUI
build on the operator's machine (extra ``console``), the headless build on robot hosts
(extra ``headless``). Each way this can be wrong here gets its own fix in the message:

* no cv2 at all -> install the console extra;
* the headless build (``cv2.imshow`` "not implemented") -> swap to the GUI build;
* no window system (``DISPLAY`` unset on Linux) -> set it, or run under Xvfb.

A DISPLAY that is set but unreachable is found later, when the window process tries it
(the Qt build aborts the process that cannot open its display).
"""

from __future__ import annotations

import os
import sys

from gui.errors import ConsoleUnavailable

INSTALL_GUI = (
    "install the GUI build: pip uninstall -y opencv-python-headless opencv-python && "
    "pip install -e .[console]"
)
UNREACHABLE_DISPLAY = (
    "start one (Xvfb :99 & export DISPLAY=:99), fix DISPLAY, or use xvfb-run -a"
)
NEED_DISPLAY = (
    "set DISPLAY to your desktop's display (ssh -X forwards one), or run under a virtual "
    "one: xvfb-run -a testbed trial --humans gui"
)


def gui_framework() -> str:
    """HighGUI's backend ("QT", "GTK3", ...) or "" for a build without windows."""
    import cv2  # lazy: callers handle a missing OpenCV

    current = getattr(cv2, "currentUIFramework", None)
    if current is not None:
        try:
            return str(current() or "")
        except Exception:  # older builds: fall back to the build info
            pass
    for line in cv2.getBuildInformation().splitlines():
        key, _, value = line.strip().partition(":")
        if key.strip() == "GUI":
            value = value.strip()
            return "" if value.upper() in ("", "NONE") else value
    return ""


def check_window_system(displays: list[str | None]) -> None:
    """Raise ``ConsoleUnavailable`` (one line, with the fix) if no window can open."""
    try:
        framework = gui_framework()
    except ImportError:
        raise ConsoleUnavailable(
            "operator console: OpenCV is not installed; " + INSTALL_GUI
        ) from None
    if not framework:
        raise ConsoleUnavailable(
            "operator console: this OpenCV is the headless build (cv2.imshow is not "
            "implemented); " + INSTALL_GUI
        )
    if sys.platform.startswith("linux") and any(not d for d in displays):
        raise ConsoleUnavailable(
            "operator console: no window system (DISPLAY is not set); " + NEED_DISPLAY
        )


def explain_window_failure(display: str | None, detail: str, log_tail: str) -> str:
    """One line for a window process that could not open its window."""
    text = f"{detail} {log_tail}".lower()
    if "not implemented" in text:
        return ("operator console: this OpenCV is the headless build (cv2.imshow is not "
                "implemented); " + INSTALL_GUI)
    if "could not connect to display" in text or "cannot open display" in text or (
        "platform plugin" in text
    ):
        return (f"operator console: cannot open a window on DISPLAY={display}: no X "
                f"server answers there; " + UNREACHABLE_DISPLAY)
    why = " ".join(f"{detail}; {log_tail}".split()) if log_tail else " ".join(detail.split())
    return f"operator console: a window on DISPLAY={display} did not open: {why[:300]}"



def default_display() -> str | None:
    return os.environ.get("DISPLAY") or None
