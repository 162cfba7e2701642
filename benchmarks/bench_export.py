"""How fast and how big is ``testbed export``, per image encoding? (issue 14, items 2-3)

Why this exists: ``--images`` offers PNG bytes in the parquet and MP4 video, and the
default is chosen by what this measures: export throughput, size per 1000 frames,
decode speed (reading every image back, as ``testbed train`` does) and how far the
decoded pixels are from the store's. Frames come from a real twin run (PyBullet cells,
the expert with 30 % random pushes, hard resets) and, as a stand-in for camera frames
(hardware), the same frames with sensor-like noise (Gaussian, sigma 4 levels).

Every figure is also printed as a ratio against a reference measured in the same run:
the raw uint8 images (12,288 bytes a frame) written to and read from one file, so the
ratios hold on a busy machine. Encodings: PNG at zlib 1 and 6 (LeRobot's level), the
npz (numpy's zip deflate), H.264 4:4:4 CRF 18 (``--images video``), and what else this
PyAV offers: H.264 4:2:0 CRF 23 (the usual setting), SVT-AV1 (LeRobot's default:
4:2:0, CRF 30, preset 12), HEVC 4:2:0 CRF 28.

    .venv/bin/python benchmarks/bench_export.py [--steps 150] [--cells 4]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim_twin import TwinCell
from testbed.datasets.dataset_io import export
from testbed.datasets.episodes import gather, iter_episodes
from testbed.datasets.lerobot import read_dataset
from testbed.datasets.npz import read_npz
from testbed.datasets.sources import find_sources
from testbed.datasets.video import VideoCodec
from testbed.records.step_record import StepRecord
from testbed.records.steps import RunWriter
from testbed.records.store import RunDataWriter

os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1's banner: errors only

ENCODINGS: dict[str, dict[str, Any]] = {
    "png zlib 1": {"images": "png", "png_level": 1},
    "png zlib 6 (--images png)": {"images": "png", "png_level": 6},
    "h264 4:4:4 crf18 (--images video)": {"images": "video"},
    "h264 4:2:0 crf23": {"images": "video", "codec": VideoCodec(pix_fmt="yuv420p", crf=23)},
    "svt-av1 4:2:0 crf30 (LeRobot's)": {"images": "video", "codec": VideoCodec(
        "libsvtav1", "yuv420p", 30, 2, (("preset", "12"),))},
    "hevc 4:2:0 crf28": {"images": "video", "codec": VideoCodec(
        "libx265", "yuv420p", 28, 2, (("x265-params", "log-level=none"),))},
}


def make_run(folder: Path, steps: int, cells: int, noise: float) -> Path:
    """A twin run's data store and steps.jsonl (autonomous pushes, some teleop)."""
    rng = np.random.default_rng(0)
    twins = [TwinCell(seed=k) for k in range(cells)]
    arms = [(c, a) for c in twins for a in c.arm_names]
    robots = [f"cell{k}/{a}" for k, c in enumerate(twins) for a in c.arm_names]
    data = RunDataWriter(folder, robots)
    with RunWriter(folder) as w:
        for t in range(steps):
            obs = {id(c): c.observe() for c in twins}
            images = np.stack([obs[id(c)][a] for c, a in arms])
            if noise:
                images = np.clip(images + rng.normal(0, noise, images.shape), 0, 255
                                 ).astype(np.uint8)
            goals = np.array([c.arm_state(a).goal_xy for c, a in arms], np.float32)
            rows, pushes = [], {id(c): {} for c in twins}
            for (c, a), name in zip(arms, robots, strict=True):
                if c.arm_state(a).violating:
                    c.hard_reset(a)
                    rows.append({"robot": name, "mode": "reset", "human": 0, "action": None})
                    continue
                teleop = rng.random() < 0.1
                face = c.expert_action(a) if teleop or rng.random() < 0.7 else int(
                    rng.integers(4))
                pushes[id(c)][a] = face
                rows.append({"robot": name, "mode": "teleop" if teleop else "autonomous",
                             "human": 0 if teleop else None, "action": face})
            outcome = {}
            for c in twins:
                outcome.update({(id(c), a): o for a, o in c.push(pushes[id(c)]).items()})
            for (c, a), r in zip(arms, rows, strict=True):
                o = outcome.get((id(c), a))
                r.update(success=bool(o and o.success), violation=bool(o and o.violation),
                         uncertainty=0.1, risk=0.2, key=[0.0])
            row = {"t": t, "robots": rows, "wall_time": time.time()}
            record = StepRecord.from_row(row, 0, images, np.ones(len(arms), bool), goals)
            data.append(record.to_frames())
            w.write_step(row)
    data.close()
    for c in twins:
        c.close()
    return folder


def _quiet(_: str) -> None:
    """The bench's runs have no demonstrations; the export's note about it is known."""


def _timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() \
        else path.stat().st_size


def bench(run: Path, work: Path) -> None:
    exact = gather(iter_episodes(find_sources([run])))
    n = len(exact)
    raw = work / "raw.bin"
    t_raw_w, _ = _timed(lambda: exact.images.tofile(raw))
    t_raw_r, _ = _timed(lambda: np.fromfile(raw, np.uint8))
    raw_kb = exact.images[0].nbytes * 1000 / 1024
    print(f"  reference raw uint8: {n / t_raw_w:,.0f} frames/s written, {raw_kb:,.0f} KB per "
          f"1000 frames, {n / t_raw_r:,.0f} frames/s read")
    print(f"  {'encoding':36s} {'export f/s':>10s} {'x raw':>8s} {'KB/1000':>9s} "
          f"{'x raw':>6s} {'decode f/s':>10s} {'x raw':>8s} {'PSNR min':>8s} {'|err|':>6s}")
    cases: list[tuple[str, Callable[[Path], Any], Callable[[Path], np.ndarray]]] = [
        ("npz (np.savez_compressed)",
         lambda p: export([run], "npz", p / "f.npz", note=_quiet),
         lambda p: read_npz(p / "f.npz").images)]
    for name, opts in ENCODINGS.items():
        o = dict(opts)
        images = o.pop("images")
        cases.append((name, lambda p, i=images, o=o: export(
            [run], "lerobot", p / "ds", i, note=_quiet, **o),
                      lambda p: read_dataset(p / "ds").images))
    for k, (name, write, read) in enumerate(cases):
        out = work / f"case{k}"
        out.mkdir()
        try:
            t_w, _ = _timed(lambda w=write, o=out: w(o))
        except Exception as exc:
            print(f"  {name:36s} not available here ({' '.join(str(exc).split())[:60]})")
            continue
        t_r, got = _timed(lambda r=read, o=out: r(o))
        kb = _size(out) * 1000 / n / 1024
        err = got.astype(np.float64) - exact.images
        mse = (err ** 2).reshape(n, -1).mean(axis=1)
        psnr = 10 * np.log10(255.0 ** 2 / np.maximum(mse, 1e-12)).min()
        shown = "inf" if psnr > 100 else f"{psnr:.1f}"
        print(f"  {name:36s} {n / t_w:10,.0f} {t_raw_w / t_w:8.4f} {kb:9,.0f} "
              f"{kb / raw_kb:6.3f} {n / t_r:10,.0f} {t_raw_r / t_r:8.4f} {shown:>8s} "
              f"{np.abs(err).mean():6.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--cells", type=int, default=4, help="twin cells, 2 arms each")
    args = ap.parse_args(argv)
    for label, noise in (("twin frames", 0.0), ("twin frames + sensor noise (sigma 4)", 4.0)):
        with tempfile.TemporaryDirectory() as tmp:
            run = make_run(Path(tmp) / "run", args.steps, args.cells, noise)
            print(f"{label}: {args.steps} steps x {2 * args.cells} arms, "
                  f"demos none (export of the store alone)")
            bench(run, Path(tmp))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
