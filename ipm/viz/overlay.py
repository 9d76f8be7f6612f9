"""Target-vs-fit mask overlays: target only red, fit only green, both yellow, IoU in the title."""

from __future__ import annotations

import numpy as np
import torch

TARGET = (220, 40, 40)
FIT = (40, 180, 60)
BOTH = (240, 210, 40)
BACKGROUND = (20, 20, 20)
TITLE_BG = (255, 255, 255)
TITLE_FG = (0, 0, 0)
TITLE_HEIGHT = 18


def _bool(mask) -> np.ndarray:
    arr = np.asarray(mask.detach().cpu() if torch.is_tensor(mask) else mask)
    if arr.ndim != 2:
        raise ValueError(f"mask: expected a (H, W) array, got shape {arr.shape}")
    return arr > (0.5 if arr.dtype.kind == "f" else 0)


def mask_iou(a, b) -> float:
    """Intersection over union of two (H, W) masks (bool, or float thresholded at 0.5); 1.0 if both empty."""
    a, b = _bool(a), _bool(b)
    if a.shape != b.shape:
        raise ValueError(f"masks: expected equal shapes, got {a.shape} and {b.shape}")
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def overlay(target, fit, title: str | None = None, *, show_iou: bool = True):
    """Color overlay of two (H, W) masks as a ``PIL.Image`` (RGB) with a title bar above.

    The title is ``title`` followed by ``IoU 0.xxx`` (when ``show_iou``).
    """
    from PIL import Image, ImageDraw

    t, f = _bool(target), _bool(fit)
    if t.shape != f.shape:
        raise ValueError(f"overlay: expected masks of one shape, got {t.shape} and {f.shape}")
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
