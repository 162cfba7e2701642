"""Regenerate the pictures in docs/ that show the product itself (not a run's results).

    .venv/bin/python scripts/doc_images.py                 # both
    .venv/bin/python scripts/doc_images.py web-idle        # docs/web-console-idle.png
    .venv/bin/python scripts/doc_images.py check-mosaic    # docs/check-mosaic.png
    .venv/bin/python scripts/doc_images.py report-page [--report F]   # docs/report-page.png

Why a script: the pictures must be what the code draws today, so they are made by the
code, never edited by hand. ``web-idle`` is the browser console's page of a human with
no arm (headless Chromium, as tests/gui/test_web_browser.py drives it; needs the
``chromium`` and ``chromium-driver`` packages); ``check-mosaic`` is ``testbed check
--config protocols/twin.toml --mosaic docs/check-mosaic.png`` (the twin fleet's 4 arms;
the twin has no full camera frame, so nothing else is written); ``report-page`` is a
``report.html`` in headless Chromium, the whole page (default: the short twin protocol's,
``runs/protocol-twin-operators/report.html``, after ``testbed protocol
protocols/twin-operators.toml``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def web_idle(out: Path) -> None:
    """Human 0's page while the fleet has no arm for them, mid-trial, 3 named humans."""
    from selenium.webdriver.common.by import By

    from gui.web import WebHumans
    from gui.web.browser import chromium, open_console
    from testbed.core.types import FleetStatus, Mode, RobotStatus

    robots = [RobotStatus("cell0/left", Mode.AUTONOMOUS, None),
              RobotStatus("cell0/right", Mode.TELEOP, None, 1),
              RobotStatus("cell1/left", Mode.RESET, None, 2),
              RobotStatus("cell1/right", Mode.AUTONOMOUS, None)]
    successes, human_actions = 41, 97
    status = FleetStatus(137, 250, successes=successes, hard_resets=6, idle_time=18,
                         human_actions=human_actions,
                         rohe=(3 / 4) * successes / (1 + human_actions), robots=robots)
    with (WebHumans(3, names=["ana", "bo", "cy"], announce=None) as web,
          chromium(width=440, height=900) as page):
        open_console(page, web.urls[0])
        web.show(status.t, status)
        deadline = time.monotonic() + 10
        while page.find_element(By.ID, "f-step").text != "137 of 250":
            if time.monotonic() > deadline:
                raise TimeoutError("the idle page did not show the fleet's state")
            time.sleep(0.05)
        out.write_bytes(page.find_element(By.TAG_NAME, "body").screenshot_as_png)


def check_mosaic(out: Path) -> None:
    """``testbed check`` of the twin protocol's fleet."""
    from testbed.cli import main

    rc = main(["check", "--config", str(ROOT / "protocols" / "twin.toml"),
               "--mosaic", str(out)])
    if rc != 0:
        raise SystemExit(f"testbed check failed ({rc})")


REPORT = ROOT / "runs" / "protocol-twin-operators" / "report.html"


def report_page(out: Path, report: Path = REPORT) -> None:
    """The whole of a report.html, as a reviewer scrolls it (one tall PNG)."""
    import base64

    from gui.web.browser import chromium

    if not report.is_file():
        raise SystemExit(f"no {report}: run testbed protocol protocols/twin-operators.toml "
                         "first, or give --report")
    with chromium(width=1400, height=1000) as page:
        page.get(report.resolve().as_uri())
        height = page.execute_script("return document.documentElement.scrollHeight")
        page.set_window_size(1400, min(height + 40, 16000))
        shot = page.execute_cdp_cmd("Page.captureScreenshot",
                                    {"captureBeyondViewport": True, "format": "png"})
        out.write_bytes(base64.b64decode(shot["data"]))


PICTURES = {"web-idle": (web_idle, "web-console-idle.png"),
            "check-mosaic": (check_mosaic, "check-mosaic.png"),
            "report-page": (report_page, "report-page.png")}


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("which", nargs="*", metavar="PICTURE",
                   help=f"any of {', '.join(PICTURES)} (default: all)")
    p.add_argument("--report", type=Path, default=REPORT,
                   help="the report.html of report-page (default: %(default)s)")
    args = p.parse_args(argv)
    unknown = [w for w in args.which if w not in PICTURES]
    if unknown:
        p.error(f"unknown picture {unknown[0]!r}: choose from {', '.join(PICTURES)}")
    for name in args.which or PICTURES:
        make, file = PICTURES[name]
        if make is report_page:
            report_page(DOCS / file, args.report)
        else:
            make(DOCS / file)
        print(f"{name} -> {DOCS / file}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
