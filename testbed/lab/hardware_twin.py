"""The hardware-twin lab: one PyBullet YuMi cell and one real ``sshd`` per YuMi host.

Why it exists: a rehearsal must reach its hosts the way a lab reaches its robots' PCs
(OpenSSH, the host agent, ``--backend yumi``), so each YuMi host of the fleet becomes a
``python -m sim_twin.yumi_server`` process (the controller's Robot Web Services 1.0, as an
IRC5 answers them, and an MJPEG camera) with an OpenSSH ``sshd`` on loopback in front of
it; the agent's controller client is the one a lab's host runs. ``HardwareTwinLab``
starts and stops both, rewrites the fleet's host section to reach them, and is the lab's
hands in fault drills (kill an agent, stop an sshd; ``testbed.lab.fault_drills``).
``LabClient`` is the lab's side channel to one twin (``/lab/*``: the truth, the lab
hand, the true camera model, the faults a person clears): what a person in the lab has
and the controller does not. The controller's decisions never read it.

The lab's processes die with the operator's (``testbed rehearse``), however it ends: a
reaper child (:func:`reap_when_orphaned`) waits for its stdin to close (the operator
exited, or was killed with SIGKILL) and kills what ``pids.json`` lists (the twins, the
sshds and the agents under them), so a killed rehearsal leaves no twin holding a port or
a robot lock; the next ``testbed rehearse`` on the folder also reaps what a killed
reaper left (:func:`reap`), then resumes (``testbed.lab.rehearsal``).

``sim_twin`` runs in its own process and ``drivers.testing.sshd`` is imported inside
the functions that start it, so importing this module starts and imports nothing.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.backend_registry import backend_of, backends
from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import FleetConfig

if TYPE_CHECKING:
    from drivers.testing.sshd import SshServer

__all__ = ["HardwareTwinLab", "LabClient", "LabError", "RehearsalError", "TwinHost",
           "require_yumi"]

PROJECT_ROOT = Path(__file__).resolve().parents[2]
"""This checkout: the twins' working folder and the rewritten hosts' ``workdir``."""
SERVER_START_S = 60.0
PIDS_FILE = "pids.json"
"""The lab's processes (twins, sshds) with their start times: what a reaper kills."""


class LabError(RuntimeError):
    """The hardware twin's lab side channel failed (the twin process is gone?)."""


class RehearsalError(RuntimeError):
    """The rehearsal itself could not go on (a twin or an sshd did not start, an arm
    could not be calibrated); ``str()`` is the one line to print."""


class LabClient:
    """The lab's side channel to one hardware twin: truth, the lab hand, the camera model.

    This is what a person in the lab has that the controller does not: eyes on the real
    table and hands to put a cube back. The controller's decisions never read it.
    """

    def __init__(self, base_url: str, timeout_s: float = 15.0) -> None:
        self.base_url = base_url.rstrip("/")
        self.timeout_s = timeout_s

    def _call(self, path: str, body: Mapping[str, Any] | None = None) -> dict[str, Any]:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(f"{self.base_url}{path}", data=data,
                                     headers={"Content-Type": "application/json"},
                                     method="GET" if body is None else "POST")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
                out: dict[str, Any] = json.loads(resp.read())
                return out
        except urllib.error.HTTPError as exc:
            detail = exc.read().decode("utf-8", "replace")[:300]
            raise LabError(f"hardware twin {self.base_url}{path}: HTTP {exc.code}: "
                           f"{detail}") from None
        except (OSError, ValueError) as exc:
            raise LabError(f"hardware twin {self.base_url}{path}: {exc}") from None

    def truth(self) -> dict[str, dict[str, Any]]:
        arms: dict[str, dict[str, Any]] = self._call("/lab/truth")["arms"]
        return arms

    def reset(self, arm: str) -> None:
        self._call("/lab/reset", {"arm": arm})

    def place(self, arm: str, xy_mm: Sequence[float], yaw: float = 0.0) -> None:
        """A person puts the cube somewhere (fault drills, tests)."""
        self._call("/lab/place", {"arm": arm, "xy_mm": [float(v) for v in xy_mm], "yaw": yaw})

    def camera(self) -> dict[str, Any]:
        return self._call("/lab/camera")

    def tcp(self) -> dict[str, list[float]]:
        """Where each pusher is now, also mid-motion (the twin's latest motion sample)."""
        out: dict[str, list[float]] = self._call("/lab/tcp")["tcp_mm"]
        return out

    def fault(self, kind: str, arm: str | None = None) -> dict[str, Any]:
        """Something goes wrong in the cell (``sim_twin.lab_faults``): a guard stop, the
        motors off, a RAPID error or a zone stop in ``arm``'s task, a frozen camera."""
        return self._call("/lab/fault", {"kind": kind, **({"arm": arm} if arm else {})})

    def clear(self, kind: str) -> dict[str, Any]:
        """A person clears ``kind`` as in the lab; ``actions``: what they did."""
        return self._call("/lab/clear", {"kind": kind})

    def healthy(self) -> bool:
        try:
            return bool(self._call("/lab/health").get("ok"))
        except LabError:
            return False


@dataclass
class TwinHost:
    """One rehearsal host: its hardware twin process and the sshd in front of it."""

    name: str
    arms: tuple[str, ...]
    port: int
    """The twin's camera and lab side channel."""
    rws_port: int
    """The twin's controller: Robot Web Services 1.0, as a lab's IRC5 answers it."""
    proc: subprocess.Popen[bytes]
    sshd: SshServer
    lab: LabClient
    login_file: Path
    """The controller login (``USER:PASSWORD``, mode 0600), the host's ``credentials_file``."""
    rws_log: Path
    """Every RWS request the twin served (JSON lines: method, path, status, ms)."""

    @property
    def camera_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/camera.mjpg"

    @property
    def controller_url(self) -> str:
        return f"http://127.0.0.1:{self.rws_port}"

    @property
    def controller_lab_url(self) -> str:
        """The twin controller's own side channel (``/lab/controller``: operating mode,
        motors, guard stop, RAPID errors), what a person at the robot's cabinet changes."""
        return f"http://127.0.0.1:{self.rws_port}"


def require_yumi(fleet: FleetConfig) -> None:
    """A rehearsal stands hardware twins where YuMi hosts are; twin hosts have none."""
    lacking = [h for h in fleet.hosts if not backend_of(h).capabilities.hardware_twin]
    if lacking:
        have = [n for n, b in backends().items() if b.capabilities.hardware_twin]
        raise ConfigError(f"fleet.hosts[{lacking[0].name}].backend: testbed rehearse needs "
                          "a physical protocol whose hosts have a hardware twin (backend = "
                          f"{' or '.join(repr(n) for n in have)}; host {lacking[0].name}'s "
                          f"{lacking[0].backend!r} has none); run a twin protocol with "
                          "testbed protocol")


class HardwareTwinLab:
    """Starts, rewrites for, and stops the hardware twin hosts of one rehearsal."""

    def __init__(self, fleet: FleetConfig, root: Path, *, seed: int = 0,
                 realtime: float = 0.0, host_python: str | None = None,
                 camera_fps: float = 15.0) -> None:
        require_yumi(fleet)
        self.fleet = fleet
        self.root = root.resolve()  # sshd's config needs absolute paths
        self.seed = seed
        self.realtime = realtime
        self.camera_fps = camera_fps
        self.host_python = host_python
        """A robot host install's interpreter (``scripts/setup.sh --host``) the agents run
        from, as on a lab's host: no checkout on their path. None: this checkout's."""
        self.hosts: dict[str, TwinHost] = {}
        self._reaper: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        from drivers.testing.sshd import sshd_available

        if not sshd_available():
            raise ConfigError("testbed rehearse needs OpenSSH's sshd and ssh-keygen "
                              "(Debian: apt-get install openssh-server)")
        self.root.mkdir(parents=True, exist_ok=True)
        reap(self.root)  # a killed session's twins and sshds, if its reaper died too
        self._reaper = _start_reaper(self.root)
        starting: list[tuple[str, tuple[str, ...], subprocess.Popen[bytes]]] = []
        try:
            for i, h in enumerate(self.fleet.hosts):
                arms = tuple(a.name for a in h.arms)
                for suffix in ("port", "rws.port"):
                    (self.root / f"{h.name}.{suffix}").unlink(missing_ok=True)
                write_login(self._login_file(h.name))
                proc = self._start_twin(h.name, arms, self.seed * 1000 + i)
                starting.append((h.name, arms, proc))
            self.record_pids(extra=[p for _, _, p in starting])
            for name, arms, proc in starting:
                log = self.root / f"{name}-twin.log"
                port = _wait_port(proc, self.root / f"{name}.port", log)
                rws_port = _wait_port(proc, self.root / f"{name}.rws.port", log)
                sshd = self._start_sshd(name)
                self.hosts[name] = TwinHost(name, arms, port, rws_port, proc, sshd,
                                            LabClient(f"http://127.0.0.1:{port}"),
                                            self._login_file(name), self._rws_log(name))
                self.record_pids(extra=[p for _, _, p in starting])
        except BaseException:
            for _, _, proc in starting:
                _terminate(proc)
            self.stop()
            raise

    def _serial(self, host: str) -> str:
        """The twin controller's serial: robot locks are keyed on it, so each twin of a
        lab (and of another lab on this machine) has its own, stable for its folder."""
        import zlib

        return f"14000-{zlib.crc32(f'{self.root}/{host}'.encode()) % 1_000_000:06d}"

    def _login_file(self, host: str) -> Path:
        return self.root / f"{host}-rws.login"

    def _rws_log(self, host: str) -> Path:
        return self.root / f"{host}-rws.jsonl"

    def _start_twin(self, host: str, arms: tuple[str, ...], seed: int
                    ) -> subprocess.Popen[bytes]:
        """``python -m sim_twin.yumi_server`` for ``host``, its output to its log: the
        camera and the lab side channel on one port, the controller's RWS on another,
        logging in with the host's login file and logging every request it serves."""
        log = open(self.root / f"{host}-twin.log", "ab")  # noqa: SIM115 (child owns it)
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim_twin.yumi_server", "--arms", ",".join(arms),
             "--seed", str(seed), "--port", "0",
             "--port-file", str(self.root / f"{host}.port"),
             "--rws-port-file", str(self.root / f"{host}.rws.port"),
             "--rws-credentials", str(self._login_file(host)),
             "--rws-log", str(self._rws_log(host)), "--realtime", f"{self.realtime:g}",
             "--fps", f"{self.camera_fps:g}",
             "--serial", self._serial(host)],
            cwd=PROJECT_ROOT, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
            start_new_session=True)
        log.close()
        return proc

    def _start_sshd(self, host: str) -> SshServer:
        from drivers.testing.sshd import SshServer

        sshd = SshServer(self.root / f"sshd-{host}")
        try:
            sshd.start()
        except RuntimeError as exc:
            raise RehearsalError(f"host {host}: the rehearsal's sshd did not start: "
                                 f"{' '.join(str(exc).split())[:300]}") from None
        return sshd

    def record_pids(self, extra: Sequence[subprocess.Popen[bytes]] = ()) -> None:
        """``pids.json``: every twin and sshd of the lab now (call it after an sshd was
        started again), what the reaper kills should this process die."""
        from testbed.core.atomic import atomic_write_json

        procs = [*extra, *(h.proc for h in self.hosts.values()),
                 *(h.sshd.proc for h in self.hosts.values() if h.sshd.proc is not None)]
        entries = {p.pid: _proc_start(p.pid) for p in procs}
        atomic_write_json(self.root / PIDS_FILE,
                          [{"pid": pid, "start": st} for pid, st in entries.items() if st])

    def stop(self) -> None:
        for h in self.hosts.values():
            with contextlib.suppress(Exception):
                h.sshd.stop()
            _terminate(h.proc)
        self.hosts = {}
        if self._reaper is not None:  # stdin closed: it reaps what is left, and exits
            with contextlib.suppress(OSError):
                if self._reaper.stdin is not None:
                    self._reaper.stdin.close()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._reaper.wait(10.0)
            self._reaper = None

    def __enter__(self) -> HardwareTwinLab:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def labs(self) -> dict[str, LabClient]:
        return {n: h.lab for n, h in self.hosts.items()}

    def calibration_path(self, host: str, arm: str) -> Path:
        return self.root / "calib" / f"{host}-{arm}.json"

    def rewrite(self, fleet: FleetConfig | None = None) -> FleetConfig:
        """The fleet with each host pointed at its twin: address, port, user and keys of
        its sshd; this checkout's interpreter and folder (or, with ``host_python``, a host
        install's interpreter and no folder); the twin's camera and controller and its
        login file; the rehearsal's calibration files. Nothing else changes."""
        fleet = fleet or self.fleet
        hosts = []
        for h in fleet.hosts:
            t = self.hosts[h.name]
            arms = [a.model_copy(update={"calibration": str(self.calibration_path(h.name,
                                                                                   a.name))})
                    for a in h.arms]
            hosts.append(h.model_copy(update={
                "transport": "ssh", "address": "127.0.0.1", "port": t.sshd.port,
                "ssh_alias": None, "ssh_config": None,
                "user": t.sshd.user, "key_file": str(t.sshd.client_key),
                "known_hosts": str(t.sshd.known_hosts),
                "python": self.host_python or sys.executable,
                "workdir": None if self.host_python else str(PROJECT_ROOT),
                "camera": t.camera_url,
                "controller_url": t.controller_url, "credentials_file": str(t.login_file),
                "arms": arms}))
        return fleet.model_copy(update={"hosts": hosts})

    def reset_all(self, *_: Any) -> None:
        """What the protocol's prompt asks of a person: every cube back near its centre."""
        for h in self.hosts.values():
            for arm in h.arms:
                h.lab.reset(arm)

    def kill_agent(self, host: str) -> int:
        """Fault drill: SIGKILL the agent on ``host`` (the process under its sshd)."""
        from drivers.testing.sshd import _children

        t = self.hosts[host]
        killed = 0
        for pid in _children(t.sshd.proc.pid) if t.sshd.proc is not None else []:
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue
            if b"drivers.agent" in cmdline:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
                    killed += 1
        return killed


def _proc_start(pid: int) -> str | None:
    """A process's start time (``/proc/PID/stat`` field 22): with the pid, who it is (a
    pid reused by another process has another start time)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2:].split()[19]


def reap(root: Path) -> int:
    """Kill the lab processes ``root/pids.json`` lists that still run as themselves
    (same pid, same start time), and everything under them (an sshd's sessions and the
    agents they run); returns how many were killed."""
    from drivers.testing.sshd import _children

    path = root / PIDS_FILE
    try:
        entries = json.loads(path.read_text())
    except (OSError, ValueError):
        return 0
    pids: list[int] = []
    for e in entries:
        pid = int(e["pid"])
        if _proc_start(pid) == e["start"]:
            pids += [pid, *_children(pid)]
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)
    path.unlink(missing_ok=True)
    return len(pids)


def reap_when_orphaned(root: str) -> None:
    """The reaper's body: wait until stdin closes (the operator's process is gone, by
    exit or by SIGKILL), then :func:`reap` the lab."""
    with contextlib.suppress(OSError, KeyboardInterrupt):
        while sys.stdin.buffer.read(4096):
            pass
    reap(Path(root))


def _start_reaper(root: Path) -> subprocess.Popen[bytes]:
    """The lab's reaper: a child whose stdin is a pipe only this process holds, in its
    own session (a Ctrl-C at the console must not take it before the lab is stopped)."""
    code = ("import sys; from testbed.lab.hardware_twin import reap_when_orphaned; "
            "reap_when_orphaned(sys.argv[1])")
    return subprocess.Popen([sys.executable, "-c", code, str(root)], cwd=PROJECT_ROOT,
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def write_login(path: Path) -> None:
    """A fresh controller login for one twin (``testbed`` and a random password), mode
    0600 from its first byte: what a lab puts on its robot host for the real controller."""
    import secrets

    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f"testbed:{secrets.token_urlsafe(18)}\n")


def _wait_port(proc: subprocess.Popen[bytes], port_file: Path, log: Path) -> int:
    deadline = time.monotonic() + SERVER_START_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            tail = log.read_text(errors="replace")[-1500:] if log.exists() else ""
            raise RehearsalError(f"the hardware twin exited with status {proc.returncode}: "
                                 f"{' '.join(tail.split())[-300:]}")
        with contextlib.suppress(OSError, ValueError):
            text = port_file.read_text().strip()
            if text:
                return int(text)
        time.sleep(0.05)
    _terminate(proc)
    raise RehearsalError(f"the hardware twin did not start within {SERVER_START_S:g} s "
                         f"(see {log})")


def _terminate(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(5.0)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5.0)
