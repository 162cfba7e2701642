"""Checkpoints of a trial, written beside the next step instead of in series with it.

A checkpoint is the learner (weights, optimisers, data, RNG: ~50 MB with the paper's
10x-augmented demos) plus ``state.json`` (the step, the allocator and priority state).
Writing 50 MB with fsync takes ~0.2 s here, a fifth of a training step, so the loop
only takes a snapshot (a copy in memory, tens of ms) and a thread writes it while the
next step runs. Two alternating learner files and ``state.json`` written last keep
every pair on disk consistent whenever the process dies: resume starts after the step
``state.json`` names. At most one write is in flight; the next snapshot waits for it.
"""

from __future__ import annotations

import copy
import threading
from pathlib import Path
from typing import Any

from testbed.interrupts import critical
from testbed.records import atomic_write_json


class CheckpointWriter:
    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def submit(self, t: int, learner: Any, state: dict[str, Any]) -> None:
        """Snapshot now, write in the background (after the previous write finished)."""
        self.wait()
        take = getattr(learner, "snapshot", None)  # the Learner copies its data once
        snapshot = take() if callable(take) else copy.deepcopy(learner.state_dict())
        name = f"learner-{t % 2}.pt"
        record = {"t": t, "learner": name, **state}

        def write() -> None:
            try:
                from testbed.learning.checkpoint import save_atomic

                save_atomic(snapshot, self.run_dir / name)
                atomic_write_json(self.run_dir / "state.json", record)
            except BaseException as exc:  # reported to the loop at the next submit/wait
                self._error = exc

        self._thread = threading.Thread(target=write, name=f"checkpoint-{t}", daemon=True)
        self._thread.start()

    def wait(self) -> None:
        """Block until the write in flight is on disk; re-raise its failure."""
        if self._thread is not None:
            with critical():
                self._thread.join()
            self._thread = None
        if self._error is not None:
            err, self._error = self._error, None
            raise RuntimeError(f"checkpoint write failed: {err}") from err
