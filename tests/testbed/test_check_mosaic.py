"""``testbed check``'s mosaic: every arm's crop, labelled with its robot and outlined.

What is proven, on the pixels: each tile's strip carries its robot's name (text pixels,
a different strip for a different name, the same for the same), the workspace polygon
is drawn along its edges and nowhere inside the workspace, the crop is otherwise the
raw crop upscaled, the tiles sit where ``mosaic_size`` says; and a twin fleet's
``preflight`` writes such a mosaic of all its arms.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed.lab.preflight import (
    MOSAIC_BACKGROUND,
    MOSAIC_GAP,
    MOSAIC_LABEL_H,
    MOSAIC_OUTLINE,
    mosaic,
    mosaic_size,
)
from testbed.perception.cube import WORKSPACE_POLYGON

SCALE = 4
SIDE = 64 * SCALE
NAMES = ["cell0/left", "cell0/right", "cell1/left", "cell1/right", "cell2/left"]


def crop(seed: int) -> np.ndarray:
    """A 64x64 RGB table with a red cube near the centre (each seed a little off)."""
    img = np.full((64, 64, 3), (150, 150, 145), np.uint8)
    x = 26 + seed
    img[28:36, x : x + 8] = (220, 40, 20)
    return img


def tile_origin(k: int, cols: int = 4) -> tuple[int, int]:
    """(y, x) of tile k's label strip in the mosaic."""
    r, c = divmod(k, cols)
    return r * (MOSAIC_LABEL_H + SIDE + MOSAIC_GAP), c * (SIDE + MOSAIC_GAP)


def split(picture: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Tile k's (label strip, image) out of the mosaic."""
    y, x = tile_origin(k)
    strip = picture[y : y + MOSAIC_LABEL_H, x : x + SIDE]
    image = picture[y + MOSAIC_LABEL_H : y + MOSAIC_LABEL_H + SIDE, x : x + SIDE]
    return strip, image


def edge_points(n: int = 12) -> np.ndarray:
    """Points along every edge of the workspace polygon, in tile pixels."""
    poly = np.asarray(WORKSPACE_POLYGON) * SIDE
    pts = [a + (b - a) * s for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True)
           for s in np.linspace(0.1, 0.9, n)]
    return np.round(pts).astype(int)


def test_every_tile_has_its_name_and_the_workspace_outline() -> None:
    images = [crop(k) for k in range(len(NAMES))]
    picture = mosaic(images, NAMES)
    assert picture.shape == (*mosaic_size(len(NAMES)), 3)
    assert picture.shape == (2 * (MOSAIC_LABEL_H + SIDE) + MOSAIC_GAP,
                             4 * SIDE + 3 * MOSAIC_GAP, 3)
    strips = []
    for k, img in enumerate(images):
        strip, tile = split(picture, k)
        raw = np.kron(img, np.ones((SCALE, SCALE, 1), np.uint8))
        # the label: light text on the strip's background
        text = np.abs(strip.astype(int) - MOSAIC_BACKGROUND).sum(axis=2) > 150
        assert text.sum() > 150, f"no name drawn above tile {k}"
        strips.append(strip.copy())
        # the outline: along every edge the tile is the outline's colour, not the crop
        for x, y in edge_points():
            near = tile[y - 1 : y + 2, x - 1 : x + 2].reshape(-1, 3).astype(int)
            assert (np.abs(near - MOSAIC_OUTLINE).sum(axis=1) < 60).any(), (k, x, y)
            assert (near != raw[y, x]).any(), f"tile {k} is the raw crop at {(x, y)}"
        # inside the workspace, away from its edges, the crop itself is untouched
        inner = slice(round(0.3 * SIDE), round(0.7 * SIDE))
        assert np.array_equal(tile[inner, inner], raw[inner, inner])
        changed = (tile != raw).any(axis=2)
        assert 0.02 < changed.mean() < 0.2, "the outline is a line, not a fill"
    assert all(not np.array_equal(strips[0], s) for s in strips[1:]), "names differ"
    again = mosaic([crop(0)], ["cell0/left"])
    assert np.array_equal(split(again, 0)[0], strips[0]), "the strip is the name's"
    # the unused slots of the last row stay background
    y, x = tile_origin(len(NAMES))
    assert (picture[y:, x:] == MOSAIC_BACKGROUND).all()


def test_a_long_name_is_cut_to_its_tile_and_a_count_mismatch_is_refused() -> None:
    long = "a-very-long-host-name-of-the-lab/left-arm-with-a-camera"
    picture = mosaic([crop(0), crop(1)], [long, "b/right"])
    strip, _ = split(picture, 0)
    assert (np.abs(strip[:, -3:].astype(int) - MOSAIC_BACKGROUND).sum(axis=2) < 30).all()
    with pytest.raises(ValueError, match="2 images but 1 names"):
        mosaic([crop(0), crop(1)], ["a/left"])


@pytest.mark.slow
def test_check_of_a_twin_fleet_writes_the_labelled_mosaic(tmp_path: Path) -> None:
    import cv2

    from testbed.experiments.fleet_config import load_config
    from testbed.lab.preflight import preflight

    cfg = load_config(Path(__file__).resolve().parents[2] / "protocols" / "twin.toml")
    lines: list[str] = []
    assert preflight(cfg, tmp_path / "m.png", lines.append), lines
    robots = [f"{h.name}/{a.name}" for h in cfg.hosts for a in h.arms]
    picture = cv2.cvtColor(cv2.imread(str(tmp_path / "m.png")), cv2.COLOR_BGR2RGB)
    assert picture.shape == (*mosaic_size(len(robots)), 3)
    for k in range(len(robots)):
        strip, tile = split(picture, k)
        assert (np.abs(strip.astype(int) - MOSAIC_BACKGROUND).sum(axis=2) > 150).sum() > 150
        x, y = edge_points()[0]
        near = tile[y - 1 : y + 2, x - 1 : x + 2].reshape(-1, 3).astype(int)
        assert (np.abs(near - MOSAIC_OUTLINE).sum(axis=1) < 60).any()
    assert f"mosaic of {len(robots)} arms -> {tmp_path / 'm.png'}" in lines
