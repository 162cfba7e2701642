"""Input mapping: raw HighGUI key codes and clicks -> what the human meant.

Kept free of OpenCV and of any state so it can be tested with synthetic codes. The key
codes are those ``cv2.waitKeyEx`` returns: under Qt and GTK on X11 the arrows are X
keysyms (0xff51..0xff54, measured with opencv-python 5.0 under Xvfb), on Windows
virtual-key codes shifted left by 16; both are accepted, as are the keypad arrows.

The push keys follow the lab's earlier code: ``w``/``a``/``x``/``d`` sit around ``s``
on the keyboard as up/left/down/right sit around the cube, so a push key names the
direction the cube moves in the canonical frame (``testbed.core.types.FACE_DIRECTIONS``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Final


class Command(StrEnum):
    PUSH = "push"
    CONFIRM = "confirm"
    """Enter: the hard reset is done (the cube is back)."""
    PAUSE = "pause"
    """p or space: pause / resume the fleet."""
    STOP = "stop"
    """Esc: ask for a graceful stop (needs YES)."""
    YES = "yes"
    OTHER = "other"


@dataclass(frozen=True, slots=True)
class KeyCommand:
    command: Command
    action: int | None = None
    """For PUSH: the action (0 up, 1 left, 2 down, 3 right)."""


PUSH_KEYS: Final[dict[int, int]] = {
    # letters, either case (caps lock or shift must not make a key dead)
    ord("w"): 0, ord("W"): 0,
    ord("a"): 1, ord("A"): 1,
    ord("x"): 2, ord("X"): 2,
    ord("d"): 3, ord("D"): 3,
    # X11 keysyms (Qt and GTK builds): Up, Left, Down, Right and the keypad's
    0xFF52: 0, 0xFF51: 1, 0xFF54: 2, 0xFF53: 3,
    0xFF97: 0, 0xFF96: 1, 0xFF99: 2, 0xFF98: 3,
    # Windows virtual keys << 16: VK_UP, VK_LEFT, VK_DOWN, VK_RIGHT
    0x260000: 0, 0x250000: 1, 0x280000: 2, 0x270000: 3,
}
CONFIRM_KEYS: Final = frozenset({13, 10, 0xFF0D, 0xFF8D})
PAUSE_KEYS: Final = frozenset({ord("p"), ord("P"), ord(" ")})
STOP_KEYS: Final = frozenset({27, 0xFF1B})
YES_KEYS: Final = frozenset({ord("y"), ord("Y")})
KEY_NAMES: Final = ("w", "a", "x", "d")
"""The letter shown on face marker k."""
ARROW_NAMES: Final = ("Up", "Left", "Down", "Right")


def decode_key(code: int) -> KeyCommand | None:
    """What a ``waitKeyEx`` code means; None for "no key" (-1)."""
    if code < 0:
        return None
    for candidate in (code, code & 0xFFFF):  # GTK puts modifier state in the high bits
        if candidate in PUSH_KEYS:
            return KeyCommand(Command.PUSH, PUSH_KEYS[candidate])
        if candidate in CONFIRM_KEYS:
            return KeyCommand(Command.CONFIRM)
        if candidate in PAUSE_KEYS:
            return KeyCommand(Command.PAUSE)
        if candidate in STOP_KEYS:
            return KeyCommand(Command.STOP)
        if candidate in YES_KEYS:
            return KeyCommand(Command.YES)
    return KeyCommand(Command.OTHER)


def action_for_click(
    point: tuple[float, float], markers: Sequence[tuple[float, float]]
) -> int:
    """The push whose face marker is nearest to a click (window coordinates)."""
    if len(markers) == 0:
        raise ValueError("no face markers to click")
    x, y = point
    dists = [(mx - x) ** 2 + (my - y) ** 2 for mx, my in markers]
    return min(range(len(dists)), key=dists.__getitem__)


BROWSER_KEYS: Final[dict[str, int]] = {
    # KeyboardEvent.key names -> the X keysyms above, so a page's key means what the
    # same key means in an OpenCV window (one table: PUSH_KEYS and friends)
    "ArrowUp": 0xFF52, "ArrowLeft": 0xFF51, "ArrowDown": 0xFF54, "ArrowRight": 0xFF53,
    "Up": 0xFF52, "Left": 0xFF51, "Down": 0xFF54, "Right": 0xFF53,  # old Edge/IE names
    "Enter": 0xFF0D, "Escape": 0xFF1B, "Esc": 0xFF1B, "Spacebar": ord(" "),
}
BUTTONS: Final[dict[str, KeyCommand]] = {
    # the page's buttons (touch screens have no keys)
    "confirm": KeyCommand(Command.CONFIRM),
    "pause": KeyCommand(Command.PAUSE),
    "stop": KeyCommand(Command.STOP),
    "yes": KeyCommand(Command.YES),
    "no": KeyCommand(Command.OTHER),
    **{f"push{k}": KeyCommand(Command.PUSH, k) for k in range(4)},
}


def decode_browser_key(key: str) -> KeyCommand | None:
    """What a page's ``KeyboardEvent.key`` means (the same as the key in a window).

    None for named keys that are not the console's (Shift, F5...); any other single
    character is ``OTHER`` (it answers "stop the trial?" with no, as in a window).
    """
    if key in BROWSER_KEYS:
        return decode_key(BROWSER_KEYS[key])
    if len(key) == 1:
        return decode_key(ord(key))
    return None
