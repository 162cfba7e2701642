"""A value measured on the robot host reaches the step by one generic path: the checklist
"A new field in every step" of docs/ARCHITECTURE.md, its short path, as tests.

Why: a host's measurement (here the push's duration on the host's clock, ``push_s``) is
filled in ONE place, the backend's ``push`` (``ArmOutcome.readings``); the wire, the
agent, the controller's ``PushResult``, the loop and the records carry every reading by
name. These tests run the real agent process (``measuring_arm.py``, the seam of
``slow_arm.py``) behind the real ``HostFleet`` and ``FleetLoop``: the reading must
arrive in the ``PushResult``, in the arm's steps.jsonl row, and read back; a backend's
bad reading faults that arm alone, a peer's bad reading is a protocol error naming the
arm. The wire's own checks are in ``test_wire_protocol.py``.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from driver_fakes import ThreadAgentTransport, local_host
from measuring_arm import BAD_ENV, MOVE_S_ENV, MeasuringBackend

import drivers.session
from drivers import wire as p
from drivers.host_fleet import HostFleet
from drivers.transport import agent_argv
from testbed.core.host_config import HostConfig
from testbed.core.types import Fault, Mode, PushResult
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.records.step_record import StepRecord
from testbed.records.steps import RunWriter, read_steps, validate_step

MEASURING_ARM = Path(__file__).with_name("measuring_arm.py")
MOVE_S = 0.02


@pytest.fixture
def measuring(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Every agent the fleet starts runs measuring_arm.py: agent_argv's argv, with
    ``-m drivers.agent`` swapped for that script."""
    def argv(host: Any, **kw: Any) -> list[str]:
        words = agent_argv(host, **kw)
        i = words.index("-m")
        assert words[i + 1] == "drivers.agent"
        return [words[0], str(MEASURING_ARM), *words[i + 2:]]

    monkeypatch.setattr(drivers.session, "agent_argv", argv)
    monkeypatch.setenv(MOVE_S_ENV, str(MOVE_S))
    monkeypatch.delenv(BAD_ENV, raising=False)
    yield


class _Calm:
    """A learner that acts (face 1, no uncertainty, no risk) and learns nothing: every
    arm that is not violating pushes on its own."""

    def act(self, images: np.ndarray) -> Any:
        n = len(images)
        return SimpleNamespace(actions=np.full(n, 1), uncertainty=np.zeros(n),
                               risk=np.zeros(n))

    def add_human(self, *args: Any) -> None:
        return None

    def add_transitions(self, *args: Any) -> None:
        return None

    def train_step(self) -> dict[str, float]:
        return {}


def test_a_reading_measured_on_the_host_reaches_the_push_result_the_row_and_reads_back(
        measuring: None, tmp_path: Path) -> None:
    with HostFleet([local_host("h", physics=False)], trial_seed=3) as fleet:
        res = fleet.execute({"h/left": 1}, [])
        left, right = res["h/left"], res["h/right"]
        assert isinstance(left, PushResult) and isinstance(right, PushResult)
        assert [name for name, _ in left.readings] == ["push_s"]
        assert MOVE_S <= dict(left.readings)["push_s"] < 5.0  # the host's clock
        assert right.readings == ()  # not pushed: nothing measured
        params = AlgorithmConfig(t_I=0, u_hat=0.5, r_hat=1.0, t_T=2, t_R=3)
        with RunWriter(tmp_path) as writer:
            loop = FleetLoop(hosts=fleet, humans=ScriptedHumans(), learner=_Calm(),
                             algorithm=get_algorithm("cur-i", params, 2, 1, seed=0),
                             writer=writer, steps=3, num_humans=1, t_T=2, t_R=3)
            try:
                for t in range(3):
                    loop.step(t)
            finally:
                loop.close()
    rows = read_steps(tmp_path)  # validated
    pushed = [e for row in rows for e in row["robots"] if e["mode"] == Mode.AUTONOMOUS.value]
    assert pushed, "the arms pushed on their own"
    for row in rows:
        for entry in row["robots"]:
            if entry["mode"] == Mode.AUTONOMOUS.value:
                assert set(entry["readings"]) == {"push_s"}
                assert MOVE_S <= entry["readings"]["push_s"] < 5.0
            else:
                assert "readings" not in entry
        images = np.zeros((2, 64, 64, 3), np.uint8)
        back = StepRecord.from_row(row, 0, images, np.ones(2, bool),
                                   np.zeros((2, 2), np.float32))
        assert [a.readings for a in back.arms] == [e.get("readings") for e in row["robots"]]
        again = back.to_row()
        validate_step(again)
        assert again["robots"] == row["robots"]


def test_a_backends_bad_reading_faults_that_arm_alone(
        measuring: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(BAD_ENV, "nan")
    with HostFleet([local_host("h", physics=False)]) as fleet:
        res = fleet.execute({"h/left": 1, "h/right": 2}, [])
        left, right = res["h/left"], res["h/right"]
        assert isinstance(left, Fault)
        assert left.reason == ("agent on host h: arm 'left' failed: the backend's readings "
                               "of the push: 'push_s' must be a finite number, got nan")
        assert isinstance(right, PushResult) and dict(right.readings)["push_s"] >= MOVE_S
        assert fleet.host_status()["h"].connected  # one arm's trouble keeps the link


def _with_reading(value: object, arm: str = "left") -> Any:
    """A reply mutation: every ``push_ok`` from the agent says ``arm`` measured
    ``{"push_s": value}`` (as a peer could write it: NaN and Infinity included)."""
    def mutate(i: int, data: bytes) -> tuple[bytes, bool]:
        _, hlen, blen, _ = p.PREFIX.unpack(data[:p.PREFIX_BYTES])
        header = json.loads(data[p.PREFIX_BYTES:p.PREFIX_BYTES + hlen])
        if header.get("type") != "push_ok":
            return data, False
        header["results"][arm]["readings"] = {"push_s": value}
        hb = json.dumps(header).encode()
        body = data[p.PREFIX_BYTES + hlen:]
        return p.PREFIX.pack(p.MAGIC, len(hb), blen, zlib.crc32(body, zlib.crc32(hb))
                             ) + hb + body, False
    return mutate


@pytest.mark.parametrize(("value", "why"), [
    (float("nan"), "'push_s' must be a finite number, got nan"),
    ("2.5", "'push_s' must be a finite number, got '2.5'"),
])
def test_a_peers_bad_reading_is_a_protocol_error_naming_the_arm(
        monkeypatch: pytest.MonkeyPatch, value: object, why: str) -> None:
    def transport(host: HostConfig) -> ThreadAgentTransport:
        return ThreadAgentTransport(host, mutate_reply=_with_reading(value),
                                    backend_factory=lambda: MeasuringBackend(0, move_s=0.0))

    monkeypatch.setattr(drivers.session, "make_transport", transport)
    with HostFleet([local_host("h", physics=False)], reconnect_backoff_s=60.0) as fleet:
        res = fleet.execute({"h/left": 1, "h/right": 2}, [])
        for r in ("h/left", "h/right"):  # a peer that breaks the protocol: its host faults
            fault = res[r]
            assert isinstance(fault, Fault)
            assert "malformed 'push_ok' message from agent on host h: arm 'left' readings " \
                   + why in fault.reason
