"""Fuzz: 1000 malformed or truncated frames in each direction, through the real agent
loop and the real fleet. Every one must give a clear error and a Fault for that host's
arms (or, for the single-host calls frame / move_tcp / save_calibration, a HostCallError
naming the host), within the deadline; the other host goes on; nothing crashes, nothing
hangs.

Seeded (numpy Generator) so a failure is reproducible: the case number is in the
assertion message.
"""

from __future__ import annotations

import json
import os
import re
import time
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from driver_fakes import RecordingBackend, ThreadAgentTransport, local_host, wait_until

import drivers.host_fleet
import drivers.session
from drivers import wire as p
from drivers.host_fleet import HostCallError, HostFleet
from drivers.png import encode_png
from testbed.core.host_config import HostConfig
from testbed.core.types import ArmObservation, Fault, PushResult

CASES = int(os.environ.get("FUZZ_CASES", "1000"))
DEADLINE_S = 0.4
STALL_P = 0.006  # a few stalled streams: only the deadline can end those

CLEAR = re.compile(
    r"malformed|truncated frame|corrupted frame|bad magic|CRC mismatch|unexpected reply|"
    r"out-of-order|not a PNG|PNG (is|data|pixel|chunk|has)|rejected our|closed the stream|"
    r"deadline exceeded|exceeds the limit|header length|link closed|claims \d+x\d+|"
    r"one PNG blob")

Mutator = Callable[[bytes], tuple[bytes, bool, str]]
"""frame -> (bytes to send, close the stream after them?, category)."""


def raw(header: bytes, body: bytes = b"") -> bytes:
    crc = zlib.crc32(body, zlib.crc32(header))
    return p.PREFIX.pack(p.MAGIC, len(header), len(body), crc) + header + body


def split(frame: bytes) -> tuple[dict[str, Any], bytes]:
    hlen = p.PREFIX.unpack(frame[:16])[1]
    return json.loads(frame[16:16 + hlen]), frame[16 + hlen:]


def reencode(h: dict[str, Any], body: bytes) -> bytes:
    return raw(json.dumps(h).encode(), body)


def semantic(rng: np.random.Generator, frame: bytes) -> bytes:
    """A frame with valid framing (magic, lengths, CRC) whose MESSAGE is wrong."""
    h, body = split(frame)
    choice = int(rng.integers(0, 12))
    if choice == 0:
        h["type"] = str(rng.choice(["push_ok", "observe_ok", "zzz", "", "hello_ok", "error"]))
        if h["type"] == "error":
            h.update(kind="protocol", message="fuzz")
        if h["type"] == frame_type(frame):
            h["type"] += "_"
    elif choice == 1:
        h["id"] = int(h["id"]) + int(rng.integers(1, 1000))
    elif choice == 2:
        h["id"] = str(rng.choice(["1", "-1"])) if rng.random() < 0.5 else 2**40
    elif choice == 3:
        return raw(b"[" * int(rng.integers(1, 3000)) + b"]", b"")
    elif choice == 4:
        return raw(bytes(rng.integers(0, 256, int(rng.integers(2, 200)), dtype=np.uint8)), b"")
    elif choice == 5:
        h["blobs"] = [len(body) + int(rng.integers(1, 9))]
        return raw(json.dumps(h).encode(), body)
    elif choice == 6:
        return raw(b'"just a string"', b"")
    else:
        return reencode(*mutate_fields(rng, h, body))
    return reencode(h, body)


def frame_type(frame: bytes) -> str:
    return str(split(frame)[0]["type"])


def mutate_fields(rng: np.random.Generator, h: dict[str, Any], body: bytes
                  ) -> tuple[dict[str, Any], bytes]:
    """Break one field of a message in a way its type's checks must catch."""
    t = h["type"]
    if t == "observe_ok":
        entries = h["arms"]
        e = entries[int(rng.integers(0, len(entries)))]
        k = int(rng.integers(0, 14))
        if k == 12:  # an arm error that is not a reason
            e.clear()
            e.update(arm="left", error=["", None, 7][int(rng.integers(0, 3))])
            return h, body
        if k == 13:  # an arm error with a view's keys
            e["error"] = "camera"
            return h, body
        if k == 0:
            del h["arms"]
        elif k == 1:
            h["arms"] = entries[:1]
        elif k == 2:
            e["arm"] = str(rng.choice(["elbow", "", "LEFT"]))
        elif k == 3:
            e["violating"] = str(rng.choice(["yes", "1"])) if rng.random() < 0.5 else None
        elif k == 4:
            e["goal"] = [[2.0, 0.5], [0.5], "x", [0.5, -0.1], None][int(rng.integers(0, 5))]
        elif k == 5:
            e["expert_action"] = int(rng.choice([4, -1, 99]))
        elif k == 6:
            e["blob"] = int(rng.choice([7, -1, 2]))
        elif k == 7:  # an image that is not a PNG
            blob = bytes(rng.integers(0, 256, 64, dtype=np.uint8))
            h["blobs"] = [len(blob), *h["blobs"][1:]]
            body = blob + body[split_blob0(h, body):]
        elif k == 8:  # a PNG of the wrong size
            blob = encode_png(np.zeros((int(rng.integers(1, 63)), 64, 3), np.uint8))
            body = blob + body[split_blob0(h, body):]
            h["blobs"] = [len(blob), *h["blobs"][1:]]
        elif k == 9:  # a truncated PNG
            first = h["blobs"][0]
            cut = int(rng.integers(1, first))
            body = body[:cut] + body[first:]
            h["blobs"] = [cut, *h["blobs"][1:]]
        elif k == 10:
            entries.append(dict(entries[0]))
        else:
            h["arms"] = "all"
        return h, body
    if t == "push_ok":
        res = h["results"]
        arm = sorted(res)[int(rng.integers(0, len(res)))]
        k = int(rng.integers(0, 7))
        if k == 0:
            del res[arm]
        elif k == 1:
            res["elbow"] = {"success": False, "violation": False}
        elif k == 2:
            res[arm]["success"] = 1
        elif k == 3:
            res[arm] = [True, False]
        elif k == 4:
            res[arm][str(rng.choice(["refused", "error"]))] = [5, "", False][
                int(rng.integers(0, 3))]
        elif k == 5:
            res[arm]["why"] = "no"
        else:
            del h["results"]
        return h, body
    if t == "frame_ok":
        k = int(rng.integers(0, 5))
        if k == 0:  # no blob
            h["blobs"] = []
            return h, b""
        if k == 1:  # not a PNG
            blob = bytes(rng.integers(0, 256, 64, dtype=np.uint8))
        elif k == 2:  # truncated PNG
            blob = body[:int(rng.integers(8, len(body) - 20))]
        elif k == 3:  # a PNG header claiming a huge image
            blob = (body[:16] + int(rng.integers(5000, 2**31)).to_bytes(4, "big") * 2
                    + body[24:])
        else:  # two blobs
            blob = body + body
            h["blobs"] = [len(body), len(body)]
            return h, blob
        h["blobs"] = [len(blob)]
        return h, blob
    if t == "move_tcp_ok":
        h["tcp"] = [None, [1, 2], "here", [1, 2, "3"], {"x": 1}][int(rng.integers(0, 5))]
        return h, body
    if t == "save_calibration_ok":
        h["path"] = ["", 3, None, ["/x"]][int(rng.integers(0, 4))]
        return h, body
    if t == "move_tcp":
        k = int(rng.integers(0, 4))
        if k == 0:
            h["arm"] = "elbow"
        elif k == 1:
            h["xyz_mm"] = [[1, 2], "origin", [1, 2, None], [1, 2, True]][int(rng.integers(0, 4))]
        elif k == 2:
            del h["arm"]
        else:
            h["type"] = "move_tcp_now"
        return h, body
    if t == "save_calibration":
        h["data"] = [[1], "x", None, 3][int(rng.integers(0, 4))]
        return h, body
    if t == "frame":  # requests carry no blobs
        blob = b"\0" * int(rng.integers(1, 64))
        h["blobs"] = [len(blob)]
        return h, blob
    if t == "observe":
        h["type"] = str(rng.choice(["observe_all", "OBSERVE", "launch"]))
        return h, body
    if t == "push":
        k = int(rng.integers(0, 5))
        arm = sorted(h["faces"])[0]
        h["faces"] = [{}, {arm: 4}, {arm: "1"}, {"elbow": 1}, {arm: True}][k]
        return h, body
    h["type"] = "?"
    return h, body


def split_blob0(h: dict[str, Any], body: bytes) -> int:
    return int(h["blobs"][0]) if h.get("blobs") else 0


def make_mutator(rng: np.random.Generator) -> Mutator:
    def mutate(frame: bytes) -> tuple[bytes, bool, str]:
        r = rng.random()
        if r < STALL_P:
            return frame[:int(rng.integers(1, len(frame)))], False, "stall"
        kind = str(rng.choice(["truncate", "flip", "garbage", "prefix", "semantic",
                               "semantic", "semantic"]))
        if kind == "truncate":
            return frame[:int(rng.integers(0, len(frame)))], True, kind
        if kind == "flip":
            b = bytearray(frame)
            i = int(rng.integers(0, len(b)))
            b[i] ^= int(rng.integers(1, 256))
            return bytes(b), True, kind
        if kind == "garbage":
            n = int(rng.integers(0, 300))
            return bytes(rng.integers(0, 256, n, dtype=np.uint8)), True, kind
        if kind == "prefix":
            junk = rng.choice([b"pybullet build time: Jan 29 2025\n", b"\n", b"Welcome!\r\n",
                               b"\x1b[0m"])
            return bytes(junk) + frame, True, kind
        return semantic(rng, frame), False, kind

    return mutate


CALLS = ("observe", "push", "frame", "move_tcp", "save_calibration")


def single_host_call(fleet: HostFleet, call: str, host: str) -> object:
    if call == "frame":
        return fleet.frame(host, timeout_s=DEADLINE_S)
    if call == "move_tcp":
        return fleet.move_tcp(host, "left", (400.0, 100.0, 10.0), timeout_s=DEADLINE_S)
    return fleet.save_calibration(host, "right", {"z_push_mm": 12.0}, timeout_s=DEADLINE_S)


def run_fuzz(monkeypatch: pytest.MonkeyPatch, direction: str, seed: int) -> dict[str, int]:
    rng = np.random.default_rng(seed)
    mutate = make_mutator(rng)
    made: list[ThreadAgentTransport] = []
    current: dict[str, str] = {}

    def transport(host: HostConfig) -> ThreadAgentTransport:
        if host.name == "good":
            t = ThreadAgentTransport(host, backend_factory=RecordingBackend)
        else:
            def hook(i: int, data: bytes) -> tuple[bytes, bool]:
                if i != 1:  # 0 is hello / hello_ok: the case starts after the handshake
                    return data, False
                out, close, kind = mutate(data)
                current["kind"] = kind
                return out, close

            t = (ThreadAgentTransport(host, mutate_reply=hook, backend_factory=RecordingBackend)
                 if direction == "reply" else
                 ThreadAgentTransport(host, mutate_request=hook,
                                      backend_factory=RecordingBackend))
        made.append(t)
        return t

    monkeypatch.setattr(drivers.session, "make_transport", transport)
    monkeypatch.setattr(drivers.host_fleet, "KEEPER_PERIOD_S", 0.002)
    hosts = [local_host("bad", deadline_s=DEADLINE_S, heartbeat_s=600),
             local_host("good", deadline_s=DEADLINE_S, heartbeat_s=600)]
    seen: dict[str, int] = {}
    with HostFleet(hosts, reconnect_backoff_s=0.0) as fleet:
        for case in range(CASES):
            wait_until(lambda: fleet.host_status()["bad"].connected, 10,
                       f"case {case}: reconnect", poll_s=0.001)
            t0 = time.monotonic()
            call = CALLS[case % len(CALLS)]
            if call not in ("observe", "push"):
                try:
                    got = single_host_call(fleet, call, "bad")
                    failure = f"the call returned {got!r:.60}"
                except HostCallError as exc:
                    failure = str(exc)
                took = time.monotonic() - t0
                kind = current.get("kind", "?")
                seen[kind] = seen.get(kind, 0) + 1
                where = f"case {case} ({direction}, {call}, {kind}, seed {seed})"
                assert took < DEADLINE_S + 1.5, f"{where}: took {took:.2f} s"
                assert failure.startswith(f"{call} on host bad failed: "), f"{where}: {failure}"
                assert CLEAR.search(failure), f"{where}: unclear reason {failure!r}"
                assert "\n" not in failure, f"{where}: not one line"
                single_host_call(fleet, call, "good")  # the other host goes on
                continue
            if call == "push":
                res: dict[str, Any] = dict(fleet.execute(dict.fromkeys(fleet.robot_names, 1), []))
                ok_type: type = PushResult
            else:
                res = dict(fleet.observe())
                ok_type = ArmObservation
            took = time.monotonic() - t0
            kind = current.get("kind", "?")
            seen[kind] = seen.get(kind, 0) + 1
            where = f"case {case} ({direction}, {kind}, seed {seed})"
            assert took < DEADLINE_S + 1.5, f"{where}: took {took:.2f} s"
            for arm in ("left", "right"):
                f = res[f"bad/{arm}"]
                assert isinstance(f, Fault), f"{where}: {f!r}"
                assert CLEAR.search(f.reason), f"{where}: unclear reason {f.reason!r}"
                assert "host bad" in f.reason, f"{where}: reason must name the host"
                assert isinstance(res[f"good/{arm}"], ok_type), f"{where}: {res[f'good/{arm}']}"
    for t in made:
        assert t.crashed is None, f"the agent loop raised: {t.crashed!r}"
    return seen


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
def test_fuzz_replies_agent_to_controller(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = run_fuzz(monkeypatch, "reply", seed=20260522)
    assert seen.get("semantic", 0) > 300 and seen.get("truncate", 0) > 50


@pytest.mark.alone  # a wall-clock bound (tests/conftest.py)
@pytest.mark.slow
def test_fuzz_requests_controller_to_agent(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = run_fuzz(monkeypatch, "request", seed=20260523)
    assert seen.get("semantic", 0) > 300 and seen.get("flip", 0) > 50
