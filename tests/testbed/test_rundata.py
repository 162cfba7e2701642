"""The run's data store (``testbed.records.store``): frames on disk, torn tails, chunks, resume
cuts, and the replay that gives a resumed learner exactly what the loop gave it."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.types import IMAGE_SIZE, ArmObservation, Fault, PushResult
from testbed.experiments.scripted_humans import ScriptedHumans
from testbed.fleet.algorithm_config import AlgorithmConfig
from testbed.fleet.algorithms import get_algorithm
from testbed.fleet.loop import FleetLoop
from testbed.learning.api import PolicyOutput
from testbed.records import store as rundata
from testbed.records.steps import RunWriter, read_steps
from testbed.records.store import FRAME_DTYPE, RunData, RunDataError, RunDataWriter

ARMS = ["a/left", "a/right", "b/left", "b/right"]


def _step(t: int, n: int = 4, session: int = 0) -> np.ndarray:
    f = np.zeros(n, FRAME_DTYPE)
    f["t"], f["arm"], f["session"] = t, np.arange(n), session
    f["image"] = (np.arange(n)[:, None, None, None] * 10 + t) % 256
    f["action"] = t % 4
    return f


def test_frames_round_trip_across_chunks_and_a_torn_record_is_dropped(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rundata, "CHUNK_BYTES", 3 * 4 * FRAME_DTYPE.itemsize)  # 3 steps
    w = RunDataWriter(tmp_path, ARMS)
    assert w.steps_per_chunk == 3
    written = [_step(t) for t in range(8)]
    for f in written:
        w.append(f)
    w.close()
    assert sorted(p.name for p in (tmp_path / "data").glob("frames-*.bin")) == [
        "frames-00000.bin", "frames-00001.bin", "frames-00002.bin"]
    data = RunData.of_run(tmp_path)
    assert data.num_steps == 8 and data.robots == ARMS
    assert np.array_equal(data.frames(), np.concatenate(written))
    assert [t for t, _ in data.iter_steps(2, 7)] == [2, 3, 4, 5, 6]
    assert np.array_equal(data.frames(4, 6), np.concatenate(written[4:6]))
    # numpy alone reads a chunk, with the dtype from meta.json
    raw = np.fromfile(tmp_path / "data" / "frames-00001.bin",
                      dtype=rundata.dtype_of(rundata.read_meta(tmp_path / "data")))
    assert np.array_equal(raw, np.concatenate(written[3:6]))
    # a crash in the middle of step 8's write: the step does not count
    with open(tmp_path / "data" / "frames-00002.bin", "ab") as f:
        f.write(_step(8).tobytes()[: FRAME_DTYPE.itemsize * 2 + 100])
    assert RunData.of_run(tmp_path).num_steps == 8


def test_a_store_of_another_frame_layout_is_read_but_never_appended_to(
        tmp_path: Path) -> None:
    """A run written by a build whose frame had other fields: its data stays readable
    (export, report), and a resume, which would append frames of this build's layout
    under the stored one, is refused in one line naming both formats; nothing changes."""
    w = RunDataWriter(tmp_path, ARMS)
    w.append(_step(0))
    w.close()
    meta_path = tmp_path / "data" / "meta.json"
    meta = json.loads(meta_path.read_text())
    old = dict(meta, format="testbed.rundata/0", dtype=[*meta["dtype"][:-2], meta["dtype"][-1]])
    meta_path.write_text(json.dumps(old))
    before = {p.name: p.read_bytes() for p in (tmp_path / "data").iterdir()}
    with pytest.raises(RunDataError) as err:
        RunDataWriter(tmp_path, ARMS, keep_steps=1)
    assert str(err.value).startswith(f"{tmp_path / 'data'}: its frames are format "
                                     "testbed.rundata/0 (13 fields), this build writes "
                                     f"{rundata.FORMAT} (14 fields)")
    assert {p.name: p.read_bytes() for p in (tmp_path / "data").iterdir()} == before
    assert RunData.of_run(tmp_path).dtype.names == tuple(n for n, _, _ in old["dtype"])
    meta_path.write_text(json.dumps(dict(meta, format="testbed.rundata/99")))
    with pytest.raises(RunDataError, match="written by a newer build"):
        RunData.of_run(tmp_path)


def test_the_frame_layout_changes_only_with_the_format_version() -> None:
    """FRAME_DTYPE is the data store's format: a field added (docs/ARCHITECTURE.md, "A
    new field in every step") must come with a new ``FORMAT`` version, so that a resume
    of an older run is refused instead of appending frames of another size. The digest
    of each version's layout is recorded here; a change of layout under the same
    version fails until ``FORMAT`` is bumped and its digest added."""
    layouts = {"testbed.rundata/1":
               "9058da8d19d3392031af1ac38bb2cf89df57818d4c90ce91248f18f8d0e408d9"}
    digest = hashlib.sha256(json.dumps(rundata.frame_layout()).encode()).hexdigest()
    assert layouts.get(rundata.FORMAT) == digest, (
        f"FRAME_DTYPE is not the layout of {rundata.FORMAT}: bump FORMAT in "
        f"testbed/records/store.py and record {digest} for it here")


def test_resume_cuts_the_store_back_to_the_checkpoint_and_appends_in_order(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rundata, "CHUNK_BYTES", 3 * 4 * FRAME_DTYPE.itemsize)
    w = RunDataWriter(tmp_path, ARMS)
    for t in range(8):
        w.append(_step(t))
    w.close()
    with pytest.raises(RunDataError, match="robots"):
        RunDataWriter(tmp_path, ARMS[:2])
    w = RunDataWriter(tmp_path, ARMS, keep_steps=2)  # the checkpoint holds steps 0..1
    assert w.steps == 2 and not (tmp_path / "data" / "frames-00001.bin").exists()
    with pytest.raises(RunDataError, match="step 5 written after 2"):
        w.append(_step(5))
    for t in range(2, 5):
        w.append(_step(t, session=1))
    w.close()
    data = RunData.of_run(tmp_path)
    assert data.num_steps == 5
    assert list(data.frames()["session"][::4]) == [0, 0, 1, 1, 1]


class _World:
    """Pictures seeded by (arm, pushes so far); arm 0 unseen at step 3, arm 1's host
    fails at step 4, arm 2's push refused at step 2: every mode a frame can have."""

    def __init__(self) -> None:
        self.robot_names = list(ARMS)
        self.n = dict.fromkeys(ARMS, 0)
        self.t = 0
        self.violating = dict.fromkeys(ARMS, False)

    def observe(self) -> dict[str, ArmObservation | Fault]:
        out: dict[str, ArmObservation | Fault] = {}
        for k, r in enumerate(ARMS):
            if (self.t, k) == (3, 0):
                out[r] = Fault(r, "camera lost")
                continue
            img = np.random.default_rng([k, self.n[r]]).integers(
                0, 256, (IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
            out[r] = ArmObservation(r, img, self.violating[r], (0.1 * k, 0.5), (k + self.t) % 4)
        return out

    def execute(self, pushes: Mapping[str, int], resets: Sequence[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, r in enumerate(ARMS):
            if r in resets:
                self.violating[r] = False
            if (self.t, k) == (4, 1):
                out[r] = Fault(r, "host lost")
            elif (self.t, k) == (2, 2) and r in pushes:
                out[r] = PushResult(r, None, False, False, refused="cube not found")
            elif r in pushes:
                self.n[r] += 1
                roll = (self.n[r] * 7 + k * 3 + pushes[r]) % 11
                self.violating[r] = roll == 0
                out[r] = PushResult(r, pushes[r], roll in (3, 5), roll == 0)
            else:
                out[r] = PushResult(r, None, False, False)
        self.t += 1
        return out


class _Recorder:
    """A learner that acts by a fixed rule and records the data it is given."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, list[np.ndarray]]] = []

    def act(self, images: np.ndarray) -> PolicyOutput:
        n = len(images)
        u = (images.reshape(n, -1)[:, 0] / 255.0).astype(np.float32)
        probs = np.full((n, 4), 0.25, np.float32)
        z = np.zeros(n, np.float32)
        return PolicyOutput(images.reshape(n, -1)[:, 1].astype(np.int64) % 4, probs, u, z, z, z)

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None:
        assert labellers is not None  # the labeller travels with every label
        self.calls.append(("human", [np.array(images), np.array(actions),
                                     np.array(labellers)]))

    def add_transitions(self, *columns: np.ndarray) -> None:
        self.calls.append(("transitions", [np.array(c) for c in columns]))

    def train_step(self) -> dict[str, float]:
        return {}


def _same_calls(a: _Recorder, b: _Recorder) -> bool:
    return [k for k, _ in a.calls] == [k for k, _ in b.calls] and all(
        all(np.array_equal(x, y) for x, y in zip(ca, cb, strict=True))
        for (_, ca), (_, cb) in zip(a.calls, b.calls, strict=True))


def test_replay_gives_what_the_loop_gave_its_learner_across_a_resume(tmp_path: Path) -> None:
    live = _Recorder()
    world = _World()
    params = AlgorithmConfig(t_I=0, u_hat=0.3, t_T=2, t_R=2)
    for session, (first, last) in enumerate([(0, 5), (5, 9)]):  # a resume after step 4
        data = RunDataWriter(tmp_path, ARMS, keep_steps=first)
        with RunWriter(tmp_path) as writer:
            loop = FleetLoop(hosts=world, humans=ScriptedHumans(), learner=live,
                             algorithm=get_algorithm("cur", params, 4, 2, 0), writer=writer,
                             steps=9, num_humans=2, t_T=2, t_R=2, data=data,
                             session=session)
            for t in range(first, last):
                loop.step(t)
                if t == 3:  # the newest fault, for the progress line and the overview
                    assert loop.status.last_fault is not None
                    assert loop.status.last_fault[:2] == (3, ARMS[0])
                    assert "camera lost" in loop.status.last_fault[2]
            if session == 0:  # step 4's, and the arm faulted then shows as faulted
                assert loop.status.last_fault is not None
                assert loop.status.last_fault[:2] == (4, ARMS[1])
                assert "host lost" in loop.status.last_fault[2]
                assert loop.status.health().startswith(f"faulted 1 ({ARMS[1]})")
            loop.close()
        data.close()
    rows = read_steps(tmp_path / "steps.jsonl")
    stored = RunData.of_run(tmp_path)
    assert stored.num_steps == len(rows) == 9
    frames = stored.frames()
    assert {rundata.MODES.index(m) for m in ("autonomous", "teleop", "fault", "refused")} \
        <= set(frames["mode"].tolist())
    for row, (t, f) in zip(rows, stored.iter_steps(), strict=True):
        assert row["t"] == t
        assert [rundata.MODES[m] for m in f["mode"]] == [r["mode"] for r in row["robots"]]
        assert [None if a < 0 else int(a) for a in f["action"]] == \
            [r["action"] for r in row["robots"]]
        assert list(f["success"]) == [r["success"] for r in row["robots"]]
        assert f["wall_time"][0] == row["wall_time"]
    assert not frames["observed"][3 * 4 + 0] and frames["image"][3 * 4 + 0].max() == 0
    assert np.allclose(frames["goal"][4 * 4 + 1], (0.1, 0.5))
    kinds = [k for k, _ in live.calls]
    assert "human" in kinds and "transitions" in kinds
    replayed = _Recorder()
    rundata.replay(replayed, stored, 9)
    assert _same_calls(live, replayed)  # with no transition from step 4 into step 5
    # who gave each label reached the learner: the rows' teleop humans, in order
    given = np.concatenate([c[2] for k, c in live.calls if k == "human"]).tolist()
    assert given == [r["human"] for row in rows for r in row["robots"]
                     if r["mode"] == "teleop" and r["action"] is not None]
    assert set(given) <= {0, 1} and given
    with pytest.raises(RunDataError, match="9 steps on disk"):
        rundata.replay(_Recorder(), stored, 10)


@pytest.mark.slow
def test_resuming_a_run_of_another_frame_layout_is_one_line_and_loses_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    from testbed.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.toml").write_text(
        '[trial]\nsteps = 3\n[learning]\nensemble_size = 2\nbatch_size = 8\ndemos = 8\n'
        'critic_transitions = 8\npretrain_steps = 1\n[humans]\ncount = 1\n'
        '[[hosts]]\nname = "cell0"\n')
    assert main(["trial", "--config", "tiny.toml", "--out", "runs", "--name", "old"]) == 0
    run = tmp_path / "runs" / "old"
    meta = json.loads((run / "data" / "meta.json").read_text())
    meta["format"], meta["dtype"] = "testbed.rundata/0", meta["dtype"][:-1]
    (run / "data" / "meta.json").write_text(json.dumps(meta))
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main(["trial", "--resume", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"testbed trial: --resume: {run / 'data'}: its frames are format testbed.rundata/0")
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
