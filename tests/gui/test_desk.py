"""One human's input rules: an input counts only for the image the human saw."""

from __future__ import annotations

from console_helpers import RequestFactory

from gui.desk import Desk
from gui.layout import ConsoleLayout, CubeMarker
from gui.view import Phase

LAYOUT = ConsoleLayout(scale=6)
CUBE = CubeMarker((0.5, 0.5), 0.0, 4 / 64)


def desk() -> Desk:
    return Desk(0, LAYOUT, locate=lambda _img: CUBE)


def shown(d: Desk, seq: int) -> int:
    """Pretend frame ``seq`` of the desk's current view went to the window."""
    d.register(seq, d.view())
    return seq


def test_push_on_the_request_frame_answers_it(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request()], t=0, serial=1)
    assert d.needs_input() and d.view().phase is Phase.CHOOSE
    seq = shown(d, 10)
    assert d.on_push(3, seq)
    assert not d.needs_input()
    assert d.view().phase is Phase.SENT
    assert not d.on_push(0, seq), "a second key must not change the answer"
    assert d.responses()["cell0/left"].action == 3


def test_push_on_a_stale_frame_is_dropped(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request()], t=0, serial=1)
    old = shown(d, 1)
    assert d.on_push(1, old)
    d.responses()
    d.assign([make_request()], t=1, serial=2)  # next step, same arm, new image
    assert not d.on_push(2, old), "key pressed on the previous step's image"
    assert not d.on_push(2, 999), "unknown frame"
    new = shown(d, 2)
    assert d.on_push(2, new)
    assert d.responses()["cell0/left"].action == 2


def test_click_maps_to_the_nearest_face(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request()], t=0, serial=1)
    seq = shown(d, 5)
    markers = LAYOUT.face_points(CUBE)
    x, y = markers[1]
    assert not d.on_click((x, 3), seq), "header clicks are not pushes"
    assert d.on_click((x - 4, y + 2), seq)
    assert d.responses()["cell0/left"].action == 1


def test_enter_confirms_a_reset_once(make_request: RequestFactory) -> None:
    d = desk()
    req = make_request(kind="reset")
    d.assign([req], t=0, serial=1)
    assert not d.needs_input(), "a reset never makes act() wait"
    assert d.responses()["cell0/left"].reset_done is False
    seq = shown(d, 3)
    assert d.view().phase is Phase.RESET
    assert not d.on_push(0, seq), "no pushes during a reset"
    assert d.on_confirm(seq)
    assert d.view().phase is Phase.RESET_CONFIRMED
    d.assign([req], t=1, serial=2)
    assert d.responses()["cell0/left"].reset_done is True
    # the arm is held t_R steps: later asks answer False, the banner stays "confirmed"
    d.assign([make_request(kind="reset", served=1, violating=False)], t=2, serial=3)
    assert d.responses()["cell0/left"].reset_done is False
    assert d.view().phase is Phase.RESET_CONFIRMED


def test_enter_between_act_calls_counts(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request(kind="reset")], t=0, serial=1)
    seq = shown(d, 1)
    assert d.responses()["cell0/left"].reset_done is False  # act returned
    assert d.on_confirm(seq)  # the human presses Enter while the fleet executes
    d.assign([make_request(kind="reset", served=1)], t=1, serial=2)
    assert d.responses()["cell0/left"].reset_done is True


def test_enter_is_forgotten_when_the_reset_is_over(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request(kind="reset")], t=0, serial=1)
    seq = shown(d, 1)
    assert d.on_confirm(seq)
    d.assign([make_request(kind="teleop")], t=1, serial=2)  # the allocator moved on
    d.assign([make_request(kind="reset")], t=5, serial=3)  # a new violation later
    assert d.responses()["cell0/left"].reset_done is False
    assert not d.on_confirm(999)
    assert d.on_confirm(shown(d, 2))  # a fresh Enter counts


def test_enter_on_a_teleop_frame_does_nothing(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request()], t=0, serial=1)
    assert not d.on_confirm(shown(d, 1))


def test_requests_for_one_human_are_served_in_turn(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request("a/left"), make_request("b/left")], t=0, serial=1)
    view = d.view()
    assert view.request is not None and view.request.robot == "a/left" and view.queued == 1
    assert d.on_push(0, shown(d, 1))
    view = d.view()
    assert view.request is not None and view.request.robot == "b/left"
    assert d.needs_input()
    assert d.on_push(3, shown(d, 2))
    assert {r: a.action for r, a in d.responses().items()} == {"a/left": 0, "b/left": 3}


def test_no_request_is_idle(make_request: RequestFactory) -> None:
    d = desk()
    assert d.view().phase is Phase.IDLE
    d.assign([make_request()], t=0, serial=1)
    d.assign([], t=1, serial=2)
    assert d.view().phase is Phase.IDLE and d.responses() == {}


def test_after_a_timeout_late_keys_do_not_count(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request()], t=0, serial=1)
    seq = shown(d, 1)
    assert d.responses()["cell0/left"].action is None  # act() gave up waiting
    assert not d.needs_input()
    assert not d.on_push(0, seq)
    view = d.view()
    assert view.phase is Phase.SENT and view.sent_action is None
