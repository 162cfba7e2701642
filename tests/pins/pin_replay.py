"""The learner's outputs, recorded once and replayed: what makes the exact pins of
``test_pinned_records.py`` independent of the CPU that runs them.

Why: the learner's float training picks its kernels by CPU (torch, oneDNN, MKL), so
its outputs are not bit-portable; everything downstream of them (the priorities, the
allocator, the loop, the humans, the twin, the records) is, once those outputs are
given. A ``LearnerBook`` in record mode wraps the real learner of every run
(``RecordingLearner``) and keeps, call by call, what it returned; in replay mode it
hands each run a ``ReplayLearner`` that returns exactly those values, step by step,
and learns nothing. Both log what the loop gave the learner (image digests, actions,
flags), so the pin covers the data path into learning too.

The learners are injected by replacing the two names ``testbed.experiments.trial``
makes its learners with (``pretrained_learner``, ``load_learner``; pytest's
``monkeypatch``), and a ``TrialHooks`` tells the book which run is starting (its
``humans(name)`` is called first in every run). No product code knows about this.

Floats are stored as JSON numbers: every value is a float32 widened to a float64,
whose ``repr`` round-trips exactly, and narrowed back without loss.
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from testbed.core.humans import Humans
from testbed.experiments.hooks import TrialHooks

HERE = Path(__file__).resolve().parent
TRACE = HERE / "learner_trace.json"
"""What the real learner returned in every run of the two scenarios."""
RECORDS = HERE / "pinned_records.json"
"""The records the replay gives: every row, the data store's digest, the learner's calls."""

TIME_FIELDS = ("wall_time", "duration_s")
"""The one part of a row that differs between two runs of one seed."""
META_KEYS = ("thresholds", "budget_matched", "protocol")
"""What run.json says that the pins keep: the resolved quantile thresholds, Random's
matched budget and the protocol's (counterbalanced) order and positions."""
SIGNALS = ("uncertainty", "risk", "goal_risk", "novelty")

LEARNING = {"ensemble_size": 2, "batch_size": 32, "demos": 60, "critic_transitions": 40,
            "pretrain_steps": 10}
"""The real learner's size when the trace is recorded (replay never trains)."""
TRIAL: dict[str, Any] = {"trial": {"steps": 20, "seed": 5}, "learning": LEARNING}
"""A 20-step C.U.R. trial on the default twin fleet: 2 hosts x 2 arms, 2 scripted humans."""
PROTOCOL: dict[str, Any] = {
    "name": "pins", "trials": 2, "algorithms": ["random", "cur", "fleet-td"], "steps": 12,
    "seeds": [1, 2], "out": "proto", "order": "counterbalanced", "evaluate_steps": 12,
    "fleet": {
        "humans": {"count": 1},
        "algorithm": {"t_T": 2, "t_R": 3, "t_I": 2, "u_hat": "q0.5",
                      "random_budget": "match:cur"},
        "learning": LEARNING,
        "hosts": [{"name": f"cell{i}", "arms": [{"name": "left"},
                                                {"name": "right", "mirror": True}]}
                  for i in range(2)],
    },
}
"""2 trials x (Random, C.U.R.), counterbalanced, Random's budget matched to C.U.R.'s, a
quantile u_hat, then each final policy and the expert evaluated: 10 runs, 1 human."""


# ---- the learners ---------------------------------------------------------------------
def _sha(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()[:16]


def _ints(a: Any) -> list[int]:
    return [int(v) for v in np.asarray(a).reshape(-1)]


def _floats(a: Any) -> list[Any]:
    """float32 values as JSON numbers (exact: a float32 widened to float64)."""
    return np.asarray(a, dtype=np.float32).astype(np.float64).tolist()


class _CallLog:
    """What the loop and the trial asked of a learner, one line a call."""

    def __init__(self, run: str) -> None:
        self.run = run
        self.calls: list[str] = []
        self._lock = threading.Lock()

    def _log(self, *words: object) -> None:
        with self._lock:
            self.calls.append(" ".join(str(w) for w in words))

    def _log_add_human(self, images: Any, actions: Any) -> None:
        self._log("add_human", _sha(np.asarray(images)), _ints(actions))

    def _log_add_transitions(self, images: Any, actions: Any, next_images: Any,
                             violation: Any, success: Any) -> None:
        self._log("add_transitions", _sha(np.asarray(images)), _ints(actions),
                  _sha(np.asarray(next_images)), _ints(violation), _ints(success))

    def _log_parts(self, train: Iterable[str] | None, read: Iterable[str] | None) -> None:
        self._log("set_parts", None if train is None else sorted(train),
                  None if read is None else sorted(read))


class RecordingLearner(_CallLog):
    """The real learner, passed through; what it returns is kept (``trace``). It has no
    ``acting_copy``, so the loop acts serially (act, then train), which the loop
    guarantees gives the records of the overlapped order."""

    def __init__(self, run: str, learner: Any) -> None:
        super().__init__(run)
        self.learner = learner
        self.trace: dict[str, Any] = {"signals": None, "act": [], "train": []}

    def act(self, images: np.ndarray) -> Any:
        out = self.learner.act(images)
        self._log("act", _sha(np.asarray(images)))
        self.trace["act"].append({"actions": _ints(out.actions),
                                  "probs": _floats(out.probs),
                                  **{k: _floats(getattr(out, k)) for k in SIGNALS},
                                  **({} if out.ood is None else {"ood": _floats(out.ood)})})
        return out

    def signals_on_data(self) -> dict[str, np.ndarray]:
        got = self.learner.signals_on_data()
        self._log("signals_on_data")
        self.trace["signals"] = {k: _floats(v) for k, v in sorted(got.items())}
        return got

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None:
        self._log_add_human(images, actions)
        self.learner.add_human(images, actions, labellers)

    def add_transitions(self, images: np.ndarray, actions: np.ndarray,
                        next_images: np.ndarray, violation: np.ndarray,
                        success: np.ndarray) -> None:
        self._log_add_transitions(images, actions, next_images, violation, success)
        self.learner.add_transitions(images, actions, next_images, violation, success)

    def train_step(self) -> dict[str, float]:
        losses = self.learner.train_step()
        self._log("train_step")
        self.trace["train"].append({k: float(v) for k, v in sorted(losses.items())})
        return losses

    def set_parts(self, *, train: Iterable[str] | None = None,
                  read: Iterable[str] | None = None) -> None:
        self._log_parts(train, read)
        self.learner.set_parts(train=train, read=read)

    def reseed(self, seed: int) -> None:
        self._log("reseed", seed)
        self.learner.reseed(seed)

    def save(self, path: str | Path) -> Path:
        self._log("save", Path(path).name)
        return self.learner.save(path)

    def training_state(self, into: dict[str, Any] | None = None) -> dict[str, Any]:
        return self.learner.training_state(into=into)


class ReplayLearner(_CallLog):
    """The learner API the loop and the trial use, answering from a recorded trace:
    the i-th ``act`` returns the i-th recorded output, ``signals_on_data`` the recorded
    arrays, ``train_step`` the recorded losses; nothing is learned. A trace that runs
    out is an error (the trial asked for more than the real learner gave)."""

    def __init__(self, run: str, trace: Mapping[str, Any]) -> None:
        super().__init__(run)
        self.trace = trace
        self._acts = 0
        self._trains = 0

    def act(self, images: np.ndarray) -> Any:
        from testbed.learning.api import PolicyOutput

        self._log("act", _sha(np.asarray(images)))
        recorded = self.trace["act"]
        if self._acts >= len(recorded):
            raise AssertionError(f"{self.run}: act call {self._acts + 1}, but the trace "
                                 f"has {len(recorded)}")
        r = recorded[self._acts]
        self._acts += 1
        if len(r["actions"]) != len(images):
            raise AssertionError(f"{self.run}: act on {len(images)} images, the trace's "
                                 f"call {self._acts} was on {len(r['actions'])}")
        f32 = {k: np.asarray(r[k], dtype=np.float32) for k in ("probs", *SIGNALS, "ood")
               if k in r}
        return PolicyOutput(np.asarray(r["actions"], dtype=np.int64), f32["probs"],
                            f32["uncertainty"], f32["risk"], f32["goal_risk"],
                            f32["novelty"], f32.get("ood"))

    def signals_on_data(self) -> dict[str, np.ndarray]:
        self._log("signals_on_data")
        signals = self.trace["signals"]
        if signals is None:
            raise AssertionError(f"{self.run}: signals_on_data was not called when recorded")
        return {k: np.asarray(v, dtype=np.float32) for k, v in signals.items()}

    def add_human(self, images: np.ndarray, actions: np.ndarray,
                  labellers: np.ndarray | None = None) -> None:
        self._log_add_human(images, actions)

    def add_transitions(self, images: np.ndarray, actions: np.ndarray,
                        next_images: np.ndarray, violation: np.ndarray,
                        success: np.ndarray) -> None:
        self._log_add_transitions(images, actions, next_images, violation, success)

    def train_step(self) -> dict[str, float]:
        self._log("train_step")
        recorded = self.trace["train"]
        losses = dict(recorded[self._trains]) if self._trains < len(recorded) else {}
        self._trains += 1
        return losses

    def set_parts(self, *, train: Iterable[str] | None = None,
                  read: Iterable[str] | None = None) -> None:
        self._log_parts(train, read)

    def reseed(self, seed: int) -> None:
        self._log("reseed", seed)

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint of this learner holds (``CheckpointWriter``)."""
        return {"replay": self.run, "acts": self._acts, "trains": self._trains}

    def save(self, path: str | Path) -> Path:
        """A marker file where the policy would be (an evaluation checks it exists)."""
        self._log("save", Path(path).name)
        target = Path(path)
        target.write_text(json.dumps(self.state_dict()) + "\n")
        return target


class LearnerBook:
    """Every run's learner: recording the real one (``traces`` None) or replaying
    ``traces`` (run name -> trace). ``current`` is the run starting now (``BindRuns``)."""

    def __init__(self, traces: Mapping[str, Any] | None = None) -> None:
        self.recording = traces is None
        self.traces: dict[str, Any] = {} if traces is None else dict(traces)
        self.learners: dict[str, _CallLog] = {}
        self.current: str | None = None

    def _run(self) -> str:
        if self.current is None:
            raise AssertionError("a learner was asked for before any run started")
        if self.current in self.learners:
            raise AssertionError(f"{self.current}: a second learner for one run")
        return self.current

    def recorder(self, learner: Any) -> RecordingLearner:
        run = self._run()
        rec = RecordingLearner(run, learner)
        self.learners[run] = rec
        self.traces[run] = rec.trace
        return rec

    def replayer(self) -> ReplayLearner:
        run = self._run()
        if run not in self.traces:
            raise AssertionError(f"{run}: no recorded trace (runs recorded: "
                                 f"{sorted(self.traces)}); re-record on purpose")
        rep = ReplayLearner(run, self.traces[run])
        self.learners[run] = rep
        return rep

    def calls(self, run: str) -> list[str]:
        learner = self.learners.get(run)
        return [] if learner is None else learner.calls


class BindRuns(TrialHooks):
    """Tells the book which run starts: ``humans(name)`` comes first in every run
    (``run_trial``), training runs and evaluations alike; the config's humans are used."""

    def __init__(self, book: LearnerBook) -> None:
        self.book = book

    def humans(self, name: str) -> Humans | None:
        self.book.current = name
        return None


def use_book(monkeypatch: pytest.MonkeyPatch, book: LearnerBook) -> None:
    """The trial's learners come from ``book``: theta_0 and a given policy alike."""
    import testbed.experiments.trial as trial
    from testbed.experiments import learners

    real_pretrained: Callable[..., Any] = learners.pretrained_learner
    real_load: Callable[..., Any] = learners.load_learner

    def pretrained_learner(cfg: Any, humans: Any, out: Path, progress: Any,
                           hosts: Any = None, trial_seed: int | None = None,
                           critics: Iterable[str] | None = None,
                           pretrain_seed: int = learners.PRETRAIN_SEED) -> tuple[Any, Path]:
        if book.recording:
            learner, ckpt = real_pretrained(cfg, humans, out, progress, hosts=hosts,
                                            trial_seed=trial_seed, critics=critics,
                                            pretrain_seed=pretrain_seed)
            return book.recorder(learner), ckpt
        return book.replayer(), Path(out) / ".pretrained" / "replayed" / "learner.pt"

    def load_learner(cfg: Any, path: Path) -> Any:
        if book.recording:
            return book.recorder(real_load(cfg, path))
        return book.replayer()

    monkeypatch.setattr(trial, "pretrained_learner", pretrained_learner)
    monkeypatch.setattr(trial, "load_learner", load_learner)


# ---- the scenarios --------------------------------------------------------------------
def run_trial_scenario(root: Path, book: LearnerBook,
                       hooks: BindRuns | None = None) -> dict[str, Any]:
    """``TRIAL`` as ``testbed trial --config trial.toml --name trial`` runs it (``hooks``:
    ``BindRuns(book)`` or one of its kind)."""
    from testbed.experiments.fleet_config import parse_config
    from testbed.experiments.trial import TrialOptions, run_trial

    cfg = parse_config(TRIAL, "pins trial")
    opts = TrialOptions(algorithm=cfg.algorithm.name, steps=cfg.trial.steps,
                        seed=cfg.trial.seed, out=str(root / "runs"),
                        humans=cfg.humans.kind, name="trial")
    run_trial(cfg, opts, hooks=hooks or BindRuns(book))
    return pins_of(root / "runs", book)


def run_protocol_scenario(root: Path, book: LearnerBook,
                          hooks: BindRuns | None = None) -> dict[str, Any]:
    """``PROTOCOL`` as ``testbed protocol`` runs it, without its prompts and its time
    plan (which times real gradient steps, several seconds of CPU, for an estimate the
    pins never read; it draws from no random stream the runs use)."""
    from testbed.experiments.protocol import Protocol, run_protocol

    proto = Protocol.model_validate(PROTOCOL)
    run_protocol(proto, out=str(root / "proto"), ask=False, hooks=hooks or BindRuns(book),
                 plan=False)
    return pins_of(root / "proto", book)


# ---- what is pinned -------------------------------------------------------------------
def dump_json(value: Any, depth: int = 0) -> str:
    """JSON with every item from depth 4 on one line (a step's row, an act call's
    outputs) and every short one too: a changed step is a changed line of the diff."""
    flat = json.dumps(value, sort_keys=True)
    if depth >= 4 or len(flat) <= 96 or not isinstance(value, dict | list):
        return flat
    pad = " " * (depth + 1)
    if isinstance(value, dict):
        items = [f"{pad}{json.dumps(k)}: {dump_json(v, depth + 1)}"
                 for k, v in sorted(value.items())]
        return "{\n" + ",\n".join(items) + "\n" + " " * depth + "}"
    items = [pad + dump_json(v, depth + 1) for v in value]
    return "[\n" + ",\n".join(items) + "\n" + " " * depth + "]"


def _rows(path: Path) -> list[dict[str, Any]]:
    rows = []
    for line in path.read_text().splitlines():
        row = json.loads(line)
        for k in TIME_FIELDS:
            row.pop(k, None)
        rows.append(row)
    return rows


def data_digest(folder: Path) -> str:
    """Every frame of every chunk, its ``wall_time`` zeroed (dtype from meta.json)."""
    meta = json.loads((folder / "meta.json").read_text())
    dtype = np.dtype([(n, k, tuple(s)) if s else (n, k) for n, k, s in meta["dtype"]])
    h = hashlib.sha256(json.dumps(meta["robots"]).encode())
    for chunk in sorted(folder.glob("frames-*.bin")):
        frames = np.fromfile(chunk, dtype=dtype).copy()
        frames["wall_time"] = 0.0
        h.update(frames.tobytes())
    return h.hexdigest()


def pins_of(runs: Path, book: LearnerBook) -> dict[str, Any]:
    """Per run folder: its rows (timing aside), the digest of its data store's frames
    (wall_time zeroed), run.json's ``META_KEYS`` and the digest of its learner's calls."""
    return {run.name: pins_of_run(run, book)
            for run in sorted(p for p in runs.iterdir() if (p / "steps.jsonl").exists())}


def pins_of_run(run: Path, book: LearnerBook) -> dict[str, Any]:
    """One run folder's pins (:func:`pins_of`)."""
    meta = json.loads((run / "run.json").read_text())
    calls = book.calls(run.name)
    return {
        "rows": _rows(run / "steps.jsonl"),
        "data": data_digest(run / "data"),
        "meta": {k: meta[k] for k in META_KEYS if k in meta},
        "learner_calls": {"count": len(calls), "sha256": hashlib.sha256(
            "\n".join(calls).encode()).hexdigest()},
    }


def differences(got: Mapping[str, Any], want: Mapping[str, Any]) -> list[str]:
    """What differs between two sets of pins, one line each (empty: the same)."""
    lines: list[str] = []
    if sorted(got) != sorted(want):
        lines.append(f"runs: {sorted(got)} != pinned {sorted(want)}")
    for name in sorted(set(got) & set(want)):
        g, w = got[name], want[name]
        for t, (gr, wr) in enumerate(zip(g["rows"], w["rows"], strict=False)):
            if gr != wr:
                lines.append(f"{name}: step {t} first differs:\n  got    "
                             f"{json.dumps(gr, sort_keys=True)}\n  pinned "
                             f"{json.dumps(wr, sort_keys=True)}")
                break
        if len(g["rows"]) != len(w["rows"]):
            lines.append(f"{name}: {len(g['rows'])} steps, pinned {len(w['rows'])}")
        for key in ("data", "meta", "learner_calls"):
            if g[key] != w[key]:
                lines.append(f"{name}: {key} {g[key]} != pinned {w[key]}")
    return lines
