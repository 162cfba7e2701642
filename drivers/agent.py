"""The host agent: ``python -m drivers.agent --backend twin|yumi ...`` on the robot host.

Why a separate process speaking frames on stdin/stdout: the same program runs under an
SSH exec channel in the lab and under a local pipe in twin mode, so the controller has
one code path, and the robot host needs no open port and no daemon. stdout carries
ONLY frames: the agent duplicates fd 1 for its frames and points fd 1 (and
``sys.stdout``) at stderr before anything else is imported, because pybullet prints its
build time to fd 1 at import and a stray ``print`` would corrupt the stream.

Lifecycle::

    start backend (errors kept for the hello reply) -> wait for hello (version check)
    -> serve observe / push / reset / rest / heartbeat until bye, EOF, a broken frame,
       or no frame for --idle-timeout seconds (the controller or the link is dead)
    -> finally: arms to rest, backend closed

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
from drivers import protocol as p
from drivers.errors import DeadlineExceeded, LinkClosed, ProtocolError

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
        startup_error = (f"{type(exc).__name__}: {exc}", traceback.format_exc())
        log.error("backend failed to start: %s", startup_error[0])
    greeted = False
    try:
        while True:
            try:
                frame = reader.read_frame(time.monotonic() + idle_timeout_s)
            except LinkClosed:
                return EXIT_OK
            except DeadlineExceeded:
                log.error("no frame from the controller in %.0f s; resting and exiting",
                          idle_timeout_s)
                return EXIT_IDLE
            except ProtocolError as exc:
                log.error("%s", exc)
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
                write(p.encode_frame({"type": "bye_ok", "id": mid}))
                return EXIT_OK
            write(_dispatch(backend, req, started))
    except (BrokenPipeError, ConnectionError) as exc:
        log.error("cannot write to the controller: %s", exc)
        return EXIT_LINK
    finally:
        if backend is not None:
            for step in (backend.rest, backend.close):
                try:
                    step()
                except Exception:  # shutting down; say it and go on
                    log.exception("during shutdown")


def _dispatch(backend: HostBackend, req: p.Request, started: float) -> bytes:
    try:
        if req.type == "observe":
            return p.make_observe_reply(req.id, backend.observe())
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
        return p.make_error(req.id, "protocol", f"unhandled request {req.type!r}")
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
    ap.add_argument("--idle-timeout", type=float, default=120.0,
                    help="exit (arms at rest) after this long without a frame")
    ap.add_argument("--chdir", default=None, help="working directory (the project checkout)")
    return ap.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    frames_fd = claim_stdout()
    args = parse_args(argv)
    logging.basicConfig(stream=sys.stderr, level=logging.WARNING,
                        format=f"agent[{args.host}] %(levelname)s %(message)s")
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

    from drivers.backends import make_backend

    def factory() -> HostBackend:
        return make_backend(args.backend, arms=arms, mirror=mirror, seed=args.seed,
                            physics=not args.no_physics, crops=crops,
                            calibrations=calibrations, camera=args.camera,
                            controller_url=args.controller_url)

    reader = p.FrameReader(fd_reader(0), "controller")
    try:
        return serve(reader, fd_writer(frames_fd, max(10.0, args.idle_timeout)), factory,
                     idle_timeout_s=args.idle_timeout)
    finally:
        for fd in (0, frames_fd):  # leave a terminal as we found it
            with contextlib.suppress(OSError):
                os.set_blocking(fd, True)


if __name__ == "__main__":
    sys.exit(main())
