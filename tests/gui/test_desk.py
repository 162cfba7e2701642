"""One human's input rules: an input counts only for the image the human saw; and
what a console calls each human (a name beside the index)."""

from __future__ import annotations

import pytest
from console_helpers import RequestFactory

from gui.console_core import ConsoleCore
from gui.desk import Desk
from gui.errors import StopRequested
from gui.keys import Command, KeyCommand
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


# ---- time to first action (HumanResponse.waited_s), on the desk's own stamps -----------
def test_waited_s_is_on_the_first_push_of_each_teleop_only(make_request: RequestFactory) -> None:
    d = desk()
    d.assign([make_request(served=0)], t=0, serial=1)
    d.register(1, d.view(), posted_at=100.0)
    d.on_shown(1, 100.25)  # on screen a quarter second after it left
    assert d.on_push(3, 1, at=102.0)
    first = d.responses()["cell0/left"]
    assert first.action == 3 and first.waited_s == pytest.approx(1.75)
    for t, served in ((1, 1), (2, 2)):  # the same intervention's later steps
        d.assign([make_request(served=served)], t=t, serial=1 + t)
        d.register(1 + t, d.view(), posted_at=103.0 + t)
        d.on_shown(1 + t, 103.0 + t)
        assert d.on_push(0, 1 + t, at=104.0 + t)
        later = d.responses()["cell0/left"]
        assert later.action == 0 and later.waited_s is None
    d.assign([make_request(served=0)], t=3, serial=4)  # a new intervention: a new clock
    d.register(4, d.view(), posted_at=200.0)
    d.on_shown(4, 200.5)
    d.on_shown(1, 90.0)  # a late report of the old intervention's frame changes nothing
    assert d.on_push(1, 4, at=203.0)
    assert d.responses()["cell0/left"].waited_s == pytest.approx(2.5)


def test_a_step_let_pass_carries_none_and_the_clock_runs_on(make_request: RequestFactory
                                                           ) -> None:
    d = desk()
    d.assign([make_request(served=0)], t=0, serial=1)
    d.register(1, d.view(), posted_at=10.0)
    d.on_shown(1, 10.5)
    passed = d.responses()["cell0/left"]  # act() gave up: no push
    assert passed.action is None and passed.waited_s is None
    d.assign([make_request(served=1)], t=1, serial=2)
    d.register(2, d.view(), posted_at=14.0)
    d.on_shown(2, 14.5)
    assert d.on_push(2, 2, at=16.0)
    # from the first time this intervention was on screen, not from this step's frame
    assert d.responses()["cell0/left"].waited_s == pytest.approx(5.5)


def test_waited_s_of_a_reset_is_on_the_answer_that_reports_it_done(
    make_request: RequestFactory,
) -> None:
    d = desk()
    d.assign([make_request(kind="reset", served=0)], t=0, serial=1)
    d.register(1, d.view(), posted_at=50.0)
    d.on_shown(1, 50.1)
    assert d.responses()["cell0/left"].waited_s is None  # not confirmed yet
    assert d.on_confirm(1, at=58.1)  # Enter while the fleet executes
    d.assign([make_request(kind="reset", served=1)], t=1, serial=2)
    done = d.responses()["cell0/left"]
    assert done.reset_done and done.waited_s == pytest.approx(8.0)
    d.assign([make_request(kind="reset", served=2, violating=False)], t=2, serial=3)
    held = d.responses()["cell0/left"]
    assert not held.reset_done and held.waited_s is None


def test_a_key_before_its_paint_report_times_from_the_frames_departure(
    make_request: RequestFactory,
) -> None:
    d = desk()
    d.assign([make_request(served=0)], t=0, serial=1)
    d.register(1, d.view(), posted_at=7.0)
    assert d.on_push(0, 1, at=7.4)  # no paint report yet (a page's key came first)
    d.on_shown(1, 7.6)
    assert d.responses()["cell0/left"].waited_s == pytest.approx(0.4)


def test_a_queued_request_is_timed_from_when_it_was_shown(make_request: RequestFactory
                                                         ) -> None:
    d = desk()
    d.assign([make_request("a/left"), make_request("b/left")], t=0, serial=1)
    d.register(1, d.view(), posted_at=1.0)  # shows a/left; b/left waits behind it
    d.on_shown(1, 1.0)
    assert d.on_push(0, 1, at=2.0)
    d.register(2, d.view(), posted_at=2.0)  # now b/left
    d.on_shown(2, 2.1)
    assert d.on_push(3, 2, at=5.1)
    out = d.responses()
    assert out["a/left"].waited_s == pytest.approx(1.0)
    assert out["b/left"].waited_s == pytest.approx(3.0)


class _Surfaceless(ConsoleCore):
    """A console with no surface: its naming and its stop, without windows or pages."""

    def _has_surface(self, wid: int) -> bool:
        return False


def test_a_named_console_calls_each_human_by_name_beside_the_index(
    make_request: RequestFactory,
) -> None:
    core = _Surfaceless(2, names=["ana", "bo"])
    assert [core.human_label(h) for h in range(2)] == ["ana (human 0)", "bo (human 1)"]
    assert core.surface_name(1) == "bo (human 1)"
    assert core.snapshot(0).window == "ana (human 0)"  # the state file's "window"
    core._desks[1].assign([make_request(human=1)], t=0, serial=1)
    assert core._desks[1].view().name == "bo", "the drawn header gets the name"
    assert core._desks[0].view().name == "ana", "an idle view too"
    with core._cond:  # as a surface reports an input: under the console's lock
        assert core._on_command(0, 0, KeyCommand(Command.STOP))
        assert core._on_command(0, 0, KeyCommand(Command.YES))
    with pytest.raises(StopRequested, match=r"stop confirmed by ana \(human 0\)"):
        core.act([], 1)
    # unnamed: today's labels, everywhere
    plain = _Surfaceless(2)
    assert plain.names == () and plain.human_name(1) is None
    assert plain.surface_name(1) == "human 1" and plain._desks[1].view().name is None


@pytest.mark.parametrize(("names", "why"), [
    (["ana"], "need 2"), (["ana", "ana"], "twice"), (["ana", ""], "not a name"),
    (["ana", "b\no"], "not a name"),
], ids=["count", "twice", "empty", "line-break"])
def test_names_a_console_cannot_show_are_refused(names: list[str], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        _Surfaceless(2, names=names)


def test_a_console_told_the_places_shows_each_beside_the_name(
    make_request: RequestFactory,
) -> None:
    """Issue 44: ``places`` (the config's ``where``) go to every view and the overview's
    lines; a console not told shows what it always showed."""
    core = _Surfaceless(2, names=["ana", "bo"], places=["on_site", "remote"])
    assert [core.overview_label(h) for h in range(2)] == ["ana (human 0), on site",
                                                          "bo (human 1), remote"]
    assert core.human_label(1) == "bo (human 1)", "titles and links keep the label"
    core._desks[1].assign([make_request(human=1)], t=0, serial=1)
    assert core._desks[1].view().place == "remote"
    assert core._desks[0].view().place == "on_site", "an idle view too"
    plain = _Surfaceless(2)
    assert plain.places == () and plain.overview_label(0) == "human 0"
    assert plain._desks[0].view().place is None


@pytest.mark.parametrize(("places", "why"), [
    (["on_site"], "need 2"), (["on_site", "lab"], r"places\[1\]: unknown place 'lab'")])
def test_places_a_console_cannot_show_are_refused(places: list[str], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        _Surfaceless(2, places=places)


def test_a_reset_addressed_to_a_remote_person_is_shown_to_one_on_site(
    make_request: RequestFactory,
) -> None:
    """The allocator never sends one; the data collection before a trial addresses its
    resets by arm index (``testbed.experiments.pretraining``): the console shows such a
    reset to a person on site, never to the remote one; teleops go where addressed."""
    core = _Surfaceless(3, places=["remote", "on_site", "remote"], teleop_timeout_s=0.05)
    out = core.act([make_request("cell0/left", 0, kind="reset"),
                    make_request("cell0/right", 2, kind="teleop")], 0)
    assert out["cell0/left"].reset_done is False
    assert core._desks[1].view().phase is Phase.RESET
    view = core._desks[1].view()
    assert view.request is not None and view.request.robot == "cell0/left"
    assert core._desks[0].view().phase is Phase.IDLE
    view = core._desks[2].view()
    assert view.request is not None and view.request.robot == "cell0/right"
