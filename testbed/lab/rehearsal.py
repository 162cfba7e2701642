"""``testbed rehearse``: a lab's whole day on hardware twins, before touching a robot.

Why: the physical path (SSH, the host agent, the robot's backend, its camera and its
controller, calibration, the physical protocol's prompts and records) is what a lab runs
on day one, and none of it runs in twin mode. A rehearsal runs the physical protocol
UNCHANGED but for where its hosts are: each host becomes the hardware twin its
backend's plugin declares (``Backend.hardware_twin``, ``testbed.lab.hardware_twin``)
reached through a real OpenSSH ``sshd`` on loopback, and the agent on it runs the host's
backend as on the robot's PC. A YuMi host's twin is ``python -m sim_twin.yumi_server``
(a PyBullet bimanual cell behind the controller's Robot Web Services, with our RAPID's
semantics, and an MJPEG camera)::

    testbed rehearse  --SSH-->  sshd  -->  python -m drivers.agent --backend yumi
                                             camera:     http://127.0.0.1:P/camera.mjpg
                                             controller: http://127.0.0.1:Q (RWS 1.0, the
                                               unchanged ABB client, a 0600 login file)
    lab side (never read by the controller's decisions):
      TwinLabHumans: scripted teleop from the twin's truth, the lab hand on a confirmed reset
      TruthRecorder: runs/<run>/twin_truth.jsonl (scoring only)
      RwsLogSlices: runs/<run>/hosts/<host>.rws.jsonl (every RWS request the twin served)

A lab's own robot rehearses the same way with whatever stand-in its plugin starts; a
twin without a lab side channel (``HardwareTwin.lab_port``) has no truth to record and
no cube for the lab hand (its observations carry the expert's action, its backend
resets), and one that is not calibrated (``HardwareTwin.calibrate``) keeps its arms'
files as written.

The protocol's host section is rewritten in addresses, ports, users and key paths (the
twin's sshd), in the host install (python, workdir: this checkout), in the fields that
reach the stand-in (a YuMi's camera and controller URLs and login file) and in the
calibration files (calibrated by ``testbed.lab.calibrate.calibrate``, what ``testbed
calibrate`` runs, against the twin at the start of the rehearsal). Crops, mirrors, the
algorithm, learning, humans and the protocol's order and prompts stay as the lab wrote
them. ``--quick`` swaps the learning sizes for the default twin trial's.

This module is the orchestration only: the twins and their sshds are
``testbed.lab.hardware_twin``, the lab's humans ``testbed.lab.lab_humans``, the truth
and its scoring ``testbed.lab.twin_truth``, the true camera's figures
``testbed.lab.camera_model``, and ``--faults``' drills (a guard stop, motors off, a
RAPID error, a zone stop, a frozen camera, a lost link, each cleared by a scripted
person) ``testbed.lab.fault_drills`` and ``testbed.lab.fault_report``.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.atomic import atomic_write_json
from testbed.core.config import ConfigError
from testbed.core.host_config import HostConfig
from testbed.core.hosts import Hosts
from testbed.core.humans import Humans
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.hooks import TrialHooks
from testbed.lab.camera_model import starting_calibration, true_model_error
from testbed.lab.fault_drills import FAULTS_FILE, RunFaults, fault_room
from testbed.lab.fault_report import faults_table, finish_faults
from testbed.lab.hardware_twin import (
    HardwareTwinLab,
    RehearsalError,
    hardware_twins,
    require_faults,
)
from testbed.lab.lab_humans import ArmView, TwinLabHumans, arm_views
from testbed.lab.rws_requests import RwsLogSlices, read_requests, requests_table
from testbed.lab.twin_truth import TruthRecorder, agreement_table, truth_agreement
from testbed.records.run_dir import RunDir

if TYPE_CHECKING:
    from testbed.experiments.protocol import Protocol
    from testbed.fleet.loop import StepOutcome

__all__ = ["RehearsalError", "RehearsalOptions", "RehearsalResult", "hardware_twins",
           "lab_calibration", "quick_learning", "rehearse", "require_faults"]

Say = Callable[[str], None]
CALIBRATED = "calibration.json"
"""In the lab folder once every arm is calibrated: each arm's error against the true
camera. A rehearsal run again keeps the calibrations (``_kept_calibration``)."""
KEEP_MAX_PX = 1.5
"""A kept calibration's largest error against the twin's camera (the calibration's own
target, docs/notes/rehearsal.md)."""


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
    host_python: str | None = None
    """The agents' interpreter: a robot host install's (``scripts/setup.sh --host``)."""
    faults: bool = False
    """Inject the lab's faults into every run (``testbed.lab.fault_drills``)."""
    camera_fps: float = 15.0
    """The twins' camera frame rate: each read waits for a frame made after the call."""


@dataclass
class RehearsalResult:
    folder: Path
    report_markdown: str
    agreement: dict[str, dict[str, Any]]
    calibration: dict[str, dict[str, float]]
    faults: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    """Run -> its faults with what the arms did (``--faults``; ``faults.jsonl``)."""


def quick_learning(fleet: FleetConfig) -> FleetConfig:
    """The default twin trial's learning sizes (README command 1), the device kept."""
    from testbed.experiments.fleet_config import default_twin_config

    quick = default_twin_config().learning.model_copy(update={"device": fleet.learning.device})
    return fleet.model_copy(update={"learning": quick})


def rehearse(opts: RehearsalOptions, say: Say = print) -> RehearsalResult:
    """Run a physical protocol against hardware twins behind real sshds (see module doc)."""
    from testbed.experiments.protocol import load_protocol, run_protocol

    proto = load_protocol(opts.protocol, check_files=False)  # its keys are the lab's
    hardware_twins(proto.fleet)  # each host's, or one line naming the one without
    if opts.faults:
        require_faults(proto.fleet)
    folder = opts.out or Path("runs") / f"rehearsal-{proto.name}"
    update = _protocol_update(proto, opts, folder)
    fleet = _rehearsal_fleet(proto.fleet, opts)
    folder.mkdir(parents=True, exist_ok=True)
    lab = HardwareTwinLab(fleet, folder / "lab", seed=proto.seed(0), realtime=opts.realtime,
                          host_python=opts.host_python, camera_fps=opts.camera_fps)
    with lab:
        fleet = lab.rewrite(fleet)
        fleet_dir = RunDir(folder / "lab" / "fleet")
        fleet_dir.path.mkdir(parents=True, exist_ok=True)
        fleet_dir.write_config(fleet)
        fleet_file = fleet_dir.path / "config.toml"
        where = ", ".join(f"{n} (sshd :{h.sshd.port}, " + (f"twin :{h.port})" if h.port
                                                             else "its agent's own twin)")
                          for n, h in lab.hosts.items())
        say(f"hardware twins: {where}")
        calibration = lab_calibration(lab, fleet, fleet_file, say)
        run_proto = proto.model_copy(update={**update, "fleet": fleet})
        _same_theta_0(run_proto, folder)
        hooks = _RehearsalHooks(lab, arm_views(fleet, hosts=lab.labs), opts.humans)
        if opts.faults:
            hooks.drills = RunFaults(lab, say)
            say(fault_room(run_proto.steps))
        try:
            report = run_protocol(run_proto, out=str(folder), ask=False, hooks=hooks)
        finally:
            hooks.rws.end()
            if hooks.drills is not None:
                hooks.drills.end()
    agreement: dict[str, dict[str, Any]] = {}
    for run in sorted(p for p in folder.iterdir() if (p / "twin_truth.jsonl").exists()):
        agreement[run.name] = truth_agreement(run)
    markdown = report.markdown
    if opts.quick:
        markdown = ("**Quick rehearsal:** the learning sizes are the default twin trial's, not "
                    "the protocol's.\n\n" + markdown)
    if agreement:  # the twins with a side channel's truth
        markdown += "\n" + agreement_table(agreement)
    faults = {run.name: finish_faults(run) for run in sorted(folder.iterdir())
              if (run / FAULTS_FILE).exists()} if opts.faults else {}
    if faults:
        markdown += "\n" + faults_table(faults)
    rws_logs = sorted(folder.glob("*/hosts/*.rws.jsonl"))
    if rws_logs:
        markdown += "\n## The controllers' RWS requests (all runs)\n\n" + requests_table(
            read_requests(rws_logs))
    (folder / "rehearsal.md").write_text(markdown, encoding="utf-8")
    return RehearsalResult(folder, markdown, agreement, calibration, faults)


def _protocol_update(proto: Protocol, opts: RehearsalOptions, folder: Path) -> dict[str, Any]:
    """What the rehearsal changes in the protocol besides its fleet: the folder, the
    humans, the trials (one by default, with the protocol's seeds), steps, algorithms."""
    update: dict[str, Any] = {"out": str(folder), "humans": opts.humans}
    trials = opts.trials or 1
    update["trials"] = trials
    update["seeds"] = [proto.seed(k % proto.trials) for k in range(trials)]
    if opts.steps is not None:
        update["steps"] = opts.steps
    if opts.algorithms:
        update["algorithms"] = opts.algorithms
    return update


def _rehearsal_fleet(fleet: FleetConfig, opts: RehearsalOptions) -> FleetConfig:
    """The protocol's fleet with the rehearsal's humans (and ``--quick``'s learning)."""
    if opts.quick:
        fleet = quick_learning(fleet)
    humans = fleet.humans.model_copy(update={"kind": opts.humans})
    return fleet.model_copy(update={"humans": humans})


def _same_theta_0(proto: Protocol, folder: Path) -> None:
    """A rehearsal run again starts the runs it has not started from the theta_0 its
    first session pretrained. theta_0's cache key leaves out how a host is reached but
    not its camera and controller URLs, and a new session's twins have new ports: without
    this every session after a kill pretrained again (~4 min at the quick sizes) and its
    runs started from another theta_0. Each algorithm's key under the first session's
    fleet (kept in ``lab/fleet/first.toml``) is linked to its key under this one's, for
    each seed a theta_0 is pretrained from (every trial's with ``pretrain_per_trial``)."""
    from testbed.experiments.fleet_config import load_fleet
    from testbed.experiments.learners import PRETRAIN_SEED
    from testbed.experiments.pretraining import pretrain_key
    from testbed.fleet.algorithms import ALGORITHMS

    first = folder / "lab" / "fleet" / "first.toml"
    if not first.exists():  # the first session: its fleet (with its twins' ports)
        RunDir(first.parent).write_config(proto.fleet)
        first.write_bytes((first.parent / "config.toml").read_bytes())
        return
    then = proto.model_copy(update={"fleet": load_fleet(first)})
    both = proto.theta0_critics()
    cache = folder / ".pretrained"
    trials = proto.trials if proto.until is None else proto.until.max_trials
    seeds = sorted({PRETRAIN_SEED} if not proto.pretrain_per_trial else
                   {proto.seed(k) for k in range(trials)})  # each trial's theta_0
    for a in proto.algorithms:
        critics = sorted(set(ALGORITHMS[proto.algorithm_of(a)].critics) | set(both))
        for seed in seeds:
            old = pretrain_key(then.fleet_of(a), seed, critics)
            new = pretrain_key(proto.fleet_of(a), seed, critics)
            if old != new and (cache / old).is_dir() and not (cache / new).exists():
                (cache / new).symlink_to(old, target_is_directory=True)


def lab_calibration(lab: HardwareTwinLab, fleet: FleetConfig, fleet_file: Path, say: Say
                    ) -> dict[str, dict[str, float]]:
    """Each calibrated arm's error against the twin's true camera: the calibrations kept
    from a session before when they still hold (``_kept_calibration``), else every arm
    calibrated with ``testbed calibrate`` and kept (``calibration.json``) for the next
    session. A rehearsal's first morning; the tests' one calibration of a run runs it too
    (``tests/testbed/kept_calibration.py``), so what they keep is what a rehearsal makes."""
    calibration = _kept_calibration(lab, fleet, say)
    if calibration is None:
        calibration = _calibrate_all(lab, fleet, fleet_file, say)
        atomic_write_json(lab.root / CALIBRATED, calibration)
    return calibration


def _kept_calibration(lab: HardwareTwinLab, fleet: FleetConfig, say: Say
                      ) -> dict[str, dict[str, float]] | None:
    """A rehearsal run again (resumed): the calibrations its first session made, when
    every arm's still holds against the twin's true camera (the same seed gives the same
    cell: a lab re-checks, it does not recalibrate) and still says what the lab knows of
    the arm (its tool, rest joints, arm angle: a new tool is a new calibration);
    None: calibrate."""
    from testbed.lab.camera_model import arm_facts

    if not (lab.root / CALIBRATED).exists():
        return None
    figures: dict[str, dict[str, float]] = {}
    for h in _calibrated(lab, fleet):
        cam = lab.hosts[h.name].lab.camera()
        for a in h.arms:
            try:
                data = json.loads(lab.calibration_path(h.name, a.name).read_text())
                err = true_model_error(cam, data["homography"], cam["workspaces_mm"][a.name])
            except (OSError, ValueError, KeyError):
                return None
            facts = arm_facts(a.name, cam)
            stale = sorted(k for k, v in facts.items() if data.get(k) != v)
            if stale or not err["max_px"] <= KEEP_MAX_PX:
                say(f"calibration of {h.name}/{a.name} no longer holds ("
                    + (f"{', '.join(stale)} changed" if stale else
                       f"max {err['max_px']:.2f} px") + "): calibrating every arm again")
                for g in _calibrated(lab, fleet):  # from the starting files, as on day one
                    for x in g.arms:
                        lab.calibration_path(g.name, x.name).unlink(missing_ok=True)
                return None
            figures[f"{h.name}/{a.name}"] = err
    if figures:
        worst = max(f["max_px"] for f in figures.values())
        say(f"calibration: every arm's from the last session, checked against the twin's "
            f"camera (max {worst:.2f} px)")
    return figures


def _calibrated(lab: HardwareTwinLab, fleet: FleetConfig) -> list[HostConfig]:
    """The hosts whose arms the rehearsal calibrates (``HardwareTwin.calibrate``)."""
    return [h for h in fleet.hosts if lab.calibrated(h.name)]


def _calibrate_all(lab: HardwareTwinLab, fleet: FleetConfig, fleet_file: Path,
                   say: Say) -> dict[str, dict[str, float]]:
    """``testbed calibrate`` for every arm, against the twin, over SSH: the lab's first
    morning. Each arm starts from a hand-written starting file (safe box, rest pose)."""
    figures: dict[str, dict[str, float]] = {}
    hosts = _calibrated(lab, fleet)
    for h in hosts:  # every arm's starting file first: the controller client needs
        for a in h.arms:   # each arm's rest pose, also while its sibling is calibrated
            starting_calibration(lab, h.name, a.name)
    for h in hosts:
        for a in h.arms:
            say(f"calibrate {h.name}/{a.name} (testbed calibrate --config {fleet_file} "
                f"--host {h.name} --arm {a.name})")
            status = _calibrate_arm(fleet_file, h.name, a.name, say)
            if status != 0:
                raise RehearsalError(f"testbed calibrate failed for {h.name}/{a.name} "
                                     f"(exit {status}); see the lines above")
            data = json.loads(lab.calibration_path(h.name, a.name).read_text())
            cam = lab.hosts[h.name].lab.camera()
            figures[f"{h.name}/{a.name}"] = true_model_error(
                cam, data["homography"], cam["workspaces_mm"][a.name])
    return figures


def _calibrate_arm(fleet_file: Path, host: str, arm: str, say: Say) -> int:
    """What ``testbed calibrate --config FLEET_FILE --host HOST --arm ARM`` does and
    exits with: the fleet read from the file, the command's defaults, and for a
    ConfigError the command's one line on stderr and exit 2."""
    from testbed.experiments.fleet_config import load_fleet
    from testbed.lab.calibrate import calibrate, default_options

    try:
        return calibrate(load_fleet(fleet_file), default_options(host, arm), say)
    except ConfigError as exc:
        sys.stderr.write(f"testbed calibrate: {exc}\n")
        return 2


class _RehearsalHooks(TrialHooks):
    """A rehearsal's runs: the lab hand puts every cube back before each run, the humans
    get the lab around them, and each run's hosts get a truth recorder."""

    def __init__(self, lab: HardwareTwinLab, views: Mapping[str, ArmView], kind: str) -> None:
        self.lab, self.views, self.kind = lab, views, kind
        self.recorders: list[TruthRecorder] = []
        self.drills: RunFaults | None = None
        """``--faults``: each run's faults, injected and cleared between its steps."""
        self.rws = RwsLogSlices({n: h.rws_log for n, h in lab.hosts.items()
                                 if h.rws_log is not None})
        """Each run's share of the twins' RWS request logs, into its ``hosts/``."""

    def before_run(self, name: str) -> bool:
        if self.drills is not None:
            self.drills.end()  # the last run's: nothing stays broken
        self.lab.reset_all(name)
        return True

    def wrap_humans(self, humans: Humans, run: RunDir) -> Humans:
        """The run's humans as the trial built them (a web console with the run's kept
        links, told when it was resumed), with the lab around them."""
        return TwinLabHumans(humans, self.lab.labs, self.views,
                             expert=self.kind == "scripted")

    def wrap_hosts(self, hosts: Hosts, run: RunDir) -> Hosts:
        """The run's truth recorder; a resumed run (its checkpoint's step in
        ``state.json``, ``steps.jsonl`` already cut back to it) starts after it, its
        truth and faults cut back to it too, and its drills caught up."""
        from testbed.records.steps import read_steps

        self.rws.begin(run.path)
        start, rows = 0, []
        if run.state.exists():
            start = int(json.loads(run.state.read_text(encoding="utf-8"))["t"]) + 1
            rows = [r for r in read_steps(run.steps) if int(r["t"]) < start]
        first = self.drills.begin(run.path, rows) if self.drills is not None else None
        if not self.lab.labs:  # no twin with a side channel: no truth (and no drills)
            return hosts
        rec = TruthRecorder(hosts, self.lab.labs, self.views, run.path / "twin_truth.jsonl",
                            start=start, before_first_step=first)
        self.recorders.append(rec)
        return rec

    def on_step(self, outcome: StepOutcome) -> None:
        if self.recorders:
            self.recorders[-1].on_step(outcome.t)
        if self.drills is not None:  # between step t and t + 1
            self.drills.after_step(outcome.t, outcome.row)
