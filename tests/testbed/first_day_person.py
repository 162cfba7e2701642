"""One colleague of the first-day rehearsal: a headless Chromium on their own machine.

Run by ``tests/testbed/test_first_day.py`` inside the colleague's network namespace
(``tests/testbed/colleagues.py``), with the link the operator's terminal printed. It
opens the link as a person would, trusting the console's certificate only by the
fingerprint the operator read out (Chromium's ``--ignore-certificate-errors-spki-list``:
that one key, nothing else), then answers what the page asks until told to stop:

* an arm to teleoperate: a push key (``w``), as a person types on their laptop (each
  push logged with how many times the page had lost its console by then);
* a hard reset: the "Reset done" button, if this person is on site; a remote person
  never presses it, and records it if the page ever asked them;

and writes what it saw as JSON: its pushes and resets (with the page's frame numbers),
every notice the page showed (a resumed trial says so), what it said of the person
(their label, and whether they are on site or remote), the times the
page lost and found its server, and the address its own connection came from.

    python first_day_person.py URL SPKI on_site|remote LOG STOPFILE
"""

from __future__ import annotations

import json
import socket
import sys
import tempfile
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from gui.web.browser import chromium, open_console, press_key  # noqa: E402


def _source_address(url: str) -> str:
    """The address this machine's connection to the console comes from (the server
    sees it): proof that the browser is not on the operator's loopback."""
    parts = urlsplit(url)
    with socket.create_connection((parts.hostname, parts.port or 443), timeout=10) as s:
        return str(s.getsockname()[0])


LOOK = """const text = id => { const e = document.getElementById(id);
                                return e ? e.textContent : ''; };
return {state: window.consoleState || null, notice: text('notice'), who: text('who'),
        place: text('place')};"""
"""What the person reads on the page at one glance: ``window.consoleState`` (what
``gui.web.browser.page_state`` returns) and the notice, who and place lines, in one
WebDriver round trip (it was four, every 50 ms, in each colleague's browser)."""


def _look(driver: Any) -> tuple[dict[str, Any], dict[str, str]]:
    """The page's state ({} before it has one) and its three lines of text."""
    seen = driver.execute_script(LOOK)
    return dict(seen["state"] or {}), {k: str(seen[k]) for k in ("notice", "who", "place")}


def main(url: str, spki: str, where: str, log: Path, stop_file: Path) -> int:
    seen: dict[str, Any] = {"where": where, "source": _source_address(url), "pushes": [],
                            "resets": [], "resets_shown": [], "notices": [], "who": [], "place": [],
                            "drops": 0, "errors": []}
    done: set[int] = set()
    with tempfile.TemporaryDirectory() as profile, chromium(extra_args=(
            f"--ignore-certificate-errors-spki-list={spki}", f"--user-data-dir={profile}",
            "--disable-background-networking", "--disable-component-update",
            "--disable-sync")) as page:
        open_console(page, url, timeout_s=180)
        was_open = True
        while not stop_file.exists():
            try:
                st, texts = _look(page)
                if was_open and not st.get("open"):
                    seen["drops"] += 1
                was_open = bool(st.get("open"))
                for key, element in (("notices", "notice"), ("who", "who"), ("place", "place")):
                    text = texts[element].strip()
                    if text and text not in seen[key]:
                        seen[key].append(text)
                head = st.get("head") or {}
                seq, phase = int(st.get("shownSeq", 0)), head.get("phase")
                if seq not in done and not head.get("paused") and phase in ("choose",
                                                                           "reset"):
                    done.add(seq)
                    if phase == "choose":
                        press_key(page, "w")
                        seen["pushes"].append([head.get("robot"), seq, seen["drops"]])
                    else:
                        seen["resets_shown"].append([head.get("robot"), seq])
                        if where == "on_site":
                            page.find_element("id", "reset").click()
                            seen["resets"].append([head.get("robot"), seq])
            except Exception as exc:  # the page reloading under us: look again
                seen["errors"].append(repr(exc)[:200])
            time.sleep(0.05)
    log.write_text(json.dumps(seen, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2], sys.argv[3], Path(sys.argv[4]),
                  Path(sys.argv[5])))
