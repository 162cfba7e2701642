"""The operator's first day as one test (issue 44, item 8): colleagues on their own
machines reach the browser console through the links as printed, a crash and a resume
keep those links, and the hard resets go to the person on site.

Everything is real: ``testbed rehearse`` with ``--humans web`` (two YuMi hardware twins
behind real OpenSSH sshds, the agents on ABB's client, torch), the console served over
https with the self-signed certificate made on this machine, and one headless Chromium
per colleague (``tests/testbed/first_day_person.py``), each in a network namespace of
its own (``tests/testbed/colleagues.py``): another address, another loopback, the
console reached only through the ``public_url`` the operator configured, the certificate
trusted only by the key whose fingerprint the operator's terminal printed. The operator's
process is killed with SIGKILL mid-run and the same command run again: the pages, left
open as a colleague would leave them, find the console again by themselves with the
links of the first session, and each says the trial was resumed.

Stand-ins, named: the robots are the hardware twins (``testbed rehearse``); a colleague's
laptop is a network namespace on this machine; the arms' calibrations are the exact ones
(``lab_fixtures.calibrate_exactly``) written into the lab folder before the first session,
as a lab calibrated that morning, so the first session keeps them as a resumed one does
(``testbed/lab/rehearsal.py::_kept_calibration``). Calibrating four arms with ``testbed
calibrate`` inside a rehearsal is ``tests/testbed/test_rehearsal.py``'s to prove, keeping
them across a kill ``tests/testbed/test_rehearsal_resume.py``'s; here it was a minute of
CPU before the first link, none of it what this test checks.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from colleagues import Colleague, colleagues, netns_missing
from lab_fixtures import calibrate_exactly, tiny_protocol

from drivers.testing.sshd import sshd_available
from gui.web.browser import browser_missing
from testbed.core.atomic import atomic_write_json
from testbed.experiments.protocol import load_protocol
from testbed.lab.camera_model import true_model_error
from testbed.lab.hardware_twin import HardwareTwinLab
from testbed.lab.rehearsal import CALIBRATED
from testbed.records.steps import read_steps

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ssh,
    pytest.mark.timeout(1500),  # two rehearsal sessions under a loaded suite
    pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd (openssh-server)"),
]

ROOT = Path(__file__).resolve().parents[2]
PERSON = Path(__file__).with_name("first_day_person.py")
STEPS = 14
KILL_AT = 6
PEOPLE = (("ana", "on_site"), ("bo", "remote"))
LEARNING = {"demos": 8, "critic_transitions": 4}
"""theta_0's data, halved from ``lab_fixtures.TINY_LEARNING``'s: its fleet steps (the
demos and rollouts on the twins) come before the first step and the kill, and no
assertion reads what the learner learnt from them (3 gradient steps either way)."""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("0.0.0.0", 0))
        return int(s.getsockname()[1])


def _protocol(tmp: Path, port: int, address: str) -> Path:
    """The shipped physical protocol (tiny learning, ``LEARNING``), its humans in
    browsers: ana on site, bo remote, the console on every interface, its links named
    by the address the colleagues reach (``public_url``), https by default."""
    people = "".join(f'\n[[fleet.humans.people]]\nname = "{n}"\nwhere = "{w}"\n'
                     for n, w in PEOPLE)
    humans = (f'[fleet.humans]\ncount = {len(PEOPLE)}\nkind = "web"\n\n'
              f'[fleet.humans.web]\nhost = "0.0.0.0"\nport = {port}\n'
              f'public_url = "https://{address}:{port}"\n{people}\n')
    path = tiny_protocol(tmp)
    text, n = re.subn(r"^\[fleet\.humans\]\n.*?(?=^\[fleet\.algorithm\])", humans,
                      path.read_text(), flags=re.M | re.S)
    assert n == 1
    for field, value in LEARNING.items():
        text, n = re.subn(rf"^{field} = \d+$", f"{field} = {value}", text, flags=re.M)
        assert n == 1, field
    path.write_text(text)
    return path


def _calibrated_lab(proto_path: Path, out: Path) -> None:
    """The rehearsal's lab folder as a session that calibrated every arm leaves it: the
    same twins (``rehearse``'s seed, the protocol's hosts and arms) started once, each
    arm's exact calibration written (``lab_fixtures.calibrate_exactly``) with its error
    against the twin's true camera (``CALIBRATED``), the twins stopped. ``rehearse``
    then checks and keeps them (``_kept_calibration``) instead of calibrating."""
    proto = load_protocol(proto_path, check_files=False)
    with HardwareTwinLab(proto.fleet, out / "lab", seed=proto.seed(0)) as lab:
        calibrate_exactly(lab)
        figures: dict[str, dict[str, float]] = {}
        for name, host in lab.hosts.items():
            cam = host.lab.camera()
            for arm in host.arms:
                data = json.loads(lab.calibration_path(name, arm).read_text())
                figures[f"{name}/{arm}"] = true_model_error(
                    cam, data["homography"], cam["workspaces_mm"][arm])
        atomic_write_json(lab.root / CALIBRATED, figures)


def _rows(out: Path) -> int:
    return max((p.read_bytes().count(b"\n") for p in out.glob("*-t0/steps.jsonl")),
               default=0)


def _wait_for(what: str, done: Any, proc: subprocess.Popen[bytes], log: Path,
              timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert proc.poll() is None, f"rehearse ended before {what}:\n" + log.read_text()[-4000:]
        assert time.monotonic() < deadline, f"no {what} in {timeout_s} s:\n" + \
            log.read_text()[-4000:]
        time.sleep(0.1)


def _links(text: str) -> dict[str, str]:
    """Each person's link as the operator's terminal printed it."""
    return dict(re.findall(r"web console: (\w+) \(human \d\): (\S+)", text))


def _trust(state: Path, printed: str) -> str:
    """What a colleague does with a self-signed certificate: compare its fingerprint
    with the one the operator read out, then trust that key (and only it): its SPKI
    pin for Chromium."""
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

    (pem,) = state.glob("fleet-testbed/web-tls/console-cert.pem")
    cert = x509.load_pem_x509_certificate(pem.read_bytes())
    digest = hashlib.sha256(cert.public_bytes(Encoding.DER)).hexdigest().upper()
    (shown,) = re.findall(r"certificate SHA-256 ([0-9A-F:]+) \(self-signed", printed)
    assert shown.replace(":", "") == digest, "the fingerprint printed is not the certificate's"
    spki = cert.public_key().public_bytes(Encoding.DER, PublicFormat.SubjectPublicKeyInfo)
    return base64.b64encode(hashlib.sha256(spki).digest()).decode()


def _person(c: Colleague, url: str, spki: str, where: str, tmp: Path
            ) -> tuple[subprocess.Popen[bytes], Path, Path]:
    log, stop = tmp / f"{where}.json", tmp / f"{where}.stop"
    out = open(tmp / f"{where}.out", "wb")  # noqa: SIM115 (closed with the process)
    proc = subprocess.Popen(c.command(sys.executable, str(PERSON), url, spki, where, str(log),
                                      str(stop)), stdout=out, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL)
    return proc, log, stop


def test_the_first_day_colleagues_in_browsers_a_crash_a_resume_and_an_on_site_reset(
        tmp_path: Path) -> None:
    why = netns_missing() or (browser_missing() and "missing " + ", ".join(browser_missing()))
    if why:
        pytest.fail(f"{why} (scripts/setup.sh --dev installs what the test needs)")
    port = _free_port()
    out, state = tmp_path / "rehearsal", tmp_path / "state"
    env = {**os.environ, "XDG_STATE_HOME": str(state), "PYTHONPATH": str(ROOT)}
    with colleagues(len(PEOPLE)) as machines:
        proto = _protocol(tmp_path, port, machines[0].gateway)
        _calibrated_lab(proto, out)
        cmd = [sys.executable, "-m", "testbed.cli", "rehearse", str(proto), "--steps",
               str(STEPS), "--algorithms", "cur", "--humans", "web", "--out", str(out)]
        first_log, second_log = tmp_path / "first.log", tmp_path / "second.log"
        with open(first_log, "wb") as f:
            first = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=f,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        people: list[tuple[subprocess.Popen[bytes], Path, Path]] = []
        try:
            _wait_for("links", lambda: len(_links(first_log.read_text())) == len(PEOPLE),
                      first, first_log, 600)
            printed = first_log.read_text()
            assert "calibration: every arm's from the last session" in printed, printed[-4000:]
            links, spki = _links(printed), _trust(state, printed)
            for c, (name, where) in zip(machines, PEOPLE, strict=True):
                people.append(_person(c, links[name], spki, where, tmp_path))
            _wait_for(f"{KILL_AT} steps", lambda: _rows(out) >= KILL_AT, first, first_log, 900)
            os.kill(first.pid, signal.SIGKILL)  # the operator's PC dies mid-run
            first.wait()
            killed_at = _rows(out)
            with open(second_log, "wb") as f:
                second = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=f,
                                          stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
            assert second.wait(timeout=600) == 0, second_log.read_text()[-4000:]
        finally:
            for proc in (first, *(p for p, _, _ in people)):
                if proc.poll() is None and proc is first:
                    proc.kill()
            for _, _, stop in people:
                stop.touch()
            for proc, _, _ in people:
                try:
                    proc.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    proc.kill()
    said = second_log.read_text()
    seen = {where: json.loads(log.read_text()) for (_, log, _), (_, where) in
            zip(people, PEOPLE, strict=True)}
    (run,) = [r for r in out.glob("*-t0")]

    # the links survived the crash: the second session printed the first's, said so
    assert _links(said) == links, "a resume must keep every person's link"
    assert re.search(r"web console: resumed at step \d+", said)
    meta = json.loads((run / "run.json").read_text())
    assert meta["status"] == "complete" and len(meta["resumed"]) == 1
    rows = read_steps(run / "steps.jsonl")
    assert [r["t"] for r in rows] == list(range(STEPS))  # every step once
    assert killed_at >= KILL_AT

    # each colleague came from their own machine, and their page said the trial resumed
    for (c, (name, where)) in zip(machines, PEOPLE, strict=True):
        s = seen[where]
        assert s["source"] == c.address, s["source"]
        assert s["drops"] >= 1, f"{name}'s page never lost the killed console"
        assert any("resumed at step" in n for n in s["notices"]), (name, s["notices"])
        assert s["pushes"], f"{name} never pushed: {s}"
        assert s["who"] == [f"{name} (human {PEOPLE.index((name, where))})"], s["who"]
        assert s["place"] == [{"on_site": "You are on site (teleop and hard resets).",
                               "remote": "You are remote (teleop only)."}[where]], s["place"]

    # the pages left open were consoles again after the resume, not only notices
    assert any(p[2] >= 1 for s in seen.values() for p in s["pushes"]), \
        "nobody pushed after the resume"

    # hard resets: only the person on site was asked, and did them
    assert seen["remote"]["resets_shown"] == [], "a remote person was given a hard reset"
    assert seen["on_site"]["resets"], "the on-site person never did a hard reset"
    remote = [i for i, (_, w) in enumerate(PEOPLE) if w == "remote"]
    for r in rows:
        for x in r["robots"]:
            assert not (x["mode"] == "reset" and x.get("human") in remote), (r["t"], x)
    assert any(x["mode"] == "reset" and x.get("human") == 0 for r in rows
               for x in r["robots"]), "no reset row of the on-site person"
