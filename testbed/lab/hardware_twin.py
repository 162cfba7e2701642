"""The hardware-twin lab: one stand-in per host and one real ``sshd`` in front of each.

Why it exists: a rehearsal must reach its hosts the way a lab reaches its robots' PCs
(OpenSSH, the host agent, the host's backend), so each host of the fleet gets the
hardware twin its backend's plugin declares (``Backend.hardware_twin``, a
``testbed.core.backend_registry.HardwareTwin``): for a YuMi, a ``python -m
sim_twin.yumi_server`` process (the controller's Robot Web Services 1.0, as an IRC5
answers them, and an MJPEG camera); for a lab's own robot, whatever its plugin starts
(or nothing, when its agent plays the robot itself). An OpenSSH ``sshd`` on loopback
stands in front of each host, and the agent under it runs the host's backend as on the
robot's PC. ``HardwareTwinLab`` starts and stops both, rewrites the fleet's host
section to reach them (the lab's part: transport, interpreter, folder, calibration
files; the plugin's part: the fields that point its agent at its stand-in), and is the
lab's hands in fault drills (kill an agent, stop an sshd; ``testbed.lab.fault_drills``).
``LabClient`` is the lab's side channel to one twin that has one (``/lab/*``: the
truth, the lab hand, the true camera model, the faults a person clears): what a person
in the lab has and the controller does not. The controller's decisions never read it.

The lab's processes die with the operator's (``testbed rehearse``), however it ends: a
reaper child (:func:`reap_when_orphaned`) waits for its stdin to close (the operator
exited, or was killed with SIGKILL) and kills what ``pids.json`` lists (the twins, the
sshds and the agents under them), so a killed rehearsal leaves no twin holding a port or
a robot lock; the next ``testbed rehearse`` on the folder also reaps what a killed
reaper left (:func:`reap`), then resumes (``testbed.lab.rehearsal``).

The stand-ins run in processes of their own and ``drivers.testing.sshd`` is imported
inside the functions that start it, so importing this module starts and imports nothing
(the plugins are asked through the registry, ``testbed.core``).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.backend_registry import HardwareTwin, TwinPlace, backend_of, backends
from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import FleetConfig
from testbed.lab.lab_client import LabClient, LabError

if TYPE_CHECKING:
    from drivers.testing.sshd import SshServer

__all__ = ["HardwareTwinLab", "LabClient", "LabError", "RehearsalError", "TwinHost",
           "hardware_twins", "require_faults"]

PROJECT_ROOT = Path(__file__).resolve().parents[2]
"""This checkout: the twins' working folder and the rewritten hosts' ``workdir``."""
SERVER_START_S = 60.0
PIDS_FILE = "pids.json"
"""The lab's processes (twins, sshds) with their start times: what a reaper kills."""
TWIN_LOG = "twin.log"
"""Each stand-in's output (``TwinPlace.file``): what a twin that died said."""


class RehearsalError(RuntimeError):
    """The rehearsal itself could not go on (a twin or an sshd did not start, an arm
    could not be calibrated); ``str()`` is the one line to print."""


@dataclass
class TwinHost:
    """One rehearsal host: its stand-in (a process, or none), the sshd in front of it, and
    what its backend's plugin declared of it."""

    name: str
    arms: tuple[str, ...]
    twin: HardwareTwin
    place: TwinPlace
    ports: dict[str, int]
    """Each of ``twin.ports``, as the stand-in wrote it."""
    proc: subprocess.Popen[bytes] | None
    """The stand-in process; None: the agent's own backend plays the robot."""
    sshd: SshServer
    side: LabClient | None
    """The lab's side channel (``twin.lab_port``), if the twin has one."""

    @property
    def lab(self) -> LabClient:
        """The side channel; LabError for a twin that declares none (its plugin's
        ``HardwareTwin.lab_port``)."""
        if self.side is None:
            raise LabError(f"host {self.name}'s hardware twin has no lab side channel (its "
                           "plugin's HardwareTwin.lab_port)")
        return self.side

    @property
    def port(self) -> int | None:
        """The side channel's port, else the stand-in's first; None: no stand-in."""
        lab = self.twin.lab_port
        return self.ports[lab] if lab else next(iter(self.ports.values()), None)

    @property
    def login_file(self) -> Path:
        """The controller login the stand-in was prepared with (``USER:PASSWORD``, mode
        0600), the host's ``credentials_file`` (a twin with a controller)."""
        return self.place.file("rws.login")

    @property
    def rws_log(self) -> Path | None:
        """Every controller request the twin served (JSON lines: method, path, status,
        ms), if it logs them (``twin.request_log``)."""
        log = self.twin.request_log
        return self.place.file(log) if log else None

    def url(self, port: str) -> str:
        """``http://127.0.0.1:N`` of the stand-in's port called ``port``."""
        return f"http://127.0.0.1:{self.ports[port]}"

    @property
    def controller_url(self) -> str:
        """A YuMi twin's controller (RWS 1.0, its ``rws.port``), as the agent reaches it."""
        return self.url("rws.port")

    @property
    def controller_lab_url(self) -> str:
        """A YuMi twin controller's own side channel (``/lab/controller``: operating mode,
        motors, guard stop, RAPID errors), what a person at the robot's cabinet changes."""
        return self.url("rws.port")


def hardware_twins(fleet: FleetConfig) -> dict[str, HardwareTwin]:
    """Each host's hardware twin, as its backend's plugin declares it; ConfigError (one
    line naming the field) for the first host whose backend declares none."""
    found: dict[str, HardwareTwin] = {}
    for h in fleet.hosts:
        twin = backend_of(h).hardware_twin()
        if twin is None:
            have = [n for n, b in backends().items() if b.hardware_twin() is not None]
            raise ConfigError(
                f"fleet.hosts[{h.name}].backend: testbed rehearse needs a physical protocol "
                "whose hosts have a hardware twin (backend = "
                f"{' or '.join(repr(n) for n in have)}; host {h.name}'s {h.backend!r} "
                "declares none: its plugin's hardware_twin()); run a twin protocol with "
                "testbed protocol")
        found[h.name] = twin
    return found


def require_faults(fleet: FleetConfig) -> None:
    """``--faults`` needs every host's twin to inject and clear the lab's faults."""
    for name, twin in hardware_twins(fleet).items():
        if not (twin.faults and twin.lab_port):
            raise ConfigError(f"--faults: host {name}'s hardware twin cannot inject the "
                              "lab's faults (its plugin's HardwareTwin.faults); rehearse "
                              "without --faults")


class HardwareTwinLab:
    """Starts, rewrites for, and stops the hardware twin hosts of one rehearsal."""

    def __init__(self, fleet: FleetConfig, root: Path, *, seed: int = 0,
                 realtime: float = 0.0, host_python: str | None = None,
                 camera_fps: float = 15.0) -> None:
        self.twins = hardware_twins(fleet)
        """Each host's hardware twin, from its backend's plugin."""
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
        starting: list[tuple[TwinPlace, subprocess.Popen[bytes] | None]] = []
        procs: list[subprocess.Popen[bytes]] = []
        try:
            for i, h in enumerate(self.fleet.hosts):
                place = self.place(h.name, self.seed * 1000 + i)
                proc = self._start_twin(place)
                starting.append((place, proc))
                procs += [proc] if proc is not None else []
            self.record_pids(extra=procs)
            for place, proc in starting:
                twin = self.twins[place.host]
                ports = {p: _wait_port(proc, place.port_file(p), place.file(TWIN_LOG))
                         for p in twin.ports} if proc is not None else {}
                sshd = self._start_sshd(place.host)
                side = (LabClient(f"http://127.0.0.1:{ports[twin.lab_port]}")
                        if twin.lab_port else None)
                self.hosts[place.host] = TwinHost(place.host, place.arms, twin, place, ports,
                                                  proc, sshd, side)
                self.record_pids(extra=procs)
        except BaseException:
            for proc in procs:
                _terminate(proc)
            self.stop()
            raise

    def place(self, host: str, seed: int = 0) -> TwinPlace:
        """Where ``host``'s twin stands: its arms, this lab's folder, seed and pace."""
        h = next(x for x in self.fleet.hosts if x.name == host)
        return TwinPlace(host, tuple(a.name for a in h.arms), self.root, seed,
                         self.realtime, self.camera_fps)

    def _serial(self, host: str) -> str | None:
        """The stand-in controller's identity (a YuMi twin's serial: robot locks are keyed
        on it), as its plugin derives it from where it stands."""
        return self.twins[host].identity(self.place(host))

    def _start_twin(self, place: TwinPlace) -> subprocess.Popen[bytes] | None:
        """The stand-in of ``place.host`` as its plugin says (``HardwareTwin.command``),
        from this checkout's folder, its output to its log, in a session of its own;
        its port files removed first (a ready twin writes them). None: no process."""
        twin = self.twins[place.host]
        for p in twin.ports:
            place.port_file(p).unlink(missing_ok=True)
        twin.prepare(place)
        argv = twin.command(place)
        if argv is None:
            return None
        log = open(place.file(TWIN_LOG), "ab")  # noqa: SIM115 (child owns it)
        try:
            proc = subprocess.Popen(argv, cwd=PROJECT_ROOT, stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=log, start_new_session=True)
        except OSError as exc:
            raise RehearsalError(f"host {place.host}: its hardware twin did not start "
                                 f"({' '.join(argv[:3])} ...): {exc}") from None
        finally:
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

        procs = [*extra, *(h.proc for h in self.hosts.values() if h.proc is not None),
                 *(h.sshd.proc for h in self.hosts.values() if h.sshd.proc is not None)]
        entries = {p.pid: _proc_start(p.pid) for p in procs}
        atomic_write_json(self.root / PIDS_FILE,
                          [{"pid": pid, "start": st} for pid, st in entries.items() if st])

    def stop(self) -> None:
        for h in self.hosts.values():
            with contextlib.suppress(Exception):
                h.sshd.stop()
            if h.proc is not None:
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
        """The side channel of every host whose twin has one (the others' agents play
        their robot themselves: no truth to read, no cube for the lab hand)."""
        return {n: h.side for n, h in self.hosts.items() if h.side is not None}

    def calibrated(self, host: str) -> bool:
        """Whether the rehearsal calibrates ``host``'s arms (``HardwareTwin.calibrate``)."""
        return self.twins[host].calibrate

    def calibration_path(self, host: str, arm: str) -> Path:
        return self.root / "calib" / f"{host}-{arm}.json"

    def rewrite(self, fleet: FleetConfig | None = None) -> FleetConfig:
        """The fleet with each host pointed at its twin: address, port, user and keys of
        its sshd; this checkout's interpreter and folder (or, with ``host_python``, a host
        install's interpreter and no folder); the rehearsal's calibration files (a twin
        that is calibrated); and the fields its plugin says reach its stand-in
        (``HardwareTwin.host_fields``: a YuMi's camera, controller and login file).
        Nothing else changes."""
        fleet = fleet or self.fleet
        hosts = []
        for h in fleet.hosts:
            t = self.hosts[h.name]
            arms = [a.model_copy(update={"calibration": str(self.calibration_path(h.name,
                                                                                   a.name))})
                    for a in h.arms] if t.twin.calibrate else list(h.arms)
            hosts.append(h.model_copy(update={
                "transport": "ssh", "address": "127.0.0.1", "port": t.sshd.port,
                "ssh_alias": None, "ssh_config": None,
                "user": t.sshd.user, "key_file": str(t.sshd.client_key),
                "known_hosts": str(t.sshd.known_hosts),
                "python": self.host_python or sys.executable,
                "workdir": None if self.host_python else str(PROJECT_ROOT),
                **t.twin.host_fields(h, t.place, t.ports),
                "arms": arms}))
        return fleet.model_copy(update={"hosts": hosts})

    def reset_all(self, *_: Any) -> None:
        """What the protocol's prompt asks of a person: every cube back near its centre
        (on the twins with a side channel; the others reset themselves)."""
        for h in self.hosts.values():
            if h.side is not None:
                for arm in h.arms:
                    h.side.reset(arm)

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
