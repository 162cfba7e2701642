"""Every exported frame's class, its episode's outcome and index (issue 30, item 1).

The run of ``test_export`` (two arms, a resume, a teleop label, a success, a violation
with its wait and two-step hard reset, a soft reset without success, a fault, a refused
push; theta_0's demonstrations) exported as npz and as LeRobot, read back by hand and
through the project's own readers; the expected classes are written out from the rules
(``testbed/records/frame_classes.py``) with k = 3, the run's default.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_export import make_run, read_lerobot

from testbed.core.types import EpisodeOutcome, FrameClass
from testbed.datasets import dataset_io, episodes
from testbed.datasets.class_columns import CLASS_COLUMNS, CLASS_NAMES, OUTCOME_NAMES
from testbed.datasets.npz import read_npz
from testbed.records.frame_classes import DEFAULT_PRE_STEPS

R, T, RS, PI, NO, DEMO = (FrameClass.ROBOT, FrameClass.TELEOP, FrameClass.RESET,
                          FrameClass.PRE_INTERVENTION, FrameClass.NONE, FrameClass.DEMO)
OPEN, SUCCESS, VIOLATION, GOAL_CHANGE = (EpisodeOutcome.OPEN, EpisodeOutcome.SUCCESS,
                                         EpisodeOutcome.VIOLATION, EpisodeOutcome.GOAL_CHANGE)
# per arm, per step 0..11: (class, outcome, class episode), k = 3
WANT = {
    0: list(zip([PI, T, R, PI, PI, NO, RS, RS, PI, PI, T, R],
                [SUCCESS] * 3 + [VIOLATION] * 5 + [OPEN] * 4,
                [0] * 3 + [1] * 5 + [2] * 4, strict=True)),
    1: list(zip([R, NO, PI, NO, T, R, R, R, R, R, R, R],
                [GOAL_CHANGE] * 6 + [OPEN] * 6, [0] * 6 + [1] * 6, strict=True)),
}
"""Arm 0: the teleop at 1 (0 before it), the success at 2; the reset at 6 takes over
(3 and the violating push 4 before it; 5 waited idle); the wait and reset are the
violated episode's; the episode after the reset goes on across the resume at 9, so the
teleop at 10 reaches back to 8 and 9. Arm 1: the teleop at 4 reaches 1..3 (a fault,
a push, a refusal), the soft reset at 6 is a goal change, the resume keeps the goal."""
DEMO_WANT = [(DEMO, SUCCESS, 0)] * 4 + [(DEMO, VIOLATION, 1)] * 3
"""The demonstrations: chain a (3 pushes + its last image) ends in a success, chain b
(2 pushes + the violating image) in a violation."""


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_run(tmp_path_factory.mktemp("proto") / "cur-t0")


def check(rows: list[dict[str, int]]) -> None:
    """Each frame's three columns are the rules' (run frames by arm and step)."""
    demo = [(r["frame_class"], r["episode_outcome"], r["class_episode"]) for r in rows
            if r["intervention"] == episodes.DEMO]
    assert demo == DEMO_WANT
    got = {(r["arm"], r["step"]): (r["frame_class"], r["episode_outcome"], r["class_episode"])
           for r in rows if r["intervention"] != episodes.DEMO}
    assert got == {(a, t): w for a, ws in WANT.items() for t, w in enumerate(ws)}


def test_npz_frames_carry_class_outcome_and_episode(run: Path, tmp_path: Path) -> None:
    dataset_io.export([run], "npz", tmp_path / "x.npz")
    with np.load(tmp_path / "x.npz") as z:  # numpy alone
        cols = {k: z[k] for k in (*CLASS_COLUMNS, "intervention", "arm", "step")}
        meta = json.loads(str(z["meta"]))
    check([{k: int(v[i]) for k, v in cols.items()} for i in range(len(cols["arm"]))])
    assert meta["frame_class"] == {str(int(c)): c.name.lower() for c in FrameClass}
    assert meta["episode_outcome"]["2"] == "violation"
    assert meta["runs"][0]["pre_intervention_steps"] == DEFAULT_PRE_STEPS == 3


def test_lerobot_features_name_the_codes_and_frames_carry_them(run: Path,
                                                                tmp_path: Path) -> None:
    dataset_io.export([run], "lerobot", tmp_path / "ds", "png")
    got = read_lerobot(tmp_path / "ds")  # pyarrow, PIL alone
    check(got["rows"])
    feats = got["info"]["features"]
    assert feats["frame_class"]["names"] == CLASS_NAMES == [
        "demo", "robot", "teleop", "reset", "pre_intervention", "none"]
    assert feats["episode_outcome"]["names"] == OUTCOME_NAMES == [
        "open", "success", "violation", "goal_change", "unknown"]
    assert feats["class_episode"] == {"dtype": "int64", "shape": [1], "names": None}
    assert got["testbed"]["frame_class"]["4"] == "pre_intervention"
    assert got["stats"]["frame_class"]["max"] == [int(NO)]


def test_reading_an_export_back_keeps_them(run: Path, tmp_path: Path) -> None:
    dataset_io.export([run], "npz", tmp_path / "x.npz")
    dataset_io.export([run], "lerobot", tmp_path / "ds", "png")
    want = read_npz(tmp_path / "x.npz")
    assert want.notes == []
    for frames in (dataset_io.load_frames(tmp_path / "ds"), dataset_io.load_frames(run)):
        assert frames.notes == []
        for name in CLASS_COLUMNS:
            assert np.array_equal(frames.columns[name], want.columns[name]), name
    check([{k: int(want.columns[k][i]) for k in (*CLASS_COLUMNS, "intervention", "arm",
                                                   "step")} for i in range(len(want))])


def test_an_export_from_before_the_classes_reads_back_with_them_derived(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dataset_io.export([run], "npz", tmp_path / "x.npz")
    with np.load(tmp_path / "x.npz") as z:
        old = {k: z[k] for k in z.files if k not in CLASS_COLUMNS}
    np.savez_compressed(tmp_path / "old.npz", **old)
    want = read_npz(tmp_path / "x.npz")
    frames = dataset_io.load_frames(tmp_path / "old.npz")
    for name in CLASS_COLUMNS:  # the run's k is the default: derived == exported
        assert np.array_equal(frames.columns[name], want.columns[name]), name
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exported before frame classes" in err[0]
    assert f"default k ({DEFAULT_PRE_STEPS})" in err[0]


def test_the_runs_own_k_decides_its_windows(run: Path, tmp_path: Path) -> None:
    mine = tmp_path / "k1"
    shutil.copytree(run, mine)
    (mine / "config.toml").write_text("[learning]\npre_intervention_steps = 1\n")
    dataset_io.export([mine], "npz", tmp_path / "x.npz")
    got = read_npz(tmp_path / "x.npz")
    c = got.columns
    arm0 = (c["arm"] == 0) & (c["intervention"] != episodes.DEMO)
    order = np.argsort(c["step"][arm0])
    # k = 1: only the step right before each takeover (0, 5: idle, so none; 9)
    assert c["frame_class"][arm0][order].tolist() == [PI, T, R, R, R, NO, RS, RS, R, PI, T, R]
    with np.load(tmp_path / "x.npz") as z:
        assert json.loads(str(z["meta"]))["runs"][0]["pre_intervention_steps"] == 1


def test_a_lerobot_export_from_before_the_classes_reads_back_with_them_derived(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import pyarrow.parquet as pq

    out = tmp_path / "ds"
    dataset_io.export([run], "lerobot", out, "png")
    want = read_npz(dataset_io.export([run], "npz", tmp_path / "x.npz").path)
    for f in (out / "data").glob("chunk-*/file-*.parquet"):  # as an older export wrote it
        table = pq.read_table(f)
        pq.write_table(table.drop_columns(list(CLASS_COLUMNS)), f)
    info = json.loads((out / "meta" / "info.json").read_text())
    for name in CLASS_COLUMNS:
        del info["features"][name]
    (out / "meta" / "info.json").write_text(json.dumps(info))
    frames = dataset_io.load_frames(out)
    for name in CLASS_COLUMNS:
        assert np.array_equal(frames.columns[name], want.columns[name]), name
    assert "exported before frame classes" in capsys.readouterr().err
