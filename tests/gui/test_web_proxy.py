"""The reverse-proxy recipe of docs/notes/web.md, tested as written: Debian's nginx
serves the console under ``/fleet/`` with the recipe's own ``location`` block (read from
the doc, only its upstream port changed), and a real Chromium opens the link the
console prints for that ``public_url``: the page loads, its socket connects under the
prefix, a frame is painted and a key pushes the person's arm; the overview link works
the same way. Stand-in, named: nginx listens on loopback here, where a lab's listens on
its public name with the lab's certificate (TLS at the proxy: ``tls = "off"`` behind
it).
"""

from __future__ import annotations

import re
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from console_helpers import ActCall

from gui.web import WebHumans
from gui.web.browser import browser_missing, chromium, open_console, page_state, press_key

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "notes" / "web.md"
TOKENS = ["ana-token-behind-the-proxy-0", "bo-token-behind-the-proxy-00"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def recipe(upstream_port: int) -> str:
    """The doc's nginx ``location`` block, with its upstream at ``upstream_port``."""
    (block,) = re.findall(r"```nginx\n(location /fleet/ \{.*?\n\})\n```", DOC.read_text(),
                          re.S)
    assert "proxy_pass http://127.0.0.1:8765/;" in block
    return block.replace("127.0.0.1:8765", f"127.0.0.1:{upstream_port}")


@pytest.fixture
def nginx(tmp_path: Path) -> Iterator[tuple[int, Any]]:
    """A function starting nginx on a free loopback port in front of an upstream port."""
    if shutil.which("nginx") is None and not Path("/usr/sbin/nginx").exists():
        pytest.fail("missing nginx: apt-get install -y nginx (scripts/setup.sh --dev does it)")
    port = _free_port()
    procs: list[subprocess.Popen[bytes]] = []

    def start(upstream_port: int) -> None:
        temp = "".join(f"    {k}_temp_path {tmp_path}/{k};\n" for k in
                       ("client_body", "proxy", "fastcgi", "uwsgi", "scgi"))
        conf = tmp_path / "nginx.conf"
        conf.write_text(
            f"daemon off;\npid {tmp_path}/nginx.pid;\nerror_log {tmp_path}/error.log;\n"
            "events {}\nhttp {\n"
            f"    access_log {tmp_path}/access.log;\n{temp}"
            f"    server {{\n        listen 127.0.0.1:{port};\n"
            + "\n".join("        " + line for line in recipe(upstream_port).splitlines())
            + "\n    }\n}\n")
        nginx_bin = shutil.which("nginx") or "/usr/sbin/nginx"
        procs.append(subprocess.Popen([nginx_bin, "-p", str(tmp_path), "-c", str(conf)],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.PIPE))
        deadline = time.monotonic() + 10
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                return
            except OSError:
                assert procs[-1].poll() is None, procs[-1].stderr.read().decode()  # type: ignore[union-attr]
                assert time.monotonic() < deadline, "nginx did not listen"
                time.sleep(0.05)

    try:
        yield port, start
    finally:
        for p in procs:
            p.terminate()
            p.wait(10)


def test_the_console_behind_nginx_under_a_path_prefix(
        nginx: tuple[int, Any], make_request: Any) -> None:
    if browser_missing():
        pytest.fail(f"missing {', '.join(browser_missing())}: apt-get install -y chromium "
                    "chromium-driver (scripts/setup.sh --dev does it)")
    port, start = nginx
    public = f"http://127.0.0.1:{port}/fleet"
    with WebHumans(2, port=0, tokens=TOKENS, names=["ana", "bo"], announce=None,
                   public_url=public, away_timeout_s=30.0) as web:
        upstream = int(web.base_url.rsplit(":", 1)[1])
        start(upstream)
        assert web.urls[0] == f"{public}/?token={TOKENS[0]}"  # the link as printed
        with chromium() as page:
            open_console(page, web.urls[0])  # loaded through nginx, a frame painted
            call = ActCall(lambda: web.act([make_request("cell0/left", 0)], 0))
            state = web.wait_for_prompt(0)
            deadline = time.monotonic() + 10
            while page_state(page).get("shownSeq") != state.seq_posted:
                assert time.monotonic() < deadline, "the frame never came through the proxy"
                time.sleep(0.02)
            press_key(page, "d")  # the socket under /fleet/ carries the push back
            assert call.join()["cell0/left"].action == 3
            assert page.current_url.startswith(f"{public}/?token=")
            open_console(page, web.overview_url)  # the overview under the prefix too
            assert web.overview_url.startswith(f"{public}/overview?token=")
            assert page_state(page)["open"] is True
