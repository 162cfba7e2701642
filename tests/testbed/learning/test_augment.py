"""The six augmentation ops: ranges (statistics on constant images), semantics, determinism,
and agreement with kornia's own functions."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from testbed.learning.augment import (
    PAPER_RANGES,
    Ranges,
    apply_fast,
    apply_kornia,
    augment,
    augment_copies,
    sample_params,
)

IDENTITY = Ranges(contrast=(1.0, 1.0), add=(0.0, 0.0), gamma=(1.0, 1.0), blur_sigma=(0.0, 0.0),
                  saturation=(1.0, 1.0), noise_sigma=(0.0, 0.0))
N = 400


def constant(rgb: tuple[int, int, int], n: int = N) -> torch.Tensor:
    img = torch.empty(n, 64, 64, 3, dtype=torch.uint8)
    img[:] = torch.tensor(rgb, dtype=torch.uint8)
    return img


def only(**ranges: tuple[float, float]) -> Ranges:
    return dataclasses.replace(IDENTITY, **ranges)


def run(images: torch.Tensor, ranges: Ranges, seed: int = 0) -> np.ndarray:
    return augment(images, torch.Generator().manual_seed(seed), ranges).numpy().astype(float)


def test_identity_ranges_leave_images_unchanged() -> None:
    img = torch.randint(0, 256, (20, 64, 64, 3), dtype=torch.uint8,
                        generator=torch.Generator().manual_seed(1))
    assert torch.equal(augment(img, torch.Generator().manual_seed(0), IDENTITY), img)


def test_linear_contrast_around_mid_grey() -> None:
    out = run(constant((100, 100, 100)), only(contrast=(0.85, 1.15)))
    per_image = out[:, 0, 0, 0]
    assert (out == per_image[:, None, None, None]).all()  # one factor per image
    lo, hi = 127.5 - 1.15 * 27.5, 127.5 - 0.85 * 27.5  # 95.9, 104.1
    assert per_image.min() >= np.floor(lo) and per_image.max() <= np.ceil(hi)
    assert per_image.min() <= lo + 1.0 and per_image.max() >= hi - 1.0  # the range is used


def test_add_is_per_image_per_channel() -> None:
    out = run(constant((100, 100, 100)), only(add=(-10.0, 10.0)))
    per_channel = out[:, :1, :1, :]
    assert (out == per_channel).all()  # the same value on every pixel of a channel
    assert out.min() >= 90 and out.max() <= 110
    assert out.min() <= 91 and out.max() >= 109
    assert (per_channel[..., 0] != per_channel[..., 1]).mean() > 0.8  # channels differ


def test_gamma_range() -> None:
    out = run(constant((100, 100, 100)), only(gamma=(0.9, 1.1)))[:, 0, 0, 0]
    lo, hi = 255 * (100 / 255) ** 1.1, 255 * (100 / 255) ** 0.9  # 91.2, 109.5
    assert out.min() >= np.floor(lo) and out.max() <= np.ceil(hi)
    assert out.min() <= lo + 1.0 and out.max() >= hi - 1.0


def test_blur_keeps_constant_images_and_bounds_an_impulse() -> None:
    ranges = only(blur_sigma=(0.0, 0.3))
    assert (run(constant((100, 50, 200)), ranges) == np.array([100, 50, 200])).all()
    img = constant((0, 0, 0))
    img[:, 32, 32] = 255
    out = run(img, ranges)
    centre = out[:, 32, 32, 0]
    side = np.exp(-0.5 / 0.09)
    assert centre.min() >= np.floor(255 / (1 + 2 * side) ** 2)  # sigma <= 0.3
    assert centre.max() == 255  # sigma near 0: no blur
    assert out[:, 32, 34].max() == 0  # a 3x3 kernel: nothing two pixels away


def test_saturation_scales_hsv_saturation_only() -> None:
    rgb = (200, 100, 50)  # HSV: s = 0.75, v = 200
    out = run(constant(rgb), only(saturation=(0.95, 1.05)))[:, 0, 0, :]
    v = out.max(axis=1)
    s = (v - out.min(axis=1)) / v
    assert (np.abs(v - 200) <= 0.5).all()
    assert s.min() >= 0.75 * 0.95 - 0.005 and s.max() <= 0.75 * 1.05 + 0.005
    assert s.min() <= 0.75 * 0.95 + 0.01 and s.max() >= 0.75 * 1.05 - 0.01
    hue_ratio = (out[:, 1] - out[:, 2]) / (out[:, 0] - out[:, 2])  # fixed hue for R > G > B
    assert np.allclose(hue_ratio, 1 / 3, atol=0.02)


def test_noise_sigma_range_and_shared_channels() -> None:
    out = run(constant((128, 128, 128)), only(noise_sigma=(0.0, 255.0 / 80.0)))
    assert (out[..., 0] == out[..., 1]).all() and (out[..., 0] == out[..., 2]).all()
    std = out[..., 0].reshape(N, -1).std(axis=1)
    assert std.max() <= 255 / 80 * 1.06  # 4096 pixels: the sample std is within ~3 %
    assert std.min() < 0.4 and std.max() > 255 / 80 * 0.9
    assert abs(out.mean() - 128) < 0.1


def test_full_pipeline_stays_in_its_envelope() -> None:
    out = run(constant((128, 128, 128)), PAPER_RANGES)
    # contrast +-2.2, add +-10, gamma, then noise (< 5 sigma of 255/80): 128 -> [104, 152]
    assert out.min() >= 255 * ((128 - 10 - 0.15 * 0.5) / 255) ** 1.1 - 16
    assert out.max() <= 255 * ((128 + 10 + 0.15 * 0.5) / 255) ** 0.9 + 16
    means = out.reshape(N, -1).mean(axis=1)
    assert means.std() > 3  # the per-image shifts are really applied


def test_deterministic_under_a_seed() -> None:
    img = torch.randint(0, 256, (300, 64, 64, 3), dtype=torch.uint8,
                        generator=torch.Generator().manual_seed(3))
    a = augment(img, torch.Generator().manual_seed(7))
    b = augment(img, torch.Generator().manual_seed(7))
    c = augment(img, torch.Generator().manual_seed(8))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_fast_path_matches_kornia_functions() -> None:
    gen = torch.Generator().manual_seed(5)
    img = torch.randint(0, 256, (64, 64, 64, 3), dtype=torch.uint8, generator=gen)
    params = sample_params(64, 64, 64, gen)
    diff = (apply_fast(img, params).int() - apply_kornia(img, params).int()).abs()
    assert diff.max() <= 1  # rounding at .5 boundaries only
    assert (diff > 0).float().mean() < 1e-3


def test_copies_keep_the_original_first() -> None:
    img = torch.randint(0, 256, (4, 64, 64, 3), dtype=torch.uint8)
    out = augment_copies(img, 10, torch.Generator().manual_seed(0))
    assert out.shape == (4, 10, 64, 64, 3)
    assert torch.equal(out[:, 0], img)
    assert all(not torch.equal(out[:, k], img) for k in range(1, 10))
    assert torch.equal(augment_copies(img, 1, torch.Generator()), img[:, None])


def test_rejects_non_uint8() -> None:
    with pytest.raises(ValueError, match="uint8"):
        augment(torch.zeros(1, 64, 64, 3), torch.Generator())
