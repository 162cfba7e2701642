"""Without a window system the console stops with ONE line that says what to do."""

from __future__ import annotations

import subprocess
import sys

import pytest

import gui.display
from gui import ConsoleUnavailable, StopRequested
from gui.console import ConsoleHumans
from testbed.core.humans import HumansStopRequested


def one_line(exc: pytest.ExceptionInfo[ConsoleUnavailable]) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("operator console: ")
    return msg


def test_no_display(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(gui.display, "gui_framework", lambda: "QT")
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(ConsoleUnavailable) as exc:
        ConsoleHumans(num_humans=2)
    msg = one_line(exc)
    assert "DISPLAY is not set" in msg and "xvfb-run" in msg


def test_headless_opencv_build(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(gui.display, "gui_framework", lambda: "")
    monkeypatch.setenv("DISPLAY", ":0")
    with pytest.raises(ConsoleUnavailable) as exc:
        ConsoleHumans(num_humans=1)
    msg = one_line(exc)
    assert "headless build" in msg and "pip install -e .[console]" in msg


def test_no_opencv(monkeypatch: pytest.MonkeyPatch) -> None:
    def missing() -> str:
        raise ImportError("No module named 'cv2'")

    monkeypatch.setattr(gui.display, "gui_framework", missing)
    with pytest.raises(ConsoleUnavailable) as exc:
        ConsoleHumans(num_humans=1)
    assert ".[console]" in one_line(exc)


def test_window_failures_are_explained() -> None:
    msg = gui.display.explain_window_failure(
        ":5", "The function is not implemented. Rebuild the library", "")
    assert "headless build" in msg
    msg = gui.display.explain_window_failure(
        ":5", "the window process exited with status -6",
        'qt.qpa.xcb: could not connect to display :5')
    assert "DISPLAY=:5" in msg and "Xvfb" in msg


def test_unreachable_display_is_one_line() -> None:
    """A real window process on a display nobody serves: Qt aborts it, we explain."""
    if not gui.display.gui_framework():
        pytest.skip("the headless OpenCV build cannot open windows at all")
    with pytest.raises(ConsoleUnavailable) as exc:
        ConsoleHumans(num_humans=1, displays=[":987"], overview=False, start_timeout_s=20)
    assert "DISPLAY=:987" in one_line(exc)


def test_stop_requested_is_the_loops_exception() -> None:
    assert issubclass(StopRequested, HumansStopRequested)
    assert StopRequested("esc").reason == "esc"


def test_import_gui_loads_no_opencv() -> None:
    code = "import sys, gui; assert 'cv2' not in sys.modules, 'cv2 imported'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
