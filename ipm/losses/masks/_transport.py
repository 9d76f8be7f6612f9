"""What the transport losses (``sinkhorn``, ``sliced``) share: their settings and the masks as mass on a
grid of pixel centres.

A mask ``(..., H, W)`` is read as a distribution of mass over the pixel centres, placed in a frame where the
image's longer side has length 1 (so blurs and dustbin distances are shares of the image, whatever its size).
Masks larger than ``TransportSettings.size`` are first summed over blocks of pixels (area pooling keeps the
mass), which bounds the cost of the solvers at any image size."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import torch
import torch.nn.functional as F
from msgspec import Meta


@dataclass(frozen=True)
class TransportSettings:
    """Settings of the transport losses (``FitSettings.transport``)."""

    # entropic blur of sinkhorn, as a share of the image's longer side (eps = blur^2, GeomLoss's convention)
    blur: Annotated[float, Meta(gt=0, le=1, extra={"noun": "a share of the image"})] = 0.05
    # sinkhorn iterations (eps-scaling from the image's diagonal down to the blur, then at the blur)
    iterations: Annotated[int, Meta(ge=1, le=1000, extra={"noun": "a number of iterations"})] = 20
    # partial transport (sinkhorn): mass farther than this from any mass of the other mask (a share of the
    # image's longer side) is left unmatched at this distance's cost instead of moved; None: all mass moves
    dustbin: Annotated[float, Meta(gt=0, le=2, extra={"noun": "a share of the image"})] | None = None
    # sliced: directions, equally spaced over half a turn
    projections: Annotated[int, Meta(ge=1, le=4096, extra={"noun": "a number of directions"})] = 64
    # masks are pooled to at most this many pixels on their longer side before transport
    size: Annotated[int, Meta(ge=8, le=512, extra={"noun": "a size in pixels"})] = 32


def pooled(mask: torch.Tensor, size: int) -> torch.Tensor:
    """``mask (..., H, W)`` summed over blocks of ``ceil(max(H, W) / size)`` pixels (zero-padded to a whole
    number of blocks): ``(..., H', W')``, the same total mass."""
    k = math.ceil(max(mask.shape[-2:]) / size)
    if k <= 1:
        return mask
    h, w = mask.shape[-2:]
    lead = mask.shape[:-2]
    m = mask.reshape(-1, 1, h, w)
    m = F.pad(m, (0, (-w) % k, 0, (-h) % k))
    return (F.avg_pool2d(m, k) * (k * k)).reshape(*lead, m.shape[-2] // k, m.shape[-1] // k)


def axes(h: int, w: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel-centre coordinates ``(y (h,), x (w,))`` in a frame where the longer side has length 1."""
    s = float(max(h, w))
    y = (torch.arange(h, dtype=like.dtype, device=like.device) + 0.5) / s
    x = (torch.arange(w, dtype=like.dtype, device=like.device) + 0.5) / s
    return y, x


def normalized(mass: torch.Tensor, eps: float = 1e-12) -> tuple[torch.Tensor, torch.Tensor]:
    """``mass (..., H, W)`` divided by its total per mask, and the totals ``(...)``."""
    total = mass.sum((-2, -1))
    return mass / (total[..., None, None] + eps), total
