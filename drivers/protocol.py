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
    hello {version, host}                   hello_ok {version, backend, arms, mirror, pid}
    observe {}                              observe_ok {arms: [{arm, violating, goal,
                                                        expert_action, blob}]} + PNGs
    push {faces: {arm: face}}               push_ok {results: {arm: {success, violation}}}
    reset {arms: [arm]}                     reset_ok {results: {arm: {done}}}
    rest {}                                 rest_ok {}
    heartbeat {}                            heartbeat_ok {uptime_s}
    bye {}                                  bye_ok {}
                                            error {kind, message, traceback, arm, fatal}
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from drivers.backends.base import IMAGE_SHAPE, ArmOutcome, ArmView
from drivers.errors import AgentError, DeadlineExceeded, LinkClosed, ProtocolError, TruncatedFrame
from drivers.png import decode_png, encode_png
from testbed.types import NUM_ACTIONS

PROTOCOL_VERSION: Final = 1
MAGIC: Final = b"FDG1"
PREFIX: Final = struct.Struct(">4sIII")
PREFIX_BYTES: Final = PREFIX.size  # 16
MAX_HEADER_BYTES: Final = 64 * 1024
MAX_FRAME_BYTES: Final = 8 * 1024 * 1024
MAX_BLOBS: Final = 64
MAX_ID: Final = 2**32 - 1

REQUEST_TYPES: Final = ("hello", "observe", "push", "reset", "rest", "heartbeat", "bye")
ERROR_KINDS: Final = ("protocol", "version", "request", "backend", "startup")

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
    brings a whole frame); the protocol is strictly request/reply, so nothing is ever
    read ahead of the frame being waited for except by a misbehaving peer.
    """

    def __init__(self, read: ReadFn, peer: str) -> None:
        self._read = read
        self._buf = bytearray()
        self.peer = peer

    def _take(self, n: int, deadline: float, *, done: int = 0, total: int = PREFIX_BYTES
              ) -> bytes:
        buf = self._buf
        while len(buf) < n:
            chunk = self._read(max(n - len(buf), 65536), deadline)
            if not chunk:
                if done == 0 and not buf:
                    raise LinkClosed(f"{self.peer} closed the stream")
                raise TruncatedFrame(f"truncated frame from {self.peer}: the stream ended "
                                    f"after {done + len(buf)} of {total} bytes")
            buf += chunk
        out = bytes(buf[:n])
        del buf[:n]
        return out

    def read_frame(self, deadline: float) -> Frame:
        prefix = self._take(PREFIX_BYTES, deadline)
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
        rest = self._take(hlen + blen, deadline, done=PREFIX_BYTES,
                          total=PREFIX_BYTES + hlen + blen)
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
    return Request(mtype, frame.id, body)


# ---------------------------------------------------------------- agent -> controller
def make_error(mid: int, kind: str, message: str, *, traceback: str = "",
               arm: str | None = None, fatal: bool = False) -> bytes:
    return encode_frame({"type": "error", "id": mid, "kind": kind, "message": message[:4000],
                         "traceback": traceback[-12000:], "arm": arm, "fatal": fatal})


def make_observe_reply(mid: int, views: Mapping[str, ArmView]) -> bytes:
    arms: list[dict[str, Any]] = []
    blobs: list[bytes] = []
    for i, (arm, v) in enumerate(views.items()):
        arms.append({"arm": arm, "violating": bool(v.violating),
                     "goal": [float(v.goal[0]), float(v.goal[1])],
                     "expert_action": None if v.expert_action is None else int(v.expert_action),
                     "blob": i})
        blobs.append(v.png if v.png is not None else encode_image(v.image))
    return encode_frame({"type": "observe_ok", "id": mid, "arms": arms}, blobs)


def make_push_reply(mid: int, outcomes: Mapping[str, ArmOutcome]) -> bytes:
    return encode_frame({"type": "push_ok", "id": mid, "results": {
        a: {"success": bool(o.success), "violation": bool(o.violation)}
        for a, o in outcomes.items()}})


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
    return HelloInfo(version, backend, tuple(arms), tuple(mirror), pid)


def parse_observe_reply(frame: Frame, arms: Sequence[str], peer: str) -> dict[str, ArmView]:
    entries = _get(frame.header, "arms", list, peer)
    out: dict[str, ArmView] = {}
    for e in entries:
        if not isinstance(e, dict):
            raise _bad("observe_ok", peer, "each entry of 'arms' must be an object")
        arm = _get(e, "arm", str, peer, "observe_ok")
        if arm not in arms or arm in out:
            raise _bad("observe_ok", peer, f"unexpected or repeated arm {arm!r}")
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
        out[arm] = ArmOutcome(_bool(r.get("success"), "push_ok", peer, f"arm {arm!r} success"),
                              _bool(r.get("violation"), "push_ok", peer,
                                    f"arm {arm!r} violation"))
    return out


def parse_reset_reply(frame: Frame, reset: Sequence[str], peer: str) -> dict[str, bool]:
    results = _arm_map(frame.header, "results", reset, peer)
    out: dict[str, bool] = {}
    for arm, r in results.items():
        if not isinstance(r, dict):
            raise _bad("reset_ok", peer, f"arm {arm!r} result must be an object")
        out[arm] = _bool(r.get("done"), "reset_ok", peer, f"arm {arm!r} done")
    return out


__all__ = [
    "MAGIC", "MAX_FRAME_BYTES", "MAX_HEADER_BYTES", "PROTOCOL_VERSION", "AgentError",
    "DeadlineExceeded", "Frame", "FrameReader", "HelloInfo", "LinkClosed", "ProtocolError",
    "Request", "check_reply", "decode_image", "encode_frame", "encode_image", "make_error",
    "make_observe_reply", "make_push_reply", "make_request", "make_reset_reply",
    "parse_hello_reply", "parse_observe_reply", "parse_push_reply", "parse_request",
    "parse_reset_reply",
]
