"""The host agent: ``python -m drivers.agent --backend twin|yumi ...`` on the robot host.

Why a separate process speaking frames on stdin/stdout: the same program runs under an
SSH exec channel in the lab and under a local pipe in twin mode, so the controller has
one code path, and the robot host needs no open port and no daemon. stdout carries
ONLY frames: the agent duplicates fd 1 for its frames and points fd 1 (and
``sys.stdout``) at stderr before anything else is imported, because pybullet prints its
build time to fd 1 at import and a stray ``print`` would corrupt the stream.

Lifecycle::

    take the robot's lock (drivers.hostlock; a second agent for the same robot is refused
    and never builds its backend) -> start backend (errors kept for the hello reply)
    -> wait for hello (version check)
    -> serve observe / push / reset / rest / heartbeat / reseed / frame / move_tcp /
       save_calibration until bye, EOF, a broken frame, or no frame for --idle-timeout
       seconds (the controller or the link is dead)
    -> bye: arms to rest, then bye_ok; anything else: NO motion
    -> finally: backend closed, lock released

An orphaned agent never moves an arm: once its controller is gone (EOF, idle timeout,
broken pipe, broken frame) nobody is watching the cell, so it closes the backend
where the arms are. Arms rest only when asked (``rest``, ``bye``).

A backend exception answers that one request with an ``error`` frame carrying the arm
and the traceback; the agent keeps serving. A broken frame (bad magic, length, CRC,
truncation) cannot be resynchronised: the agent answers ``error`` (fatal) and exits.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import select
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

# Light imports only (numpy, json, zlib): nothing here prints to fd 1. The backends
# (pybullet!) are imported in main(), after claim_stdout().
from drivers import wire as p
from drivers.backends.base import ArmView
from drivers.errors import DeadlineExceeded, LinkClosed, ProtocolError
from drivers.hostlock import RobotBusy, RobotLock, default_lock_dir, lock_identity

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_PROTOCOL = 3
EXIT_VERSION = 4
EXIT_STARTUP = 5
EXIT_IDLE = 6
EXIT_LINK = 7

log = logging.getLogger("drivers.agent")


def claim_stdout() -> int:
    """Keep fd 1 for frames (returned dup) and send everything else printed to stderr."""
    frames_fd = os.dup(1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    return frames_fd


def fd_reader(fd: int) -> Callable[[int, float], bytes]:
    os.set_blocking(fd, False)

    def read(n: int, deadline: float) -> bytes:
        while True:
            try:
                return os.read(fd, n)  # a pipelined request is often there already
            except BlockingIOError:
                pass
            timeout = deadline - time.monotonic()
            if timeout <= 0:
                raise DeadlineExceeded("no frame from the controller in time")
            select.select([fd], [], [], timeout)

    return read


def fd_writer(fd: int, timeout_s: float) -> Callable[[bytes], None]:
    os.set_blocking(fd, False)

    def write(data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                n = 0
            view = view[n:]
            if view:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise BrokenPipeError("the controller stopped reading our replies")
                select.select([], [fd], [], left)

    return write


def serve(reader: p.FrameReader, write: Callable[[bytes], None],
          make_backend: Callable[[], HostBackend], *, idle_timeout_s: float = 120.0) -> int:
    """Serve one controller until bye/EOF/broken frame; returns the exit status.

    Never raises: every failure becomes an ``error`` frame and/or an exit status.
    """
    started = time.monotonic()
    backend: HostBackend | None = None
    startup_error: tuple[str, str] | None = None
    try:
        backend = make_backend()
    except Exception as exc:  # reported to the controller at hello
        what = str(exc) if isinstance(exc, RobotBusy) else f"{type(exc).__name__}: {exc}"
        startup_error = (what, traceback.format_exc())
        log.error("backend failed to start: %s", startup_error[0])
    greeted = False
    try:
        while True:
            try:
                frame = reader.read_frame(time.monotonic() + idle_timeout_s)
            except LinkClosed:
                log.info("the controller closed the stream; closing the backend without "
                         "moving the arms")
                return EXIT_OK
            except DeadlineExceeded:
                log.error("no frame from the controller in %.0f s; the controller or the "
                          "link is dead: exiting WITHOUT moving the arms", idle_timeout_s)
                return EXIT_IDLE
            except ProtocolError as exc:
                log.error("%s; exiting without moving the arms", exc)
                write(p.make_error(0, "protocol", str(exc), fatal=True))
                return EXIT_PROTOCOL
            mid = frame.id
            try:
                req = p.parse_request(frame, backend.arm_names if backend else None)
            except ProtocolError as exc:
                write(p.make_error(mid, "protocol", str(exc)))
                continue
            if req.type == "hello":
                if req.body["version"] != p.PROTOCOL_VERSION:
                    write(p.make_error(mid, "version", (
                        f"controller speaks protocol {req.body['version']}, this agent "
                        f"speaks {p.PROTOCOL_VERSION}; update the project on the host"),
                        fatal=True))
                    return EXIT_VERSION
                if backend is None:
                    assert startup_error is not None
                    write(p.make_error(mid, "startup", startup_error[0],
                                       traceback=startup_error[1], fatal=True))
                    return EXIT_STARTUP
                write(p.encode_frame({"type": "hello_ok", "id": mid,
                                      "version": p.PROTOCOL_VERSION, "backend": backend.kind,
                                      "arms": list(backend.arm_names),
                                      "mirror": [bool(m) for m in backend.mirror],
                                      "pid": os.getpid()}))
                greeted = True
                continue
            if not greeted or backend is None:
                write(p.make_error(mid, "protocol", f"{req.type!r} before hello"))
                continue
            if req.type == "bye":
                # Rest BEFORE bye_ok: the controller's close waits for it, so the arms are
                # out of the way when the agent is gone.
                log.info("bye: arms to rest, then exiting")
                try:
                    backend.rest()
                except Exception:
                    log.exception("rest at bye failed")
                write(p.encode_frame({"type": "bye_ok", "id": mid}))
                return EXIT_OK
            write(_dispatch(backend, req, started))
            prepare = getattr(backend, "prepare", None)
            if req.type in ("push", "reset") and prepare is not None:
                try:  # the next observation, while the controller is busy elsewhere
                    prepare()
                except Exception:  # observe will try again and report it
                    log.exception("preparing the next observation")
    except (BrokenPipeError, ConnectionError) as exc:
        log.error("cannot write to the controller: %s; exiting without moving the arms", exc)
        return EXIT_LINK
    finally:
        if backend is not None:
            try:
                backend.close()  # never rest here: an orphaned agent does not move
            except Exception:  # shutting down; say it and go on
                log.exception("closing the backend")


_CANNOT: dict[str, str] = {
    "reseed": "be reseeded", "frame": "take a full camera frame",
    "move_tcp": "move a TCP to a point", "save_calibration": "save a calibration"}


def _observe_reply(backend: HostBackend, mid: int) -> bytes:
    """Views for the arms that have one; the others' errors (that arm alone faults).

    A backend says an arm has no view by leaving it out, or by giving an exception or a
    :class:`~drivers.wire.ArmFailed` in its place."""
    got: dict[str, object] = dict(backend.observe())
    views: dict[str, ArmView] = {}
    errors: dict[str, str] = {}
    for arm in backend.arm_names:
        v = got.get(arm)
        if isinstance(v, ArmView):
            views[arm] = v
        elif isinstance(v, p.ArmFailed):
            errors[arm] = v.error
        elif isinstance(v, BaseException):
            errors[arm] = f"{type(v).__name__}: {v}"
        else:
            errors[arm] = f"the backend returned no view for arm {arm!r}"
    return p.make_observe_reply(mid, views, errors)


def _dispatch(backend: HostBackend, req: p.Request, started: float) -> bytes:
    try:
        if req.type == "observe":
            return _observe_reply(backend, req.id)
        if req.type == "push":
            return p.make_push_reply(req.id, backend.push(req.body["faces"]))
        if req.type == "reset":
            return p.make_reset_reply(req.id, backend.reset(req.body["arms"]))
        if req.type == "rest":
            backend.rest()
            return p.encode_frame({"type": "rest_ok", "id": req.id})
        if req.type == "heartbeat":
            return p.encode_frame({"type": "heartbeat_ok", "id": req.id,
                                   "uptime_s": round(time.monotonic() - started, 3)})
        if req.type == "reseed":
            backend.reseed(req.body["seed"])
            return p.encode_frame({"type": "reseed_ok", "id": req.id})
        if req.type == "frame":
            return p.make_frame_reply(req.id, backend.frame())
        if req.type == "move_tcp":
            tcp = backend.move_tcp(req.body["arm"], req.body["xyz_mm"])
            return p.encode_frame({"type": "move_tcp_ok", "id": req.id,
                                   "tcp": [float(v) for v in tcp]})
        if req.type == "save_calibration":
            path = backend.save_calibration(req.body["arm"], req.body["data"])
            return p.encode_frame({"type": "save_calibration_ok", "id": req.id,
                                   "path": str(path)})
        return p.make_error(req.id, "protocol", f"unhandled request {req.type!r}")
    except NotImplementedError as exc:
        what = _CANNOT.get(req.type, f"do {req.type!r}")
        return p.make_error(req.id, "request", f"this backend ({backend.kind}) cannot {what}"
                            f"{f': {exc}' if str(exc) else ''}", arm=req.body.get("arm"))
    except ValueError as exc:
        return p.make_error(req.id, "request", str(exc), traceback=traceback.format_exc(),
                            arm=getattr(exc, "arm", None))
    except Exception as exc:  # the controller decides; we keep serving
        log.exception("%s failed", req.type)
        return p.make_error(req.id, "backend", f"{type(exc).__name__}: {exc}",
                            traceback=traceback.format_exc(), arm=getattr(exc, "arm", None))


def _pairs(values: Sequence[str], flag: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for v in values:
        arm, sep, rest = v.partition("=")
        if not sep or not arm or not rest:
            raise SystemExit(f"{flag} expects ARM=VALUE, got {v!r}")
        out[arm] = rest
    return out


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m drivers.agent",
                                 description="Serve one robot host's arms on stdin/stdout.")
    ap.add_argument("--backend", choices=("twin", "yumi"), required=True)
    ap.add_argument("--host", default="host", help="host name, for messages")
    ap.add_argument("--arms", default="left,right")
    ap.add_argument("--mirror", default=None, help="0/1 per arm (default: right arms mirror)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-physics", action="store_true",
                    help="twin: canned images, no simulation (benchmarks)")
    ap.add_argument("--camera", default=None, help="yumi: device index or video file")
    ap.add_argument("--controller-url", default=None, help="yumi: RWS URL of the controller")
    ap.add_argument("--crop", action="append", default=[], metavar="ARM=x0,y0,x1,y1")
    ap.add_argument("--calibration", action="append", default=[], metavar="ARM=FILE")
    ap.add_argument("--calibrate", action="append", default=[], metavar="ARM",
                    help="yumi: this arm is being calibrated (provisional calibration; "
                         "frame, move_tcp, rest and save_calibration only); repeatable")
    ap.add_argument("--lock-dir", default=None,
                    help="directory of the per-robot lock files (default "
                         "${XDG_RUNTIME_DIR:-/tmp}/fleet-testbed-locks)")
    ap.add_argument("--lock-id", default=None,
                    help="lock this identity (default: yumi: the controller URL; twin: "
                         "no lock, every twin agent owns its own cell)")
    ap.add_argument("--idle-timeout", type=float, default=120.0,
                    help="exit (arms NOT moved) after this long without a frame")
    ap.add_argument("--chdir", default=None, help="working directory (the project checkout)")
    return ap.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    frames_fd = claim_stdout()
    args = parse_args(argv)
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING,
                        format=f"%(asctime)s agent[{args.host}] %(levelname)s %(message)s")
    log.setLevel(logging.INFO)  # our lifecycle lines (a few per session), not others
    if args.chdir:
        os.chdir(args.chdir)
    arms = [a for a in args.arms.split(",") if a]
    if args.mirror is None:
        mirror = [a.startswith("right") for a in arms]
    else:
        mirror = [m.strip() in ("1", "true") for m in args.mirror.split(",")]
    if len(mirror) != len(arms):
        print(f"--mirror needs one value per arm ({len(arms)})", file=sys.stderr)
        return EXIT_USAGE
    crops: dict[str, tuple[int, int, int, int]] = {}
    for arm, box in _pairs(args.crop, "--crop").items():
        try:
            x0, y0, x1, y1 = (int(v) for v in box.split(","))
        except ValueError:
            print(f"--crop {arm}=... needs four integers", file=sys.stderr)
            return EXIT_USAGE
        crops[arm] = (x0, y0, x1, y1)
    calibrations = _pairs(args.calibration, "--calibration")

    identity = lock_identity(args.backend, args.controller_url, args.lock_id)
    lock = (RobotLock(identity, args.lock_dir or default_lock_dir(), args.host)
            if identity else None)
    log.info("agent pid %d for host %s: backend %s, protocol %d", os.getpid(), args.host,
             args.backend, p.PROTOCOL_VERSION)

    def factory() -> HostBackend:
        if lock is not None:  # before anything touches the robot (refusal: at hello)
            lock.acquire()
            log.info("holding the lock of robot %s (%s)", lock.identity, lock.path)
        from drivers.backends import make_backend

        return make_backend(args.backend, arms=arms, mirror=mirror, seed=args.seed,
                            physics=not args.no_physics, crops=crops,
                            calibrations=calibrations, camera=args.camera,
                            controller_url=args.controller_url, calibrating=args.calibrate)

    reader = p.FrameReader(fd_reader(0), "controller")
    try:
        return serve(reader, fd_writer(frames_fd, max(10.0, args.idle_timeout)), factory,
                     idle_timeout_s=args.idle_timeout)
    finally:
        if lock is not None:
            lock.release()
        for fd in (0, frames_fd):  # leave a terminal as we found it
            with contextlib.suppress(OSError):
                os.set_blocking(fd, True)


if __name__ == "__main__":
    sys.exit(main())
