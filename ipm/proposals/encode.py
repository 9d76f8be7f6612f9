"""What a proposal network sees of a target: one mask cropped square around the object and resized, and the
camera's azimuth, which turns the network's yaw (relative to the camera) into the world's.

The crop makes the input independent of where the object is in the image and how large (the fit's pose grid sets
scale and translation); the object's proportions and what it shows of itself are left.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ipm.errors import InputError
from ipm.types import Camera

SIZE = 64          # pixels a side of the network's input
MARGIN = 0.08      # of the crop's side, on every side of the object's bounding box
# the camera's azimuth (degrees) of the training renders: yaws are learned relative to it
TRAIN_AZIMUTH = 30.0


def crop_box(mask: torch.Tensor, margin: float = MARGIN) -> tuple[float, float, float]:
    """``(cx, cy, side)`` in pixels: the square around the pixels over 0.5 of ``mask (H, W)``, ``margin`` of
    its side free on every side. ``InputError`` for an empty mask."""
    ys, xs = torch.nonzero(mask > 0.5, as_tuple=True)
    if len(xs) == 0:
        raise InputError("proposal: expected a mask with some foreground pixels, got none")
    x0, x1 = float(xs.min()), float(xs.max()) + 1.0
    y0, y1 = float(ys.min()), float(ys.max()) + 1.0
    side = max(x1 - x0, y1 - y0) / (1.0 - 2.0 * margin)
    return 0.5 * (x0 + x1), 0.5 * (y0 + y1), side


def encode_mask(mask: torch.Tensor, size: int = SIZE, box: tuple[float, float, float] | None = None,
                dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """``(1, size, size)`` of ``dtype`` in [0, 1]: ``mask (H, W)`` cropped to :func:`crop_box` (or ``box``) and
    resampled bilinearly (pixels outside the image are background)."""
    m = mask.detach().to(dtype)
    cx, cy, side = crop_box(m) if box is None else box
    H, W = m.shape
    # the crop's pixel centres in the normalized coordinates of grid_sample (align_corners=False)
    t = (torch.arange(size, dtype=dtype) + 0.5) / size - 0.5
    xs = (cx + t * side) / W * 2.0 - 1.0
    ys = (cy + t * side) / H * 2.0 - 1.0
    grid = torch.stack(torch.meshgrid(ys, xs, indexing="ij")[::-1], dim=-1)[None]
    out = F.grid_sample(m[None, None], grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    return out[0].clamp(0.0, 1.0)


def camera_azimuth(cam: Camera) -> float:
    """The azimuth (degrees) of ``cam``'s eye about its target, in :func:`ipm.render.camera.orbit_eye`'s
    convention (0 on +z, 90 on +x)."""
    d = (cam.eye - cam.target).detach().double()
    return math.degrees(math.atan2(float(d[0]), float(d[2])))
