"""A dataset's per-feature statistics, as LeRobot's ``meta/stats.json`` has them.

Why apart: what LeRobot's ``compute_stats.py`` computes (min, max, mean, std, count and
the quantiles q01 q10 q50 q90 q99 of every feature) changes with LeRobot's format, not
with how frames are written. Numbers are exact: the values are kept, and images are
counted in a 256-bin histogram per channel, scaled to [0, 1].
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Final

import numpy as np

QUANTILES: Final = (0.01, 0.10, 0.50, 0.90, 0.99)


class Stats:
    """Per-feature statistics as LeRobot's stats.json has them (exact quantiles: the
    values are kept; images by a 256-bin histogram per channel, scaled to [0, 1])."""

    def __init__(self) -> None:
        self.values: dict[str, list[np.ndarray]] = {}
        self.hist = np.zeros((3, 256), np.int64)
        self.count = 0

    def add(self, columns: dict[str, np.ndarray], images: np.ndarray) -> None:
        """One episode's columns and its uint8 images (N, H, W, 3)."""
        for k, v in columns.items():
            self.values.setdefault(k, []).append(v)
        for ch in range(3):
            self.hist[ch] += np.bincount(images[..., ch].reshape(-1), minlength=256)
        self.count += len(images)

    @staticmethod
    def _of(v: np.ndarray) -> dict[str, list[float]]:
        v = v.astype(np.float64).reshape(len(v), -1)
        ok = np.isfinite(v)
        cols = [v[ok[:, j], j] for j in range(v.shape[1])]

        def each(fn: Any) -> list[float]:
            return [float(fn(c)) if len(c) else 0.0 for c in cols]

        out = {"min": each(np.min), "max": each(np.max), "mean": each(np.mean),
               "std": each(np.std), "count": [len(v)]}
        for q in QUANTILES:
            out[f"q{round(q * 100):02d}"] = each(lambda c, q=q: np.quantile(c, q))
        return out

    def _image(self) -> dict[str, Any]:
        levels = np.arange(256, dtype=np.float64) / 255.0
        n = self.hist.sum(axis=1)
        mean = (self.hist * levels).sum(axis=1) / np.maximum(n, 1)
        var = (self.hist * (levels[None] - mean[:, None]) ** 2).sum(axis=1) / np.maximum(n, 1)
        cum = np.cumsum(self.hist, axis=1)

        def per_channel(values: Iterable[float]) -> list[list[list[float]]]:
            return [[[float(x)]] for x in values]

        out: dict[str, Any] = {
            "min": per_channel(levels[np.argmax(self.hist > 0, axis=1)]),
            "max": per_channel(levels[255 - np.argmax(self.hist[:, ::-1] > 0, axis=1)]),
            "mean": per_channel(mean), "std": per_channel(np.sqrt(var)),
            "count": [self.count]}
        for q in QUANTILES:
            at = [int(np.searchsorted(cum[ch], q * n[ch])) for ch in range(3)]
            out[f"q{round(q * 100):02d}"] = per_channel(levels[at])
        return out

    def result(self, image_key: str) -> dict[str, Any]:
        """Every column's statistics, then the images' under ``image_key``."""
        stats = {k: self._of(np.concatenate(v)) for k, v in self.values.items()}
        stats[image_key] = self._image()
        return stats
