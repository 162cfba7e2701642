"""Who gave each label, by name, through exports and ``testbed train`` (issue 37).

A frame's ``human`` is an index into its own run's people (run.json ``humans.people``),
so two runs' indices say nothing of each other. Two runs of ``test_export``'s plan
(human 0 teleoperates twice, human 1 once) with people ``["ana", "bo"]`` and ``["cy",
"ana"]``: ana is index 0 in one and 1 in the other, cy has ana's first index. Exported
(npz and LeRobot), merged, trained on: ana is one labeller, cy another; an export of
the layout before names reads back with each labeller its run and index, said so.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from test_export import DEMOS, make_run

from testbed.cli import main
from testbed.datasets import dataset_io, episodes
from testbed.datasets.npz import read_npz
from testbed.datasets.training import TrainingData, training_data
from testbed.people.people_config import HumansConfig
from testbed.records.run_dir import human_names

PEOPLE = (["ana", "bo"], ["cy", "ana"])
"""Each run's people by human index (its run.json)."""


def named_run(run: Path, people: list[str]) -> Path:
    make_run(run)
    meta = json.loads((run / "run.json").read_text())
    meta["humans"] = {"kind": "gui", "people": [{"name": n} for n in people]}
    (run / "run.json").write_text(json.dumps(meta))
    return run


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("people")
    return (named_run(root / "one", PEOPLE[0]), named_run(root / "two", PEOPLE[1]))


def who(data: TrainingData) -> Counter[str]:
    """Labels per labeller, by the labeller's name (offline demonstrations apart)."""
    return Counter(data.labeller_names[c] for c in data.labellers.tolist() if c >= 0)


def test_exports_name_each_runs_people_and_merges_tell_labellers_by_name(
        runs: tuple[Path, Path], tmp_path: Path) -> None:
    one, two = runs
    assert human_names(one) == PEOPLE[0]
    dataset_io.export([one], "npz", tmp_path / "one.npz")
    dataset_io.export([two], "lerobot", tmp_path / "two", "png")
    with np.load(tmp_path / "one.npz") as z:  # numpy alone: the meta names the people
        assert json.loads(str(z["meta"]))["runs"][0]["people"] == PEOPLE[0]
    assert json.loads((tmp_path / "two" / "meta" / "testbed.json").read_text()
                      )["runs"][0]["people"] == PEOPLE[1]
    parts = [training_data(dataset_io.load_frames(p))
             for p in (tmp_path / "one.npz", tmp_path / "two")]
    assert who(parts[0]) == {"ana": 2, "bo": 1} and who(parts[1]) == {"cy": 2, "ana": 1}
    merged = TrainingData.merge(parts)
    # ana (index 0, then 1) is one labeller; cy (index 0 like ana's first) is not ana
    assert who(merged) == {"ana": 3, "bo": 1, "cy": 2}
    assert sorted(merged.labeller_names) == ["ana", "bo", "cy"]
    assert (merged.labellers == -1).sum() == 2 * DEMOS
    # one export of both runs: the same labellers (source by source)
    dataset_io.export([one.parent], "npz", tmp_path / "both.npz")
    assert who(training_data(read_npz(tmp_path / "both.npz"))) == who(merged)
    # run folders read directly name them too
    assert who(training_data(dataset_io.load_frames(one.parent))) == who(merged)


def test_train_on_merged_exports_keeps_labellers_by_name(
        runs: tuple[Path, Path], tmp_path: Path) -> None:
    from testbed.learning import Learner

    one, two = runs
    dataset_io.export([one], "npz", tmp_path / "one.npz")
    dataset_io.export([two], "npz", tmp_path / "two.npz")
    cfg = tmp_path / "small.toml"
    cfg.write_text("[learning]\nensemble_size = 2\nbatch_size = 8\naugmentation_factor = 2\n")
    out = tmp_path / "learner.pt"
    assert main(["train", "--config", str(cfg), "--data", str(tmp_path / "one.npz"),
                 str(tmp_path / "two.npz"), "--steps", "1", "--out", str(out)]) == 0
    learner = Learner.load(out)
    names = learner.labeller_names
    assert sorted(names) == ["ana", "bo", "cy"]
    assert Counter(names[c] for c in learner.labellers.tolist() if c >= 0) == {
        "ana": 3, "bo": 1, "cy": 2}


def _before_names(npz: Path, out: Path, drop: str) -> Path:
    """``npz`` as an export of the layout before names (no ``people`` in its meta) and
    before column ``drop``."""
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files if k != drop}
    meta = json.loads(str(arrays["meta"]))
    for r in meta["runs"]:
        del r["people"]
    arrays["meta"] = np.asarray(json.dumps(meta))
    np.savez_compressed(out, **arrays)
    return out


def test_an_export_before_names_and_a_column_reads_with_labellers_by_run_and_index(
        runs: tuple[Path, Path], tmp_path: Path) -> None:
    one, two = runs
    dataset_io.export([one], "npz", tmp_path / "one.npz")
    dataset_io.export([two], "npz", tmp_path / "two.npz")
    old = [_before_names(tmp_path / f"{n}.npz", tmp_path / f"old-{n}.npz", "risk")
           for n in ("one", "two")]
    frames = read_npz(old[0])
    assert np.isnan(frames.columns["risk"]).all()  # a column it lacks: not known
    assert any("risk" in n and "not known" in n for n in frames.notes)
    assert any("before people's names" in n for n in frames.notes)
    merged = TrainingData.merge([training_data(read_npz(p)) for p in old])
    # names unknown: index 0 of one run is not index 0 of the other, and says so
    assert who(merged) == {f"human 0 of {one} (unnamed)": 2, f"human 1 of {one} (unnamed)": 1,
                           f"human 0 of {two} (unnamed)": 2, f"human 1 of {two} (unnamed)": 1}
    # a LeRobot export before names: the same (meta/testbed.json without people)
    dataset_io.export([two], "lerobot", tmp_path / "lr", "png")
    meta_path = tmp_path / "lr" / "meta" / "testbed.json"
    meta = json.loads(meta_path.read_text())
    del meta["runs"][0]["people"]
    meta_path.write_text(json.dumps(meta))
    frames = dataset_io.load_frames(tmp_path / "lr")
    assert any("before people's names" in n for n in frames.notes)
    assert who(training_data(frames)) == {f"human 0 of {two} (unnamed)": 2,
                                          f"human 1 of {two} (unnamed)": 1}
    # an export missing a column the learner's data needs is not read as one
    bare = _before_names(tmp_path / "one.npz", tmp_path / "bare.npz", "human")
    with pytest.raises(Exception, match="missing human"):
        read_npz(bare)


def test_a_new_store_field_is_an_export_column_with_no_edit() -> None:
    """The export's columns are the store's ``FRAME_DTYPE`` (``t`` as ``step``, integers
    as int64) and the export's own, each declared once."""
    store = {episodes.RENAMED.get(n, n) for n in episodes.FRAME_DTYPE.names or ()} - {"image"}
    own = {n for n, _, _ in episodes.EXPORT_ONLY}
    assert {n for n, _, _ in episodes.COLUMNS} == store | own and not store & own
    for name, dtype, shape in episodes.COLUMNS:
        if name in store:
            field = {v: k for k, v in episodes.RENAMED.items()}.get(name, name)
            base = episodes.FRAME_DTYPE[field]
            assert shape == base.shape
            assert dtype == ("int64" if base.base.kind in "iu" else base.base.name)


def test_a_name_the_config_did_not_give_names_no_one(tmp_path: Path) -> None:
    """Without ``[[humans.people]]`` the humans are called ``human0``, ``human1``...:
    that is an index, not a person, so two such runs' human0 are two labellers."""
    defaults = HumansConfig(count=2).names  # what run.json then lists
    one = named_run(tmp_path / "one", defaults)
    two = named_run(tmp_path / "two", [defaults[0], "bo"])
    assert human_names(one) == [None, None] and human_names(two) == [None, "bo"]
    dataset_io.export([one.parent], "npz", tmp_path / "both.npz")
    assert who(training_data(read_npz(tmp_path / "both.npz"))) == {
        f"human 0 of {one} (unnamed)": 2, f"human 1 of {one} (unnamed)": 1,
        f"human 0 of {two} (unnamed)": 2, "bo": 1}
