"""The verbs of the lab's hardware: ``deploy``, ``check``, ``calibrate`` and ``rehearse``.

Each is one ``Verb`` (its arguments and its handler together); the work is
``testbed.lab``'s. Imported for ``testbed --help``, so ``testbed.lab`` (cv2, the
hardware twin) is imported inside the handlers.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from testbed.cli.arguments import HUMANS, Verb, add_config, positive
from testbed.cli.checks import (
    check_device,
    check_humans,
    check_out_file,
    load_config,
    refused,
)
from testbed.core.config import ConfigError
from testbed.experiments.controller_gate import TrialRefused


# ---- deploy -----------------------------------------------------------------------------
def _deploy_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", required=True,
                   help="fleet config or protocol file whose ssh hosts get this build")
    p.add_argument("--host", metavar="NAME", help="only this host (default: every ssh host)")
    p.add_argument("--dry-run", action="store_true",
                   help="print the backends found (and where from) and what each host would "
                        "install and verify; connect to nothing")


def cmd_deploy(args: argparse.Namespace) -> int:
    from testbed.lab.deploy import deploy, plan  # paramiko, only when asked

    cfg = load_config(args)
    if args.dry_run:
        plan(cfg, args.host, print_line=print)
        return 0
    return 0 if deploy(cfg, args.host, print_line=print) else 1


DEPLOY = Verb(
    "deploy", help="install this checkout's build on the robot hosts",
    description="Build a wheel of this checkout stamped with its build id (the commit, "
    "and a hash of uncommitted changes), copy it to each ssh host (or --host NAME) by "
    "SFTP, install it into the environment the host's python names, install the host "
    "extras' dependencies it lacks, and verify the host's python imports the agent and "
    "reports this build. A host that runs another build is refused at hello.",
    add_arguments=_deploy_arguments, run=cmd_deploy)


# ---- check ------------------------------------------------------------------------------
def _check_arguments(p: argparse.ArgumentParser) -> None:
    add_config(p)
    p.add_argument("--mosaic", default="check.png", metavar="PNG")


def cmd_check(args: argparse.Namespace) -> int:
    from testbed.lab.preflight import preflight

    cfg = load_config(args)
    check_out_file("--mosaic", args.mosaic)
    ok = preflight(cfg, Path(args.mosaic), print_line=print)
    return 0 if ok else 1


CHECK = Verb(
    "check", help="preflight every host and arm, read-only, write a mosaic PNG",
    description="Reach every host, check the agent version, report each robot "
    "controller (state, RAPID version, zones active, tool frame, layout and sweep "
    "margins, an arm in the camera's view), take a frame of every arm, write a mosaic "
    "PNG. It never moves an arm; trial, evaluate, protocol and rehearse run its "
    "controller part first and refuse with its FAULT lines.",
    add_arguments=_check_arguments, run=cmd_check)


# ---- calibrate --------------------------------------------------------------------------
def _calibrate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", required=True,
                   help="fleet config or protocol file with the yumi host")
    p.add_argument("--host", required=True, metavar="NAME")
    p.add_argument("--arm", required=True, metavar="NAME")
    p.add_argument("--box", metavar="x0,y0,x1,y1", help="safe box of TCP points, mm, in the "
                   "robot's world frame (wobj0): ABB's world frame of the YuMi, x forward, y "
                   "to the robot's left, z up (default: the calibration's table_box_mm, else "
                   "the backend's default for the arm, printed; a YuMi: left 150,75,470,370, "
                   "right 150,-370,470,-75); written as table_box_mm")
    p.add_argument("--grid", default="5x4", metavar="NXxNY", help="points over the box (5x4)")
    p.add_argument("--z", type=float, default=10.0, metavar="MM", help="TCP height (default "
                   "10: the marker in the cube-top plane)")
    p.add_argument("--marker-above-tcp", type=float, default=30.0, metavar="MM",
                   help="marker plane above the TCP (default 30)")
    p.add_argument("--marker-id", type=int, metavar="ID", help="ArUco DICT_4X4_50 id "
                   "(default: left 0, right 1)")
    p.add_argument("--out", metavar="FILE", help="also write the calibration JSON here, locally")
    p.add_argument("--image", metavar="PNG", help="the last frame with sightings, crop and box")
    p.add_argument("--max-px", type=float, default=2.0, metavar="PX",
                   help="fail (exit 1, nothing written) above this max error in pixels")
    p.add_argument("--max-mm", type=float, default=3.0, metavar="MM",
                   help="fail (exit 1, nothing written) above this max error in mm")


def cmd_calibrate(args: argparse.Namespace) -> int:
    from testbed.lab.calibrate import cmd_calibrate as calibrate  # cv2, only when asked

    return calibrate(args)


CALIBRATE = Verb(
    "calibrate", help="fit a YuMi arm's image-to-table homography",
    description="Drive the arm's TCP over a grid in a safe box, find the ArUco marker on "
    "its pusher in each camera frame, fit pixel -> table mm (RANSAC), print the errors, "
    "propose the crop box, check the rest pose is out of view, and write the calibration "
    "file on the host.",
    add_arguments=_calibrate_arguments, run=cmd_calibrate)


# ---- rehearse ---------------------------------------------------------------------------
def _rehearse_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("protocol", nargs="?", default="protocols/physical.toml", metavar="PROTOCOL")
    p.add_argument("--trials", type=positive, metavar="N", help="trials (default 1)")
    p.add_argument("--steps", type=positive, metavar="T", help="steps per run "
                   "(default: the protocol's)")
    p.add_argument("--humans", choices=HUMANS, default="scripted")
    p.add_argument("--quick", action="store_true", help="the default twin trial's learning "
                   "sizes instead of the protocol's (the report says so)")
    p.add_argument("--algorithms", metavar="A,B", help="a subset of the protocol's algorithms")
    p.add_argument("--out", metavar="DIR", help="folder of the rehearsal's runs "
                   "(default runs/rehearsal-NAME)")
    p.add_argument("--realtime", type=float, default=0.0, metavar="X",
                   help="pace the twins' motion at X times real time (default 0: as fast "
                   "as they compute)")
    p.add_argument("--host-python", metavar="PYTHON",
                   help="run the agents with this robot host install's interpreter "
                        "(scripts/setup.sh --host), not this checkout")
    p.add_argument("--faults", action="store_true",
                   help="inject a guard stop, motors off, a RAPID error, a zone stop, a "
                        "frozen camera and a lost SSH link into every run, at steps drawn "
                        "from its seed, each cleared by a scripted person (faults.jsonl)")
    p.add_argument("--camera-fps", type=float, default=15.0, metavar="F",
                   help="the twins' camera frame rate (default 15; a lab's USB camera is "
                        "often 30: a picture made after the call comes sooner)")


def cmd_rehearse(args: argparse.Namespace) -> int:
    from rich.console import Console

    from testbed.experiments.protocol import load_protocol
    from testbed.lab.rehearsal import (
        RehearsalError,
        RehearsalOptions,
        hardware_twins,
        rehearse,
        require_faults,
    )

    path = Path(args.protocol)
    proto = load_protocol(path, check_files=False)  # the lab's key files need not exist here
    hardware_twins(proto.fleet)  # each host's backend declares one, or one line
    if args.faults:
        require_faults(proto.fleet)
    algorithms = [a for a in (args.algorithms or "").split(",") if a] or None
    for a in algorithms or []:
        if a not in proto.algorithms:
            raise ConfigError(f"--algorithms: {a!r} is not one of the protocol's "
                              f"{', '.join(proto.algorithms)}")
    check_humans(args.humans, proto.fleet, teleop=False)
    check_device(proto.fleet)
    if args.realtime < 0:
        raise ConfigError("--realtime: must be >= 0")
    if not 0 < args.camera_fps <= 60:
        raise ConfigError("--camera-fps: must be in (0, 60]")
    if args.host_python is not None and not (Path(args.host_python).is_absolute()
                                             and Path(args.host_python).is_file()):
        raise ConfigError(f"--host-python: {args.host_python!r} is not an interpreter's "
                          "absolute path; give the host install's (scripts/setup.sh --host "
                          "prints it)")
    try:
        result = rehearse(RehearsalOptions(path, args.trials, args.steps, args.humans,
                                           args.quick, Path(args.out) if args.out else None,
                                           algorithms, args.realtime, args.host_python,
                                           args.faults, args.camera_fps))
    except RehearsalError as exc:
        Console(stderr=True).print(f"testbed rehearse: {exc}", markup=False, highlight=False)
        return 1
    except TrialRefused as exc:  # a twin's controller not ready: its FAULT lines
        return refused("rehearse", exc)
    print(result.report_markdown)
    for robot, fig in result.calibration.items():
        print(f"calibration {robot}: against the twin's true camera model median "
              f"{fig['median_px']:.2f} px / {fig['median_mm']:.2f} mm, max "
              f"{fig['max_px']:.2f} px / {fig['max_mm']:.2f} mm")
    print(f"rehearsal: {result.folder} (one folder per run; report.md, rehearsal.md)")
    return 0


REHEARSE = Verb(
    "rehearse", help="a physical protocol on hardware twins over real SSH",
    description="Start the hardware twin each host's backend declares (a YuMi's: a "
    "PyBullet cell, an MJPEG camera, the controller's API) behind a real OpenSSH sshd on "
    "loopback, calibrate every arm whose twin is calibrated with testbed calibrate, and "
    "run the protocol against them with the hosts' own backends.",
    add_arguments=_rehearse_arguments, run=cmd_rehearse)
