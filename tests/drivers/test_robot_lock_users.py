"""One lock per robot per host, for EVERY user of the host, keyed on the robot as its
controller names itself.

A lab's robot host has several users (two operators, a colleague's script). The lock
folder is shared by all of them (``/run/lock/fleet-testbed`` by default, sticky and
world-writable, each lock file 0666), so an agent started under another Unix user for a
held robot is refused naming its holder (user, pid, host, controller, since when); and a
YuMi's lock is keyed on its serial (``ctrl/identity``, one read-only RWS request before
the lock), so two spellings of one controller's address are one robot.

The other user is Debian's ``nobody``, running the agent's own lock code
(``drivers.hostlock.RobotLock``, standard library only) under the system's
``/usr/bin/python3``: this project's interpreter lives under /root, which ``nobody``
cannot enter; everything else is real (two Unix users, one kernel flock).
"""

from __future__ import annotations

import json
import os
import pwd
import shutil
import stat
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from test_agent_safety import LiveAgent, agents  # noqa: F401 (the fixture)

from drivers.hostlock import default_lock_dir, lock_path

ROOT = Path(__file__).resolve().parents[2]
ME = pwd.getpwuid(os.geteuid()).pw_name
SYSTEM_PYTHON = "/usr/bin/python3"
HOLD = """
import sys, time
sys.path.insert(0, {root!r})
from drivers.hostlock import RobotLock, RobotBusy
lock = RobotLock({identity!r}, {locks!r}, "other-host", controller="http://192.0.2.7")
try:
    lock.acquire()
except RobotBusy as exc:
    print("BUSY", exc, flush=True)
    sys.exit(3)
print("HELD", flush=True)
time.sleep({hold_s})
"""


def as_nobody(identity: str, locks: Path, hold_s: float = 0.0) -> subprocess.Popen[str]:
    code = HOLD.format(root=str(ROOT), identity=identity, locks=str(locks), hold_s=hold_s)
    return subprocess.Popen(["runuser", "-u", "nobody", "--", SYSTEM_PYTHON, "-c", code],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


needs_root = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("runuser") is None or not Path(SYSTEM_PYTHON).exists(),
    reason="starts a process as another Unix user (runuser, as root) with the system python")


@pytest.fixture
def shared() -> Iterator[Path]:
    """A folder every user may enter, holding the lock folder the agents create."""
    top = Path(tempfile.mkdtemp(prefix="fleet-locks-"))
    top.chmod(0o755)
    yield top / "locks"
    shutil.rmtree(top, ignore_errors=True)


@needs_root
def test_another_users_agent_is_refused_naming_the_holder(
        shared: Path, agents: Callable[..., LiveAgent]) -> None:  # noqa: F811
    first = agents("--backend", "twin", "--no-physics", "--host", "yumi-a", "--lock-id",
                   "robot-7", "--lock-dir", str(shared))
    assert first.hello().type == "hello_ok"
    assert stat.S_IMODE(shared.stat().st_mode) == 0o1777  # made for every user
    assert stat.S_IMODE(lock_path(shared, "robot-7").stat().st_mode) == 0o666
    other = as_nobody("robot-7", shared)
    out, _ = other.communicate(timeout=30)
    assert other.returncode == 3, out
    assert out.startswith(f"BUSY robot robot-7 is held by agent pid {first.proc.pid} of user "
                          f"{ME} on host yumi-a since "), out
    first.call("bye", 2)
    first.proc.wait(10)
    # The other way round: nobody's holds it, ours is refused at hello, naming nobody.
    holder = as_nobody("robot-7", shared, hold_s=30)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "HELD"
        second = agents("--backend", "twin", "--no-physics", "--lock-id", "robot-7",
                        "--lock-dir", str(shared))
        f = second.hello()
        assert f.type == "error" and f.header["kind"] == "startup"
        msg = f.header["message"]
        assert "is held by agent pid " in msg and "of user nobody on host other-host" in msg
        assert "controller http://192.0.2.7" in msg
    finally:
        holder.kill()
        holder.wait(5)


def test_the_default_lock_folder_is_one_for_every_user() -> None:
    d = default_lock_dir()
    assert not d.startswith(os.environ.get("XDG_RUNTIME_DIR") or "/nonexistent")
    assert d.endswith("fleet-testbed") and d.startswith(("/run/lock", "/var/lock", "/tmp"))


def test_a_yumi_lock_is_keyed_on_the_controllers_serial(
        tmp_path: Path, agents: Callable[..., LiveAgent]) -> None:  # noqa: F811
    from sim_twin.rws import Irc5Controller, serve
    from sim_twin.rws.irc5 import Identity

    server = serve(Irc5Controller(identity=Identity(ctrl_id="14000-512345")))
    port = server.url.rsplit(":", 1)[1]
    locks = str(tmp_path / "locks")
    try:
        # No camera: the backend cannot start, but the agent holds the lock until it exits.
        first = agents("--backend", "yumi", "--host", "yumi-a", "--lock-dir", locks,
                       "--controller-url", f"http://127.0.0.1:{port}",
                       "--credentials-file", "factory-default")
        path = lock_path(locks, "IRC5 14000-512345")
        t0 = time.monotonic()
        while not (path.exists() and str(first.proc.pid) in path.read_text()):
            assert time.monotonic() - t0 < 20, "the first agent never took the lock"
            time.sleep(0.05)
        holder = json.loads(path.read_text())
        assert holder["user"] == ME and holder["controller"] == f"http://127.0.0.1:{port}"
        second = agents("--backend", "yumi", "--host", "yumi-b", "--lock-dir", locks,
                        "--controller-url", f"http://localhost:{port}/", "--camera", "0",
                        "--credentials-file", "factory-default")
        f = second.hello()
        assert f.type == "error" and f.header["kind"] == "startup"
        assert (f"robot IRC5 14000-512345 is held by agent pid {first.proc.pid} of user {ME} "
                f"on host yumi-a") in f.header["message"]
    finally:
        server.stop()
