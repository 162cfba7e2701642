"""What an export reads: the runs with a data store and their offline demonstrations.

Why apart: which folders count as runs, how many of their steps are complete, and where
a run's theta_0 demonstrations lie (its own ``data/demos.npz``, else the protocol's
pretraining cache) follow the run folder's layout (``testbed.records.run_dir``), not
what an episode is. Everything left out is one line in ``Sources.notes``, printed by
the verbs.
"""

from __future__ import annotations

import hashlib
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np

from testbed.core.config import ConfigError
from testbed.records.steps import RecordError, read_steps
from testbed.records.store import RunData, RunDataError

DEMO_FIELDS: Final = ("images", "actions", "next_images", "violation", "success")
"""``testbed.experiments.pretraining.FIELDS`` (not imported: that module pulls in the fleet)."""


@dataclass
class Sources:
    """What an export reads: runs with a data store, the demonstrations files (each
    once, however many runs share it), and one line per thing left out."""

    runs: list[tuple[Path, int]] = field(default_factory=list)
    """(run folder, complete steps)."""
    demos: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        """``source_index`` -> what it is (runs first, then demonstrations files)."""
        return [str(r) for r, _ in self.runs] + [f"demos:{d}" for d in self.demos]


def complete_steps(run: Path) -> int:
    """Steps both in the data store and in steps.jsonl (a crash may leave one ahead);
    RecordError if steps.jsonl cannot be read, RunDataError without a data store."""
    stored = RunData.of_run(run).num_steps
    return min(stored, len(read_steps(run, validate=False)))


def load_demos(path: Path) -> dict[str, np.ndarray]:
    """A demonstrations file's ``DEMO_FIELDS``; ConfigError if one is missing."""
    with np.load(path) as z:
        missing = [k for k in DEMO_FIELDS if k not in z.files]
        if missing:
            raise ConfigError(f"{path}: not a demonstrations file (missing "
                              f"{', '.join(missing)})")
        return {k: z[k] for k in DEMO_FIELDS}


def _run_folders(d: Path) -> list[Path]:
    if (d / "steps.jsonl").exists():
        return [d]
    return sorted(p.parent for p in d.glob("*/steps.jsonl"))


def _demos_of(run: Path) -> tuple[Path | None, str | None]:
    """The run's theta_0 demonstrations, or why there are none (one line)."""
    own = run / "data" / "demos.npz"
    if own.exists():
        return own, None
    cached = sorted((run.parent / ".pretrained").glob("*/demos.npz"))
    if len(cached) == 1:
        return cached[0], None
    why = "none" if not cached else f"{len(cached)}, not one"
    return None, (f"{run}: no data/demos.npz and {why} in ../.pretrained/*/demos.npz; "
                  "its offline demonstrations are not exported")


def find_sources(dirs: Sequence[Path], flag: str = "RUN_OR_PROTOCOL_DIR") -> Sources:
    """The runs in or below ``dirs`` that have a data store, and their demos files."""
    src = Sources()
    seen_demos: set[str] = set()
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"{flag}: no such folder {str(d)!r}")
        for run in _run_folders(d):
            try:
                steps = complete_steps(run)
            except RunDataError:
                src.notes.append(f"{run}: no data store (data/meta.json: made before "
                                 "runs kept their frames); skipped")
                continue
            except RecordError as exc:
                src.notes.append(f"{run}: steps.jsonl unreadable ({exc}); skipped")
                continue
            if steps == 0:
                src.notes.append(f"{run}: no complete step in its data store; skipped")
                continue
            src.runs.append((run, steps))
            demos, why = _demos_of(run)
            if why is not None:
                src.notes.append(why)
            if demos is not None:
                digest = hashlib.sha256(demos.read_bytes()).hexdigest()
                if digest in seen_demos:  # a protocol's runs share theta_0's
                    continue
                seen_demos.add(digest)
                try:
                    load_demos(demos)
                except (ConfigError, OSError, ValueError, zipfile.BadZipFile) as exc:
                    why = " ".join(str(exc).split())[:120]
                    src.notes.append(f"{demos}: unreadable ({why}); not exported")
                    continue
                src.demos.append(demos)
    if not src.runs:
        raise ConfigError(f"{flag}: no run with a data store (data/meta.json) in "
                          f"{', '.join(map(str, dirs))}; give run or protocol folders")
    return src
