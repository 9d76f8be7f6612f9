"""Strokes drawn along curves: the raster an SVG of the result shows, for the IoU check."""

from __future__ import annotations

import numpy as np

from ipm.curves.bezier import sample_beziers
from ipm.curves.settings import Curve, Vectorized
from ipm.errors import InputError


def _beziers(curves_or_beziers) -> np.ndarray:
    if isinstance(curves_or_beziers, Vectorized):
        curves_or_beziers = curves_or_beziers.curves
    if isinstance(curves_or_beziers, np.ndarray):
        arr = np.asarray(curves_or_beziers, float)
        if arr.ndim != 3 or arr.shape[1:] != (4, 2):
            raise InputError(f"expected Bezier control points (m, 4, 2), got shape {arr.shape}")
        return arr
    parts = [c.beziers if isinstance(c, Curve) else np.asarray(c, float).reshape(-1, 4, 2)
             for c in curves_or_beziers]
    return np.concatenate(parts) if parts else np.zeros((0, 4, 2))


def distance_to_curves(curves_or_beziers, size: tuple[int, int], upper: float) -> np.ndarray:
    """Distance (H, W) from every pixel centre to the curves (Beziers sampled every 0.2 pixel, so up
    to 0.1 pixel too long), inf beyond ``upper``."""
    from scipy.spatial import cKDTree

    H, W = size
    pts = sample_beziers(_beziers(curves_or_beziers), 0.2)
    if len(pts) == 0:
        return np.full((H, W), np.inf)
    yy, xx = np.mgrid[0:H, 0:W]
    q = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    d, _ = cKDTree(pts).query(q, distance_upper_bound=upper)
    return d.reshape(H, W)


def render_strokes(curves_or_beziers, size: tuple[int, int], width: float) -> np.ndarray:
    """(H, W) bool: pixels whose centre lies within ``width`` (the stroke half-width) of the curves.
    ``curves_or_beziers``: a :class:`Vectorized`, a sequence of :class:`Curve` or of Bezier arrays, or
    one (m, 4, 2) array."""
    H, W = int(size[0]), int(size[1])
    if H < 0 or W < 0 or not np.isfinite(width) or width < 0:
        raise InputError(f"expected a size (H, W) >= 0 and a width >= 0, got {size} and {width}")
    return distance_to_curves(curves_or_beziers, (H, W), width + 1.0) <= width


def calibrate_width(curves: tuple[Curve, ...], mask: np.ndarray, guess: float) -> float:
    """The half-width r in [guess / 2, 2 guess] whose strokes along ``curves`` match ``mask`` (H, W)
    bool best (intersection over union), to 1 % of the guess."""
    d = distance_to_curves(curves, mask.shape, 2.0 * guess + 1.0)
    best, best_iou = guess, -1.0
    for r in np.arange(0.5, 2.0001, 0.01) * guess:
        drawn = d <= r
        union = np.count_nonzero(drawn | mask)
        iou = np.count_nonzero(drawn & mask) / union if union else 0.0
        if iou > best_iou + 1e-12:
            best, best_iou = float(r), iou
    return best
