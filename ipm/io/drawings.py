"""Line drawings read as ink: PNG, JPEG or any image Pillow reads.

Grey is the luminance; dark strokes on light paper become ink 1 (ink = 1 - grey / 255); an image whose
median is dark (light strokes on dark paper) is inverted; transparent pixels are paper.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ipm.errors import InputError


def read_drawing(path: str | Path) -> np.ndarray:
    """Ink (H, W) float64 in [0, 1], 1 = stroke, of the image at ``path``. :class:`InputError` if it is
    missing, not an image, or has no pixels."""
    from ipm.io.masks import read_image

    rgba = read_image(path, "drawing", "RGBA").astype(np.float64) / 255.0
    if rgba.shape[0] == 0 or rgba.shape[1] == 0:
        raise InputError(f"drawing {path}: expected an image with pixels, got {rgba.shape[1]} x {rgba.shape[0]}")
    grey = 0.299 * rgba[..., 0] + 0.587 * rgba[..., 1] + 0.114 * rgba[..., 2]  # ITU-R BT.601 luma
    alpha = rgba[..., 3]
    ink = 1.0 - grey
    opaque = alpha > 0.5
    if opaque.any() and np.median(grey[opaque]) < 0.5:  # light strokes on dark paper
        ink = grey
    return np.clip(ink * alpha, 0.0, 1.0)
