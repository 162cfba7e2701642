"""Checkpoints of a trial, written beside the next step instead of in series with it.

A checkpoint is the learner's training state (weights, optimisers, RNG, counters and
the data's sizes: ~the weights' size, whatever the run's length; the data itself is in
the run's data store, ``testbed.records.store``) plus ``state.json`` (the step, the
allocator and priority state). The loop takes a snapshot (a copy in memory) and a
thread writes it while the next step runs. Two alternating learner files and
``state.json`` written last keep every pair on disk consistent whenever the process
dies: resume starts after the step ``state.json`` names. At most one write is in
flight; the next snapshot waits for it, then overwrites the last one's tensors in place
(``Learner.training_state(into=...)``: no fresh memory in the loop's thread). Each
write's size and time are kept (``stats()``: run.json ``checkpoint``).
"""

from __future__ import annotations

import copy
import threading
import time
from pathlib import Path
from typing import Any

from testbed.core.atomic import atomic_write_json
from testbed.core.interrupts import critical


class CheckpointWriter:
    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._writes: list[tuple[int, float]] = []  # (bytes, seconds) per checkpoint
        self._buffer: dict[str, Any] | None = None  # the last snapshot, once written

    def submit(self, t: int, learner: Any, state: dict[str, Any]) -> None:
        """Snapshot now, write in the background (after the previous write finished)."""
        self.wait()
        take = getattr(learner, "training_state", None)
        if callable(take):  # the last snapshot is on disk: its tensors are reused
            snapshot = self._buffer = take(into=self._buffer)
        else:
            snapshot = copy.deepcopy(learner.state_dict())
        name = f"learner-{t % 2}.pt"
        record = {"t": t, "learner": name, **state}

        def write() -> None:
            try:
                from testbed.learning.checkpoint import save_atomic

                began = time.perf_counter()
                path = save_atomic(snapshot, self.run_dir / name)
                atomic_write_json(self.run_dir / "state.json", record)
                self._writes.append((path.stat().st_size, time.perf_counter() - began))
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

    def stats(self) -> dict[str, float]:
        """Checkpoints written by this writer: count, size (last, max) and write time
        (learner file and state.json, each fsynced; mean, max)."""
        if not self._writes:
            return {"writes": 0}
        sizes = [b for b, _ in self._writes]
        times = [s for _, s in self._writes]
        return {"writes": len(self._writes), "bytes_last": sizes[-1], "bytes_max": max(sizes),
                "write_s_mean": sum(times) / len(times), "write_s_max": max(times)}
