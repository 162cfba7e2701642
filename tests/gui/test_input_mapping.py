"""Key codes and clicks -> commands, with the codes HighGUI really returns."""

from __future__ import annotations

import pytest

from gui.keys import BUTTONS, Command, action_for_click, decode_browser_key, decode_key


@pytest.mark.parametrize(
    ("code", "action"),
    [
        (ord("w"), 0), (ord("a"), 1), (ord("x"), 2), (ord("d"), 3),
        (ord("W"), 0), (ord("D"), 3),
        (0xFF52, 0), (0xFF51, 1), (0xFF54, 2), (0xFF53, 3),  # X11 arrows (Qt, GTK)
        (0xFF97, 0), (0xFF98, 3),  # keypad arrows
        (0x260000, 0), (0x250000, 1), (0x280000, 2), (0x270000, 3),  # Windows arrows
        (0x10000 | ord("a"), 1),  # GTK: modifier state in the high bits
    ],
)
def test_push_keys(code: int, action: int) -> None:
    cmd = decode_key(code)
    assert cmd is not None
    assert cmd.command is Command.PUSH and cmd.action == action


@pytest.mark.parametrize(
    ("code", "command"),
    [
        (13, Command.CONFIRM), (10, Command.CONFIRM), (0xFF8D, Command.CONFIRM),
        (ord("p"), Command.PAUSE), (ord(" "), Command.PAUSE),
        (27, Command.STOP), (ord("y"), Command.YES), (ord("Y"), Command.YES),
        (ord("s"), Command.OTHER), (ord("n"), Command.OTHER), (0xFFE1, Command.OTHER),
    ],
)
def test_other_keys(code: int, command: Command) -> None:
    cmd = decode_key(code)
    assert cmd is not None and cmd.command is command and cmd.action is None


def test_no_key() -> None:
    assert decode_key(-1) is None


def test_click_picks_the_nearest_marker() -> None:
    markers = [(100, 50), (50, 100), (100, 150), (150, 100)]  # up, left, down, right
    assert action_for_click((100, 10), markers) == 0
    assert action_for_click((60, 95), markers) == 1
    assert action_for_click((99, 149), markers) == 2
    assert action_for_click((300, 120), markers) == 3
    with pytest.raises(ValueError):
        action_for_click((0, 0), [])


@pytest.mark.parametrize(
    ("key", "code"),
    [("w", ord("w")), ("A", ord("A")), ("x", ord("x")), ("d", ord("d")),
     ("ArrowUp", 0xFF52), ("ArrowLeft", 0xFF51), ("ArrowDown", 0xFF54),
     ("ArrowRight", 0xFF53), ("Enter", 0xFF0D), ("Escape", 0xFF1B), (" ", ord(" ")),
     ("p", ord("p")), ("y", ord("y")), ("n", ord("n"))],
)
def test_a_browser_key_means_what_the_window_key_means(key: str, code: int) -> None:
    """One mapping for both consoles: the page's KeyboardEvent.key goes through the
    window's table, so w, the arrows, Enter, Esc, p and y mean the same everywhere."""
    assert decode_browser_key(key) == decode_key(code)


def test_browser_keys_that_are_not_the_consoles() -> None:
    assert decode_browser_key("Shift") is None
    assert decode_browser_key("F5") is None
    assert decode_browser_key("") is None


def test_buttons() -> None:
    assert BUTTONS["confirm"].command is Command.CONFIRM
    assert BUTTONS["pause"].command is Command.PAUSE
    assert BUTTONS["stop"].command is Command.STOP
    assert BUTTONS["yes"].command is Command.YES
    assert BUTTONS["no"].command is Command.OTHER
    assert [BUTTONS[f"push{k}"].action for k in range(4)] == [0, 1, 2, 3]
