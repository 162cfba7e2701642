"""The wire's edges that scripts/mutation.sh found untested (docs/notes/tests.md).

Why: a host's agent obeys what ``drivers.wire.parse_request`` lets through and the
controller believes what ``check_reply`` and the framing let through; a mutation run
changed limits, messages and defaults there that no test noticed. Each expected value
here comes from the protocol as the module's docstring defines it (the frame layout, the
limits, the messages' fields and their ranges), and each refusal is checked with the
exact message the peer receives, since that message is what an operator reads. Fast:
no agent, no twin, no sshd (the mutation run repeats these once per mutant).
"""

from __future__ import annotations

import json
import struct
import zlib
from typing import Any

import pytest

from drivers import wire as p
from drivers.errors import AgentError, DeadlineExceeded, LinkClosed, ProtocolError, TruncatedFrame

ARMS = ("left", "right")


def raw(header: bytes, body: bytes = b"", *, hlen: int | None = None,
        blen: int | None = None, crc: int | None = None) -> bytes:
    """A frame laid out by hand from the docstring's table (not by ``encode_frame``)."""
    hlen = len(header) if hlen is None else hlen
    blen = len(body) if blen is None else blen
    crc = zlib.crc32(header + body) if crc is None else crc
    return b"FDG1" + struct.pack(">III", hlen, blen, crc) + header + body


def frame_of(header: dict[str, Any], blobs: list[bytes] | None = None) -> p.Frame:
    """A frame as the agent's reader gives it: through the real framing."""
    h = dict(header)
    if blobs is not None:
        h["blobs"] = [len(b) for b in blobs]
    data = raw(json.dumps(h).encode(), b"".join(blobs or []))
    return reader(data).read_frame(1e18)


def reader(data: bytes, peer: str = "agent on host t", step: int | None = None,
           asked: list[int] | None = None) -> p.FrameReader:
    """A reader over ``data``, giving at most ``step`` bytes per read (all it is asked
    for when None); ``asked`` collects the sizes asked for."""
    pos = 0

    def read(n: int, deadline: float) -> bytes:
        nonlocal pos
        if asked is not None:
            asked.append(n)
        k = n if step is None else min(n, step)
        out = data[pos:pos + k]
        pos += len(out)
        return out

    return p.FrameReader(read, peer)


def refusal(header: dict[str, Any], arms: tuple[str, ...] | None = ARMS,
            blobs: list[bytes] | None = None) -> str:
    """The message the agent refuses a request with (its peer: "controller" by default;
    the same refusal naming another peer is checked too)."""
    frame = frame_of({"id": 1, **header}, blobs)
    with pytest.raises(ProtocolError) as ei:
        p.parse_request(frame, arms)
    with pytest.raises(ProtocolError) as named:
        p.parse_request(frame, arms, peer="ctl on x")
    why = str(ei.value)
    assert why.startswith(f"malformed {header['type']!r} message from controller: ")
    assert str(named.value) == why.replace(" from controller: ", " from ctl on x: ", 1)
    return why


def parsed(header: dict[str, Any], arms: tuple[str, ...] | None = ARMS) -> p.Request:
    return p.parse_request(frame_of({"id": 1, **header}), arms)


# ------------------------------------------------------------------- parse_request
@pytest.mark.parametrize("mtype", ["observe", "rest", "heartbeat", "bye", "frame", "stop",
                                   "describe"])
def test_every_request_without_fields_parses_to_an_empty_body(mtype: str) -> None:
    req = p.parse_request(frame_of({"type": mtype, "id": 77}), ARMS)
    assert req == p.Request(mtype, 77, {})


def test_hello_carries_version_and_host_and_needs_no_arms_yet() -> None:
    req = parsed({"type": "hello", "version": 3, "host": "cell0"}, arms=None)
    assert req == p.Request("hello", 1, {"version": 3, "host": "cell0"})


@pytest.mark.parametrize(("header", "why"), [
    ({"type": "hello", "version": "3", "host": "h"}, "field 'version' must be int, got '3'"),
    ({"type": "hello", "version": True, "host": "h"}, "field 'version' must be int, got True"),
    ({"type": "hello", "version": 3}, "field 'host' must be str, got None"),
    ({"type": "hello", "version": 3, "host": 5}, "field 'host' must be str, got 5"),
])
def test_a_bad_hello_is_refused_naming_the_field(header: dict[str, Any], why: str) -> None:
    assert refusal(header, None) == f"malformed 'hello' message from controller: {why}"


def test_a_field_of_the_wrong_kind_shows_at_most_60_characters_of_it() -> None:
    why = refusal({"type": "hello", "version": 3, "host": ["x" * 100]}, None)
    shown = repr(["x" * 100])[:60]
    assert why == ("malformed 'hello' message from controller: field 'host' must be str, "
                   f"got {shown}")


def test_an_unknown_request_type_is_refused_with_the_known_ones() -> None:
    known = ("hello", "observe", "push", "reset", "rest", "heartbeat", "bye", "reseed",
             "frame", "move_tcp", "save_calibration", "stop", "describe")
    assert refusal({"type": "launch"}) == (
        f"malformed 'launch' message from controller: unknown request type; expected one "
        f"of {known}")
    # a reply type is not a request either
    assert "unknown request type" in refusal({"type": "observe_ok"})


def test_a_request_with_a_blob_is_refused_even_an_empty_one() -> None:
    assert refusal({"type": "observe"}, blobs=[b""]) == (
        "malformed 'observe' message from controller: requests carry no blobs")
    assert refusal({"type": "push", "faces": {"left": 1}}, blobs=[b"x"]).endswith(
        "requests carry no blobs")


@pytest.mark.parametrize("face", [0, 1, 2, 3])
def test_every_face_of_the_four_is_obeyed(face: int) -> None:
    assert parsed({"type": "push", "faces": {"left": face}}).body == {"faces": {"left": face}}


def test_a_push_of_both_arms_keeps_both_faces_in_a_copy() -> None:
    f = frame_of({"type": "push", "id": 9, "faces": {"left": 0, "right": 3}})
    req = p.parse_request(f, ARMS)
    assert req == p.Request("push", 9, {"faces": {"left": 0, "right": 3}})
    f.header["faces"]["left"] = 2  # the frame is not the request
    assert req.body["faces"] == {"left": 0, "right": 3}


@pytest.mark.parametrize(("faces", "why"), [
    ({"left": 4}, "arm 'left': face must be an int in 0..3, got 4"),
    ({"left": -1}, "arm 'left': face must be an int in 0..3, got -1"),
    ({"left": True}, "arm 'left': face must be an int in 0..3, got True"),
    ({"left": 1.0}, "arm 'left': face must be an int in 0..3, got 1.0"),
    ({"left": None}, "arm 'left': face must be an int in 0..3, got None"),
    ({"left": 1, "right": 7}, "arm 'right': face must be an int in 0..3, got 7"),
    ({"left": "x" * 50}, "arm 'left': face must be an int in 0..3, got " + repr("x" * 50)[:40]),
    ({}, "'faces' names no arm"),
    ({"elbow": 1}, "unknown arm 'elbow'; this host has ['left', 'right']"),
    ({"left": 1, "elbow": 1}, "unknown arm 'elbow'; this host has ['left', 'right']"),
])
def test_a_bad_push_is_refused_with_the_reason(faces: dict[str, Any], why: str) -> None:
    assert refusal({"type": "push", "faces": faces}) == (
        f"malformed 'push' message from controller: {why}")


def test_a_push_whose_faces_is_not_an_object_is_refused() -> None:
    assert refusal({"type": "push", "faces": [1]}) == (
        "malformed 'push' message from controller: field 'faces' must be dict, got [1]")


def test_before_hello_any_arm_name_is_taken_but_the_face_is_still_checked() -> None:
    assert parsed({"type": "push", "faces": {"elbow": 2}}, None).body == {"faces": {"elbow": 2}}
    assert refusal({"type": "push", "faces": {"elbow": 4}}, None).endswith(
        "arm 'elbow': face must be an int in 0..3, got 4")
    assert parsed({"type": "reset", "arms": ["elbow"]}, None).body == {"arms": ["elbow"]}
    assert parsed({"type": "move_tcp", "arm": "elbow", "xyz_mm": [1, 2, 3]}, None).body == {
        "arm": "elbow", "xyz_mm": (1.0, 2.0, 3.0)}
    assert parsed({"type": "save_calibration", "arm": "elbow", "data": {}}, None).body == {
        "arm": "elbow", "data": {}}


def test_a_reset_names_its_arms_in_order() -> None:
    assert parsed({"type": "reset", "arms": ["right", "left"]}) == p.Request(
        "reset", 1, {"arms": ["right", "left"]})
    assert parsed({"type": "reset", "arms": ["left"]}).body == {"arms": ["left"]}


@pytest.mark.parametrize(("rarms", "why"), [
    ([], "'arms' must be a non-empty list of distinct arm names"),
    (["left", "left"], "'arms' must be a non-empty list of distinct arm names"),
    (["left", 1], "'arms' must be a non-empty list of distinct arm names"),
    ([1], "'arms' must be a non-empty list of distinct arm names"),
    ("left", "field 'arms' must be list, got 'left'"),
    (["elbow"], "unknown arm(s) ['elbow']; this host has ['left', 'right']"),
    (["left", "knee", "elbow"], "unknown arm(s) ['knee', 'elbow']; this host has "
                                "['left', 'right']"),
])
def test_a_bad_reset_is_refused_with_the_reason(rarms: Any, why: str) -> None:
    assert refusal({"type": "reset", "arms": rarms}) == (
        f"malformed 'reset' message from controller: {why}")


@pytest.mark.parametrize("seed", [0, 1, 2**63 - 1])
def test_every_seed_of_0_to_2_63_minus_1_is_taken(seed: int) -> None:
    assert parsed({"type": "reseed", "seed": seed}) == p.Request("reseed", 1, {"seed": seed})


@pytest.mark.parametrize(("seed", "why"), [
    (2**63, f"'seed' must be in 0..2**63-1, got {2**63}"),
    (-1, "'seed' must be in 0..2**63-1, got -1"),
    (1.0, "field 'seed' must be int, got 1.0"),
])
def test_a_seed_out_of_range_is_refused(seed: Any, why: str) -> None:
    assert refusal({"type": "reseed", "seed": seed}) == (
        f"malformed 'reseed' message from controller: {why}")


def test_move_tcp_and_save_calibration_name_one_known_arm() -> None:
    assert parsed({"type": "move_tcp", "arm": "right", "xyz_mm": [1, -2.5, 0]}) == p.Request(
        "move_tcp", 1, {"arm": "right", "xyz_mm": (1.0, -2.5, 0.0)})
    xyz = parsed({"type": "move_tcp", "arm": "left", "xyz_mm": [1, 2, 3]}).body["xyz_mm"]
    assert all(type(c) is float for c in xyz)
    assert parsed({"type": "save_calibration", "arm": "left", "data": {"a": [1]}}) == (
        p.Request("save_calibration", 1, {"arm": "left", "data": {"a": [1]}}))
    for mtype in ("move_tcp", "save_calibration"):
        assert refusal({"type": mtype, "arm": "elbow", "xyz_mm": [1, 2, 3], "data": {}}) == (
            f"malformed {mtype!r} message from controller: unknown arm 'elbow'; this host "
            f"has ['left', 'right']")
        assert refusal({"type": mtype, "arm": 1}) == (
            f"malformed {mtype!r} message from controller: field 'arm' must be str, got 1")


@pytest.mark.parametrize(("xyz", "shown"), [
    ([1, 2], "[1, 2]"), ([1, 2, 3, 4], "[1, 2, 3, 4]"), ([1, 2, True], "[1, 2, True]"),
    ([1, 2, "3"], "[1, 2, '3']"), (None, "None"), ({"x": 1}, "{'x': 1}"),
    ([1, 2, float("nan")], "[1, 2, nan]"), ([float("-inf"), 2, 3], "[-inf, 2, 3]"),
    ([0.5] * 30, repr([0.5] * 30)[:60]),
])
def test_a_bad_point_is_refused_and_shown(xyz: Any, shown: str) -> None:
    header = {"type": "move_tcp", "id": 1, "arm": "left"}
    if xyz is not None:
        header["xyz_mm"] = xyz
    # json.dumps writes NaN and Infinity: a peer could send them (our encoder refuses to)
    f = reader(raw(json.dumps(header).encode())).read_frame(1e18)
    with pytest.raises(ProtocolError) as ei:
        p.parse_request(f, ARMS)
    assert str(ei.value) == ("malformed 'move_tcp' message from controller: 'xyz_mm' must be "
                             f"[x, y, z] finite numbers, got {shown}")


def test_save_calibration_data_must_be_an_object() -> None:
    assert refusal({"type": "save_calibration", "arm": "left", "data": [1]}) == (
        "malformed 'save_calibration' message from controller: field 'data' must be dict, "
        "got [1]")


# ------------------------------------------------------------------------- framing
FRAME = raw(b'{"type":"observe","id":5}')


def test_a_frame_split_at_every_byte_is_read_whole() -> None:
    data = raw(b'{"type":"x","id":3,"blobs":[2,0,3]}', b"abcde")
    two = data + FRAME
    f = reader(two, step=1)
    first, second = f.read_frame(1e18), f.read_frame(1e18)
    assert (first.type, first.id, first.blobs) == ("x", 3, [b"ab", b"", b"cde"])
    assert (second.type, second.id, second.blobs) == ("observe", 5, [])
    with pytest.raises(LinkClosed):
        f.read_frame(1e18)
    for cut in range(1, len(data)):
        chunks = [data[:cut], data[cut:]]

        def read(n: int, deadline: float, chunks: list[bytes] = chunks) -> bytes:
            return chunks.pop(0) if chunks else b""

        got = p.FrameReader(read, "a").read_frame(1e18)
        assert got.blobs == [b"ab", b"", b"cde"], cut


def test_the_stream_ending_inside_a_frame_says_where() -> None:
    for cut in range(1, len(FRAME)):
        total = 16 if cut < 16 else len(FRAME)
        with pytest.raises(TruncatedFrame) as ei:
            reader(FRAME[:cut], peer="agent on host c", step=3).read_frame(1e18)
        assert str(ei.value) == (f"truncated frame from agent on host c: the stream ended "
                                 f"after {cut} of {total} bytes"), cut


def test_the_stream_ending_between_frames_is_a_closed_link_naming_the_peer() -> None:
    f = reader(FRAME, peer="agent on host c")
    assert f.read_frame(1e18).id == 5
    with pytest.raises(LinkClosed) as ei:
        f.read_frame(1e18)
    assert str(ei.value) == "agent on host c closed the stream"
    assert not isinstance(ei.value, ProtocolError)


def test_pipelined_frames_come_with_one_read() -> None:
    """The docstring's "one read usually brings a whole frame, and a pipelined one may
    come with it": the reader asks for more than the bytes it lacks."""
    asked: list[int] = []
    f = reader(FRAME * 3, asked=asked)
    assert [f.read_frame(1e18).id for _ in range(3)] == [5, 5, 5]
    assert len(asked) == 1 and asked[0] > 3 * len(FRAME)


def test_a_frame_larger_than_one_read_asks_for_what_it_lacks() -> None:
    body = bytes(range(256)) * 1024  # 256 KiB
    data = raw(b'{"type":"x","id":1,"blobs":[262144]}', body)
    asked: list[int] = []
    got = reader(data, asked=asked).read_frame(1e18)
    assert got.blobs == [body]
    assert len(asked) == 2 and asked[1] == len(data) - asked[0]


def test_a_deadline_in_the_prefix_loses_no_byte() -> None:
    parts = [FRAME[:7], None, FRAME[7:]]
    deadlines: list[float] = []

    def read(n: int, deadline: float) -> bytes:
        deadlines.append(deadline)
        part = parts.pop(0)
        if part is None:
            raise DeadlineExceeded("slice over")
        return part

    f = p.FrameReader(read, "a")
    with pytest.raises(DeadlineExceeded):
        f.read_frame(1.0)
    assert f.read_frame(2.0).id == 5
    assert deadlines == [1.0, 1.0, 2.0]  # every read is bounded by the frame's deadline


@pytest.mark.parametrize(("data", "why"), [
    (b"FDG2" + FRAME[4:], f"malformed frame from P: bad magic {b'FDG2' + FRAME[4:16]!r} "
                          "(expected b'FDG1'); is something else writing to the agent's stdout?"),
    (raw(b"{}", hlen=1), "malformed frame from P: header length 1 outside 2..65536"),
    (raw(b"{}", hlen=0), "malformed frame from P: header length 0 outside 2..65536"),
    (raw(b"{}", hlen=65537), "malformed frame from P: header length 65537 outside 2..65536"),
    (raw(b"{}", blen=8 * 1024 * 1024 - 1),
     "malformed frame from P: 8388609 bytes exceeds the limit of 8388608"),
    (raw(b'{"type":"x","id":1}', crc=0),
     "corrupted frame from P: CRC mismatch over 19 bytes"),
])
def test_a_bad_prefix_is_refused_with_the_reason(data: bytes, why: str) -> None:
    with pytest.raises(ProtocolError) as ei:
        reader(data, peer="P").read_frame(1e18)
    assert str(ei.value) == why


def test_the_bad_magic_preview_is_24_bytes_and_marks_the_cut() -> None:
    junk = b"pybullet build time: Jan 29 2025\n" + FRAME
    with pytest.raises(ProtocolError) as ei:
        reader(junk, peer="P").read_frame(1e18)
    assert f"bad magic {junk[:16]!r} (expected" in str(ei.value)


def test_the_smallest_header_and_the_largest_frame_pass_the_framing() -> None:
    # a 2-byte header passes the framing (and "{}" then lacks its type)
    with pytest.raises(ProtocolError) as ei:
        reader(raw(b"{}")).read_frame(1e18)
    assert str(ei.value) == "malformed frame from agent on host t: header has no string 'type'"
    # a header of exactly 64 KiB, padded with JSON whitespace
    h = b'{"type":"x","id":2}'
    got = reader(raw(h + b" " * (65536 - len(h)))).read_frame(1e18)
    assert (got.type, got.id) == ("x", 2)
    # header + blobs of exactly 8 MiB
    body = b"\x01" * (8 * 1024 * 1024 - 64)
    h = json.dumps({"type": "x", "id": 4, "blobs": [len(body)]}).encode()
    h += b" " * (64 - len(h))
    got = reader(raw(h, body)).read_frame(1e18)
    assert got.blobs == [body]


def test_the_crc_covers_the_header_and_the_blobs() -> None:
    h, body = b'{"type":"x","id":1,"blobs":[3]}', b"abc"
    for crc in (zlib.crc32(h), zlib.crc32(body)):
        with pytest.raises(ProtocolError, match="CRC mismatch over 34 bytes"):
            reader(raw(h, body, crc=crc)).read_frame(1e18)


# --------------------------------------------------------------------- decode_body
def body_refusal(header: bytes, body: bytes = b"", peer: str = "P") -> str:
    with pytest.raises(ProtocolError) as ei:
        p.decode_body(header, body, peer)
    return str(ei.value)


@pytest.mark.parametrize(("header", "why"), [
    (b'"x"', "header is a JSON str, expected an object"),
    (b"null", "header is a JSON NoneType, expected an object"),
    (b'{"type":"","id":1}', "header has no string 'type'"),
    (b'{"type":7,"id":1}', "header has no string 'type'"),
    (b'{"type":"x"}', "'id' must be a u32, got None"),
])
def test_a_header_that_is_not_a_message_is_refused(header: bytes, why: str) -> None:
    kind = "frame" if "'id'" not in why else "'x' frame"
    assert body_refusal(header) == f"malformed {kind} from P: {why}"


def test_a_header_that_is_not_json_says_why_in_at_most_80_characters() -> None:
    deep = b"[" * 30000 + b"]" * 30000
    with pytest.raises(RecursionError) as ei:
        json.loads(deep.decode())
    detail = str(ei.value)
    assert len(detail) > 80  # Python's own words, cut by the reader
    assert body_refusal(deep) == (
        f"malformed frame from P: header is not UTF-8 JSON (RecursionError: {detail[:80]})")
    with pytest.raises(UnicodeDecodeError) as ui:
        b"\xff{}".decode("utf-8")
    assert body_refusal(b"\xff{}") == (
        f"malformed frame from P: header is not UTF-8 JSON (UnicodeDecodeError: {ui.value})")
    assert body_refusal(b'{"type": "x",}').startswith(
        "malformed frame from P: header is not UTF-8 JSON (JSONDecodeError: ")


@pytest.mark.parametrize("mid", [0, 1, 2**32 - 1])
def test_every_u32_is_an_id(mid: int) -> None:
    assert p.decode_body(json.dumps({"type": "x", "id": mid}).encode(), b"", "P").id == mid


@pytest.mark.parametrize("mid", [2**32, -1, 1.0, "1", True, False])
def test_an_id_that_is_not_a_u32_is_refused(mid: Any) -> None:
    assert body_refusal(json.dumps({"type": "x", "id": mid}).encode()) == (
        f"malformed 'x' frame from P: 'id' must be a u32, got {mid!r}")


def test_blobs_default_to_none_and_split_the_body_in_order() -> None:
    f = p.decode_body(b'{"type":"x","id":1}', b"", "P")
    assert f.blobs == [] and f.header == {"type": "x", "id": 1}
    f = p.decode_body(b'{"type":"x","id":1,"blobs":[1,0,2,3]}', b"abcdef", "P")
    assert f.blobs == [b"a", b"", b"bc", b"def"]


def test_sixty_four_blobs_are_allowed_sixty_five_are_not() -> None:
    f = p.decode_body(json.dumps({"type": "x", "id": 1, "blobs": [1] * 64}).encode(),
                      b"z" * 64, "P")
    assert f.blobs == [b"z"] * 64
    assert body_refusal(json.dumps({"type": "x", "id": 1, "blobs": [0] * 65}).encode()) == (
        "malformed 'x' frame from P: 'blobs' must be a list of at most 64 sizes")


@pytest.mark.parametrize("sizes", [[-1, 1], [True], [1.0], "3", {"a": 1}, None])
def test_blob_sizes_must_be_a_list_of_naturals(sizes: Any) -> None:
    assert body_refusal(json.dumps({"type": "x", "id": 1, "blobs": sizes}).encode()) == (
        "malformed 'x' frame from P: 'blobs' must be a list of at most 64 sizes")


def test_blob_sizes_must_sum_to_the_body() -> None:
    assert body_refusal(b'{"type":"x","id":1,"blobs":[1,2]}', b"abcd") == (
        "malformed 'x' frame from P: blob sizes sum to 3 but the body has 4 bytes")
    assert body_refusal(b'{"type":"x","id":1}', b"a") == (
        "malformed 'x' frame from P: blob sizes sum to 0 but the body has 1 bytes")
    f = p.decode_body(b'{"type":"x","id":1,"blobs":[0]}', b"", "P")
    assert f.blobs == [b""]


# --------------------------------------------------------------------- check_reply
def error_frame(**fields: Any) -> p.Frame:
    return frame_of({"type": "error", "id": 9, **fields})


def agent_error(frame: p.Frame, expected: str = "observe_ok") -> AgentError:
    with pytest.raises(AgentError) as ei:
        p.check_reply(frame, expected, 9, "agent on host h")
    return ei.value


def test_a_reply_of_the_expected_type_and_id_is_returned_as_is() -> None:
    f = frame_of({"type": "push_ok", "id": 4, "results": {}})
    assert p.check_reply(f, "push_ok", 4, "a") is f


@pytest.mark.parametrize("kind", ["version", "request", "backend", "startup"])
def test_each_error_kind_reaches_the_controller_with_its_fields(kind: str) -> None:
    e = agent_error(error_frame(kind=kind, message="no camera", traceback="TB\n", arm="left",
                                fatal=True))
    assert str(e) == f"agent on host h: {kind} error on arm 'left': no camera"
    assert (e.kind, e.arm, e.remote_traceback, e.fatal) == (kind, "left", "TB\n", True)


def test_an_error_without_an_arm_names_none() -> None:
    e = agent_error(error_frame(kind="request", message="bad seed"))
    assert str(e) == "agent on host h: request error: bad seed"
    assert (e.kind, e.arm, e.remote_traceback, e.fatal) == ("request", None, "", False)


@pytest.mark.parametrize(("fields", "text", "attrs"), [
    ({"kind": "boom", "message": "m"}, "backend error: m", ("backend", None, "", False)),
    ({"kind": None, "message": "m"}, "backend error: m", ("backend", None, "", False)),
    ({"kind": "backend"}, "backend error: (no message)", ("backend", None, "", False)),
    ({"kind": "backend", "message": ""}, "backend error: (no message)",
     ("backend", None, "", False)),
    ({"kind": "backend", "message": 12}, "backend error: 12", ("backend", None, "", False)),
    ({"kind": "backend", "message": "m", "traceback": ["TB"], "arm": 3, "fatal": 1},
     "backend error: m", ("backend", None, "", False)),
    ({"kind": "backend", "message": "m", "arm": "", "fatal": "yes"},
     "backend error: m", ("backend", "", "", False)),
])
def test_a_garbled_error_frame_still_becomes_a_named_error(
        fields: dict[str, Any], text: str, attrs: tuple[Any, ...]) -> None:
    e = agent_error(error_frame(**fields))
    assert str(e) == f"agent on host h: {text}"
    assert (e.kind, e.arm, e.remote_traceback, e.fatal) == attrs


def test_an_error_message_is_cut_to_4000_characters() -> None:
    e = agent_error(error_frame(kind="backend", message="m" * 5000))
    assert str(e) == "agent on host h: backend error: " + "m" * 4000
    with pytest.raises(ProtocolError) as ei:
        p.check_reply(error_frame(kind="protocol", message="q" * 5000), "push_ok", 9, "a")
    assert str(ei.value) == "a rejected our 'push_ok' frame: " + "q" * 4000


def test_a_protocol_error_frame_is_a_protocol_error_not_an_agent_error() -> None:
    with pytest.raises(ProtocolError) as ei:
        p.check_reply(error_frame(kind="protocol", message="what is this"), "reset_ok", 9,
                      "agent on host h")
    assert str(ei.value) == "agent on host h rejected our 'reset_ok' frame: what is this"
    with pytest.raises(ProtocolError) as ei:
        p.check_reply(error_frame(kind="protocol"), "reset_ok", 9, "a")
    assert str(ei.value) == "a rejected our 'reset_ok' frame: (no message)"


def test_a_reply_of_another_type_or_id_is_refused_with_both() -> None:
    f = frame_of({"type": "push_ok", "id": 4})
    with pytest.raises(ProtocolError) as ei:
        p.check_reply(f, "observe_ok", 4, "P")
    assert str(ei.value) == "unexpected reply from P: got 'push_ok', expected 'observe_ok'"
    with pytest.raises(ProtocolError) as ei:
        p.check_reply(f, "push_ok", 5, "P")
    assert str(ei.value) == "out-of-order reply from P: 'push_ok' has id 4, expected 5"
    # an error frame is an error whatever id it carries
    assert agent_error(frame_of({"type": "error", "id": 0, "kind": "backend",
                                 "message": "x"})).kind == "backend"


# ------------------------------------------- the checkers the reply parsers share
def reply_refusal(parse: Any, header: dict[str, Any], *args: Any) -> str:
    frame = frame_of({"id": 1, **header})
    with pytest.raises(ProtocolError) as ei:
        parse(frame, *args, "agent on host h")
    return str(ei.value)


def test_a_reset_reply_done_must_be_a_bool() -> None:
    assert reply_refusal(p.parse_reset_reply, {"type": "reset_ok",
                                               "results": {"left": {"done": 1}}}, ["left"]) == (
        "malformed 'reset_ok' message from agent on host h: arm 'left' done must be "
        "true/false, got 1")
    long = "y" * 60
    assert reply_refusal(p.parse_reset_reply, {"type": "reset_ok",
                                               "results": {"left": {"done": long}}},
                         ["left"]).endswith(f"got {repr(long)[:40]}")


def test_a_reply_must_name_exactly_the_arms_asked() -> None:
    assert reply_refusal(p.parse_push_reply, {"type": "push_ok", "results": {
        "right": {"success": True, "violation": False}}}, ["left"]) == (
        "malformed 'push_ok' message from agent on host h: 'results' names arms ['right'], "
        "expected ['left']")
    assert reply_refusal(p.parse_reset_reply, {"type": "reset_ok", "results": {}},
                         ["right", "left"]) == (
        "malformed 'reset_ok' message from agent on host h: 'results' names arms [], "
        "expected ['left', 'right']")


def test_a_moved_tcp_is_three_finite_numbers() -> None:
    f = frame_of({"type": "move_tcp_ok", "id": 1, "tcp": [1, 2.5, -3]})
    assert p.parse_move_tcp_reply(f, "a") == (1.0, 2.5, -3.0)
    assert reply_refusal(p.parse_move_tcp_reply, {"type": "move_tcp_ok", "tcp": [1, 2]}) == (
        "malformed 'move_tcp_ok' message from agent on host h: 'tcp' must be [x, y, z] "
        "finite numbers, got [1, 2]")


def test_an_observe_entry_names_its_arm_as_a_string() -> None:
    assert reply_refusal(p.parse_observe_reply, {"type": "observe_ok", "arms": [{"arm": 1}]},
                         ["left"]) == (
        "malformed 'observe_ok' message from agent on host h: field 'arm' must be str, got 1")


def push_result(result: dict[str, Any]) -> p.Frame:
    return frame_of({"type": "push_ok", "id": 1, "results": {"left": result}})


@pytest.mark.parametrize(("key", "value", "why"), [
    ("refused", "", "arm 'left' refused must be null or a non-empty string, got ''"),
    ("error", 5, "arm 'left' error must be null or a non-empty string, got 5"),
    ("error", ["z" * 50], "arm 'left' error must be null or a non-empty string, got "
                          + repr(["z" * 50])[:40]),
])
def test_a_per_arm_reason_is_null_or_text(key: str, value: Any, why: str) -> None:
    with pytest.raises(ProtocolError) as ei:
        p.parse_push_reply(push_result({"success": False, "violation": False, key: value}),
                           ["left"], "P")
    assert str(ei.value) == f"malformed 'push_ok' message from P: {why}"


def test_a_per_arm_reason_is_cut_to_2000_characters() -> None:
    out = p.parse_push_reply(push_result({"success": False, "violation": False,
                                          "refused": "r" * 2500, "error": None}), ["left"], "P")
    assert out["left"].refused == "r" * 2000 and out["left"].error is None


def test_readings_up_to_the_limits_pass() -> None:
    sixteen = {f"r{i}": float(i) for i in range(16)}
    assert p.reading_problem(sixteen) is None
    assert p.reading_problem({"a" * 40: 1, "_x9": 2, "B": -0.5}) is None
    assert p.reading_problem({}) is None


@pytest.mark.parametrize(("readings", "why"), [
    ({f"r{i}": 1.0 for i in range(17)}, "has 17 names, at most 16 are allowed"),
    ({"a" * 41: 1.0}, f"name {'a' * 41!r} is not an identifier of at most 40 characters"),
    ({"9a": 1.0}, "name '9a' is not an identifier of at most 40 characters"),
    ({"push s": 1.0}, "name 'push s' is not an identifier of at most 40 characters"),
    ({"push_s": True}, "'push_s' must be a finite number, got True"),
    ({"push_s": float("inf")}, "'push_s' must be a finite number, got inf"),
    ({"push_s": 10**400}, "'push_s' must be a finite number, got " + repr(10**400)[:40]),
    ({"push_s": "1"}, "'push_s' must be a finite number, got '1'"),
    ([1.0], "must be an object of names to numbers, got [1.0]"),
    ("x" * 100, "must be an object of names to numbers, got " + repr("x" * 100)[:60]),
])
def test_readings_beyond_the_limits_say_what_is_wrong(readings: Any, why: str) -> None:
    assert p.reading_problem(readings) == why
