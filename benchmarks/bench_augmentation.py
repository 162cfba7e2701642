"""How fast is the paper's 10x augmentation of the 375 offline images, next to imgaug?

Why this exists: every labelled image is stored with 9 augmented copies (the paper's
"10x"), offline for the 375 demonstrations and online for every human label. The target
(issue 6) is at least 2x faster than imgaug's 570 ms per 1000 64x64 images measured on
this machine (docs/notes/learning.md; imgaug itself no longer installs next to numpy 2,
so its figure is the recorded one). Three implementations of the same six ops, timed
interleaved on the same images:

* fast:    testbed.learning.augment (LUT + separable blur + closed-form saturation), used
* kornia functional: the same parameters through kornia.enhance / kornia.filters
* kornia.augmentation: the closest AugmentationSequential of kornia's modules (reference)

    .venv/bin/python benchmarks/bench_augmentation.py [--repeats 5] [--images 375]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.learning.augment import CHUNK, augment, augment_copies, kornia_module_pipeline
from testbed.learning.runtime import configure_torch

IMGAUG_MS_PER_1000 = 570.0  # ENVIRONMENT.md, 64x64, the six ops, this machine
FACTOR = 10


def twin_like_images(n: int, seed: int) -> torch.Tensor:
    """Flat table colour, a cube and a goal disc at random places, mild sensor noise."""
    rng = np.random.default_rng(seed)
    img = np.empty((n, 64, 64, 3), dtype=np.uint8)
    img[:] = rng.integers(90, 140, (n, 1, 1, 3), dtype=np.uint8)
    yy, xx = np.mgrid[0:64, 0:64]
    for i in range(n):
        gx, gy, cx, cy = rng.integers(8, 56, 4)
        img[i][(xx - gx) ** 2 + (yy - gy) ** 2 < 16] = (40, 200, 60)
        img[i, cy - 4 : cy + 4, cx - 4 : cx + 4] = (200, 40, 40)
    noise = rng.integers(-3, 4, img.shape)
    return torch.from_numpy(np.clip(img.astype(int) + noise, 0, 255).astype(np.uint8))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--images", type=int, default=375)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    threads = configure_torch()
    images = twin_like_images(args.images, args.seed)
    copies = images.repeat_interleave(FACTOR - 1, dim=0)  # what augment_copies augments
    module = kornia_module_pipeline()

    def run_module() -> None:
        for start in range(0, len(copies), CHUNK):
            x = copies[start : start + CHUNK].permute(0, 3, 1, 2).float().div(255.0)
            module(x).mul(255.0).round().to(torch.uint8)

    gen = torch.Generator().manual_seed(args.seed)
    runs: dict[str, Callable[[], object]] = {
        "fast (used)": lambda: augment(copies, gen),
        "kornia functional": lambda: augment(copies, gen, backend="kornia"),
        "kornia.augmentation": run_module,
    }
    times: dict[str, list[float]] = {name: [] for name in runs}
    for fn in runs.values():  # warm-up
        fn()
    for _ in range(args.repeats):
        for name, fn in runs.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)

    n = len(copies)
    print(f"{args.images} images x {FACTOR} ({n} augmented copies + {args.images} originals), "
          f"64x64x3, torch threads {threads}, chunks of {CHUNK}")
    print(f"imgaug (recorded in ENVIRONMENT.md): {IMGAUG_MS_PER_1000:.0f} ms per 1000 images")
    for name, ts in times.items():
        best = min(ts) / n * 1e6
        med = statistics.median(ts) / n * 1e6
        print(f"{name:20s}: {best:6.1f} ms per 1000 (min), {med:6.1f} (median); "
              f"imgaug / this = {IMGAUG_MS_PER_1000 / med:4.2f}x (median)")
    gen = torch.Generator().manual_seed(args.seed)
    start = time.perf_counter()
    augment_copies(images, FACTOR, gen)
    print(f"augment_copies({args.images} images, x{FACTOR}) as the learner calls it: "
          f"{(time.perf_counter() - start) * 1e3:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
