"""The folder of one run: its resolved config, its records, its checkpoint.

``runs/<name>/`` holds ``config.toml`` (the resolved config, so a run can be resumed or
repeated without the original file), ``run.json`` (how it was started, its status),
``steps.jsonl`` and ``summary.json`` (the run-record schema: docs/ARCHITECTURE.md),
``data/`` (every arm's frame of every step: ``testbed.records.store``;
``data/demos.npz``: theta_0's offline demonstrations), ``learner-start.pt`` (the
learner the run started from, its data included), ``state.json`` + ``learner-0.pt`` /
``learner-1.pt`` (the checkpoint of the last complete step: weights, optimisers, RNG,
counters; its data is replayed from ``data/``) and, once finished, ``learner.pt`` (the
trained learner, data included: ``testbed evaluate --policy``). A step is *complete* once it is in
data/, steps.jsonl and the checkpoint; resume starts after it.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from testbed.core.atomic import atomic_write_bytes, atomic_write_json
from testbed.core.config import ConfigError, ModelT, StrictModel, parse_model
from testbed.core.humans import unnamed_human

CONFIG = "config.toml"
STEPS = "steps.jsonl"
SUMMARY = "summary.json"
STATE = "state.json"
LEARNER = "learner.pt"
START_LEARNER = "learner-start.pt"
META = "run.json"


def _drop_none(obj: Any) -> Any:
    """TOML has no null: leave unset optional fields out of the resolved config."""
    if isinstance(obj, dict):
        return {k: _drop_none(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, list | tuple):
        return [_drop_none(v) for v in obj]
    return obj


@dataclass(frozen=True)
class RunDir:
    path: Path

    @property
    def steps(self) -> Path:
        return self.path / STEPS

    @property
    def summary(self) -> Path:
        return self.path / SUMMARY

    @property
    def state(self) -> Path:
        return self.path / STATE

    @property
    def learner(self) -> Path:
        return self.path / LEARNER

    @property
    def start_learner(self) -> Path:
        return self.path / START_LEARNER

    def write_config(self, cfg: StrictModel) -> None:
        """config.toml, without the web console's tokens: a run folder is data a lab
        keeps, exports and shares, and a token is a credential. A resumed run gets its
        links back from ``web-links.json`` (mode 0600, only the operator's user reads it:
        ``testbed.experiments.web_links``).
        """
        data = _drop_none(cfg.model_dump(mode="json"))
        web = data.get("humans", {}).get("web", {})
        if web.get("tokens"):
            web["tokens"] = []
        for key in ("overview_token", "operator_token"):
            web.pop(key, None)
        atomic_write_bytes(self.path / CONFIG, tomli_w.dumps(data).encode())

    def read_config(self, model: type[ModelT]) -> ModelT:
        """The run's resolved config as ``model`` (the fleet's: ``FleetConfig``, whose
        room is above this one), or ConfigError in one line."""
        p = self.path / CONFIG
        if not p.exists():
            raise ConfigError(f"{self.path}: not a run folder (no {CONFIG}); check --resume")
        return parse_model(model, tomllib.loads(p.read_text()), str(p))

    def write_meta(self, meta: dict[str, Any]) -> None:
        atomic_write_json(self.path / META, meta)

    def read_meta(self) -> dict[str, Any]:
        p = self.path / META
        return json.loads(p.read_text()) if p.exists() else {}


def new_run_dir(out: str | Path, name: str) -> RunDir:
    """A fresh folder ``out/name`` (``name-2``, ``name-3``... if it is taken)."""
    base = Path(out)
    base.mkdir(parents=True, exist_ok=True)
    p = base / name
    k = 2
    while p.exists():
        p = base / f"{name}-{k}"
        k += 1
    p.mkdir(parents=True)
    return RunDir(p)


EVAL_PREFIX = "eval:"
"""What the records call an evaluation's algorithm: ``eval:<the evaluated algorithm>``."""


def evaluation_label(algorithm: str | None) -> str:
    """The report row of an evaluation of ``algorithm``'s policy (never a training row)."""
    return f"{EVAL_PREFIX}{algorithm or 'policy'}"


def evaluated(policy: Path) -> dict[str, str | None]:
    """What a policy file is: the run it ends (``<run>/learner.pt`` with a run.json) and
    that run's algorithm, else just the file (run.json ``evaluates`` of an evaluation)."""
    meta_path = policy.parent / META
    algorithm = run = None
    if meta_path.exists():
        try:
            options = json.loads(meta_path.read_text()).get("options", {})
            algorithm = options.get("label") or options.get("algorithm")
            run = policy.parent.name
        except (OSError, ValueError, AttributeError):
            pass
    return {"policy": str(policy), "run": run, "algorithm": algorithm}


def human_names(run: Path) -> list[str | None] | None:
    """Each human index's person in a run (run.json ``humans.people[i].name``; None for
    one the config did not name, whose name is the index's ``unnamed_human``), or None
    when its run.json does not list them (a run from before, or no run.json).

    Why here: a row's or frame's ``human`` is an index into this run's people only, so
    whatever leaves the run (an export, a merged training set) carries this list beside
    the index to say who the person was; a default name is no person (two runs' human0
    may be anyone), so it is never taken for one."""
    try:
        people = json.loads((run / META).read_text()).get("humans", {}).get("people")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(people, list) or not all(
            isinstance(p, dict) and isinstance(p.get("name"), str) for p in people):
        return None
    return [None if p["name"] == unnamed_human(i) else p["name"]
            for i, p in enumerate(people)]


def display_names(run: Path, humans: Mapping[str, Any], count: int) -> list[str]:
    """Each of a run's ``count`` human indices by name, for a table: as its run.json
    recorded them (:func:`human_names`; one left unnamed is its ``unnamed_human``); a run
    from before, by its config.toml's ``[humans]`` (``humans``) people."""
    recorded = human_names(run)
    if recorded is not None and len(recorded) == count:
        return [name or unnamed_human(i) for i, name in enumerate(recorded)]
    people = humans.get("people") or []
    return ([str(p["name"]) for p in people] if len(people) == count
            else [unnamed_human(i) for i in range(count)])
