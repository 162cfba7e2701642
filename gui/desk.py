"""One human's console logic: which request is shown, which input counts, what is answered.

Pure Python (no OpenCV, no threads) so that the input rules can be tested with
synthetic events. The console (``gui.console``) owns one ``Desk`` per human and calls
it under its lock.

The rule that matters: an input counts only for the image the human saw. Every frame
sent to a window gets a sequence number, the window tags each key and click with the
number of the frame on screen, and the desk accepts a push only if that frame showed
the very request now waiting (same ``act`` call, same arm). A key pressed on a stale
image (the previous step's, or while the arm was executing) is dropped instead of
being applied to an image the human never saw. A hard reset's Enter is tied to the arm
only: the banner is the same from step to step.

Several requests for one human in one ``act`` call are served one after the other
(``testbed collect`` teleoperates every arm with fewer humans than arms).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from gui.keys import action_for_click
from gui.layout import ConsoleLayout, CubeMarker, Point
from gui.scene import locate_cube
from gui.view import ConsoleView, Phase
from testbed.core.types import HumanRequest, HumanResponse, InterventionKind

ItemId = tuple[int, str, InterventionKind]
"""(act call serial, robot, kind): identifies what a frame showed."""
MAX_FRAMES_REMEMBERED = 64


@dataclass(slots=True)
class _Item:
    request: HumanRequest
    serial: int
    cube: CubeMarker | None
    markers: tuple[Point, ...]
    answer: int | None = None
    expired: bool = False
    """``act`` returned without a push (timeout): later keys must not pretend to count."""

    @property
    def ident(self) -> ItemId:
        return (self.serial, self.request.robot, self.request.kind)

    @property
    def teleop(self) -> bool:
        return self.request.kind is InterventionKind.TELEOP


@dataclass(frozen=True, slots=True)
class _FrameInfo:
    item: ItemId | None
    markers: tuple[Point, ...]


class Desk:
    """The requests one human is working on and the inputs that answer them."""

    def __init__(
        self,
        human: int,
        layout: ConsoleLayout,
        locate: Callable[[npt.NDArray[np.uint8]], CubeMarker | None] = locate_cube,
    ) -> None:
        self.human = human
        self.layout = layout
        self._locate = locate
        self._items: list[_Item] = []
        self._t: int | None = None
        self._frames: OrderedDict[int, _FrameInfo] = OrderedDict()
        self._confirmed: set[str] = set()
        """Robots whose reset the human confirmed, not yet reported to the loop."""
        self._delivered: set[str] = set()
        """Robots whose confirmed reset was reported in this intervention."""

    # ---- from the loop ----------------------------------------------------------------
    def assign(self, requests: Sequence[HumanRequest], t: int, serial: int) -> None:
        """A new ``act`` call: these are this human's requests now (maybe none)."""
        self._t = t
        items: list[_Item] = []
        for req in requests:
            cube = self._locate(req.observation.image)
            markers = self.layout.face_points(cube) if req.kind is InterventionKind.TELEOP else ()
            items.append(_Item(req, serial, cube, markers))
        self._items = items
        resetting = {i.request.robot for i in items if not i.teleop}
        self._confirmed &= resetting
        self._delivered &= resetting

    def needs_input(self) -> bool:
        """True while a teleop request has no push yet (``act`` waits for it)."""
        return any(i.teleop and i.answer is None and not i.expired for i in self._items)

    def responses(self) -> dict[str, HumanResponse]:
        """The answers of this ``act`` call; a reported reset confirmation is used up."""
        out: dict[str, HumanResponse] = {}
        for item in self._items:
            robot = item.request.robot
            if item.teleop:
                item.expired = item.answer is None
                out[robot] = HumanResponse(robot, action=item.answer)
            else:
                done = robot in self._confirmed
                if done:
                    self._confirmed.discard(robot)
                    self._delivered.add(robot)
                out[robot] = HumanResponse(robot, reset_done=done)
        return out

    def has_request(self) -> bool:
        return bool(self._items)

    # ---- from the window ------------------------------------------------------------
    def on_push(self, action: int, seq: int) -> bool:
        """A push key on frame ``seq``; True if it answered the waiting request."""
        item = self._current()
        info = self._frames.get(seq)
        if item is None or not item.teleop or item.answer is not None or info is None:
            return False
        if item.expired:
            return False
        if info.item != item.ident:
            return False
        item.answer = int(action)
        return True

    def on_click(self, point: tuple[float, float], seq: int) -> bool:
        """A left click on frame ``seq`` at window ``point``: the nearest face's push."""
        info = self._frames.get(seq)
        if info is None or not info.markers or not self.layout.in_image(point):
            return False
        return self.on_push(action_for_click(point, info.markers), seq)

    def on_confirm(self, seq: int) -> bool:
        """Enter on frame ``seq``: confirms the hard reset that frame showed."""
        info = self._frames.get(seq)
        if info is None or info.item is None or info.item[2] is not InterventionKind.RESET:
            return False
        robot = info.item[1]
        waiting = [i for i in self._items if not i.teleop and i.request.robot == robot]
        if not waiting or robot in self._confirmed:
            return False
        self._confirmed.add(robot)
        return True

    # ---- what to show -------------------------------------------------------------------
    def _current(self) -> _Item | None:
        for item in self._items:
            if item.teleop and item.answer is None and not item.expired:
                return item
        resets = [i for i in self._items if not i.teleop]
        for item in resets:
            if self._reset_phase(item) is Phase.RESET:
                return item
        if resets:
            return resets[0]
        answered = [i for i in self._items if i.teleop]
        return answered[-1] if answered else None

    def _reset_phase(self, item: _Item) -> Phase:
        robot = item.request.robot
        if robot in self._confirmed:
            return Phase.RESET_CONFIRMED
        if robot in self._delivered and not item.request.observation.violating:
            return Phase.RESET_CONFIRMED
        return Phase.RESET

    def view(self) -> ConsoleView:
        item = self._current()
        if item is None:
            return ConsoleView(self.human, Phase.IDLE, t=self._t)
        if item.teleop:
            phase = Phase.CHOOSE if item.answer is None and not item.expired else Phase.SENT
        else:
            phase = self._reset_phase(item)
        waiting = sum(
            1 for i in self._items
            if i is not item and ((i.teleop and i.answer is None and not i.expired)
                                  or (not i.teleop and self._reset_phase(i) is Phase.RESET))
        )
        return ConsoleView(
            self.human, phase, item.request, self._t, item.cube, item.markers,
            sent_action=item.answer, queued=waiting,
        )

    def register(self, seq: int, view: ConsoleView) -> None:
        """Frame ``seq`` (now on its way to the window) shows ``view``."""
        item = self._current()
        shown = item.ident if item is not None and view.request is item.request else None
        markers = view.markers if view.phase is Phase.CHOOSE else ()
        self._frames[seq] = _FrameInfo(shown, markers)
        while len(self._frames) > MAX_FRAMES_REMEMBERED:
            self._frames.popitem(last=False)

    @staticmethod
    def with_flags(
        view: ConsoleView, *, paused: bool, confirming_stop: bool, stop_requested: bool
    ) -> ConsoleView:
        return replace(view, paused=paused, confirming_stop=confirming_stop,
                       stop_requested=stop_requested)
