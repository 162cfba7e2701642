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

The desk also times each intervention's first action (``HumanResponse.waited_s``, the
per-human "time to first action"): a clock per arm starts on the first request with
``served == 0`` (a new intervention restarts it), notes when a frame showing that
intervention first reached the human's screen (``on_shown``) and when the first push or
reset confirmation counted, and the answer that carries that action carries the
difference; every other answer carries None. The desk takes the times from its caller
(``time.monotonic()`` stamps) so that each console can say which moment is honest for
its surface (``gui.console_core``).
"""

from __future__ import annotations

import time
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


@dataclass(slots=True)
class _Clock:
    """One intervention's time to first action, for this human and one arm."""

    serial: int
    """The ``act`` call that started the intervention: frames of older ones do not count."""
    posted_at: float | None = None
    """When the first frame showing it left for the screen (the fallback start)."""
    shown_at: float | None = None
    """When a frame showing it was first on the human's screen (the start)."""
    acted_at: float | None = None
    """When the first push or reset confirmation that counted was made."""
    reported: bool = False
    """The answer with ``waited_s`` was handed to the loop: later ones carry None."""

    def take_waited_s(self) -> float | None:
        """Seconds from first shown to the first action, once; None otherwise.

        A frame whose paint report came after the action (a page that sent its key
        before its paint report) cannot be the one seen: the frame's departure is used.
        """
        if self.acted_at is None or self.reported:
            return None
        self.reported = True
        start = self.shown_at
        if start is None or start > self.acted_at:
            start = self.posted_at
        return None if start is None else max(0.0, self.acted_at - start)


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
        *,
        name: str | None = None,
        place: str | None = None,
    ) -> None:
        self.human = human
        self.name = name
        """Shown with every view (the header names the person), None when unnamed."""
        self.place = place
        """Shown with every view beside the name (``ConsoleView.place``), None: untold."""
        self.layout = layout
        self._locate = locate
        self._items: list[_Item] = []
        self._t: int | None = None
        self._frames: OrderedDict[int, _FrameInfo] = OrderedDict()
        self._confirmed: set[str] = set()
        """Robots whose reset the human confirmed, not yet reported to the loop."""
        self._delivered: set[str] = set()
        """Robots whose confirmed reset was reported in this intervention."""
        self._clocks: dict[str, _Clock] = {}
        """Per robot: the current intervention's time to first action."""

    # ---- from the loop ----------------------------------------------------------------
    def assign(self, requests: Sequence[HumanRequest], t: int, serial: int) -> None:
        """A new ``act`` call: these are this human's requests now (maybe none)."""
        self._t = t
        items: list[_Item] = []
        for req in requests:
            cube = self._locate(req.observation.image)
            markers = self.layout.face_points(cube) if req.kind is InterventionKind.TELEOP else ()
            items.append(_Item(req, serial, cube, markers))
            if req.served == 0 or req.robot not in self._clocks:  # a new intervention
                self._clocks[req.robot] = _Clock(serial)
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
            clock = self._clocks[robot]
            if item.teleop:
                item.expired = item.answer is None
                waited = clock.take_waited_s() if item.answer is not None else None
                out[robot] = HumanResponse(robot, action=item.answer, waited_s=waited)
            else:
                done = robot in self._confirmed
                waited = None
                if done:
                    self._confirmed.discard(robot)
                    self._delivered.add(robot)
                    waited = clock.take_waited_s()
                out[robot] = HumanResponse(robot, reset_done=done, waited_s=waited)
        return out

    def has_request(self) -> bool:
        return bool(self._items)

    # ---- from the window ------------------------------------------------------------
    def on_push(self, action: int, seq: int, at: float | None = None) -> bool:
        """A push key on frame ``seq``, made at ``at`` (``time.monotonic()``, default
        now); True if it answered the waiting request."""
        item = self._current()
        info = self._frames.get(seq)
        if item is None or not item.teleop or item.answer is not None or info is None:
            return False
        if item.expired:
            return False
        if info.item != item.ident:
            return False
        item.answer = int(action)
        self._acted(item.request.robot, at)
        return True

    def on_click(self, point: tuple[float, float], seq: int, at: float | None = None) -> bool:
        """A left click on frame ``seq`` at window ``point``: the nearest face's push."""
        info = self._frames.get(seq)
        if info is None or not info.markers or not self.layout.in_image(point):
            return False
        return self.on_push(action_for_click(point, info.markers), seq, at)

    def on_confirm(self, seq: int, at: float | None = None) -> bool:
        """Enter on frame ``seq`` (made at ``at``, default now): confirms the hard reset
        that frame showed."""
        info = self._frames.get(seq)
        if info is None or info.item is None or info.item[2] is not InterventionKind.RESET:
            return False
        robot = info.item[1]
        waiting = [i for i in self._items if not i.teleop and i.request.robot == robot]
        if not waiting or robot in self._confirmed:
            return False
        self._confirmed.add(robot)
        self._acted(robot, at)
        return True

    def on_shown(self, seq: int, at: float) -> None:
        """Frame ``seq`` was on the human's screen at ``at``: it starts the clock of the
        intervention it showed, if none of that intervention's frames was seen before."""
        info = self._frames.get(seq)
        if info is None or info.item is None:
            return
        clock = self._clocks.get(info.item[1])
        if clock is None or info.item[0] < clock.serial:
            return  # a frame of an earlier intervention of that arm
        if clock.shown_at is None or at < clock.shown_at:
            clock.shown_at = at

    def _acted(self, robot: str, at: float | None) -> None:
        clock = self._clocks[robot]
        if clock.acted_at is None:
            clock.acted_at = time.monotonic() if at is None else at

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
            return ConsoleView(self.human, Phase.IDLE, t=self._t, name=self.name,
                               place=self.place)
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
            sent_action=item.answer, queued=waiting, name=self.name, place=self.place,
        )

    def register(self, seq: int, view: ConsoleView, posted_at: float | None = None) -> None:
        """Frame ``seq`` (on its way to the window at ``posted_at``, default now) shows
        ``view``."""
        item = self._current()
        shown = item.ident if item is not None and view.request is item.request else None
        markers = view.markers if view.phase is Phase.CHOOSE else ()
        self._frames[seq] = _FrameInfo(shown, markers)
        if item is not None and shown is not None:
            clock = self._clocks.get(item.request.robot)
            if clock is not None and clock.posted_at is None and item.serial >= clock.serial:
                clock.posted_at = time.monotonic() if posted_at is None else posted_at
        while len(self._frames) > MAX_FRAMES_REMEMBERED:
            self._frames.popitem(last=False)

    @staticmethod
    def with_flags(
        view: ConsoleView, *, paused: bool, confirming_stop: bool, stop_requested: bool
    ) -> ConsoleView:
        return replace(view, paused=paused, confirming_stop=confirming_stop,
                       stop_requested=stop_requested)
