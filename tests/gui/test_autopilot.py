"""The end-to-end tests' autopilot answers a prompt once, and again only if it was lost.

One CI run of ``test_console_trial_e2e`` never ended: a prompt answered once and never
taken would leave its human's arm waiting for the whole trial. The autopilot now sends
an answer again when the prompt is still there ``retry_s`` later, as a person would; a
prompt the console took (its phase moved on) is never answered twice. xdotool and the
window lookup are replaced here by recorders: what is tested is the autopilot's rule.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

import gui.xdo as xdo

RETRY_S = 0.2


def _state(path: Path, phase: str, seq: int = 5, *, human: int = 0) -> None:
    window = {"human": human, "window": f"human {human}", "phase": phase, "robot": "cell0/left",
              "kind": "teleop", "markers": [[10, 10], [20, 10], [10, 20], [20, 20]],
              "seq_posted": seq, "seq_shown": seq, "on_screen": True}
    path.write_text(json.dumps({"windows": [window]}))


@pytest.fixture
def sent(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, Any]]:
    """Every key and click the autopilot sends, and every window lookup."""
    out: list[tuple[str, Any]] = []
    monkeypatch.setattr(xdo, "press", lambda wid, key, display=None: out.append(("key", key)))
    monkeypatch.setattr(xdo, "click",
                        lambda wid, x, y, display=None: out.append(("click", (x, y))))

    def find(name: str, *, display: str | None = None, timeout_s: float = 10.0) -> str:
        out.append(("find", name))
        return "0x1"

    monkeypatch.setattr(xdo, "find_window", find)
    return out


def test_a_lost_answer_is_sent_again_and_a_taken_one_never(
        tmp_path: Path, sent: list[tuple[str, Any]]) -> None:
    state = tmp_path / "console.json"
    pilot = xdo.Autopilot(state, None, lambda h: ("key", "w"), retry_s=RETRY_S)
    _state(state, "choose")
    pilot._answer_prompts()
    pilot._answer_prompts()  # the same frame, before retry_s: nothing more
    assert [s for s in sent if s[0] == "key"] == [("key", "w")]
    time.sleep(RETRY_S * 1.5)
    pilot._answer_prompts()  # still "choose" on frame 5: the key was lost, press again
    assert [s for s in sent if s[0] == "key"] == [("key", "w")] * 2
    assert pilot.retries == 1
    assert [s for s in sent if s[0] == "find"] == [("find", "human 0")] * 2  # looked up anew

    _state(state, "sent")  # taken: the push went to the fleet
    time.sleep(RETRY_S * 1.5)
    pilot._answer_prompts()
    assert len([s for s in sent if s[0] == "key"]) == 2 and pilot.retries == 1


def test_a_reset_banner_gets_enter_again_only_while_it_waits(
        tmp_path: Path, sent: list[tuple[str, Any]]) -> None:
    state = tmp_path / "console.json"
    pilot = xdo.Autopilot(state, None, lambda h: ("click", 3), retry_s=RETRY_S)
    _state(state, "reset", seq=9)
    pilot._answer_prompts()
    time.sleep(RETRY_S * 1.5)
    pilot._answer_prompts()
    assert [s for s in sent if s[0] == "key"] == [("key", "Return")] * 2
    _state(state, "reset_confirmed", seq=9)
    time.sleep(RETRY_S * 1.5)
    pilot._answer_prompts()
    _state(state, "choose", seq=10)  # the next frame: a new prompt, answered at once
    pilot._answer_prompts()
    assert [s for s in sent if s[0] != "find"] == [("key", "Return")] * 2 + [
        ("click", (20, 20))]
    assert [(a[0], a[2]) for a in pilot.answers] == [(0, "reset")] * 2 + [(0, "choose")]
