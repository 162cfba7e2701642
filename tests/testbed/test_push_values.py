"""``testbed values``: every push of a run valued by a learner's value critic (issue 46,
item 1), on the hand-built run of test_export.py (two arms, two sessions, teleop labels,
a success, a violation and its reset, a fault, a refused push) and a real learner.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from test_export import make_run

from testbed.cli import main
from testbed.learning import Learner, Transitions
from testbed.learning.learning_config import LearningConfig
from testbed.records.frame_classes import classify
from testbed.records.push_values import PushValuesError, read_push_values
from testbed.records.store import MODES, RunData

SMALL = LearningConfig(ensemble_size=2, batch_size=8, augmentation_factor=2)


def _learner(path: Path, critics: bool) -> Path:
    learner = Learner(SMALL, seed=0)
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (12, 64, 64, 3), dtype=np.uint8)
    actions = rng.integers(0, 4, 12)
    learner.pretrain(images, actions, steps=2)
    if critics:
        learner.pretrain(transitions=Transitions.build(
            images, actions, images[::-1], np.zeros(12, bool), np.arange(12) % 3 == 0),
            steps=3, critics=["value"])
    learner.save(path)
    return path


def test_every_push_is_valued_with_its_class_and_the_checkpoint_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = make_run(tmp_path / "cur-t0")
    pt = _learner(tmp_path / "learner.pt", critics=True)
    assert main(["values", str(run), "--checkpoint", str(pt)]) == 0
    printed = capsys.readouterr().out
    meta, cols = read_push_values(run)
    frames = RunData.of_run(run).frames()
    pushes = ((frames["action"] >= 0) & frames["observed"]
              & np.isin(frames["mode"], (MODES.index("autonomous"), MODES.index("teleop"))))
    want = frames[pushes]
    assert len(cols["t"]) == pushes.sum() == meta["pushes"] > 15
    assert cols["t"].tolist() == want["t"].tolist() and cols["arm"].tolist() == want["arm"].tolist()
    assert cols["action"].tolist() == want["action"].tolist()
    assert cols["mode"].tolist() == want["mode"].tolist()
    got = Learner.load(pt).push_values(want["image"], want["action"].astype(np.int64))
    np.testing.assert_array_equal(cols["advantage"], got.advantage)
    np.testing.assert_array_equal(cols["value"], got.value)
    np.testing.assert_array_equal(cols["q"], got.q)
    assert cols["policy_action"].tolist() == got.policy_action.tolist()
    classes = classify(frames, 2)
    assert cols["frame_class"].tolist() == classes.classes[pushes].tolist()
    assert cols["outcome"].tolist() == classes.outcomes[pushes].tolist()
    assert meta["checkpoint_sha256"] == hashlib.sha256(pt.read_bytes()).hexdigest()
    assert meta["checkpoint"] == str(pt) and meta["robots"] == ["a/left", "a/right"]
    assert f"{pushes.sum()} pushes valued with {pt}" in printed
    assert "mode teleop: 3 pushes, mean advantage" in printed
    # another checkpoint: computed again, never kept from the older file
    other = _learner(tmp_path / "other.pt", critics=True)
    assert main(["values", str(run), "--checkpoint", str(other)]) == 0
    assert read_push_values(run)[0]["checkpoint"] == str(other)


def test_bad_input_is_one_line_exit_2_and_the_file_untouched(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = make_run(tmp_path / "cur-t0")
    bare = _learner(tmp_path / "bare.pt", critics=False)
    cases = [
        (["values", str(run), "--checkpoint", str(bare)], "value critic never trained"),
        (["values", str(run), "--checkpoint", str(tmp_path / "no.pt")], "no such file"),
        (["values", str(run)], "learner.pt"),  # a run without its final learner
        (["values", str(tmp_path)], "holds no run data"),
        (["values", str(run), "--checkpoint", str(bare), "--truth", "-1"], "--truth"),
    ]
    for argv, words in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], (argv, err)
    assert not (run / "push_values.npz").exists()
    (run / "push_values.npz").write_bytes(b"not npz")
    with pytest.raises(PushValuesError, match="not a push values file"):
        read_push_values(run)
    np.savez(run / "push_values.npz", meta=np.asarray(json.dumps({"format": "x"})),
             **{c: np.zeros(0) for c in ("t", "arm", "mode", "action", "frame_class",
                                         "outcome", "q", "value", "advantage",
                                         "policy_action")})
    with pytest.raises(PushValuesError, match="format 'x'"):
        read_push_values(run)
