"""A protocol serial vs fanned out on a local Ray (issue 12, item 5).

A short version of ``protocols/twin.toml`` (its fleet and learner: 4 arms, 2 scripted
humans, 5 members at batch 64; ``--trials`` x {Fleet-ED, C.U.R.} x ``--steps``, no
evaluation) run twice from the same warm theta_0: serially as ``testbed protocol``
runs it (torch on every core), then with ``--workers N`` (N trials at a time, one
torch thread each). Printed: both wall times and the ratio serial / fanned out
(target >= 1.6 on this 2-core machine). theta_0 is made once before both and copied,
so neither pays for pretraining.

    .venv/bin/python benchmarks/bench_fanout.py [--trials 2] [--steps 60] [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]


def _run(args: list[str], cwd: Path) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "testbed.cli", *args], cwd=cwd, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=2)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    proto = tomllib.loads((ROOT / "protocols" / "twin.toml").read_text())
    proto.update(trials=args.trials, algorithms=["fleet-ed", "cur"], steps=args.steps,
                 seeds=list(range(args.trials)), evaluate_steps=0)
    proto["fleet"]["algorithm"].pop("random_budget", None)
    work = Path(tempfile.mkdtemp(prefix="bench-fanout-", dir=Path.cwd()))
    try:
        (work / "p.toml").write_text(tomli_w.dumps(proto))
        warm = dict(proto, trials=1, algorithms=["cur"], steps=1, seeds=[0])
        (work / "warm.toml").write_text(tomli_w.dumps(warm))
        s = _run(["protocol", "warm.toml", "--yes", "--out", "warm"], work)
        print(f"theta_0 (once, copied to both): {s:.0f} s; load {os.getloadavg()[0]:.2f}",
              flush=True)
        for out in ("serial", "fan"):
            shutil.copytree(work / "warm" / ".pretrained", work / out / ".pretrained")
        serial = _run(["protocol", "p.toml", "--yes", "--out", "serial"], work)
        print(f"serial ({args.trials} trials x 2 algorithms x {args.steps} steps): "
              f"{serial:.0f} s", flush=True)
        fan = _run(["protocol", "p.toml", "--out", "fan", "--workers", str(args.workers)],
                   work)
        print(f"--workers {args.workers}: {fan:.0f} s (Ray's start-up included)")
        print(f"ratio serial / fanned out = {serial / fan:.2f} (target >= 1.6); "
              f"load {os.getloadavg()[0]:.2f}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
