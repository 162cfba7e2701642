"""The ``testbed`` command (DESIGN.md section 7).

Every verb parses its arguments, loads and validates the config, and hands over to a
function of its own module; this file only turns their outcomes into exit statuses:
0 done, 1 the run failed (a fault the operator must look at), 2 bad config or
argument (one line naming the field and the fix, never a traceback), 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import NoReturn

from testbed.core.config import ConfigError
from testbed.core.interrupts import EXIT_INTERRUPTED, INTERRUPTS


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad argument is one line and exit status 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message}; see {self.prog} --help\n")
        raise SystemExit(2)


def _positive(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 1")
    return v


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="fleet config (TOML), or a protocol file "
                   "(its [fleet] is used); default: the built-in twin fleet")


def _trial_args(p: argparse.ArgumentParser) -> None:
    _common(p)
    p.add_argument("--algorithm", metavar="NAME", help="bc, random, fleet-ed, fleet-td, cur, "
                   "cur-i and the ablations c, u, r, cu, cr, ur, uc, ru, cru (default: config)")
    p.add_argument("--steps", type=_positive, metavar="T", help="timesteps (default: config)")
    p.add_argument("--seed", type=int, metavar="S", help="trial seed (default: config)")
    p.add_argument("--out", metavar="DIR", help="folder of runs (default: config, runs/)")
    p.add_argument("--humans", choices=["scripted", "gui", "web"],
                   help="who helps: scripted (twin), gui (the OpenCV console), web (the "
                   "browser console, [humans.web] of the config) (default: config)")
    p.add_argument("--policy", metavar="FILE", help="start from this trained learner.pt "
                   "instead of pretraining")
    p.add_argument("--name", help="run folder name (default: ALGORITHM-sSEED)")


def _fanout_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=_positive, metavar="N",
                   help="run the trials on a local Ray with N CPUs (twin fleets only; "
                   'needs the "ray" extra)')
    g.add_argument("--ray", metavar="ADDRESS",
                   help="run the trials on the Ray cluster at ADDRESS; the output folder "
                   "must be on storage every worker sees")
    p.add_argument("--cpus-per-trial", type=_positive, default=1, metavar="C",
                   help="with --workers/--ray: CPUs (and torch threads) per trial")


def build_parser() -> argparse.ArgumentParser:
    root = _Parser(prog="testbed", description="Fleet-DAgger testbed: a fleet of pushing arms, "
                   "remote humans, online behaviour cloning.")
    sub = root.add_subparsers(dest="verb", required=True, parser_class=_Parser)

    p = sub.add_parser("trial", help="run one trial", description="Run one trial (default: the "
                       "built-in twin fleet, 4 arms, 2 scripted humans, C.U.R., 250 steps).")
    _trial_args(p)
    p.add_argument("--resume", metavar="DIR", help="continue a crashed or killed trial")

    p = sub.add_parser("protocol", help="run a protocol file end to end, then its report",
                       description="Run trials x algorithms x steps of a protocol, then report.")
    p.add_argument("file", metavar="FILE")
    p.add_argument("--out", metavar="DIR", help="override the protocol's output folder")
    p.add_argument("--yes", action="store_true", help="do not prompt between trials")
    _fanout_args(p)

    p = sub.add_parser("sweep", help="a grid over config fields x seeds, then its figure",
                       description="Run every grid point x seed of a sweep file (e.g. "
                       "protocols/sweeps/humans.toml), then report: one line per value, "
                       "mean +- std over seeds, as the seed's figures 6-9.")
    p.add_argument("file", metavar="FILE")
    p.add_argument("--out", metavar="DIR", help="override the sweep's output folder")
    _fanout_args(p)

    p = sub.add_parser("report", help="tables and plots of runs or protocol folders",
                       description="Mean +- std per algorithm, Markdown + CSV, PNG curves.")
    p.add_argument("dirs", nargs="+", metavar="RUN_OR_PROTOCOL_DIR")
    p.add_argument("--out", metavar="DIR", help="where to write the report (default: first dir)")

    p = sub.add_parser("check", help="preflight every host and arm, write a mosaic PNG",
                       description="Reach every host, check the agent version, take a frame of "
                       "every arm, write a mosaic PNG.")
    _common(p)
    p.add_argument("--mosaic", default="check.png", metavar="PNG")

    p = sub.add_parser("calibrate", help="fit a YuMi arm's image-to-table homography",
                       description="Drive the arm's TCP over a grid in a safe box, find the "
                       "ArUco marker on its pusher in each camera frame, fit pixel -> table mm "
                       "(RANSAC), print the errors, propose the crop box, check the rest pose "
                       "is out of view, and write the calibration file on the host.")
    p.add_argument("--config", metavar="FILE", required=True,
                   help="fleet config or protocol file with the yumi host")
    p.add_argument("--host", required=True, metavar="NAME")
    p.add_argument("--arm", required=True, metavar="NAME")
    p.add_argument("--box", metavar="x0,y0,x1,y1", help="safe box of TCP points, mm, robot "
                   "base frame (default: the calibration's table_box_mm); written as table_box_mm")
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

    p = sub.add_parser("rehearse", help="a physical protocol on hardware twins over real SSH",
                       description="Start a hardware twin (PyBullet YuMi cell, MJPEG camera, "
                       "controller API) behind a real OpenSSH sshd on loopback for each host "
                       "of a physical protocol, calibrate every arm with testbed calibrate, "
                       "and run the protocol against them with the YuMi backend.")
    p.add_argument("protocol", nargs="?", default="protocols/physical.toml", metavar="PROTOCOL")
    p.add_argument("--trials", type=_positive, metavar="N", help="trials (default 1)")
    p.add_argument("--steps", type=_positive, metavar="T", help="steps per run "
                   "(default: the protocol's)")
    p.add_argument("--humans", choices=["scripted", "gui", "web"], default="scripted")
    p.add_argument("--quick", action="store_true", help="the default twin trial's learning "
                   "sizes instead of the protocol's (the report says so)")
    p.add_argument("--algorithms", metavar="A,B", help="a subset of the protocol's algorithms")
    p.add_argument("--out", metavar="DIR", help="folder of the rehearsal's runs "
                   "(default runs/rehearsal-NAME)")
    p.add_argument("--realtime", type=float, default=0.0, metavar="X",
                   help="pace the twins' motion at X times real time (default 0: as fast "
                   "as they compute)")

    p = sub.add_parser("collect", help="offline demonstrations (375 pairs by default)",
                       description="Humans drive every arm; keep the state-action pairs.")
    _common(p)
    p.add_argument("--count", type=_positive, help="pairs (default: config learning.demos)")
    p.add_argument("--humans", choices=["scripted", "gui", "web"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="demos.npz", metavar="NPZ")

    p = sub.add_parser("pretrain", help="pretrain policy and critics from demonstrations",
                       description="Train the policy on demos, roll it out for the critics' "
                       "data, train the critics; write learner.pt.")
    _common(p)
    p.add_argument("--demos", required=True, metavar="NPZ")
    p.add_argument("--humans", choices=["scripted", "gui", "web"])
    p.add_argument("--steps", type=int,
                   help="gradient steps of each phase, policy and critics (default: config)")
    p.add_argument("--out", default="learner.pt", metavar="PT")

    p = sub.add_parser("evaluate", help="a trained policy alone, humans for hard resets only",
                       description="Run a trained policy for K steps with C-prioritised hard "
                       "resets only (seed 8.3.4); same records and report.")
    _common(p)
    p.add_argument("--policy", required=True, metavar="FILE")
    p.add_argument("--steps", type=_positive, default=250, metavar="K")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", metavar="DIR")
    p.add_argument("--humans", choices=["scripted", "gui", "web"])
    p.add_argument("--name")

    p = sub.add_parser("export", help="runs' frames as a LeRobot v3 dataset or numpy arrays",
                       description="Cut the runs' data stores into episodes (one arm, one "
                       "goal) with every label (who acted, intervention, success, "
                       "violation, uncertainty, risk) and theta_0's demonstrations, and "
                       "write them as a LeRobot v3 dataset or one npz.")
    p.add_argument("dirs", nargs="+", metavar="RUN_OR_PROTOCOL_DIR")
    p.add_argument("--format", choices=["lerobot", "npz"], default="lerobot",
                   help="lerobot (default; needs the export extra) or npz (numpy only)")
    p.add_argument("--out", required=True, metavar="DIR_OR_FILE",
                   help="lerobot: a new or empty folder; npz: a .npz file, or a folder "
                   "to hold frames.npz")
    p.add_argument("--images", choices=["png", "video"],
                   help="lerobot only: png (default: lossless, PNG bytes in the parquet) "
                   "or video (H.264 MP4, smaller for camera images, lossy)")

    p = sub.add_parser("train", help="pretrain a learner from exported data",
                       description="Pretrain policy and critics from exported datasets "
                       "(testbed export's npz or LeRobot folders, or run folders; several "
                       "are merged): the human-labelled frames and the demonstrations for "
                       "the policy, every push with its next frame for the critics; "
                       "write learner.pt (testbed evaluate --policy).")
    _common(p)
    p.add_argument("--data", required=True, nargs="+", metavar="DIR")
    p.add_argument("--steps", type=int,
                   help="gradient steps of each phase, policy and critics (default: config)")
    p.add_argument("--out", default="learner.pt", metavar="PT")
    return root


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    INTERRUPTS.install()
    from gui.errors import ConsoleUnavailable
    from testbed.cli.verbs import VERBS  # imported after parsing: keeps --help fast

    try:
        return VERBS[args.verb](args)
    except (ConfigError, ConsoleUnavailable) as exc:
        # ConsoleUnavailable: a DISPLAY that is set but that no X server answers, found
        # only when the console opens its windows (its message is one line with the fix).
        sys.stderr.write(f"testbed {args.verb}: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("testbed: interrupted; arms at rest, records closed\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
