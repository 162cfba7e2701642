"""Drive console pages in a real browser: Debian's Chromium, headless, via Selenium.

For the tests and the latency benchmark, as ``gui.xdo`` is for the OpenCV windows:
the console's promises (a key on this page pushes that arm, the reset button completes
a reset, a frame is painted within 50 ms) hold only in a real browser.

Why Selenium with chromedriver rather than Playwright: Debian ships ``chromium`` and
``chromium-driver`` built from one source, so the driver always matches the browser,
and Selenium talks to it with no browser download of its own (Playwright's Python
package expects its own browser builds; it can launch a system Chromium, but against
a protocol version it does not pin). Debian packages: ``chromium``,
``chromium-driver``; Python: ``selenium`` (the ``dev`` extra).

    with chromium() as page:
        page.get(console.urls[0])
        wait_for_page(page)
        page_state(page)          # window.consoleState: shownSeq, head, replies...
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


def browser_missing() -> list[str]:
    """The Debian packages this module needs that are not installed."""
    missing = []
    if shutil.which("chromium") is None and not os.path.exists(CHROMIUM):
        missing.append("chromium")
    if shutil.which("chromedriver") is None and not os.path.exists(CHROMEDRIVER):
        missing.append("chromium-driver")
    return missing


@contextmanager
def chromium(width: int = 900, height: int = 1000, extra_args: Sequence[str] = ()
             ) -> Iterator[Any]:
    """One headless Chromium window driven by Selenium; quit on exit. ``extra_args``:
    more command-line switches (a colleague's browser trusting the console's
    self-signed certificate by its key: ``--ignore-certificate-errors-spki-list=...``)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    if browser_missing():
        raise RuntimeError(f"missing {', '.join(browser_missing())}: apt-get install -y "
                           "chromium chromium-driver (scripts/setup.sh --dev does it)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--disable-extensions", "--no-first-run", f"--window-size={width},{height}",
                *extra_args):
        opts.add_argument(arg)
    service = Service(shutil.which("chromedriver") or CHROMEDRIVER)  # no driver download
    driver = webdriver.Chrome(service=service, options=opts)
    try:
        yield driver
    finally:
        driver.quit()


def page_state(driver: Any) -> dict[str, Any]:
    """The page's ``window.consoleState`` (``gui/web/static/console.js``), or {}."""
    state = driver.execute_script("return window.consoleState || null")
    return dict(state) if state else {}


def open_console(driver: Any, url: str, timeout_s: float = 60.0) -> None:
    """Load a console page, retrying while its server is not up yet; wait for a frame."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            driver.get(url)
            if page_state(driver).get("open") is not None:
                break
        except Exception:  # connection refused: the controller is still starting
            pass
        if time.monotonic() > deadline:
            raise TimeoutError(f"no console page at {url}")
        time.sleep(0.5)
    while not page_state(driver).get("painted"):
        if time.monotonic() > deadline:
            raise TimeoutError(f"the console page at {url} painted no frame")
        time.sleep(0.05)


def click_frame_point(driver: Any, x: float, y: float, *, touch: bool = False) -> None:
    """Click (or, ``touch``, tap with a finger) the page's frame canvas at frame pixel
    (x, y), whatever the page's zoom."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions import interaction
    from selenium.webdriver.common.actions.action_builder import ActionBuilder
    from selenium.webdriver.common.actions.pointer_input import PointerInput
    from selenium.webdriver.common.by import By

    canvas = driver.find_element(By.ID, "frame")
    natural_w = driver.execute_script("return document.getElementById('frame').width")
    rect = canvas.rect
    scale = rect["width"] / natural_w
    dx = round(x * scale - rect["width"] / 2)  # Selenium 4: offsets from the centre
    dy = round(y * scale - rect["height"] / 2)
    if not touch:
        ActionChains(driver).move_to_element_with_offset(canvas, dx, dy).click().perform()
        return
    finger = ActionBuilder(driver, mouse=PointerInput(interaction.POINTER_TOUCH, "finger"))
    finger.pointer_action.move_to(canvas, dx, dy).pointer_down().pointer_up()
    finger.perform()


def press_key(driver: Any, key: str) -> None:
    """Type one key into the page (``selenium.webdriver.common.keys.Keys`` names work)."""
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(driver).send_keys(key).perform()
