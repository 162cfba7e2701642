"""The wire protocol between the controller and a host agent: frames and messages.

Why its own module: the same bytes travel over a local pipe and an SSH exec channel, and
both ends (``drivers.link`` in the controller's worker, ``drivers.agent`` on the robot
host) must agree on them exactly. Everything that can be wrong with a frame is checked
here and becomes a :class:`~drivers.errors.ProtocolError` with a message that says what
was expected and what came, so a stray ``print`` on the agent's stdout, a truncated
stream or a corrupted byte is a clear error, never a hang (every read has a deadline)
and never a crash.

Frame (all integers big-endian)::

    offset  size  field
    0       4     magic  b"FDG1"
    4       4     header_len   u32, 2 <= header_len <= MAX_HEADER_BYTES
    8       4     blobs_len    u32, header_len + blobs_len <= MAX_FRAME_BYTES
    12      4     crc32        u32, zlib.crc32(header + blobs)
    16      H     header: a UTF-8 JSON object {"type": str, "id": u32, "blobs": [u32...], ...}
    16+H    B     blobs: the binary attachments, concatenated; sum(header.blobs) == B

Messages (``type``; a reply echoes the request's ``id``; images are PNG blobs):

    controller -> agent                     agent -> controller
    hello {version, host}                   hello_ok {version, backend, arms, mirror, pid,
                                                      build [, controller]}
    observe {}                              observe_ok {arms: [{arm, violating, goal,
                                                        expert_action, blob} | {arm, error}]}
                                                        + PNGs
    push {faces: {arm: face}}               push_ok {results: {arm: {success, violation
                                                        [, refused] [, error]
                                                        [, readings: {name: number}]}}}
    reset {arms: [arm]}                     reset_ok {results: {arm: {done}}}
    rest {}                                 rest_ok {}
    heartbeat {}                            heartbeat_ok {uptime_s, busy}    (at once)
    stop {}                                 stop_ok {}                       (at once)
    reseed {seed}                           reseed_ok {}
    frame {}                                frame_ok {} + one PNG (the full BGR camera frame)
    move_tcp {arm, xyz_mm}                  move_tcp_ok {tcp: [x, y, z]}
    save_calibration {arm, data}            save_calibration_ok {path}
    describe {}                             describe_ok {info: {...}} (the controller's report)
    bye {}                                  bye_ok {} (after the arms are at rest, if
                                            the session asked anything that moves one)
                                            error {kind, message, traceback, arm, fatal}

The agent answers requests in order, one at a time (they may be pipelined), except the
two marked "at once": ``heartbeat`` and ``stop`` are answered as soon as they arrive,
even while another request (a motion of seconds) is in progress, so their replies may
overtake the reply of an earlier request. The controller matches replies by id and
skips a ``heartbeat_ok`` or ``stop_ok`` it is not waiting for. ``stop`` stops any motion
in progress now (``HostBackend.stop``); the interrupted request still gets its reply (an
error or its outcome). ``busy`` of ``heartbeat_ok``: the type of the request in progress,
or null.

Version 3 (this one) added ``stop``, ``describe`` and the answers at once: a version-2 agent reads
nothing while it runs a request, so it would queue a stop behind the very motion it
should stop (and fall silent for the length of every motion), so the versions must
match. Version 2 added the per-arm ``refused``/``error`` of push and observe replies and
the four requests reseed, frame, move_tcp, save_calibration (a version-1 peer would
misread a refused push as a plain failure).

``build`` of ``hello_ok`` (``drivers.build_id``): the exact code the agent runs; the
controller refuses a host whose build is not its own (``drivers.link``), before any arm
moves. It came without a version change on purpose: an older controller ignores the
field, and an older agent, which lacks it, is refused by a newer controller with the
line that says to deploy (an agent's version refusal would say less).

``readings`` of a ``push_ok`` arm (``ArmOutcome.readings``): what the host measured of
that arm's push, by name (``"push_s"``), written only when the backend measured
something, so an ordinary reply is byte for byte as before. One generic object, checked
here once (``reading_problem``: at most ``MAX_READINGS`` names, each an identifier of at
most ``MAX_READING_NAME`` characters, each value a finite number), so a new measurement
needs no edit of this module. It came without a version change: a controller talks only
to an agent of its own build (``build`` below), and the twin sends none.

``controller`` of ``hello_ok`` (a YuMi agent): its robot controller as it named itself
when the agent started, ``{serial, robotware, system}`` (only those it said; strings),
so a run records which controller drove its arms without a request of its own
(``HostFleet.hosts_info``). Optional, and without a version change for the same reason
as ``build``: an older controller ignores it, and its absence only means "not known"
(a twin, a controller that could not be asked, an agent from before it, which is
refused for its build anyway).

Over 450 lines, on purpose: both ends of the protocol must agree byte for byte, so every
message's make and parse sit side by side here: a field added to one is seen next to the
other.
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from drivers.backends.base import IMAGE_SHAPE, ArmOutcome, ArmView
from drivers.errors import AgentError, DeadlineExceeded, LinkClosed, ProtocolError, TruncatedFrame
from drivers.png import SIGNATURE as PNG_SIGNATURE
from drivers.png import decode_png, encode_png
from testbed.core.types import NUM_ACTIONS

PROTOCOL_VERSION: Final = 3
MAGIC: Final = b"FDG1"
PREFIX: Final = struct.Struct(">4sIII")
PREFIX_BYTES: Final = PREFIX.size  # 16
MAX_HEADER_BYTES: Final = 64 * 1024
MAX_FRAME_BYTES: Final = 8 * 1024 * 1024
MAX_BLOBS: Final = 64
MAX_ID: Final = 2**32 - 1

REQUEST_TYPES: Final = ("hello", "observe", "push", "reset", "rest", "heartbeat", "bye",
                        "reseed", "frame", "move_tcp", "save_calibration", "stop",
                        "describe")
AT_ONCE: Final = ("heartbeat", "stop")
"""Requests the agent answers as soon as they arrive, even during another request."""
AT_ONCE_REPLIES: Final = ("heartbeat_ok", "stop_ok")
"""Their replies: a reader skips one it is not waiting for (it may overtake others)."""
MAX_REASON_CHARS: Final = 2000
"""A per-arm ``refused``/``error`` text is cut to this (a reason, not a traceback)."""
MAX_FRAME_PIXELS: Final = 4096 * 4096
"""A camera frame PNG may not claim more pixels than this (a PNG bomb is refused)."""
ERROR_KINDS: Final = ("protocol", "version", "request", "backend", "startup")
CONTROLLER_KEYS: Final = ("serial", "robotware", "system")
"""What ``hello_ok.controller`` may say of the robot's controller (never a credential)."""
MAX_CONTROLLER_CHARS: Final = 200

MAX_READINGS: Final = 16
"""At most this many readings per arm's push (a host's measurements, not a log)."""
MAX_READING_NAME: Final = 40
"""A reading's name is an identifier of at most this many characters (``push_s``)."""
_READING_NAME: Final = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

_JSON: Final = json.JSONEncoder(separators=(",", ":"), allow_nan=False)

ReadFn = Callable[[int, float], bytes]
"""``read(n, deadline)``: up to ``n`` bytes (at least 1), ``b""`` at EOF; raises
DeadlineExceeded when ``time.monotonic()`` passes ``deadline``."""


@dataclass(slots=True)
class Frame:
    header: dict[str, Any]
    blobs: list[bytes] = field(default_factory=list)

    @property
    def type(self) -> str:
        return str(self.header["type"])

    @property
    def id(self) -> int:
        return int(self.header["id"])


# ---------------------------------------------------------------------------- framing
def encode_frame(header: Mapping[str, Any], blobs: Sequence[bytes] = ()) -> bytes:
    """Serialise one frame; raises ProtocolError if it would break the limits."""
    h = dict(header)
    h["blobs"] = [len(b) for b in blobs]
    try:
        hb = _JSON.encode(h).encode("utf-8")
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"cannot encode a {h.get('type')!r} header: {exc}") from None
    body = b"".join(blobs)
    if len(hb) > MAX_HEADER_BYTES or len(hb) + len(body) > MAX_FRAME_BYTES:
        raise ProtocolError(f"{h.get('type')!r} frame of {len(hb) + len(body)} bytes "
                            f"exceeds the limit ({MAX_FRAME_BYTES} bytes)")
    crc = zlib.crc32(body, zlib.crc32(hb))
    return b"".join((PREFIX.pack(MAGIC, len(hb), len(body), crc), hb, body))


def _preview(data: bytes) -> str:
    return repr(data[:24]) + ("..." if len(data) > 24 else "")


class FrameReader:
    """Reads whole frames from a byte source; every failure is a named error.

    ``peer`` names the other end in messages ("agent on host cell0", "controller").
    EOF exactly at a frame boundary is :class:`LinkClosed`; EOF inside a frame is a
    truncated frame (:class:`ProtocolError`). Reads are buffered (one read usually
    brings a whole frame, and a pipelined one may come with it). A deadline that passes
    mid-frame consumes nothing: the bytes already read stay in the buffer and the next
    ``read_frame`` goes on from them, so the agent can wait in short slices (to watch
    its worker) without ever losing a frame boundary.
    """

    def __init__(self, read: ReadFn, peer: str) -> None:
        self._read = read
        self._buf = bytearray()
        self.peer = peer

    def _fill(self, n: int, deadline: float, total: int) -> None:
        """At least ``n`` bytes in the buffer (``total``: the frame's size, for messages)."""
        buf = self._buf
        while len(buf) < n:
            chunk = self._read(max(n - len(buf), 65536), deadline)
            if not chunk:
                if not buf:
                    raise LinkClosed(f"{self.peer} closed the stream")
                raise TruncatedFrame(f"truncated frame from {self.peer}: the stream ended "
                                     f"after {len(buf)} of {total} bytes")
            buf += chunk

    def read_frame(self, deadline: float) -> Frame:
        self._fill(PREFIX_BYTES, deadline, PREFIX_BYTES)
        prefix = bytes(self._buf[:PREFIX_BYTES])
        magic, hlen, blen, crc = PREFIX.unpack(prefix)
        if magic != MAGIC:
            raise ProtocolError(
                f"malformed frame from {self.peer}: bad magic {_preview(prefix)} (expected "
                f"{MAGIC!r}); is something else writing to the agent's stdout?")
        if not 2 <= hlen <= MAX_HEADER_BYTES:
            raise ProtocolError(f"malformed frame from {self.peer}: header length {hlen} "
                                f"outside 2..{MAX_HEADER_BYTES}")
        if hlen + blen > MAX_FRAME_BYTES:
            raise ProtocolError(f"malformed frame from {self.peer}: {hlen + blen} bytes "
                                f"exceeds the limit of {MAX_FRAME_BYTES}")
        total = PREFIX_BYTES + hlen + blen
        self._fill(total, deadline, total)
        rest = bytes(self._buf[PREFIX_BYTES:total])
        del self._buf[:total]
        if zlib.crc32(rest) != crc:
            raise ProtocolError(f"corrupted frame from {self.peer}: CRC mismatch over "
                                f"{hlen + blen} bytes")
        return decode_body(rest[:hlen], rest[hlen:], self.peer)


def decode_body(hb: bytes, body: bytes, peer: str) -> Frame:
    """Parse header JSON and split the blobs; the framing checks are already done."""
    try:
        header = json.loads(hb.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ProtocolError(f"malformed frame from {peer}: header is not UTF-8 JSON "
                            f"({type(exc).__name__}: {str(exc)[:80]})") from None
    if not isinstance(header, dict):
        raise ProtocolError(f"malformed frame from {peer}: header is a JSON "
                            f"{type(header).__name__}, expected an object")
    mtype = header.get("type")
    if not isinstance(mtype, str) or not mtype:
        raise ProtocolError(f"malformed frame from {peer}: header has no string 'type'")
    mid = header.get("id")
    if type(mid) is not int or not 0 <= mid <= MAX_ID:
        raise ProtocolError(f"malformed {mtype!r} frame from {peer}: 'id' must be a u32, "
                            f"got {mid!r}")
    sizes = header.get("blobs", [])
    if (not isinstance(sizes, list) or len(sizes) > MAX_BLOBS
            or any(type(s) is not int or s < 0 for s in sizes)):
        raise ProtocolError(f"malformed {mtype!r} frame from {peer}: 'blobs' must be a list "
                            f"of at most {MAX_BLOBS} sizes")
    if sum(sizes) != len(body):
        raise ProtocolError(f"malformed {mtype!r} frame from {peer}: blob sizes sum to "
                            f"{sum(sizes)} but the body has {len(body)} bytes")
    blobs: list[bytes] = []
    off = 0
    for s in sizes:
        blobs.append(body[off:off + s])
        off += s
    return Frame(header, blobs)


# ----------------------------------------------------------------------------- images
def encode_image(image: npt.NDArray[np.uint8]) -> bytes:
    return encode_png(image)


def decode_image(data: bytes, what: str) -> npt.NDArray[np.uint8]:
    """A (64, 64, 3) RGB image from a PNG blob; ProtocolError for anything else."""
    return decode_png(data, IMAGE_SHAPE, what)


# --------------------------------------------------------------------- field checkers
def _bad(mtype: str, peer: str, msg: str) -> ProtocolError:
    return ProtocolError(f"malformed {mtype!r} message from {peer}: {msg}")


def _get(h: Mapping[str, Any], key: str, kind: type, peer: str, mtype: str | None = None
         ) -> Any:
    v = h.get(key)
    # bool is an int subclass: a JSON true is never a valid number here.
    ok = type(v) is int if kind is int else isinstance(v, kind)
    if not ok:
        raise _bad(mtype or str(h.get("type")), peer,
                   f"field {key!r} must be {kind.__name__}, got {v!r:.60}")
    return v


def _arm_map(h: Mapping[str, Any], key: str, expected: Sequence[str], peer: str) -> dict:
    m = _get(h, key, dict, peer)
    if set(m) != set(expected):
        raise _bad(str(h["type"]), peer, f"{key!r} names arms {sorted(m)}, expected "
                                         f"{sorted(expected)}")
    return m


def _bool(v: Any, mtype: str, peer: str, what: str) -> bool:
    if type(v) is not bool:
        raise _bad(mtype, peer, f"{what} must be true/false, got {v!r:.40}")
    return v


# ---------------------------------------------------------------- controller -> agent
@dataclass(frozen=True, slots=True)
class Request:
    type: str
    id: int
    body: dict[str, Any]


def make_request(mtype: str, mid: int, **fields: Any) -> bytes:
    return encode_frame({"type": mtype, "id": mid, **fields})


def parse_request(frame: Frame, arms: Sequence[str] | None, peer: str = "controller") -> Request:
    """Validate a request (agent side). ``arms``: the host's arms (None before hello)."""
    h = frame.header
    mtype = frame.type
    if mtype not in REQUEST_TYPES:
        raise _bad(mtype, peer, f"unknown request type; expected one of {REQUEST_TYPES}")
    if frame.blobs:
        raise _bad(mtype, peer, "requests carry no blobs")
    body: dict[str, Any] = {}
    if mtype == "hello":
        body["version"] = _get(h, "version", int, peer)
        body["host"] = _get(h, "host", str, peer)
    elif mtype == "push":
        faces = _get(h, "faces", dict, peer)
        if not faces:
            raise _bad(mtype, peer, "'faces' names no arm")
        for arm, face in faces.items():
            if arms is not None and arm not in arms:
                raise _bad(mtype, peer, f"unknown arm {arm!r}; this host has {list(arms)}")
            if type(face) is not int or not 0 <= face < NUM_ACTIONS:
                raise _bad(mtype, peer, f"arm {arm!r}: face must be an int in "
                                        f"0..{NUM_ACTIONS - 1}, got {face!r:.40}")
        body["faces"] = dict(faces)
    elif mtype == "reset":
        rarms = _get(h, "arms", list, peer)
        if not rarms or any(not isinstance(a, str) for a in rarms) or len(set(rarms)) != len(
                rarms):
            raise _bad(mtype, peer, "'arms' must be a non-empty list of distinct arm names")
        if arms is not None and (unknown := [a for a in rarms if a not in arms]):
            raise _bad(mtype, peer, f"unknown arm(s) {unknown}; this host has {list(arms)}")
        body["arms"] = list(rarms)
    elif mtype == "reseed":
        seed = _get(h, "seed", int, peer)
        if not 0 <= seed < 2**63:
            raise _bad(mtype, peer, f"'seed' must be in 0..2**63-1, got {seed}")
        body["seed"] = seed
    elif mtype in ("move_tcp", "save_calibration"):
        arm = _get(h, "arm", str, peer)
        if arms is not None and arm not in arms:
            raise _bad(mtype, peer, f"unknown arm {arm!r}; this host has {list(arms)}")
        body["arm"] = arm
        if mtype == "move_tcp":
            body["xyz_mm"] = _xyz(h.get("xyz_mm"), mtype, peer, "'xyz_mm'")
        else:
            body["data"] = _get(h, "data", dict, peer)
    return Request(mtype, frame.id, body)


def _xyz(v: Any, mtype: str, peer: str, what: str) -> tuple[float, float, float]:
    """Three finite numbers (a point in mm)."""
    if (not isinstance(v, list) or len(v) != 3
            or any(type(c) not in (int, float) or not math.isfinite(c) for c in v)):
        raise _bad(mtype, peer, f"{what} must be [x, y, z] finite numbers, got {v!r:.60}")
    return (float(v[0]), float(v[1]), float(v[2]))


def reading_problem(readings: object) -> str | None:
    """What is wrong with an arm's push ``readings``, or None when nothing is.

    Why one checker for both ends: the agent checks what its backend measured before it
    sends it and the controller checks what came, by the same rule (an object of at most
    ``MAX_READINGS`` names, each an identifier of at most ``MAX_READING_NAME``
    characters, each value a finite number; never a bool)."""
    if not isinstance(readings, Mapping):
        return f"must be an object of names to numbers, got {readings!r:.60}"
    if len(readings) > MAX_READINGS:
        return f"has {len(readings)} names, at most {MAX_READINGS} are allowed"
    for name, v in readings.items():
        if (not isinstance(name, str) or len(name) > MAX_READING_NAME
                or not _READING_NAME.fullmatch(name)):
            return (f"name {name!r:.60} is not an identifier of at most "
                    f"{MAX_READING_NAME} characters")
        if (isinstance(v, bool | np.bool_) or not isinstance(v, int | float | np.number)
                or not _finite(v)):
            return f"{name!r} must be a finite number, got {v!r:.40}"
    return None


def _finite(v: int | float | np.number) -> bool:
    """A number that is a finite float (an int of 400 digits is not: it overflows)."""
    try:
        return math.isfinite(float(v))
    except (OverflowError, TypeError, ValueError):
        return False


def _reason(v: Any, mtype: str, peer: str, what: str) -> str | None:
    """An optional per-arm text (null or a non-empty string)."""
    if v is None:
        return None
    if not isinstance(v, str) or not v:
        raise _bad(mtype, peer, f"{what} must be null or a non-empty string, got {v!r:.40}")
    return v[:MAX_REASON_CHARS]


# ---------------------------------------------------------------- agent -> controller
def make_error(mid: int, kind: str, message: str, *, traceback: str = "",
               arm: str | None = None, fatal: bool = False) -> bytes:
    return encode_frame({"type": "error", "id": mid, "kind": kind, "message": message[:4000],
                         "traceback": traceback[-12000:], "arm": arm, "fatal": fatal})


def make_observe_reply(mid: int, views: Mapping[str, ArmView],
                       errors: Mapping[str, str] | None = None) -> bytes:
    """``views``: the arms that have a view; ``errors``: arm -> why it has none (that arm
    alone is faulted by the controller)."""
    arms: list[dict[str, Any]] = []
    blobs: list[bytes] = []
    for arm, v in views.items():
        arms.append({"arm": arm, "violating": bool(v.violating),
                     "goal": [float(v.goal[0]), float(v.goal[1])],
                     "expert_action": None if v.expert_action is None else int(v.expert_action),
                     "blob": len(blobs)})
        blobs.append(v.png if v.png is not None else encode_image(v.image))
    for arm, why in (errors or {}).items():
        arms.append({"arm": arm, "error": (why or "failed")[:MAX_REASON_CHARS]})
    return encode_frame({"type": "observe_ok", "id": mid, "arms": arms}, blobs)


def make_push_reply(mid: int, outcomes: Mapping[str, ArmOutcome]) -> bytes:
    """Each arm's outcome. A backend's readings that the controller would refuse
    (``reading_problem``) make that arm's ``error`` instead: the arm alone faults, with
    the reason, and its siblings' outcomes still reach the controller."""
    results: dict[str, dict[str, Any]] = {
        a: {"success": bool(o.success), "violation": bool(o.violation)}
        for a, o in outcomes.items()}
    for a, o in outcomes.items():
        # Only when set: the frame of an ordinary push stays as in version 1.
        error = o.error
        if o.readings:
            if (why := reading_problem(o.readings)) is None:
                results[a]["readings"] = {str(k): float(v) for k, v in o.readings.items()}
            elif error is None:
                error = f"the backend's readings of the push: {why}"
        if o.refused is not None:
            results[a]["refused"] = str(o.refused)[:MAX_REASON_CHARS] or "refused"
        if error is not None:
            results[a]["error"] = str(error)[:MAX_REASON_CHARS] or "failed"
    return encode_frame({"type": "push_ok", "id": mid, "results": results})


def make_frame_reply(mid: int, image_bgr: npt.NDArray[np.uint8]) -> bytes:
    """The full camera frame, lossless: a PNG (OpenCV's, adaptive filters, fast level)."""
    import cv2

    img = np.asarray(image_bgr)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3 or 0 in img.shape:
        raise ValueError(f"a camera frame must be an (H, W, 3) uint8 BGR image, got "
                         f"{img.shape} {img.dtype}")
    if img.shape[0] * img.shape[1] > MAX_FRAME_PIXELS:
        raise ValueError(f"camera frame {img.shape[1]}x{img.shape[0]} exceeds "
                         f"{MAX_FRAME_PIXELS} pixels")
    ok, png = cv2.imencode(".png", np.ascontiguousarray(img), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("OpenCV could not encode the camera frame as PNG")
    return encode_frame({"type": "frame_ok", "id": mid}, [png.tobytes()])


def make_reset_reply(mid: int, done: Mapping[str, bool]) -> bytes:
    return encode_frame({"type": "reset_ok", "id": mid,
                         "results": {a: {"done": bool(d)} for a, d in done.items()}})


@dataclass(frozen=True, slots=True)
class HelloInfo:
    version: int
    backend: str
    arms: tuple[str, ...]
    mirror: tuple[bool, ...]
    pid: int
    build: str | None = None
    """The agent's build id (``drivers.build_id``); None from an agent before build ids."""
    controller: Mapping[str, str] | None = None
    """A YuMi's controller as it named itself (``CONTROLLER_KEYS``); None: not known."""


@dataclass(frozen=True, slots=True)
class ArmFailed:
    """One arm's entry of an observe reply when that arm alone has no view (e.g. its
    calibration is missing): the controller faults that arm, its siblings go on."""

    error: str


def check_reply(frame: Frame, expected_type: str, expected_id: int, peer: str) -> Frame:
    """Common reply checks; an ``error`` reply becomes AgentError or ProtocolError."""
    if frame.type == "error":
        h = frame.header
        kind = h.get("kind") if h.get("kind") in ERROR_KINDS else "backend"
        msg = str(h.get("message", ""))[:4000] or "(no message)"
        tb = h.get("traceback") if isinstance(h.get("traceback"), str) else ""
        arm = h.get("arm") if isinstance(h.get("arm"), str) else None
        fatal = h.get("fatal") is True
        if kind == "protocol":
            raise ProtocolError(f"{peer} rejected our {expected_type!r} frame: {msg}")
        raise AgentError(f"{peer}: {kind} error"
                         f"{f' on arm {arm!r}' if arm else ''}: {msg}", kind=kind, arm=arm,
                         remote_traceback=tb, fatal=fatal)
    if frame.type != expected_type:
        raise ProtocolError(f"unexpected reply from {peer}: got {frame.type!r}, expected "
                            f"{expected_type!r}")
    if frame.id != expected_id:
        raise ProtocolError(f"out-of-order reply from {peer}: {frame.type!r} has id "
                            f"{frame.id}, expected {expected_id}")
    return frame


def parse_hello_reply(frame: Frame, peer: str) -> HelloInfo:
    h = frame.header
    version = _get(h, "version", int, peer)
    backend = _get(h, "backend", str, peer)
    arms = _get(h, "arms", list, peer)
    mirror = _get(h, "mirror", list, peer)
    pid = _get(h, "pid", int, peer)
    if not arms or any(not isinstance(a, str) or not a for a in arms) or len(set(arms)) != len(
            arms):
        raise _bad("hello_ok", peer, "'arms' must be a non-empty list of distinct names")
    if len(mirror) != len(arms) or any(type(m) is not bool for m in mirror):
        raise _bad("hello_ok", peer, "'mirror' must be one true/false per arm")
    build = h.get("build")
    if build is not None and (not isinstance(build, str) or not build):
        raise _bad("hello_ok", peer, f"'build' must be a build id string, got {build!r:.60}")
    return HelloInfo(version, backend, tuple(arms), tuple(mirror), pid, build,
                     _controller(h.get("controller"), peer))


def _controller(v: Any, peer: str) -> dict[str, str] | None:
    """``hello_ok.controller``: null, or an object of some of ``CONTROLLER_KEYS`` with
    string values (each cut to ``MAX_CONTROLLER_CHARS``)."""
    if v is None:
        return None
    if (not isinstance(v, dict) or any(k not in CONTROLLER_KEYS or not isinstance(x, str)
                                       for k, x in v.items())):
        raise _bad("hello_ok", peer, f"'controller' must be null or an object of "
                                     f"{list(CONTROLLER_KEYS)} strings, got {v!r:.80}")
    return {k: v[k][:MAX_CONTROLLER_CHARS] for k in CONTROLLER_KEYS if k in v}


def parse_observe_reply(frame: Frame, arms: Sequence[str], peer: str
                        ) -> dict[str, ArmView | ArmFailed]:
    """A view, or an :class:`ArmFailed` (that arm's view is missing), for every arm."""
    entries = _get(frame.header, "arms", list, peer)
    out: dict[str, ArmView | ArmFailed] = {}
    for e in entries:
        if not isinstance(e, dict):
            raise _bad("observe_ok", peer, "each entry of 'arms' must be an object")
        arm = _get(e, "arm", str, peer, "observe_ok")
        if arm not in arms or arm in out:
            raise _bad("observe_ok", peer, f"unexpected or repeated arm {arm!r}")
        if "error" in e:
            if set(e) != {"arm", "error"}:
                raise _bad("observe_ok", peer, f"arm {arm!r}: an entry with 'error' carries "
                                               f"nothing else, got keys {sorted(e)}")
            why = _reason(e["error"], "observe_ok", peer, f"arm {arm!r} 'error'")
            if why is None:
                raise _bad("observe_ok", peer, f"arm {arm!r} 'error' must be a string")
            out[arm] = ArmFailed(why)
            continue
        violating = _bool(e.get("violating"), "observe_ok", peer, f"arm {arm!r} 'violating'")
        goal = e.get("goal")
        if (not isinstance(goal, list) or len(goal) != 2
                or any(type(g) not in (int, float) or not math.isfinite(g) or not 0 <= g <= 1
                       for g in goal)):
            raise _bad("observe_ok", peer, f"arm {arm!r} 'goal' must be [x, y] in [0, 1], "
                                           f"got {goal!r:.60}")
        ea = e.get("expert_action")
        if ea is not None and (type(ea) is not int or not 0 <= ea < NUM_ACTIONS):
            raise _bad("observe_ok", peer, f"arm {arm!r} 'expert_action' must be null or a "
                                           f"face, got {ea!r:.40}")
        bi = e.get("blob")
        if type(bi) is not int or not 0 <= bi < len(frame.blobs):
            raise _bad("observe_ok", peer, f"arm {arm!r} 'blob' must index one of the "
                                           f"{len(frame.blobs)} blobs, got {bi!r:.40}")
        image = decode_image(frame.blobs[bi], f"observe_ok from {peer}, arm {arm!r}")
        out[arm] = ArmView(image, violating, (float(goal[0]), float(goal[1])), ea)
    if set(out) != set(arms):
        raise _bad("observe_ok", peer, f"views for {sorted(out)}, expected {sorted(arms)}")
    return out


def parse_push_reply(frame: Frame, pushed: Sequence[str], peer: str) -> dict[str, ArmOutcome]:
    results = _arm_map(frame.header, "results", pushed, peer)
    out: dict[str, ArmOutcome] = {}
    for arm, r in results.items():
        if not isinstance(r, dict):
            raise _bad("push_ok", peer, f"arm {arm!r} result must be an object")
        success = r.get("success")
        violation = r.get("violation")
        if type(success) is not bool or type(violation) is not bool:
            _bool(success, "push_ok", peer, f"arm {arm!r} success")
            _bool(violation, "push_ok", peer, f"arm {arm!r} violation")
        if len(r) == 2:  # the ordinary case, checked above
            out[arm] = ArmOutcome(success, violation)
            continue
        if extra := set(r) - {"success", "violation", "refused", "error", "readings"}:
            raise _bad("push_ok", peer, f"arm {arm!r} result has unknown keys {sorted(extra)}")
        readings = r.get("readings", {})
        if (why := reading_problem(readings)) is not None:
            raise _bad("push_ok", peer, f"arm {arm!r} readings {why}")
        out[arm] = ArmOutcome(success, violation,
                              _reason(r.get("refused"), "push_ok", peer, f"arm {arm!r} refused"),
                              _reason(r.get("error"), "push_ok", peer, f"arm {arm!r} error"),
                              {k: float(v) for k, v in readings.items()})
    return out


def parse_reset_reply(frame: Frame, reset: Sequence[str], peer: str) -> dict[str, bool]:
    results = _arm_map(frame.header, "results", reset, peer)
    out: dict[str, bool] = {}
    for arm, r in results.items():
        if not isinstance(r, dict):
            raise _bad("reset_ok", peer, f"arm {arm!r} result must be an object")
        out[arm] = _bool(r.get("done"), "reset_ok", peer, f"arm {arm!r} done")
    return out


def parse_frame_reply(frame: Frame, peer: str) -> npt.NDArray[np.uint8]:
    """The camera frame (H, W, 3) uint8 BGR from a ``frame_ok``; checked before decoding
    (PNG signature, 8-bit RGB, at most MAX_FRAME_PIXELS)."""
    if len(frame.blobs) != 1:
        raise _bad("frame_ok", peer, f"expected one PNG blob, got {len(frame.blobs)}")
    data = frame.blobs[0]
    what = f"frame_ok from {peer}"
    if len(data) < 33 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise ProtocolError(f"{what}: not a PNG image ({len(data)} bytes)")
    width, height = struct.unpack(">II", data[16:24])
    if width == 0 or height == 0 or width * height > MAX_FRAME_PIXELS:
        raise ProtocolError(f"{what}: PNG claims {width}x{height} pixels; at most "
                            f"{MAX_FRAME_PIXELS} are accepted")
    rgb = decode_png(data, (height, width, 3), what)
    return np.ascontiguousarray(rgb[..., ::-1])


def parse_move_tcp_reply(frame: Frame, peer: str) -> tuple[float, float, float]:
    return _xyz(frame.header.get("tcp"), "move_tcp_ok", peer, "'tcp'")


def parse_describe_reply(frame: Frame, peer: str) -> dict[str, Any]:
    info: dict[str, Any] = _get(frame.header, "info", dict, peer)
    return info


def parse_save_calibration_reply(frame: Frame, peer: str) -> str:
    path = _get(frame.header, "path", str, peer)
    if not path:
        raise _bad("save_calibration_ok", peer, "'path' is empty")
    return path


__all__ = [
    "AT_ONCE", "AT_ONCE_REPLIES", "MAGIC", "MAX_FRAME_BYTES", "MAX_HEADER_BYTES",
    "MAX_READINGS", "MAX_READING_NAME", "PROTOCOL_VERSION", "AgentError",
    "ArmFailed", "DeadlineExceeded", "Frame", "FrameReader", "HelloInfo", "LinkClosed",
    "ProtocolError", "Request", "check_reply", "decode_image", "encode_frame", "encode_image",
    "make_error", "make_frame_reply", "make_observe_reply", "make_push_reply", "make_request",
    "make_reset_reply", "parse_describe_reply", "parse_frame_reply", "parse_hello_reply",
    "parse_move_tcp_reply", "parse_observe_reply", "parse_push_reply", "parse_request",
    "parse_reset_reply", "parse_save_calibration_reply", "reading_problem",
]
