"""The frame format and the messages (drivers.wire, drivers.png)."""

from __future__ import annotations

import io
import json
import struct
import zlib

import cv2
import numpy as np
import pytest

from drivers import wire as p
from drivers.backends.base import ArmOutcome, ArmView
from drivers.errors import AgentError, DeadlineExceeded, LinkClosed, ProtocolError
from drivers.png import decode_png, encode_png


def reader_of(data: bytes, peer: str = "agent on host t") -> p.FrameReader:
    bio = io.BytesIO(data)
    return p.FrameReader(lambda n, deadline: bio.read(n), peer)


def raw_frame(header: bytes, body: bytes = b"", *, magic: bytes = p.MAGIC,
              hlen: int | None = None, blen: int | None = None, crc: int | None = None
              ) -> bytes:
    hlen = len(header) if hlen is None else hlen
    blen = len(body) if blen is None else blen
    crc = zlib.crc32(body, zlib.crc32(header)) if crc is None else crc
    return p.PREFIX.pack(magic, hlen, blen, crc) + header + body


def test_frame_round_trip_with_blobs() -> None:
    data = p.encode_frame({"type": "x", "id": 7, "k": [1, 2]}, [b"abc", b"", b"\x00" * 5])
    f = reader_of(data).read_frame(1e18)
    assert f.type == "x" and f.id == 7 and f.header["k"] == [1, 2]
    assert f.blobs == [b"abc", b"", b"\x00" * 5]


def test_eof_at_boundary_is_link_closed_and_inside_a_frame_is_truncation() -> None:
    with pytest.raises(LinkClosed):
        reader_of(b"").read_frame(1e18)
    data = p.make_request("observe", 1)
    with pytest.raises(ProtocolError, match=r"truncated frame .* after 20 of"):
        reader_of(data[:20]).read_frame(1e18)


@pytest.mark.parametrize(("frame", "match"), [
    (b"pybullet build time: Jan 29 2025\n" + p.make_request("observe", 1),
     "bad magic b'pybu.*something else writing to the agent's stdout"),
    (raw_frame(b'{"type":"x","id":1}', hlen=10**6), "header length 1000000"),
    (raw_frame(b'{"type":"x","id":1}', blen=p.MAX_FRAME_BYTES), "exceeds the limit"),
    (raw_frame(b'{"type":"x","id":1}', crc=1), "CRC mismatch"),
    (raw_frame(b'\xff\xfe{}'), "not UTF-8 JSON"),
    (raw_frame(b"[" * 30000 + b"]" * 30000), "not UTF-8 JSON"),
    (raw_frame(b"[1, 2]"), "header is a JSON list"),
    (raw_frame(b'{"id": 1}'), "no string 'type'"),
    (raw_frame(b'{"type": "x", "id": -1}'), "'id' must be a u32"),
    (raw_frame(b'{"type": "x", "id": true}'), "'id' must be a u32"),
    (raw_frame(b'{"type": "x", "id": 1, "blobs": [4]}', b"abc"), "blob sizes sum to 4"),
])
def test_every_framing_error_is_a_clear_protocol_error(frame: bytes, match: str) -> None:
    with pytest.raises(ProtocolError, match=match):
        reader_of(frame).read_frame(1e18)


def test_encode_frame_refuses_oversize_and_nan() -> None:
    with pytest.raises(ProtocolError, match="exceeds the limit"):
        p.encode_frame({"type": "x", "id": 1}, [b"\0" * p.MAX_FRAME_BYTES])
    with pytest.raises(ProtocolError, match="cannot encode"):
        p.encode_frame({"type": "x", "id": 1, "v": float("nan")})


def test_png_writer_is_standard_and_reader_takes_any_png() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    ours = encode_png(img)
    assert np.array_equal(cv2.imdecode(np.frombuffer(ours, np.uint8), cv2.IMREAD_COLOR),
                          img[..., ::-1])  # any decoder reads it
    assert np.array_equal(decode_png(ours, (64, 64, 3), "t"), img)
    ok, theirs = cv2.imencode(".png", img[..., ::-1])  # adaptive filters: fallback path
    assert ok and np.array_equal(decode_png(theirs.tobytes(), (64, 64, 3), "t"), img)
    back = decode_png(ours, (64, 64, 3), "t")
    back[0, 0] = 1  # the decoded array is the caller's to change


@pytest.mark.parametrize(("data", "match"), [
    (b"GIF89a" + b"\0" * 40, "not a PNG"),
    (encode_png(np.zeros((32, 32, 3), np.uint8)), "32x32"),
    (encode_png(np.zeros((64, 64, 3), np.uint8))[:60], "runs past the end|no IEND"),
])
def test_bad_images_name_the_arm(data: bytes, match: str) -> None:
    with pytest.raises(ProtocolError, match=f"arm 'left'.*({match})|({match})"):
        decode_png(data, (64, 64, 3), "arm 'left'")


def test_png_bomb_is_capped() -> None:
    raw = zlib.compress(b"\0" * (50 * 1024 * 1024))
    ihdr = struct.pack(">IIBBBBB", 64, 64, 8, 2, 0, 0, 0)

    def chunk(kind: bytes, d: bytes) -> bytes:
        return struct.pack(">I", len(d)) + kind + d + struct.pack(">I", zlib.crc32(kind + d))

    bomb = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", raw) + chunk(b"IEND", b"")
    with pytest.raises(ProtocolError):
        decode_png(bomb, (64, 64, 3), "arm 'left'")


def view(v: int = 0, violating: bool = False) -> ArmView:
    return ArmView(np.full((64, 64, 3), v, np.uint8), violating, (0.25, 0.75),
                   None if violating else 3)


def test_observe_reply_round_trip() -> None:
    frame = reader_of(p.make_observe_reply(5, {"left": view(1), "right": view(2, True)})
                      ).read_frame(1e18)
    views = p.parse_observe_reply(p.check_reply(frame, "observe_ok", 5, "a"),
                                  ["left", "right"], "a")
    assert views["left"].image[0, 0, 0] == 1 and views["left"].expert_action == 3
    assert views["right"].violating and views["right"].expert_action is None
    assert views["right"].goal == (0.25, 0.75)


def test_push_and_reset_replies_must_name_exactly_the_asked_arms() -> None:
    f = reader_of(p.make_push_reply(1, {"left": ArmOutcome(True, False)})).read_frame(1e18)
    assert p.parse_push_reply(f, ["left"], "a")["left"].success
    with pytest.raises(ProtocolError, match="names arms"):
        p.parse_push_reply(f, ["left", "right"], "a")
    f = reader_of(p.make_reset_reply(2, {"right": True})).read_frame(1e18)
    assert p.parse_reset_reply(f, ["right"], "a") == {"right": True}


def test_reply_checks_type_id_and_turns_error_frames_into_named_errors() -> None:
    f = reader_of(p.make_push_reply(4, {})).read_frame(1e18)
    with pytest.raises(ProtocolError, match="got 'push_ok', expected 'observe_ok'"):
        p.check_reply(f, "observe_ok", 4, "a")
    with pytest.raises(ProtocolError, match=r"out-of-order reply .* id 4, expected 5"):
        p.check_reply(f, "push_ok", 5, "a")
    err = reader_of(p.make_error(9, "backend", "camera gone", traceback="TB", arm="left")
                    ).read_frame(1e18)
    with pytest.raises(AgentError, match="backend error on arm 'left': camera gone") as ei:
        p.check_reply(err, "observe_ok", 9, "agent on host h")
    assert ei.value.arm == "left" and ei.value.remote_traceback == "TB"
    bad = reader_of(p.make_error(9, "protocol", "what is this")).read_frame(1e18)
    with pytest.raises(ProtocolError, match="rejected our 'observe_ok' frame"):
        p.check_reply(bad, "observe_ok", 9, "a")


@pytest.mark.parametrize(("header", "match"), [
    ({"type": "launch"}, "unknown request type"),
    ({"type": "push", "faces": {}}, "names no arm"),
    ({"type": "push", "faces": {"left": 4}}, "face must be an int in 0..3"),
    ({"type": "push", "faces": {"left": True}}, "face must be an int"),
    ({"type": "push", "faces": {"elbow": 1}}, "unknown arm 'elbow'"),
    ({"type": "reset", "arms": ["left", "left"]}, "distinct"),
    ({"type": "hello", "version": "1", "host": "h"}, "'version' must be int"),
])
def test_bad_requests_are_refused_with_the_reason(header: dict, match: str) -> None:
    f = reader_of(p.encode_frame({"id": 1, **header})).read_frame(1e18)
    with pytest.raises(ProtocolError, match=match):
        p.parse_request(f, ("left", "right"))


def test_header_is_compact_json() -> None:
    data = p.make_request("push", 3, faces={"left": 1})
    hlen = p.PREFIX.unpack(data[:16])[1]
    assert json.loads(data[16:16 + hlen]) == {"type": "push", "id": 3, "faces": {"left": 1},
                                              "blobs": []}


# ------------------------------------------------------------- version 3 additions
def test_protocol_version_is_3_with_stop_answered_at_once() -> None:
    assert p.PROTOCOL_VERSION == 3
    assert "stop" in p.REQUEST_TYPES and set(p.AT_ONCE) == {"heartbeat", "stop"}
    assert set(p.AT_ONCE_REPLIES) == {f"{t}_ok" for t in p.AT_ONCE}
    req = p.parse_request(reader_of(p.make_request("stop", 9)).read_frame(1e18), ("left",))
    assert req == p.Request("stop", 9, {})
    with pytest.raises(ProtocolError, match="carry no blobs"):
        p.parse_request(reader_of(p.encode_frame({"type": "stop", "id": 1}, [b"x"])
                                  ).read_frame(1e18), None)


def test_a_deadline_mid_frame_loses_nothing() -> None:
    """The agent waits in short slices: a deadline inside a frame (prefix read, body
    not yet) must leave the next read_frame to go on from the same bytes."""
    frames = p.make_request("push", 4, faces={"left": 1}) + p.make_request("stop", 5)
    pieces = [frames[:10], None, frames[10:20], None, frames[20:]]

    def read(n: int, deadline: float) -> bytes:
        if not pieces:
            return b""
        piece = pieces.pop(0)
        if piece is None:
            raise DeadlineExceeded("nothing yet")
        return piece

    r = p.FrameReader(read, "controller")
    for _ in range(2):
        with pytest.raises(DeadlineExceeded):
            r.read_frame(0.0)
    assert (r.read_frame(0.0).type, r.read_frame(0.0).type) == ("push", "stop")
    with pytest.raises(LinkClosed):
        r.read_frame(0.0)


# ------------------------------------------------------------- version 2 additions


def test_push_reply_carries_per_arm_refused_and_error_only_when_set() -> None:
    plain = p.make_push_reply(1, {"left": ArmOutcome(True, False)})
    assert b"refused" not in plain and b"error" not in plain  # v1-sized ordinary frames
    data = p.make_push_reply(1, {"left": ArmOutcome(False, False, refused="cube not found"),
                                 "right": ArmOutcome(False, False, error="planning failed")})
    out = p.parse_push_reply(reader_of(data).read_frame(1e18), ["left", "right"], "a")
    assert out["left"] == ArmOutcome(False, False, "cube not found", None)
    assert out["right"] == ArmOutcome(False, False, None, "planning failed")


@pytest.mark.parametrize(("result", "match"), [
    ({"success": False, "violation": False, "refused": ""}, "refused must be null or"),
    ({"success": False, "violation": False, "error": 3}, "error must be null or"),
    ({"success": False, "violation": False, "why": "x"}, "unknown keys"),
])
def test_bad_per_arm_reasons_are_protocol_errors(result: dict, match: str) -> None:
    f = reader_of(p.encode_frame({"type": "push_ok", "id": 1, "results": {"left": result}})
                  ).read_frame(1e18)
    with pytest.raises(ProtocolError, match=match):
        p.parse_push_reply(f, ["left"], "a")


def test_observe_reply_may_fault_one_arm_and_keep_the_other() -> None:
    data = p.make_observe_reply(3, {"left": view(7)}, {"right": "arm right is being calibrated"})
    views = p.parse_observe_reply(reader_of(data).read_frame(1e18), ["left", "right"], "a")
    assert isinstance(views["left"], ArmView) and views["left"].image[0, 0, 0] == 7
    assert views["right"] == p.ArmFailed("arm right is being calibrated")
    bad = p.encode_frame({"type": "observe_ok", "id": 1, "arms": [
        {"arm": "left", "error": "x", "violating": False}]})
    with pytest.raises(ProtocolError, match="carries nothing else"):
        p.parse_observe_reply(reader_of(bad).read_frame(1e18), ["left"], "a")


def test_frame_reply_is_a_lossless_bgr_png() -> None:
    img = np.random.default_rng(2).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    f = reader_of(p.make_frame_reply(4, img)).read_frame(1e18)
    back = p.parse_frame_reply(p.check_reply(f, "frame_ok", 4, "a"), "a")
    assert back.dtype == np.uint8 and np.array_equal(back, img)  # BGR in, BGR out
    with pytest.raises(ValueError, match="uint8 BGR"):
        p.make_frame_reply(1, np.zeros((4, 4), np.uint8))


@pytest.mark.parametrize(("blobs", "match"), [
    ([], "one PNG blob"),
    ([b"GIF89a" + b"\0" * 40], "not a PNG"),
    ([b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR"
      + struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0) + b"\0" * 8], "claims"),
])
def test_bad_frame_replies_are_refused(blobs: list[bytes], match: str) -> None:
    f = reader_of(p.encode_frame({"type": "frame_ok", "id": 1}, blobs)).read_frame(1e18)
    with pytest.raises(ProtocolError, match=match):
        p.parse_frame_reply(f, "a")


def test_move_tcp_and_save_calibration_replies() -> None:
    f = reader_of(p.encode_frame({"type": "move_tcp_ok", "id": 1, "tcp": [1, 2.5, 3]})
                  ).read_frame(1e18)
    assert p.parse_move_tcp_reply(f, "a") == (1.0, 2.5, 3.0)
    f = reader_of(p.encode_frame({"type": "move_tcp_ok", "id": 1, "tcp": [1, 2]})
                  ).read_frame(1e18)
    with pytest.raises(ProtocolError, match="'tcp' must be"):
        p.parse_move_tcp_reply(f, "a")
    f = reader_of(p.encode_frame({"type": "save_calibration_ok", "id": 1, "path": "/x.json"})
                  ).read_frame(1e18)
    assert p.parse_save_calibration_reply(f, "a") == "/x.json"


@pytest.mark.parametrize(("header", "body"), [
    ({"type": "reseed", "seed": 12}, {"seed": 12}),
    ({"type": "frame"}, {}),
    ({"type": "move_tcp", "arm": "left", "xyz_mm": [400, 100.5, 10]},
     {"arm": "left", "xyz_mm": (400.0, 100.5, 10.0)}),
    ({"type": "save_calibration", "arm": "right", "data": {"z_push_mm": 12}},
     {"arm": "right", "data": {"z_push_mm": 12}}),
])
def test_new_requests_parse(header: dict, body: dict) -> None:
    f = reader_of(p.encode_frame({"id": 1, **header})).read_frame(1e18)
    assert p.parse_request(f, ("left", "right")).body == body


@pytest.mark.parametrize(("header", "match"), [
    ({"type": "reseed"}, "'seed' must be int"),
    ({"type": "reseed", "seed": -1}, "'seed' must be in"),
    ({"type": "reseed", "seed": True}, "'seed' must be int"),
    ({"type": "move_tcp", "arm": "elbow", "xyz_mm": [1, 2, 3]}, "unknown arm 'elbow'"),
    ({"type": "move_tcp", "arm": "left", "xyz_mm": [1, 2]}, "'xyz_mm' must be"),
    ({"type": "move_tcp", "arm": "left", "xyz_mm": [1, 2, "3"]}, "'xyz_mm' must be"),
    ({"type": "move_tcp", "arm": "left", "xyz_mm": [1, 2, 1e999]}, "'xyz_mm' must be"),
    ({"type": "save_calibration", "arm": "left", "data": [1]}, "'data' must be dict"),
    ({"type": "save_calibration", "data": {}}, "'arm' must be str"),
])
def test_bad_new_requests_are_refused(header: dict, match: str) -> None:
    # json.dumps writes Infinity (a peer could send it; our encoder refuses to)
    f = reader_of(raw_frame(json.dumps({"id": 1, **header}).encode())).read_frame(1e18)
    with pytest.raises(ProtocolError, match=match):
        p.parse_request(f, ("left", "right"))


def test_every_arm_outcome_field_crosses_the_wire_and_reaches_the_step() -> None:
    """The start of the step-field checklist (docs/ARCHITECTURE.md, "A new field in every
    step"): a field added to ``ArmOutcome`` and forgotten in the wire's make or parse, or
    in ``PushResult``, fails here (``error`` makes the arm a fault, not a result)."""
    import dataclasses

    from testbed.core.types import PushResult
    from testbed.records.step_record import ArmStep

    assert [f.name for f in dataclasses.fields(ArmOutcome)] == [
        "success", "violation", "refused", "error", "readings"
    ], "a new field: give it a value below (a host's measurement is a reading, no field)"
    sent = {"left": ArmOutcome(True, False, readings={"push_s": 1.5, "force_n": 2}),
            "right": ArmOutcome(False, True, refused="no cube", error="stopped")}
    f = reader_of(p.make_push_reply(7, sent)).read_frame(1e18)
    assert p.parse_push_reply(f, ["left", "right"], "a") == sent
    carried = {f.name for f in dataclasses.fields(ArmOutcome)} - {"error"}
    assert carried <= {f.name for f in dataclasses.fields(PushResult)}
    assert carried <= {f.name for f in dataclasses.fields(ArmStep)}


# ------------------------------------------------------------- readings (host measurements)
PLAIN_PUSH_OK = (b'{"type":"push_ok","id":9,"results":{"left":{"success":true,'
                 b'"violation":false}},"blobs":[]}')
"""An ordinary push reply's header, as written before readings existed."""


def test_a_push_reply_without_readings_is_byte_for_byte_as_before() -> None:
    plain = p.make_push_reply(9, {"left": ArmOutcome(True, False)})
    assert plain == p.PREFIX.pack(p.MAGIC, len(PLAIN_PUSH_OK), 0, zlib.crc32(PLAIN_PUSH_OK)
                                  ) + PLAIN_PUSH_OK
    assert p.make_push_reply(9, {"left": ArmOutcome(True, False, readings={})}) == plain
    measured = p.make_push_reply(9, {"left": ArmOutcome(True, False, readings={"push_s": 2})})
    assert b'"readings":{"push_s":2.0}' in measured
    out = p.parse_push_reply(reader_of(measured).read_frame(1e18), ["left"], "a")
    assert out["left"].readings == {"push_s": 2.0}
    assert type(out["left"].readings["push_s"]) is float


@pytest.mark.parametrize(("readings", "match"), [
    ({"push_s": float("nan")}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({"push_s": float("inf")}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({"push_s": "1.5"}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({"push_s": True}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({"push_s": None}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({"push_s": [1.0]}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({"push_s": 10**400}, r"arm 'left' readings 'push_s' must be a finite number"),
    ({f"r{i}": 1.0 for i in range(p.MAX_READINGS + 1)},
     rf"arm 'left' readings has {p.MAX_READINGS + 1} names, at most {p.MAX_READINGS}"),
    ({"push s": 1.0}, r"arm 'left' readings name 'push s' is not an identifier"),
    ({"": 1.0}, r"arm 'left' readings name '' is not an identifier"),
    ({"9lives": 1.0}, r"arm 'left' readings name '9lives' is not an identifier"),
    ({"x" * (p.MAX_READING_NAME + 1): 1.0}, r"arm 'left' readings name 'x+' is not an"),
    ([1.0], r"arm 'left' readings must be an object of names to numbers"),
    (1.5, r"arm 'left' readings must be an object of names to numbers"),
])
def test_bad_readings_from_a_peer_are_a_protocol_error_naming_the_arm(
        readings: object, match: str) -> None:
    result = {"success": True, "violation": False, "readings": readings}
    # json.dumps writes NaN and Infinity (a peer could send them; our encoder refuses to)
    data = raw_frame(json.dumps({"type": "push_ok", "id": 1, "results": {
        "right": {"success": False, "violation": False}, "left": result}}).encode())
    with pytest.raises(ProtocolError, match=r"malformed 'push_ok' message from a: " + match):
        p.parse_push_reply(reader_of(data).read_frame(1e18), ["left", "right"], "a")


def test_an_agent_sends_a_backends_bad_readings_as_that_arms_error() -> None:
    """A backend's bug (a NaN duration) faults that arm alone, with the reason: the
    controller would refuse the reading, and the sibling's push still counts."""
    data = p.make_push_reply(3, {
        "left": ArmOutcome(True, False, readings={"push_s": float("nan")}),
        "right": ArmOutcome(True, False, readings={"push_s": np.float64(0.5)}),
        "third": ArmOutcome(False, False, error="IK failed", readings={"bad name": 1})})
    out = p.parse_push_reply(reader_of(data).read_frame(1e18), ["left", "right", "third"], "a")
    assert out["left"].error == ("the backend's readings of the push: 'push_s' must be a "
                                 "finite number, got nan")
    assert out["left"].readings == {}
    assert out["right"] == ArmOutcome(True, False, readings={"push_s": 0.5})
    assert out["third"] == ArmOutcome(False, False, error="IK failed")  # its own error first
