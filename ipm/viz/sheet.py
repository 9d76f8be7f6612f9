"""Contact sheets: many pictures (masks, previews, overlays) in one grid image."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from ipm.errors import InputError

LABEL_HEIGHT = 14


def to_image(x):
    """A ``PIL.Image`` (RGB) from an image, a (H, W) bool / float mask or a (H, W, 3) uint8 array."""
    from PIL import Image

    if isinstance(x, Image.Image):
        return x.convert("RGB")
    arr = np.asarray(x.detach().cpu() if torch.is_tensor(x) else x)
    if arr.ndim == 2:
        if arr.dtype == bool:
            arr = arr.astype(np.uint8) * 255
        elif arr.dtype.kind == "f":
            arr = np.clip(arr * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return Image.fromarray(arr.astype(np.uint8), "L").convert("RGB")
    if arr.ndim == 3 and arr.shape[2] in (3, 4) and arr.dtype == np.uint8:
        return Image.fromarray(arr).convert("RGB")
    raise InputError(f"image: expected a PIL image, a (H, W) mask or a (H, W, 3) uint8 array, got "
                     f"{arr.dtype} {arr.shape}")


def contact_sheet(images: Sequence, cols: int | None = None, labels: Sequence[str] | None = None, *,
                  pad: int = 4, background=(255, 255, 255)):
    """Arrange pictures in a grid (``PIL.Image``); ``cols`` defaults to about sqrt(N); cells take the
    largest picture's size; optional labels are drawn under each picture."""
    from PIL import Image, ImageDraw

    if len(images) == 0:
        raise InputError("contact sheet: expected at least one image, got none")
    if labels is not None and len(labels) != len(images):
        raise InputError(f"contact sheet: expected one label per image, got {len(labels)} labels for "
                         f"{len(images)} images")
    ims = [to_image(x) for x in images]
    cols = cols or math.ceil(math.sqrt(len(ims)))
    rows = math.ceil(len(ims) / cols)
    cw = max(i.width for i in ims)
    ch = max(i.height for i in ims) + (LABEL_HEIGHT if labels else 0)
    sheet = Image.new("RGB", (cols * cw + (cols + 1) * pad, rows * ch + (rows + 1) * pad), background)
    draw = ImageDraw.Draw(sheet)
    for k, im in enumerate(ims):
        r, c = divmod(k, cols)
        x, y = pad + c * (cw + pad), pad + r * (ch + pad)
        sheet.paste(im, (x, y))
        if labels:
            draw.text((x + 2, y + im.height + 1), str(labels[k]), fill=(0, 0, 0))
    return sheet
