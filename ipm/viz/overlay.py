"""Target-vs-fit mask overlays: target only red, fit only green, both yellow, IoU in the title."""

from __future__ import annotations

import numpy as np

from ipm.errors import InputError
from ipm.metrics import as_mask, mask_iou

TARGET = (220, 40, 40)
FIT = (40, 180, 60)
BOTH = (240, 210, 40)
BACKGROUND = (20, 20, 20)
TITLE_BG = (255, 255, 255)
TITLE_FG = (0, 0, 0)
TITLE_HEIGHT = 18


def _bool(mask) -> np.ndarray:
    arr = as_mask(mask)
    if arr.ndim != 2:
        raise InputError(f"mask: expected a (H, W) array, got shape {arr.shape}")
    return arr


def overlay(target, fit, title: str | None = None, *, show_iou: bool = True):
    """Color overlay of two (H, W) masks as a ``PIL.Image`` (RGB) with a title bar above.

    The title is ``title`` followed by ``IoU 0.xxx`` (when ``show_iou``).
    """
    from PIL import Image, ImageDraw

    t, f = _bool(target), _bool(fit)
    if t.shape != f.shape:
        raise InputError(f"overlay: expected masks of one shape, got {t.shape} and {f.shape}")
    rgb = np.empty(t.shape + (3,), dtype=np.uint8)
    rgb[:] = BACKGROUND
    rgb[t & ~f] = TARGET
    rgb[f & ~t] = FIT
    rgb[t & f] = BOTH
    text = " ".join(x for x in (title, f"IoU {mask_iou(t, f):.3f}" if show_iou else None) if x)
    if not text:
        return Image.fromarray(rgb)
    img = Image.new("RGB", (t.shape[1], t.shape[0] + TITLE_HEIGHT), TITLE_BG)
    img.paste(Image.fromarray(rgb), (0, TITLE_HEIGHT))
    ImageDraw.Draw(img).text((3, 3), text, fill=TITLE_FG)
    return img
