"""Protocol and sweep trials fanned out on Ray (``--workers N`` or ``--ray ADDRESS``).

Why Ray: a protocol's or a sweep's trials are independent once theta_0 exists, and a
lab that outgrows one machine wants them on many, with a trial lost to a dead worker
done again elsewhere. Ray gives exactly that: tasks with dependencies (Random after
the run whose human effort it matches, each evaluation after the run it evaluates),
placement by CPU, and retries of a task whose worker died. It is an optional extra
(``pip install -e ".[ray]"``), imported only here and only on this path; the serial
path (no flag) needs none of it.

How a trial runs: one Ray task per run, calling the same function the serial loop
calls (``run_protocol_run``, ``run_named``), which skips a finished run and resumes
one that has a checkpoint. The run folders live on storage every worker sees (the
driver's ``out``; on a cluster, a shared file system): a trial writes its records
and its checkpoint every step, so when a worker dies mid-trial Ray retries the task
(``max_retries``) and the retry, on any worker, resumes the run from its last
complete step. Returning records to the driver at the end instead would lose a
crashed trial's finished steps and its checkpoint, which is why the folders are
shared.

Before the fan-out one task makes theta_0 (the pretraining cache), holding every CPU
(otherwise every first trial would pretrain the same theta_0 at once) but computing
at the trials' thread count, so theta_0 is the serial run's at that count. A protocol
with ``pretrain_per_trial`` has a theta_0 per trial seed instead, each cached apart: one
task per trial makes it, at the trial's CPUs, and that trial's runs wait for it.

Threads: each trial task takes ``cpus_per_trial`` CPUs and torch uses that many
threads (``TESTBED_THREADS``), so two trials do not oversubscribe the cores. The
numbers of a run depend on its thread count (run.json ``numerics``): a fanned-out
protocol gives the serial run's records when both use the same thread count.

Physical fleets are refused: arms are not interchangeable workers (a trial's arms
are on its hosts, wherever the task would run), and a person at a console cannot
be fanned out either (``humans = "gui"`` or ``"web"``: only scripted humans run on
workers).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from testbed.core.backend_registry import backend_of
from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import FleetConfig

if TYPE_CHECKING:
    from testbed.experiments.protocol import Protocol
    from testbed.experiments.sweep import Sweep

THREADS_ENV = "TESTBED_THREADS"
"""torch's thread count in a process that shares its machine (read by
``configure_torch`` when no count is given)."""

MAX_RETRIES = 3


def check_fanout(fleet: FleetConfig, humans: str, what: str) -> None:
    """ConfigError (exit 2, one line) unless every host is a twin and the humans are
    scripted."""
    physical = [h.name for h in fleet.hosts if not backend_of(h).capabilities.simulated]
    if physical:
        raise ConfigError(
            f"--ray/--workers: {what} drives physical arms (host {physical[0]!r}); arms are "
            "not interchangeable workers: run it without --ray/--workers")
    if humans != "scripted":
        raise ConfigError(f"--ray/--workers: {what} has humans = {humans!r}; only scripted "
                          "humans run on workers: run it without --ray/--workers")


def _init(address: str | None, workers: int | None) -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError('--ray/--workers: Ray is not installed; pip install -e ".[ray]"'
                          ) from None
    root = str(Path(__file__).resolve().parents[2])
    env = {"PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH"))
                                         if p)}
    if address is not None:
        ray.init(address=address, runtime_env={"env_vars": env}, log_to_driver=True)
    else:
        ray.init(num_cpus=workers, runtime_env={"env_vars": env}, include_dashboard=False,
                 object_store_memory=128 * 2**20, log_to_driver=True)
    return ray


def _threads(n: int) -> None:
    os.environ[THREADS_ENV] = str(n)


def _pretrain(fleet: FleetConfig, folder: str, critics: list[str], threads: int,
              seed: int | None = None) -> str:
    """theta_0 pretrained from ``seed`` (None: the shared ``PRETRAIN_SEED``) into
    ``folder/.pretrained`` (the cache the trials then read)."""
    from testbed.experiments.learners import PRETRAIN_SEED, pretrained_learner
    from testbed.experiments.scripted_humans import ScriptedHumans

    _threads(threads)
    _, path = pretrained_learner(fleet, ScriptedHumans(), Path(folder), None, critics=critics,
                                 pretrain_seed=PRETRAIN_SEED if seed is None else seed)
    return str(path)


def _worker_meta() -> dict[str, Any]:
    import ray

    return {"worker": {"node": ray.util.get_node_ip_address(), "pid": os.getpid()}}


def _protocol_run(proto: Protocol, folder: str, k: int, algorithm: str, threads: int,
                  *after: Any) -> str:
    from testbed.experiments.protocol import run_protocol_run

    _threads(threads)
    summary = run_protocol_run(proto, Path(folder), k, algorithm, meta=_worker_meta())
    return str(summary.get("status"))


def _evaluation(proto: Protocol, folder: str, k: int, algorithm: str, threads: int,
                *after: Any, start_of: str | None = None) -> None:
    from testbed.experiments.protocol import evaluate_run

    _threads(threads)
    evaluate_run(proto, Path(folder), algorithm, k, start_of=start_of)


def _sweep_run(sweep: Sweep, folder: str, index: int, threads: int, *after: Any) -> str:
    from testbed.experiments.sweep import run_sweep_run

    _threads(threads)
    return str(run_sweep_run(sweep, Path(folder), index, meta=_worker_meta()).get("status"))


def _remote(ray: Any, fn: Callable[..., Any], cpus: int) -> Any:
    return ray.remote(num_cpus=cpus, max_retries=MAX_RETRIES, retry_exceptions=False)(fn)


def _cpus(ray: Any) -> int:
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def run_protocol_on_ray(proto: Protocol, folder: Path, *, address: str | None = None,
                        workers: int | None = None, cpus_per_trial: int = 1) -> None:
    """Every run of ``proto`` as a Ray task (dependencies as in the serial order:
    Random after the run it matches, each evaluation after its run), theta_0 first.

    With ``until``, trials go out in waves: the first ``trials`` at once, then one trial
    at a time, and after each wave :func:`sequential_decision` reads the finished trials
    exactly as the serial loop does, so a fanned-out protocol stops after the trial the
    serial one stops after and runs no trial past it. Evaluations of finished trials run
    beside the next wave. With ``pretrain_per_trial`` each trial's runs wait for a task
    that pretrains its own theta_0 (at the trial's CPUs) instead."""
    from testbed.experiments.protocol import sequential_decision

    check_fanout(proto.fleet, proto.humans, f"protocol {proto.name!r}")
    critics = protocol_critics(proto)
    ray = _init(address, workers)
    try:
        if not proto.pretrain_per_trial:
            pre = _remote(ray, _pretrain, _cpus(ray))
            ray.get(pre.remote(proto.fleet, str(folder), critics, cpus_per_trial))
        own = _remote(ray, _pretrain, cpus_per_trial)
        trial = _remote(ray, _protocol_run, cpus_per_trial)
        evaluation = _remote(ray, _evaluation, cpus_per_trial)
        evaluations: list[Any] = []
        cache: dict[Path, dict[str, Any]] = {}
        done, wave = 0, proto.trials
        while done < proto.max_trials:
            runs: list[Any] = []
            for k in range(done, min(done + wave, proto.max_trials)):
                theta = ([own.remote(proto.fleet, str(folder), critics, cpus_per_trial,
                                     proto.pretrain_seed(k))]
                         if proto.pretrain_per_trial else [])
                refs = _trial_tasks(proto, folder, k, trial, cpus_per_trial, theta)
                runs.extend(refs.values())
                evaluations.extend(_evaluation_tasks(proto, folder, k, evaluation,
                                                     cpus_per_trial, refs))
            ray.get(runs)
            done = min(done + wave, proto.max_trials)
            if proto.until is None or sequential_decision(proto, folder, done, cache).stop:
                break
            wave = 1
        ray.get(evaluations)
    finally:
        ray.shutdown()


def protocol_critics(proto: Protocol) -> list[str]:
    """The critics a protocol's theta_0 is pretrained with, as ``run_protocol_run`` asks
    (by the algorithm each name runs: a way's name is no algorithm)."""
    return proto.theta0_critics()


def _trial_tasks(proto: Protocol, folder: Path, k: int, trial: Any, cpus: int,
                 theta: list[Any] | None = None) -> dict[str, Any]:
    """Trial ``k``'s runs as tasks, by algorithm (the matched run before Random), each
    after ``theta`` (the task pretraining the trial's own theta_0, if any)."""
    match = proto.fleet.algorithm.budget_match
    done: dict[str, Any] = {}
    for algorithm in proto.run_order(k):
        after = [*(theta or []),
                 *([done[match]] if algorithm == "random" and match in done else [])]
        done[algorithm] = trial.remote(proto, str(folder), k, algorithm, cpus, *after)
    return done


def _evaluation_tasks(proto: Protocol, folder: Path, k: int, evaluation: Any, cpus: int,
                      runs: dict[str, Any]) -> list[Any]:
    """Trial ``k``'s evaluations as tasks, each after the run it evaluates: every final
    policy, theta_0 (``evaluate_start``) and the expert row, as the serial
    ``_evaluate_all`` does."""
    from testbed.experiments.protocol import START

    if not proto.evaluate_steps:
        return []
    refs = [evaluation.remote(proto, str(folder), k, a, cpus, ref) for a, ref in runs.items()]
    order = proto.run_order(k)
    if proto.evaluate_start and order:
        refs.append(evaluation.remote(proto, str(folder), k, START, cpus, runs[order[0]],
                                      start_of=order[0]))
    if proto.evaluate_expert:
        refs.append(evaluation.remote(proto, str(folder), k, "expert", cpus))
    return refs


def run_sweep_on_ray(sweep: Sweep, folder: Path, *, address: str | None = None,
                     workers: int | None = None, cpus_per_trial: int = 1) -> None:
    """Every (point, seed) of ``sweep`` as a Ray task, each distinct theta_0 first."""
    from testbed.experiments.learners import PRETRAIN_SEED
    from testbed.experiments.pretraining import critic_set, pretrain_key
    from testbed.experiments.sweep import pretrain_critics_of

    check_fanout(sweep.fleet, sweep.humans, f"sweep {sweep.name!r}")
    runs = sweep.runs()
    for run in runs:
        check_fanout(run.fleet, sweep.humans, f"sweep {sweep.name!r}")
    critics = pretrain_critics_of(sweep)
    ray = _init(address, workers)
    try:
        pre = _remote(ray, _pretrain, _cpus(ray))
        fleets = {pretrain_key(r.fleet, PRETRAIN_SEED, critic_set(critics)): r.fleet
                  for r in runs} if sweep.policy is None else {}  # a held policy: none
        ray.get([pre.remote(f, str(folder), critics, cpus_per_trial)
                 for f in fleets.values()])
        task = _remote(ray, _sweep_run, cpus_per_trial)
        ray.get([task.remote(sweep, str(folder), i, cpus_per_trial) for i in range(len(runs))])
    finally:
        ray.shutdown()
