"""The day-one checklist is safe in the order written (issue 43, item 5).

Why: docs/rws-checklist.md is followed line by line by a person at a real YuMi. A line
with no mode, a "read" line that writes to the controller, or an Auto line before the
paragraph that empties the RAM disk would have that person start motion nobody planned.
These are the checks a text can fail; what each line does on the robot is the lab's.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "rws-checklist.md"
MODES = {"read", "no motion", "manual reduced, one arm", "Auto, RAM disk empty",
         "manual reduced, RAM disk empty", "Auto 10 %, e-stop in hand"}
"""The tags of the checklist's table "The order, and the mode each line needs"."""
WRITES = re.compile(r"\bsend\b|-X\s|action=|\bPOST\b|\bPUT\b|\bDELETE\b")
"""What writes to a controller over RWS in the checklist's commands (``send`` is its
POST helper; a ``rws``/``code`` call is a GET)."""
TAG = re.compile(r"- \[ \] \*\*\[([^\]]+)\]\*\*")


def items(text: str) -> list[tuple[int, str, str | None]]:
    """Every ``- [ ]`` line with its indented continuation: (line number, text, tag)."""
    out: list[tuple[int, str, str | None]] = []
    cur: list[str] | None = None
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith("- [ ]"):
            cur = [line]
            m = TAG.match(line)
            out.append((n, "", m.group(1) if m else None))
        elif cur is not None and line.startswith("  "):
            cur.append(line)
        else:
            cur = None
        if cur is not None:
            out[-1] = (out[-1][0], "\n".join(cur), out[-1][2])
    return out


def problems(text: str) -> list[str]:
    """Why ``text`` is not a checklist safe in the order written (empty: it is)."""
    found = items(text)
    out = [f"line {n}: no mode tag from the table" for n, _, tag in found if tag is None]
    out += [f"line {n}: tag [{tag}] is not in the table" for n, _, tag in found
            if tag is not None and tag not in MODES]
    out += [f"line {n}: a [read] line writes to the controller" for n, body, tag in found
            if tag == "read" and WRITES.search(body)]
    lines = text.splitlines()
    first = min((n for n, _, _ in found), default=len(lines) + 1)
    for heading in ("**Before the first line: the emergency stop and the FlexPendant.**",
                    "**Before any start in Auto: an empty RAM disk.**"):
        at = next((n for n, line in enumerate(lines, 1) if line.startswith(heading)), None)
        if at is None or at > first:
            out.append(f"{heading} is not before the first line")
    return out


def test_every_line_names_its_mode_reads_write_nothing_and_the_preconditions_come_first(
        ) -> None:
    text = DOC.read_text(encoding="utf-8")
    assert len(items(text)) > 80  # the whole checklist was read, not a part of it
    assert problems(text) == []


def test_each_unsafe_order_is_caught() -> None:
    text = DOC.read_text(encoding="utf-8")
    lines = text.splitlines()
    n, _, _ = next(i for i in items(text) if i[2] == "read")
    def with_line(new: str) -> str:
        return "\n".join([*lines[:n - 1], new, *lines[n:]])

    untagged = with_line(re.sub(r"\*\*\[read\]\*\* ", "", lines[n - 1]))
    assert problems(untagged) == [f"line {n}: no mode tag from the table"]
    writing = with_line(lines[n - 1] + ' `send "$C/rw/panel/ctrlstate"`')
    assert problems(writing) == [f"line {n}: a [read] line writes to the controller"]
    head = "**Before any start in Auto: an empty RAM disk.**"
    at = next(k for k, line in enumerate(lines) if line.startswith(head))
    moved = "\n".join([*lines[:at], *lines[at + 1:], head])
    assert problems(moved) == [f"{head} is not before the first line"]
