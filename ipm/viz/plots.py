"""Loss curves drawn with Pillow.

A run folder's ``loss.png`` is written at the end of every fit; matplotlib would add about half a second of
import to each ``ipm fit`` process (measured: 0.56 s of a 60-evaluation fit's 4 s, issue #30), so the plot is
drawn here: axes, ticks at round numbers (decades on a log scale), a grid, the curves and a legend.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ipm.errors import InputError

SIZE = (600, 400)
MARGIN = (64, 34, 18, 46)  # left, top, right, bottom
COLORS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189))
GRID, AXIS, TEXT = (225, 225, 225), (90, 90, 90), (30, 30, 30)


def nice_ticks(lo: float, hi: float, n: int = 6, *, integer: bool = False) -> list[float]:
    """About ``n`` round values (1, 2 or 5 times a power of ten apart, at least 1 apart if ``integer``) within
    ``[lo, hi]``."""
    if not hi > lo:
        return [lo]
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    step = max(step, 1.0) if integer else step
    first = math.ceil(lo / step - 1e-9) * step
    return [first + i * step for i in range(int((hi - first) / step + 1e-9) + 1)]


def _label(v: float, log_y: bool) -> str:
    return f"1e{int(round(v))}" if log_y else f"{v:.4g}"


def plot_losses(curves: Mapping[str, Sequence[float]] | Sequence[float], path: str | Path, *,
                title: str = "loss", log_y: bool = True, xlabel: str = "evaluation") -> Path:
    """Plot one or several loss curves (log scale where every value is positive) and write a PNG atomically;
    returns the path."""
    from PIL import Image, ImageDraw, ImageFont

    from ipm.files import atomic_path

    if not isinstance(curves, Mapping):
        curves = {"loss": curves}
    if not curves or all(len(v) == 0 for v in curves.values()):
        raise InputError("plot_losses: expected at least one non-empty curve, got none")
    ys = {name: np.asarray([float(y) for y in v], dtype=np.float64) for name, v in curves.items() if len(v)}
    finite = np.concatenate([v[np.isfinite(v)] for v in ys.values()])
    log_y = log_y and finite.size > 0 and bool((finite > 0).all())
    if log_y:
        ys = {k: np.log10(np.where(v > 0, v, np.nan)) for k, v in ys.items()}
        finite = np.log10(finite)
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    lo, hi = (lo - 0.5, hi + 0.5) if hi - lo < 1e-12 else (lo - 0.03 * (hi - lo), hi + 0.03 * (hi - lo))
    n = max(len(v) for v in ys.values())
    im = Image.new("RGB", SIZE, "white")
    draw = ImageDraw.Draw(im)
    font = ImageFont.load_default(size=12)
    box = (MARGIN[0], MARGIN[1], SIZE[0] - MARGIN[2], SIZE[1] - MARGIN[3])
    to_x = lambda i: box[0] + (box[2] - box[0]) * (i / max(n - 1, 1))  # noqa: E731
    to_y = lambda v: box[3] - (box[3] - box[1]) * ((v - lo) / (hi - lo))  # noqa: E731
    y_ticks = [t for t in (range(math.ceil(lo), math.floor(hi) + 1) if log_y and hi - lo >= 1
                           else nice_ticks(lo, hi)) if lo <= t <= hi]
    for t in y_ticks:
        draw.line([(box[0], to_y(t)), (box[2], to_y(t))], fill=GRID)
        draw.text((box[0] - 6, to_y(t)), _label(t, log_y), fill=TEXT, font=font, anchor="rm")
    for t in nice_ticks(0, max(n - 1, 1), integer=True):
        draw.line([(to_x(t), box[1]), (to_x(t), box[3])], fill=GRID)
        draw.text((to_x(t), box[3] + 6), f"{t:g}", fill=TEXT, font=font, anchor="mt")
    draw.rectangle(box, outline=AXIS)
    for k, (name, v) in enumerate(ys.items()):
        pts = [(to_x(i), to_y(y)) for i, y in enumerate(v) if np.isfinite(y)]
        color = COLORS[k % len(COLORS)]
        draw.line(pts, fill=color, width=2) if len(pts) > 1 else draw.point(pts, fill=color)
        if len(ys) > 1:
            ly = box[1] + 8 + 16 * k
            draw.line([(box[2] - 110, ly), (box[2] - 90, ly)], fill=color, width=2)
            draw.text((box[2] - 84, ly), name, fill=TEXT, font=font, anchor="lm")
    draw.text(((box[0] + box[2]) / 2, MARGIN[1] / 2), title, fill=TEXT, font=font, anchor="mm")
    draw.text(((box[0] + box[2]) / 2, SIZE[1] - 12), xlabel, fill=TEXT, font=font, anchor="mm")
    with atomic_path(path) as tmp:
        im.save(tmp, format="PNG")
    return Path(path)
