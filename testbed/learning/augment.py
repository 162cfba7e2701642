"""The paper's six photometric augmentations (its 8.3.3), batched, seeded, fast.

Why this module and not a library pipeline: the paper used imgaug, which does not import
with numpy 2 and drags in the GUI OpenCV build; albumentations drags in the headless
OpenCV build, which would clobber the operator's GUI build (docs/notes/learning.md).
kornia depends on torch only. Its ``kornia.augmentation`` pipeline, however, is not fast
enough here (measured: ~300 ms per 1000 64x64 images; the target is <= 285 ms,
twice imgaug's 570 ms) and has no op with imgaug's exact semantics for two of the six
(``RandomContrast`` scales around 0, not mid-grey; ``RandomGaussianNoise`` has a fixed
sigma). So the six ops run as one batched function with per-image parameters:

    op (in this order, as imgaug's Sequential)   parameter, per image      implementation
    1 LinearContrast  v <- 127.5 + a (v - 127.5)  a ~ U(0.85, 1.15)          \\ one per-image,
    2 Add per channel v_c <- v_c + b_c            b_c ~ U(-10, 10), per ch.   > per-channel
    3 GammaContrast   v <- 255 (v / 255)^g        g ~ U(0.9, 1.1)            / 256-entry LUT
    4 GaussianBlur    3x3 Gaussian, reflect       sigma ~ U(0, 0.3)           separable, 2 passes
    5 MultiplySaturation  HSV: s <- min(1, f s)   f ~ U(0.95, 1.05)           closed form
    6 AdditiveGaussianNoise v <- v + n            sigma ~ U(0, 255/80); n per pixel, shared
                                                  by the 3 channels (imgaug per_channel=False)

Semantics decided here (the paper's text is ambiguous):

* "Add ... to each pixel value per channel" is imgaug's ``Add(per_channel=True)``: one
  value per image and channel, the same for every pixel (a colour shift). Per-pixel
  randomness is op 6's job. The value is continuous (imgaug with an int tuple would draw
  integers; the difference is below the final uint8 rounding).
* Values are clipped to [0, 255] after every op (as imgaug does on uint8), and rounded
  to uint8 once at the end (imgaug rounds after every op: at most 0.5 level per op).
* Ops 1-3 are per-channel point maps of the uint8 input, so they compose into one lookup
  table per image and channel, evaluated exactly at the 256 input levels.
* Op 3 equals ``kornia.enhance.adjust_gamma``; op 4 equals
  ``kornia.filters.gaussian_blur2d`` with a 3x3 kernel (at sigma <= 0.3 the taps beyond
  +-1 weigh < 1e-9); op 5 equals ``kornia.enhance.adjust_saturation`` (an HSV round trip)
  by the identity c' = max - f (max - c) (clamped where f s > 1): scaling S at fixed H and
  V moves every channel towards the pixel's max. ``apply_kornia`` runs the same
  parameters through those kornia functions; the tests check both agree, and the
  benchmark times both and the ``kornia.augmentation`` module pipeline.

Determinism: every random number comes from the ``torch.Generator`` passed in, consumed in
a fixed order, in fixed chunks of ``CHUNK`` images (the chunks also keep the working set
in cache, which is 3-4x faster than one large batch on this machine).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

CHUNK = 256


@dataclass(frozen=True, slots=True)
class Ranges:
    """Uniform ranges of the six ops' parameters (pixel units on the 0-255 scale)."""

    contrast: tuple[float, float] = (0.85, 1.15)
    add: tuple[float, float] = (-10.0, 10.0)
    gamma: tuple[float, float] = (0.9, 1.1)
    blur_sigma: tuple[float, float] = (0.0, 0.3)
    saturation: tuple[float, float] = (0.95, 1.05)
    noise_sigma: tuple[float, float] = (0.0, 255.0 / 80.0)


PAPER_RANGES = Ranges()


@dataclass(frozen=True, slots=True)
class Params:
    """Per-image parameters for N images (and the noise draw), float32."""

    contrast: Tensor  # (N,)
    add: Tensor  # (N, 3)
    gamma: Tensor  # (N,)
    blur_sigma: Tensor  # (N,)
    saturation: Tensor  # (N,)
    noise_sigma: Tensor  # (N,)
    noise: Tensor  # (N, H, W) standard normal


def sample_params(
    n: int, height: int, width: int, generator: torch.Generator, ranges: Ranges = PAPER_RANGES
) -> Params:
    """Draw one image's worth of parameters for each of ``n`` images."""

    def uniform(bounds: tuple[float, float], *shape: int) -> Tensor:
        lo, hi = bounds
        return torch.rand(n, *shape, generator=generator).mul_(hi - lo).add_(lo)

    return Params(
        contrast=uniform(ranges.contrast),
        add=uniform(ranges.add, 3),
        gamma=uniform(ranges.gamma),
        blur_sigma=uniform(ranges.blur_sigma),
        saturation=uniform(ranges.saturation),
        noise_sigma=uniform(ranges.noise_sigma),
        noise=torch.randn(n, height, width, generator=generator),
    )


def _point_lut(p: Params) -> Tensor:
    """Ops 1-3 as a table (N, 3, 256) on the 0-255 scale, clipped after every op."""
    levels = torch.arange(256, dtype=torch.float32).view(1, 1, 256)
    x = (levels - 127.5).mul(p.contrast.view(-1, 1, 1)).add_(127.5).clamp_(0.0, 255.0)
    x = x.add(p.add.view(-1, 3, 1)).clamp_(0.0, 255.0)
    return x.div_(255.0).pow_(p.gamma.view(-1, 1, 1)).mul_(255.0)


def _blur_weight(sigma: Tensor) -> Tensor:
    """Outer tap weight of the normalised 3-tap Gaussian; sigma = 0 gives 0 (identity)."""
    w = torch.exp(-0.5 / sigma.square())  # sigma = 0 -> exp(-inf) = 0, no NaN
    return w / (1.0 + 2.0 * w)


def _blur(x: Tensor, side: Tensor) -> Tensor:
    """Separable 3-tap blur of (N, C, H, W) with per-image outer weight ``side`` (N,)."""
    w = side.view(-1, 1, 1, 1)
    for dim, pad in ((3, (1, 1, 0, 0)), (2, (0, 0, 1, 1))):
        padded = F.pad(x, pad, mode="reflect")
        size = x.shape[dim]
        centre = padded.narrow(dim, 1, size)
        out = padded.narrow(dim, 0, size) + padded.narrow(dim, 2, size)
        x = out.sub_(centre, alpha=2.0).mul_(w).add_(centre)
    return x


def _saturate(x: Tensor, factor: Tensor) -> Tensor:
    """HSV saturation x factor, clamped to 1, at fixed hue and value; in place."""
    top = x.amax(dim=1, keepdim=True)
    spread = top - x.amin(dim=1, keepdim=True)
    # f s > 1 clamps s to 1: the largest scale is max / (max - min) = 1 / s.
    scale = torch.minimum(factor.view(-1, 1, 1, 1).expand_as(top), top / spread.clamp_min(1e-12))
    return x.sub_(top).mul_(scale).add_(top)


def _finish(x: Tensor, p: Params) -> Tensor:
    """Op 6, clip, round; (N, 3, H, W) float -> (N, H, W, 3) uint8."""
    x.add_(p.noise.unsqueeze(1) * p.noise_sigma.view(-1, 1, 1, 1))
    return x.clamp_(0.0, 255.0).round_().to(torch.uint8).permute(0, 2, 3, 1).contiguous()


def apply_fast(images: Tensor, p: Params) -> Tensor:
    """The six ops with parameters ``p`` on uint8 (N, H, W, 3); returns uint8 (N, H, W, 3)."""
    n, h, w, c = images.shape
    index = images.permute(0, 3, 1, 2).reshape(n, c, h * w).long()
    x = torch.gather(_point_lut(p), 2, index).view(n, c, h, w)
    x = _blur(x, _blur_weight(p.blur_sigma))
    x = _saturate(x, p.saturation)
    return _finish(x, p)


def apply_kornia(images: Tensor, p: Params) -> Tensor:
    """The same ops with kornia's functions where kornia has them: the reference that
    ``apply_fast`` is tested against, and the "kornia functional" line of the benchmark."""
    from kornia.enhance import adjust_gamma, adjust_saturation
    from kornia.filters import gaussian_blur2d

    x = images.permute(0, 3, 1, 2).float()
    x = (x - 127.5).mul_(p.contrast.view(-1, 1, 1, 1)).add_(127.5).clamp_(0.0, 255.0)
    x = x.add_(p.add.view(-1, 3, 1, 1)).clamp_(0.0, 255.0).div_(255.0)
    x = adjust_gamma(x, p.gamma)
    sigma = p.blur_sigma.clamp_min(1e-3)  # kornia divides by sigma; 1e-3 is the identity
    x = gaussian_blur2d(x, (3, 3), torch.stack([sigma, sigma], dim=1), border_type="reflect")
    x = adjust_saturation(x, p.saturation).mul_(255.0)
    return _finish(x, p)


def augment(
    images: Tensor,
    generator: torch.Generator,
    ranges: Ranges = PAPER_RANGES,
    backend: str = "fast",
) -> Tensor:
    """Augment uint8 (N, H, W, 3) images once each; deterministic given the generator."""
    if images.dtype != torch.uint8 or images.dim() != 4 or images.shape[-1] != 3:
        raise ValueError(f"expected uint8 (N, H, W, 3), got {images.dtype} {tuple(images.shape)}")
    apply = {"fast": apply_fast, "kornia": apply_kornia}[backend]
    n, h, w, _ = images.shape
    out = torch.empty_like(images)
    for start in range(0, n, CHUNK):
        chunk = images[start : start + CHUNK]
        params = sample_params(chunk.shape[0], h, w, generator, ranges)
        out[start : start + CHUNK] = apply(chunk, params)
    return out


def augment_copies(images: Tensor, factor: int, generator: torch.Generator) -> Tensor:
    """(N, H, W, 3) -> (N, factor, H, W, 3): copy 0 is the image itself, copies 1..factor-1
    are augmented ("10x augmentation": each labelled image stands for ``factor`` images)."""
    if factor < 1:
        raise ValueError("factor must be >= 1")
    n = images.shape[0]
    out = images.unsqueeze(1).repeat(1, factor, 1, 1, 1)
    if factor > 1 and n:
        extra = out[:, 1:].reshape(n * (factor - 1), *images.shape[1:])
        out[:, 1:] = augment(extra, generator).view(n, factor - 1, *images.shape[1:])
    return out


def kornia_module_pipeline(ranges: Ranges = PAPER_RANGES) -> torch.nn.Module:
    """The closest ``kornia.augmentation`` pipeline, for timing only (benchmark): its
    contrast scales around 0 and its noise sigma is fixed at the range's top."""
    import kornia.augmentation as K

    shift = ranges.add[1] / 255.0
    return K.AugmentationSequential(
        K.RandomContrast(ranges.contrast, p=1.0),
        K.RandomRGBShift(shift, shift, shift, p=1.0),
        K.RandomGamma(ranges.gamma, p=1.0),
        K.RandomGaussianBlur((3, 3), (1e-3, ranges.blur_sigma[1]), p=1.0),
        K.RandomSaturation(ranges.saturation, p=1.0),
        K.RandomGaussianNoise(std=ranges.noise_sigma[1] / 255.0, p=1.0),
    )
