"""The web console's links (issue 44): kept with the run for its resume, named as others
reach the machine, a read-only overview separate from every person's, the operator's
controls on a link of its own.

Real parts: the console's real server (``gui.web.WebHumans``) on loopback and the run
folder's file as a resume reads it (a "new process" is this one with its session
tokens forgotten).
"""

from __future__ import annotations

import io
import json
import socket
import stat
from pathlib import Path

import pytest

from gui.console_core import OVERVIEW
from gui.web.links import link_base
from gui.web.web_humans import WebHumans
from testbed.core.config import ConfigError
from testbed.experiments import web_links
from testbed.experiments.fleet_config import parse_config
from testbed.experiments.web_links import LINKS_FILE, links_for_run
from testbed.people.people_config import WebConsoleConfig
from testbed.records.run_dir import RunDir

TOKENS = ["human0-token-aaaaaaaaaaaa", "human1-token-bbbbbbbbbbbb"]


def test_a_resume_gets_the_links_its_run_gave_and_only_the_operator_reads_them(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(web_links, "_SESSION", {})
    run, other = tmp_path / "run-a", tmp_path / "run-b"
    first = links_for_run(run, WebConsoleConfig(port=0), 2)
    kept = json.loads((run / LINKS_FILE).read_text())
    assert kept == {"humans": first.tokens, "overview": first.overview_token,
                    "operator": first.operator_token}
    assert len({*first.tokens, first.overview_token, first.operator_token}) == 4
    assert stat.S_IMODE((run / LINKS_FILE).stat().st_mode) == 0o600
    # the protocol's next trial in this process: the same links
    assert links_for_run(other, WebConsoleConfig(port=0), 2).tokens == first.tokens
    # a crash, a new process, --resume: the tokens come back from the run's folder
    monkeypatch.setattr(web_links, "_SESSION", {})
    again = links_for_run(run, WebConsoleConfig(port=0), 2)
    assert (again.tokens, again.overview_token, again.operator_token) == (
        first.tokens, first.overview_token, first.operator_token)
    # ... and become this process's, for the protocol's trials after it
    assert links_for_run(tmp_path / "run-c", WebConsoleConfig(port=0), 2).tokens == \
        first.tokens
    # the console built from it prints the same links, says it was resumed, and so does
    # every page
    said = io.StringIO()
    with WebHumans(2, port=0, tokens=again.tokens, overview_token=again.overview_token,
                   operator_token=again.operator_token, resumed_at=7, announce=said) as web:
        printed = said.getvalue()
        for h, tok in enumerate(first.tokens):
            assert f"web console: human {h}: {web.link_base}/?token={tok}" in printed
        assert (f"web console: fleet overview (to watch; share it): {web.link_base}"
                f"/overview?token={first.overview_token}") in printed
        assert (f"web console: operator (pause and stop; keep it to yourself): "
                f"{web.link_base}/overview?token={first.operator_token}") in printed
        assert "web console: resumed at step 7: the links are the ones given" in printed
        notice = "This trial was resumed at step 7; your link is the one given at its start."
        for wid in (0, OVERVIEW):
            assert notice in web.page(wid)
            # a page left open through the crash reconnects: its new socket is told
            assert {"type": "session", "notice": notice} in web.connected(wid)
            web.disconnected(wid)
    with WebHumans.from_config(2, again.model_copy(update={"port": 0}), resumed_at=7) as web:
        assert web.resumed_at == 7 and web.urls[0].endswith(f"/?token={first.tokens[0]}")


def test_the_configs_own_tokens_are_kept_and_a_file_for_another_crew_is_an_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(web_links, "_SESSION", {})
    given = WebConsoleConfig(port=0, tokens=TOKENS, operator_token="operator-token-dddddddddd")
    got = links_for_run(tmp_path, given, 2)
    assert got.tokens == TOKENS and got.operator_token == "operator-token-dddddddddd"
    assert got.overview_token is not None and got.overview_token not in TOKENS
    with pytest.raises(ValueError, match=rf"{LINKS_FILE}: 2 humans' links kept, the run has 3"):
        links_for_run(tmp_path, WebConsoleConfig(port=0), 3)


def test_the_run_folders_config_holds_no_token_and_reads_back(tmp_path: Path) -> None:
    cfg = parse_config({"humans": {"count": 2, "kind": "web", "web": {
        "tokens": TOKENS, "overview_token": "overview-token-cccccccccc",
        "operator_token": "operator-token-dddddddddd",
        "public_url": "https://lab.example.org/fleet"}}})
    run = RunDir(tmp_path)
    run.write_config(cfg)
    text = (tmp_path / "config.toml").read_text()
    assert "token-" not in text and "public_url" in text
    back = run.read_config(type(cfg))
    assert back.humans.web.tokens == [] and back.humans.web.operator_token is None


@pytest.mark.parametrize(("web", "field"), [
    ({"overview_token": "overview-token-cccccccccc"}, "overview_token"),  # without tokens
    ({"tokens": TOKENS, "operator_token": "short"}, "operator_token"),
    ({"tokens": TOKENS, "operator_token": TOKENS[0]}, "operator_token"),
    ({"tokens": TOKENS, "overview_token": "same-token-eeeeeeeeeeee",
      "operator_token": "same-token-eeeeeeeeeeee"}, "operator_token"),
    ({"public_url": "lab-pc:8765"}, "public_url"),
])
def test_a_bad_link_setting_names_its_field(web: dict[str, object], field: str) -> None:
    with pytest.raises(ConfigError, match=rf"humans\.web\.{field}"):
        parse_config({"humans": {"count": 2, "kind": "web", "web": web}})


def test_the_links_name_the_machine_as_others_reach_it() -> None:
    assert link_base("http://127.0.0.1:8765", None) == "http://127.0.0.1:8765"
    assert link_base("https://0.0.0.0:8765", None) == f"https://{socket.getfqdn()}:8765"
    assert link_base("http://[::]:8765", None) == f"http://{socket.getfqdn()}:8765"
    assert link_base("http://0.0.0.0:8765", "https://lab.example.org/fleet/") == \
        "https://lab.example.org/fleet"
    with WebHumans(1, port=0, tokens=TOKENS[:1], announce=None,
                   public_url="https://lab.example.org/fleet") as web:
        assert web.urls == [f"https://lab.example.org/fleet/?token={TOKENS[0]}"]
        assert web.overview_url.startswith("https://lab.example.org/fleet/overview?token=")
        assert web.base_url.startswith("http://127.0.0.1:")  # where it listens: unchanged


def test_only_the_operators_overview_shows_pause_and_stop() -> None:
    with WebHumans(2, port=0, tokens=TOKENS, announce=None) as web:
        for page in (web.page(0), web.page(OVERVIEW, controls=False)):
            assert '<button id="pause" hidden' in page
            assert '<button class="stop" id="stop" hidden' in page
        operator = web.page(OVERVIEW, controls=True)
        assert '<button id="pause" data-button="pause">' in operator
        assert '<button class="stop" id="stop" data-button="stop">' in operator
        assert "resumed" not in operator  # a run that was not resumed says nothing
        assert not [m for m in web.connected(0) if m["type"] == "session"]
        web.disconnected(0)
        assert web.overview_role(web.tokens.operator) == "operator"
        assert web.overview_role(web.tokens.overview) == "viewer"
        assert web.overview_role(TOKENS[1]) == "viewer"
        assert web.overview_role("operator-token-dddddddddx") is None
        assert web.human_of(web.tokens.operator) is None  # no person's page either


@pytest.mark.ssh
def test_a_colleague_reaches_the_console_through_an_ssh_tunnel(tmp_path: Path) -> None:
    """The recipe of docs/notes/web.md, "Reaching the console": the console stays on the
    operator's loopback; a colleague runs ``ssh -N -L PORT:127.0.0.1:PORT operator@lab-pc``
    and opens her link as printed (``public_url`` names the tunnel's end). A real OpenSSH
    server and client on loopback stand in for the lab machine and her laptop."""
    import subprocess
    import time
    import urllib.request

    from websockets.sync.client import connect

    from drivers.testing.sshd import SshServer, free_port, sshd_available

    if not sshd_available():
        pytest.fail("needs OpenSSH sshd (openssh-server): scripts/setup.sh --dev installs it")
    local = free_port()
    with SshServer(tmp_path / "sshd") as server, WebHumans(
            2, port=0, tokens=TOKENS, announce=None,
            public_url=f"http://127.0.0.1:{local}") as web:
        tunnel = subprocess.Popen(
            ["ssh", "-N", "-L", f"{local}:127.0.0.1:{web.port}", "-p", str(server.port),
             "-i", str(server.client_key), "-o", f"UserKnownHostsFile={server.known_hosts}",
             "-o", "StrictHostKeyChecking=yes", "-o", "BatchMode=yes",
             "-o", "ExitOnForwardFailure=yes", f"{server.user}@127.0.0.1"],
            stdin=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
            deadline, body = time.monotonic() + 20.0, ""
            while time.monotonic() < deadline:
                try:
                    with opener.open(web.urls[1], timeout=5.0) as resp:  # as printed
                        body = resp.read().decode()
                        break
                except OSError:
                    assert tunnel.poll() is None, tunnel.stderr.read() if tunnel.stderr else ""
                    time.sleep(0.2)
            assert "<title>testbed console - human 1</title>" in body
            with connect(f"ws://127.0.0.1:{local}/ws?token={TOKENS[1]}", proxy=None,
                         open_timeout=20.0) as ws:
                ws.recv(timeout=10.0)  # the page's first frame, through the tunnel
                deadline = time.monotonic() + 10.0
                while not web.presence().available[1] and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert web.presence().available.tolist() == [False, True]
        finally:
            tunnel.terminate()
            tunnel.wait(10)


def test_off_loopback_the_console_serves_https_with_a_kept_certificate_and_prints_it(
        tmp_path: Path) -> None:
    """Issue 44: https by default for a console others reach. With no certificate of the
    lab's, one is made on this machine once (its key 0600) and kept, so its fingerprint,
    printed with the links, stays the same; a browser that checks the fingerprint gets
    the very certificate printed. ``tls = "off"`` (a proxy terminates TLS) and loopback
    stay plain http."""
    import hashlib
    import ssl
    import urllib.request

    from gui.web.tls import certificate_fingerprint

    said = io.StringIO()
    with WebHumans(1, host="0.0.0.0", port=0, tokens=TOKENS[:1], announce=said,
                   tls_dir=tmp_path / "tls") as web:
        assert web.base_url.startswith("https://")
        cert = tmp_path / "tls" / "console-cert.pem"
        assert stat.S_IMODE((tmp_path / "tls" / "console-key.pem").stat().st_mode) == 0o600
        assert web.fingerprint == certificate_fingerprint(cert)
        assert (f"web console: https, certificate SHA-256 {web.fingerprint} (self-signed: "
                f"compare it with what the browser shows") in said.getvalue()
        assert all(u.startswith(f"https://{socket.getfqdn()}:") for u in web.urls)
        ctx = ssl.create_default_context(cafile=str(cert))
        ctx.check_hostname = False  # fetched by address; the chain is still verified
        opener = urllib.request.build_opener(urllib.request.ProxyHandler({}),
                                             urllib.request.HTTPSHandler(context=ctx))
        url = f"https://127.0.0.1:{web.port}/?token={TOKENS[0]}"
        with opener.open(url, timeout=10.0) as resp:
            assert resp.status == 200
        with socket.create_connection(("127.0.0.1", web.port), timeout=10.0) as raw, \
                ctx.wrap_socket(raw) as tls:
            der = tls.getpeercert(binary_form=True)
        assert der is not None
        seen = hashlib.sha256(der).hexdigest().upper()
        assert web.fingerprint.replace(":", "") == seen
        first = web.fingerprint
    with WebHumans(1, host="0.0.0.0", port=0, tokens=TOKENS[:1], announce=None,
                   tls_dir=tmp_path / "tls") as web:
        assert web.fingerprint == first  # kept: a colleague accepts it once
    with WebHumans(1, host="0.0.0.0", port=0, tokens=TOKENS[:1], announce=None, tls="off",
                   tls_dir=tmp_path / "none") as web:
        assert web.base_url.startswith("http://") and web.fingerprint is None
    with WebHumans(1, port=0, tokens=TOKENS[:1], announce=None,
                   tls_dir=tmp_path / "none") as web:
        assert web.base_url.startswith("http://127.0.0.1:")
    assert not (tmp_path / "none").exists()
    with pytest.raises(ConfigError, match=r"humans\.web\.tls"):
        parse_config({"humans": {"count": 1, "kind": "web", "web": {
            "tls": "off", "certfile": str(cert), "keyfile": str(cert)}}})


def test_every_command_of_a_folder_of_runs_gives_the_same_links(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """collect, then pretrain, then the protocol, each a process of its own, in one
    folder of runs: the first keeps its links in the folder's web-links.json (0600),
    every later one reads them back (its runs too); a config's own tokens still win."""
    folder = tmp_path / "runs"
    monkeypatch.setattr(web_links, "_SESSION", {})  # testbed collect
    collect = web_links.links_for_folder(folder, WebConsoleConfig(port=0), 2)
    assert stat.S_IMODE((folder / LINKS_FILE).stat().st_mode) == 0o600
    assert json.loads((folder / LINKS_FILE).read_text()) == {
        "humans": collect.tokens, "overview": collect.overview_token,
        "operator": collect.operator_token}
    monkeypatch.setattr(web_links, "_SESSION", {})  # testbed pretrain
    pretrain = web_links.links_for_folder(folder, WebConsoleConfig(port=0), 2)
    monkeypatch.setattr(web_links, "_SESSION", {})  # testbed protocol: a run in the folder
    run = links_for_run(folder / "cur-t0", WebConsoleConfig(port=0), 2, folder)
    for got in (pretrain, run):
        assert (got.tokens, got.overview_token, got.operator_token) == (
            collect.tokens, collect.overview_token, collect.operator_token)
    monkeypatch.setattr(web_links, "_SESSION", {})  # another folder: other links
    assert web_links.links_for_folder(tmp_path / "other", WebConsoleConfig(port=0),
                                      2).tokens != collect.tokens
    monkeypatch.setattr(web_links, "_SESSION", {})
    given = web_links.links_for_folder(folder, WebConsoleConfig(port=0, tokens=TOKENS), 2)
    assert given.tokens == TOKENS and given.operator_token == collect.operator_token
