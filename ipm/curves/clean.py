"""Cleaning scanned or sketched ink before the fit: paper tone, noise and specks.

A clean anti-aliased drawing (paper exactly 0) is handed back as it is. Otherwise the paper level and the
noise are read off the image by robust statistics over blocks (most of a line drawing is paper): the
paper as the blocks' medians (median-filtered over the block grid, so that a block full of ink does not
count, and interpolated bilinearly), the noise sigma as the median over blocks of the upper quartile
spread (q75 - q50) / 0.6745 (the upper side: noise clipped at 0 below the paper leaves it intact). When
the noise says so the image is denoised (non-local means, Buades, Coll and Morel 2005, OpenCV's
``fastNlMeansDenoising``: it averages the strokes along themselves rather than across), the paper
subtracted and the strokes scaled to 1; the stroke mask (``> 1/2``) loses its specks (components much
smaller than a stroke) and its pinholes, and ink farther than a few pixels from the mask is set to 0 (what
is left there is noise), so that the fit, the width estimate and the ink checks see strokes on clean paper.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger("ipm.curves")

NOISY = 0.02    # noise sigma (ink units) from which the image is denoised
PAPER = 0.01    # paper level from which it is subtracted


@dataclass(frozen=True)
class Cleaned:
    """The ink to fit (H, W) float64 in [0, 1], its stroke mask (H, W) bool, the strokes to calibrate the
    re-render width against (the cleaned ink > 1/2 before its strokes are scaled to 1) and what was
    estimated."""

    ink: np.ndarray
    mask: np.ndarray
    strokes: np.ndarray
    paper: float = 0.0
    noise: float = 0.0
    cleaned: bool = False


def _blocks(arr: np.ndarray, block: int) -> np.ndarray:
    """(by, bx, block * block) views of ``arr`` in blocks (the last row / column of blocks reaches back
    inside the image rather than padding)."""
    H, W = arr.shape
    ys = sorted({min(y, max(H - block, 0)) for y in range(0, H, block)})
    xs = sorted({min(x, max(W - block, 0)) for x in range(0, W, block)})
    return np.stack([np.stack([arr[y:y + block, x:x + block].ravel() for x in xs]) for y in ys])


def paper_and_noise(arr: np.ndarray, block: int = 32) -> tuple[np.ndarray, float]:
    """The paper level (H, W) and the noise sigma of ink ``arr`` (H, W) (module docstring)."""
    from scipy.ndimage import median_filter, zoom

    H, W = arr.shape
    block = max(4, min(block, H, W))
    b = _blocks(arr, block)
    q50 = np.median(b, axis=2)
    q75 = np.quantile(b, 0.75, axis=2)
    noise = float(np.median(q75 - q50) / 0.6745)
    grid = median_filter(q50, size=3, mode="nearest")
    if grid.size == 1:
        return np.full((H, W), float(grid.ravel()[0])), noise
    paper = zoom(grid, (H / grid.shape[0], W / grid.shape[1]), order=1, mode="nearest", grid_mode=True)
    return np.clip(paper[:H, :W], 0.0, 1.0), noise


def denoise(arr: np.ndarray, noise: float) -> np.ndarray:
    """Non-local means of ``arr`` (H, W) in [0, 1] with filter strength from the noise sigma."""
    import cv2

    img = np.clip(np.rint(arr * 255.0), 0, 255).astype(np.uint8)
    out = cv2.fastNlMeansDenoising(img, None, h=float(1.2 * noise * 255.0), templateWindowSize=7,
                                   searchWindowSize=21)
    return out.astype(np.float64) / 255.0


def clean_ink(arr: np.ndarray) -> Cleaned:
    """The ink to vectorize from ink ``arr`` (H, W) float in [0, 1] (module docstring)."""
    from scipy.ndimage import distance_transform_edt
    from skimage.morphology import remove_small_holes, remove_small_objects, skeletonize

    paper, noise = paper_and_noise(arr)
    if noise < NOISY and float(paper.max()) < PAPER:
        mask = arr > 0.5
        return Cleaned(arr, mask, mask)
    ink = denoise(arr, noise) if noise >= NOISY else arr
    level, rest = paper_and_noise(ink)
    ink = np.clip((ink - level) / np.maximum(1.0 - level, 1e-6), 0.0, 1.0)
    mask = remove_small_objects(ink > 0.5, max_size=24)
    strokes = remove_small_holes(mask, max_size=8)
    if mask.any():
        peak = float(np.median(ink[skeletonize(mask)]))
        ink = np.clip(ink / min(max(peak, 0.5), 1.0), 0.0, 1.0)
        mask = remove_small_objects(ink > 0.5, max_size=24)
    mask = remove_small_holes(mask, max_size=8)
    near = distance_transform_edt(~mask) <= 3.0
    ink = np.where(near, ink, 0.0)
    log.debug("curves: paper %.3f, noise %.3f (left %.3f), %d stroke pixels", float(np.median(paper)), noise,
              rest, int(mask.sum()))
    return Cleaned(ink, mask, strokes, float(np.median(paper)), noise, True)
