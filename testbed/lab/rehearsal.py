"""``testbed rehearse``: a lab's whole day on the hardware twin, before touching a robot.

Why: the physical path (SSH, the host agent, the YuMi backend, its camera and its
controller, calibration, the physical protocol's prompts and records) is what a lab runs
on day one, and none of it runs in twin mode. A rehearsal runs the physical protocol
UNCHANGED but for where its hosts are: each YuMi host becomes a hardware twin
(``python -m sim_twin.yumi_server``: a PyBullet bimanual cell behind an HTTP controller
API and an MJPEG camera) reached through a real OpenSSH ``sshd`` on loopback, and the
agent on it runs ``--backend yumi`` as on the robot's PC::

    testbed rehearse  --SSH-->  sshd  -->  python -m drivers.agent --backend yumi
                                             camera:     http://127.0.0.1:P/camera.mjpg
                                             controller: twin+http://127.0.0.1:P
    lab side (never read by the controller's decisions):
      TwinLabHumans: scripted teleop from the twin's truth, the lab hand on a confirmed reset
      TruthRecorder: runs/<run>/twin_truth.jsonl (scoring only)

The protocol's host section is rewritten in addresses, ports, users and key paths (the
twin's sshd), in the host install (python, workdir: this checkout), in the devices
(camera and controller URLs of the twin) and in the calibration files (written by
``testbed calibrate`` against the twin at the start of the rehearsal). Crops, mirrors,
the algorithm, learning, humans and the protocol's order and prompts stay as the lab
wrote them. ``--quick`` swaps the learning sizes for the default twin trial's.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.config import ConfigError, FleetConfig
from testbed.core.hosts import Hosts
from testbed.core.humans import Humans
from testbed.experiments.hooks import TrialHooks
from testbed.records.run_dir import RunDir

if TYPE_CHECKING:
    from testbed.fleet.loop import StepOutcome
from testbed.core.types import (
    SUCCESS_RADIUS,
    ArmObservation,
    FleetStatus,
    HumanRequest,
    HumanResponse,
    InterventionKind,
    PushResult,
)

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SERVER_START_S = 60.0


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

    def healthy(self) -> bool:
        try:
            return bool(self._call("/lab/health").get("ok"))
        except LabError:
            return False


@dataclass(frozen=True, slots=True)
class ArmView:
    """How the controller's config maps one arm's camera pixels into its canonical frame."""

    host: str
    arm: str
    crop: tuple[int, int, int, int]
    mirror: bool

    def canonical(self, px: Sequence[float]) -> tuple[float, float]:
        x0, y0, x1, y1 = self.crop  # pixel centres at integers (OpenCV): edges at -0.5
        cx = (float(px[0]) + 0.5 - x0) / (x1 - x0)
        cy = (float(px[1]) + 0.5 - y0) / (y1 - y0)
        return (1.0 - cx if self.mirror else cx, cy)

    def canonical_yaw(self, yaw_px: float) -> float:
        return -yaw_px if self.mirror else yaw_px


def arm_views(cfg: FleetConfig) -> dict[str, ArmView]:
    """Every robot's crop and mirror, from the (rewritten) fleet config."""
    out: dict[str, ArmView] = {}
    for h in cfg.hosts:
        for a in h.arms:
            if a.crop is None:
                raise ConfigError(f"hosts[{h.name}].arms[{a.name}].crop: a YuMi arm needs "
                                  "its crop box")
            out[f"{h.name}/{a.name}"] = ArmView(h.name, a.name, a.crop, a.mirror)
    return out


def _polygon() -> Any:
    import numpy as np

    from testbed.perception.cube import WORKSPACE_POLYGON

    return np.asarray(WORKSPACE_POLYGON, dtype=float)


def _inside_workspace(xy: Sequence[float]) -> bool:
    import numpy as np

    poly = _polygon()
    e = np.roll(poly, -1, axis=0) - poly
    rel = np.asarray(xy, dtype=float)[None, :] - poly
    cross = e[:, 0] * rel[:, 1] - e[:, 1] * rel[:, 0]
    return bool(np.all(cross >= 0) or np.all(cross <= 0))


def edge_distance(xy: Sequence[float]) -> float:
    """Distance (canonical units) from a point to the workspace polygon's boundary."""
    import numpy as np

    poly = _polygon()
    a, b = poly, np.roll(poly, -1, axis=0)
    p = np.asarray(xy, dtype=float)[None, :]
    ab = b - a
    u = np.clip(np.sum((p - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + u[:, None] * ab - p, axis=1)))


BORDERLINE = 1.0 / 64.0
"""A cube this close (one canonical pixel, ~5 mm) to the workspace edge or to the success
circle is a call perception may make either way: its centre error is ~0.2/64."""


class TwinLabHumans:
    """The humans of a rehearsal: whoever helps (scripted or a person at the console),
    plus the lab around them.

    * Teleop: a scripted human looks at the table (the twin's truth, through the lab side
      channel) and pushes the expert's face, as a person looks at the real cube; a person
      at the console chooses for themselves.
    * Hard reset: when the human confirms it (scripted: at the end of the t_R-th step;
      console: the confirm button), the lab hand puts the cube back near the centre of
      its workspace before the controller looks at the picture. The YuMi backend then
      believes the picture, as in the lab.
    """

    def __init__(self, inner: Any, labs: Mapping[str, LabClient], views: Mapping[str, ArmView],
                 *, expert: bool) -> None:
        self.inner = inner
        self.labs = dict(labs)
        self.views = dict(views)
        self.expert = expert
        self.lab_resets = 0

    def _expert_face(self, req: HumanRequest, truths: dict[str, dict[str, dict[str, Any]]]
                     ) -> int:
        from sim_twin.supervisor import expert_face

        view = self.views[req.robot]
        if view.host not in truths:
            truths[view.host] = self.labs[view.host].truth()
        t = truths[view.host][view.arm]
        cube = view.canonical(t["cube_px"])
        return int(expert_face(cube, view.canonical_yaw(float(t["yaw_px"])),
                               req.observation.goal))

    def act(self, requests: Sequence[HumanRequest], t: int) -> dict[str, HumanResponse]:
        truths: dict[str, dict[str, dict[str, Any]]] = {}
        asked: list[HumanRequest] = []
        for req in requests:
            if self.expert and req.kind is InterventionKind.TELEOP:
                face = self._expert_face(req, truths)
                req = replace(req, observation=replace(req.observation, expert_action=face))
            asked.append(req)
        answers: dict[str, HumanResponse] = self.inner.act(asked, t)
        for robot, answer in answers.items():
            if answer.reset_done:
                view = self.views[robot]
                self.labs[view.host].reset(view.arm)
                self.lab_resets += 1
        return answers

    def show(self, t: int, status: FleetStatus) -> None:
        self.inner.show(t, status)

    def close(self) -> None:
        self.inner.close()

    def __getattr__(self, name: str) -> Any:  # anything else the console offers
        return getattr(self.inner, name)


@dataclass
class TruthRecorder:
    """Writes ``twin_truth.jsonl`` (DESIGN.md section 9): the twin's ground truth per step
    and arm, for scoring perception only. It sits beside the controller's ``HostFleet``
    (every call passes through unchanged) to learn each step's goals and pushes, and asks
    the twin where the cubes really are; nothing it learns flows back into the trial.
    """

    hosts: Any
    labs: Mapping[str, LabClient]
    views: Mapping[str, ArmView]
    path: Path
    _goals: dict[str, tuple[float, float]] = field(default_factory=dict)
    _inside: dict[str, bool] = field(default_factory=dict)
    _pending: list[dict[str, Any]] = field(default_factory=list)

    def _truth(self) -> dict[str, tuple[tuple[float, float], bool]]:
        out: dict[str, tuple[tuple[float, float], bool]] = {}
        for host, lab in self.labs.items():
            try:
                arms = lab.truth()
            except LabError:
                continue  # the twin of a host being killed in a fault drill
            for arm, t in arms.items():
                robot = f"{host}/{arm}"
                if robot in self.views:
                    xy = self.views[robot].canonical(t["cube_px"])
                    out[robot] = (xy, bool(t["on_table"]) and _inside_workspace(xy))
        return out

    def observe(self) -> Any:
        obs = self.hosts.observe()
        self._goals = {r: o.goal for r, o in obs.items() if isinstance(o, ArmObservation)}
        self._inside = {r: inside for r, (_, inside) in self._truth().items()}
        self._pending = []
        return obs

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> Any:
        results = self.hosts.execute(pushes, resets)
        after = self._truth()
        rows = []
        for robot in self.views:
            if robot not in after:
                continue
            xy, inside = after[robot]
            res = results.get(robot)
            pushed = (robot in pushes and isinstance(res, PushResult) and not res.refused)
            goal = self._goals.get(robot)
            success = bool(pushed and inside and goal is not None
                           and math.dist(xy, goal) <= SUCCESS_RADIUS)
            violation = bool(pushed and self._inside.get(robot, True) and not inside)
            rows.append({"robot": robot, "success": success, "violation": violation,
                         "cube_xy": [round(xy[0], 5), round(xy[1], 5)], "pushed": pushed,
                         "goal": None if goal is None else [round(g, 5) for g in goal]})
        self._pending = rows
        return results

    def on_step(self, t: int) -> None:
        """The loop finished step ``t``: its truth rows go to disk (pretraining's pushes,
        which pass through here too, are never written)."""
        if not self._pending:
            return
        with open(self.path, "a", encoding="utf-8") as f:
            for row in self._pending:
                f.write(json.dumps({"t": t, **row}, separators=(",", ":")) + "\n")
        self._pending = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.hosts, name)


def _borderline(row: Mapping[str, Any], prev: Mapping[str, Any] | None) -> bool:
    """Whether a disagreement is a call within perception's resolution: the cube (now, or
    one step earlier for a violation seen one step late) within BORDERLINE of the
    workspace edge, or of the success circle around the goal."""
    for r in (row, prev):
        if r is None:
            continue
        if edge_distance(r["cube_xy"]) <= BORDERLINE:
            return True
        goal = r.get("goal")
        if goal is not None and abs(math.dist(r["cube_xy"], goal) - SUCCESS_RADIUS) <= BORDERLINE:
            return True
    return False


def truth_agreement(run: Path) -> dict[str, Any]:
    """Perception's success/violation decisions (steps.jsonl) against the twin's truth,
    over every arm-step the twin recorded that was not a fault; each disagreement says
    whether it was borderline (see :data:`BORDERLINE`)."""
    from testbed.records.steps import read_steps

    truth: dict[tuple[int, str], dict[str, Any]] = {}
    tpath = run / "twin_truth.jsonl"
    if tpath.exists():
        for line in tpath.read_text(encoding="utf-8").splitlines():
            if line.strip():
                row = json.loads(line)
                truth[(int(row["t"]), str(row["robot"]))] = row
    n = agree = pushed_n = pushed_agree = 0
    disagreements: list[dict[str, Any]] = []
    for step in read_steps(run / "steps.jsonl"):
        t = int(step["t"])
        for r in step["robots"]:
            tr = truth.get((t, r["robot"]))
            if tr is None or r["mode"] == "fault":
                continue
            same = (bool(r["success"]) == tr["success"] and bool(r["violation"]) == tr["violation"])
            n += 1
            agree += same
            if tr.get("pushed"):
                pushed_n += 1
                pushed_agree += same
            if not same:
                disagreements.append({
                    "t": t, "robot": r["robot"], "perceived": [r["success"], r["violation"]],
                    "truth": [tr["success"], tr["violation"]], "cube_xy": tr["cube_xy"],
                    "borderline": _borderline(tr, truth.get((t - 1, r["robot"])))})
    return {"arm_steps": n, "agree": agree, "rate": agree / n if n else float("nan"),
            "pushed_arm_steps": pushed_n, "pushed_agree": pushed_agree,
            "pushed_rate": pushed_agree / pushed_n if pushed_n else float("nan"),
            "disagreements": disagreements,
            "borderline": sum(d["borderline"] for d in disagreements)}


# -- the twin hosts: one hardware twin process and one sshd per YuMi host --------------
@dataclass
class TwinHost:
    """One rehearsal host: its hardware twin process and the sshd in front of it."""

    name: str
    arms: tuple[str, ...]
    port: int
    proc: subprocess.Popen[bytes]
    sshd: Any
    lab: LabClient

    @property
    def camera_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/camera.mjpg"

    @property
    def controller_url(self) -> str:
        return f"twin+http://127.0.0.1:{self.port}"


def require_yumi(fleet: FleetConfig) -> None:
    """A rehearsal stands hardware twins where YuMi hosts are; twin hosts have none."""
    not_yumi = [h.name for h in fleet.hosts if h.backend != "yumi"]
    if not_yumi:
        raise ConfigError(f"fleet.hosts[{not_yumi[0]}].backend: testbed rehearse needs a "
                          "physical protocol (backend = \"yumi\" hosts); run a twin "
                          "protocol with testbed protocol")


class HardwareTwinLab:
    """Starts, rewrites for, and stops the hardware twin hosts of one rehearsal."""

    def __init__(self, fleet: FleetConfig, root: Path, *, seed: int = 0,
                 realtime: float = 0.0) -> None:
        require_yumi(fleet)
        self.fleet = fleet
        self.root = root.resolve()  # sshd's config needs absolute paths
        self.seed = seed
        self.realtime = realtime
        self.hosts: dict[str, TwinHost] = {}

    def start(self) -> None:
        from drivers.testing.sshd import SshServer, sshd_available

        if not sshd_available():
            raise ConfigError("testbed rehearse needs OpenSSH's sshd and ssh-keygen "
                              "(Debian: apt-get install openssh-server)")
        self.root.mkdir(parents=True, exist_ok=True)
        starting: list[tuple[str, tuple[str, ...], subprocess.Popen[bytes], Path]] = []
        try:
            for i, h in enumerate(self.fleet.hosts):
                arms = tuple(a.name for a in h.arms)
                port_file = self.root / f"{h.name}.port"
                port_file.unlink(missing_ok=True)
                log = open(self.root / f"{h.name}-twin.log", "ab")  # noqa: SIM115 (child owns it)
                proc = subprocess.Popen(
                    [sys.executable, "-m", "sim_twin.yumi_server", "--arms", ",".join(arms),
                     "--seed", str(self.seed * 1000 + i), "--port", "0",
                     "--port-file", str(port_file), "--realtime", f"{self.realtime:g}"],
                    cwd=PROJECT_ROOT, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                    start_new_session=True)
                log.close()
                starting.append((h.name, arms, proc, port_file))
            for name, arms, proc, port_file in starting:
                port = _wait_port(proc, port_file, self.root / f"{name}-twin.log")
                sshd = SshServer(self.root / f"sshd-{name}")
                try:
                    sshd.start()
                except RuntimeError as exc:
                    raise RehearsalError(f"host {name}: the rehearsal's sshd did not start: "
                                         f"{' '.join(str(exc).split())[:300]}") from None
                self.hosts[name] = TwinHost(name, arms, port, proc, sshd,
                                            LabClient(f"http://127.0.0.1:{port}"))
        except BaseException:
            for _, _, proc, _ in starting:
                _terminate(proc)
            self.stop()
            raise

    def stop(self) -> None:
        for h in self.hosts.values():
            with contextlib.suppress(Exception):
                h.sshd.stop()
            _terminate(h.proc)
        self.hosts = {}

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
        its sshd; this checkout's interpreter and folder; the twin's camera and
        controller; the rehearsal's calibration files. Nothing else changes."""
        fleet = fleet or self.fleet
        hosts = []
        for h in fleet.hosts:
            t = self.hosts[h.name]
            arms = [a.model_copy(update={"calibration": str(self.calibration_path(h.name,
                                                                                   a.name))})
                    for a in h.arms]
            hosts.append(h.model_copy(update={
                "transport": "ssh", "address": "127.0.0.1", "port": t.sshd.port,
                "user": t.sshd.user, "key_file": str(t.sshd.client_key),
                "known_hosts": str(t.sshd.known_hosts), "python": sys.executable,
                "workdir": str(PROJECT_ROOT), "camera": t.camera_url,
                "controller_url": t.controller_url, "arms": arms}))
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


__all__ = ["ArmView", "HardwareTwinLab", "LabClient", "TruthRecorder", "TwinLabHumans",
           "truth_agreement"]



# -- the verb ------------------------------------------------------------------------
@dataclass
class RehearsalResult:
    folder: Path
    report_markdown: str
    agreement: dict[str, dict[str, Any]]
    calibration: dict[str, dict[str, float]]


def quick_learning(fleet: FleetConfig) -> FleetConfig:
    """The default twin trial's learning sizes (README command 1), the device kept."""
    from testbed.core.config import default_twin_config

    quick = default_twin_config().learning.model_copy(update={"device": fleet.learning.device})
    return fleet.model_copy(update={"learning": quick})


def seed_calibration(lab: HardwareTwinLab, host: str, arm: str) -> Path:
    """The file a lab writes by hand before its first calibration: the arm's safe table
    box and its rest pose (here, the twin's), no homography yet."""
    cam = lab.hosts[host].lab.camera()
    path = lab.calibration_path(host, arm)
    if path.exists():
        return path
    from testbed.core.atomic import atomic_write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    seed = true_calibration(cam, arm)
    del seed["homography"]  # what a person knows before calibrating: box and rest pose
    atomic_write_json(path, seed)
    return path


@dataclass
class RehearsalOptions:
    protocol: Path
    trials: int | None = None
    steps: int | None = None
    humans: str = "scripted"
    quick: bool = False
    out: Path | None = None
    algorithms: list[str] | None = None
    realtime: float = 0.0


def _calibrate_all(lab: HardwareTwinLab, fleet: FleetConfig, fleet_file: Path,
                   say: Any) -> dict[str, dict[str, float]]:
    """``testbed calibrate`` for every arm, against the twin, over SSH: the lab's first
    morning. Each arm starts from a hand-written seed file (safe box, rest pose)."""
    from testbed.cli import main as testbed_main

    figures: dict[str, dict[str, float]] = {}
    for h in fleet.hosts:
        for a in h.arms:
            seed_calibration(lab, h.name, a.name)
            say(f"calibrate {h.name}/{a.name} (testbed calibrate --config {fleet_file} "
                f"--host {h.name} --arm {a.name})")
            status = testbed_main(["calibrate", "--config", str(fleet_file), "--host", h.name,
                                   "--arm", a.name])
            if status != 0:
                raise RehearsalError(f"testbed calibrate failed for {h.name}/{a.name} "
                                     f"(exit {status}); see the lines above")
            data = json.loads(lab.calibration_path(h.name, a.name).read_text())
            cam = lab.hosts[h.name].lab.camera()
            figures[f"{h.name}/{a.name}"] = true_model_error(
                cam, data["homography"], cam["workspaces_mm"][a.name])
    return figures


def project_plane(cam: Mapping[str, Any], box_mm: Sequence[float], plane_z_mm: float,
                  n: int) -> tuple[Any, Any]:
    """An n x n grid of the box at height ``plane_z_mm`` (mm, (n*n, 3)) and where the
    twin's TRUE camera (pinhole, distortion, pose from ``/lab/camera``) sees it ((n*n, 2))."""
    import cv2
    import numpy as np

    xs = np.linspace(box_mm[0], box_mm[2], n)
    ys = np.linspace(box_mm[1], box_mm[3], n)
    pts = np.array([(x, y, plane_z_mm) for x in xs for y in ys], dtype=np.float64)
    rvec, _ = cv2.Rodrigues(np.asarray(cam["R"], dtype=np.float64))
    px, _ = cv2.projectPoints(pts, rvec, np.asarray(cam["t"], dtype=np.float64),
                              np.asarray(cam["K"], dtype=np.float64),
                              np.asarray(cam["dist"], dtype=np.float64))
    return pts, px.reshape(-1, 2)


def true_calibration(cam: Mapping[str, Any], arm: str, plane_z_mm: float = 40.0,
                     n: int = 9) -> dict[str, Any]:
    """The arm's calibration file as a perfect ``testbed calibrate`` would write it: the
    homography fitted to the twin's TRUE projection of the cube-top plane over the arm's
    workspace. For tests and benchmarks that need a calibrated twin quickly; a rehearsal
    calibrates with ``testbed calibrate`` itself."""
    import cv2

    box = [float(v) for v in cam["workspaces_mm"][arm]]
    pts, px = project_plane(cam, box, plane_z_mm, n)
    h, _ = cv2.findHomography(px, pts[:, :2])
    side = "L" if arm.startswith("l") else "R"
    return {"homography": h.tolist(), "table_box_mm": box,
            "rest_joints_deg": [0.0, -130.0, 30.0, 0.0, 40.0, 0.0,
                                -135.0 if side == "L" else 135.0],
            "task": f"T_ROB_{side}", "mechunit": f"ROB_{side}"}


def true_model_error(cam: Mapping[str, Any], homography: Any, box_mm: Sequence[float],
                     plane_z_mm: float = 40.0, n: int = 9) -> dict[str, float]:
    """A fitted pixel -> table homography against the twin's TRUE camera model (pinhole,
    distortion, pose), over an n x n grid of the box in the cube-top plane: the error a
    calibrated arm makes in pixels (where it thinks a table point is seen) and in
    millimetres (where it thinks a seen point is on the table)."""
    import cv2
    import numpy as np

    pts, px = project_plane(cam, box_mm, plane_z_mm, n)
    h = np.asarray(homography, dtype=np.float64)
    mm = cv2.perspectiveTransform(px.reshape(-1, 1, 2), h).reshape(-1, 2)
    back = cv2.perspectiveTransform(pts[:, None, :2].copy(), np.linalg.inv(h)).reshape(-1, 2)
    err_mm = np.linalg.norm(mm - pts[:, :2], axis=1)
    err_px = np.linalg.norm(back - px, axis=1)
    return {"median_px": float(np.median(err_px)), "max_px": float(err_px.max()),
            "median_mm": float(np.median(err_mm)), "max_mm": float(err_mm.max())}


def rehearse(opts: RehearsalOptions, say: Any = print) -> RehearsalResult:
    """Run a physical protocol against hardware twins behind real sshds (see module doc)."""
    from testbed.experiments.protocol import load_protocol, run_protocol

    proto = load_protocol(opts.protocol, check_files=False)  # its keys are the lab's
    require_yumi(proto.fleet)
    folder = opts.out or Path("runs") / f"rehearsal-{proto.name}"
    update: dict[str, Any] = {"out": str(folder), "humans": opts.humans}
    trials = opts.trials or 1
    update["trials"] = trials
    update["seeds"] = [proto.seed(k % proto.trials) for k in range(trials)]
    if opts.steps is not None:
        update["steps"] = opts.steps
    if opts.algorithms:
        update["algorithms"] = opts.algorithms
    fleet = proto.fleet
    if opts.quick:
        fleet = quick_learning(fleet)
    kind = opts.humans
    fleet = fleet.model_copy(update={"humans": fleet.humans.model_copy(update={"kind": kind})})
    folder.mkdir(parents=True, exist_ok=True)
    lab = HardwareTwinLab(fleet, folder / "lab", seed=proto.seed(0), realtime=opts.realtime)
    with lab:
        fleet = lab.rewrite(fleet)
        fleet_dir = RunDir(folder / "lab" / "fleet")
        fleet_dir.path.mkdir(parents=True, exist_ok=True)
        fleet_dir.write_config(fleet)
        fleet_file = fleet_dir.path / "config.toml"
        where = ", ".join(f"{n} (sshd :{h.sshd.port}, twin :{h.port})"
                          for n, h in lab.hosts.items())
        say(f"hardware twins: {where}")
        calibration = _calibrate_all(lab, fleet, fleet_file, say)
        run_proto = proto.model_copy(update={**update, "fleet": fleet})
        views = arm_views(fleet)
        hooks = _RehearsalHooks(lab, views, kind)
        report = run_protocol(run_proto, out=str(folder), ask=False, hooks=hooks)
    agreement: dict[str, dict[str, Any]] = {}
    for run in sorted(p for p in folder.iterdir() if (p / "twin_truth.jsonl").exists()):
        agreement[run.name] = truth_agreement(run)
    markdown = report.markdown
    if opts.quick:
        markdown = ("**Quick rehearsal:** the learning sizes are the default twin trial's, not "
                    "the protocol's.\n\n" + markdown)
    markdown += "\n" + agreement_table(agreement)
    (folder / "rehearsal.md").write_text(markdown, encoding="utf-8")
    return RehearsalResult(folder, markdown, agreement, calibration)


class _RehearsalHooks(TrialHooks):
    """A rehearsal's runs: the lab hand puts every cube back before each run, the humans
    get the lab around them, and each run's hosts get a truth recorder."""

    def __init__(self, lab: HardwareTwinLab, views: Mapping[str, ArmView], kind: str) -> None:
        self.lab, self.views, self.kind = lab, views, kind
        self.recorders: list[TruthRecorder] = []

    def before_run(self, name: str) -> bool:
        self.lab.reset_all(name)
        return True

    def humans(self, name: str) -> Humans | None:
        from testbed.experiments.build import make_humans

        fleet = self.lab.fleet
        inner = make_humans(self.kind, fleet.humans.count, fleet.humans.web)
        return TwinLabHumans(inner, self.lab.labs, self.views, expert=self.kind == "scripted")

    def wrap_hosts(self, hosts: Hosts, run: RunDir) -> Hosts:
        rec = TruthRecorder(hosts, self.lab.labs, self.views, run.path / "twin_truth.jsonl")
        self.recorders.append(rec)
        return rec

    def on_step(self, outcome: StepOutcome) -> None:
        if self.recorders:
            self.recorders[-1].on_step(outcome.t)


def agreement_table(agreement: Mapping[str, Mapping[str, Any]]) -> str:
    lines = ["Perception (steps.jsonl) against the twin's truth (twin_truth.jsonl):", "",
             "| run | arm-steps | agree | pushed arm-steps | agree | disagreements "
             "(borderline) |", "|---|---|---|---|---|---|"]
    for name, a in agreement.items():
        lines.append(f"| {name} | {a['arm_steps']} | {a['rate']:.2%} | {a['pushed_arm_steps']} "
                     f"| {a['pushed_rate']:.2%} | {len(a['disagreements'])} "
                     f"({a['borderline']}) |")
    return "\n".join(lines) + "\n"
