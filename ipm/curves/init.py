"""The start of the fit: the stroke half-width and the per-cell Hermite data, read off the image.

A random field gets stuck (the raster loss has no slope where |p| >> w), so every cell that holds ink
starts as a signed distance to the ink's centreline near it: the skeleton pixels in the cell widened by
half a cell on each side are fitted by a line (principal components) or, where a line leaves a residual
(a corner, a crossing, a tight bend), by a conic (Taubin's fit, "Estimation of planar curves, surfaces and
nonplanar space curves defined by implicit equations", PAMI 1991: min sum f^2 / sum |grad f|^2, a
generalized eigenproblem; a crossing comes out as a line pair, a saddle). Each is scaled to |grad p| = 1
on the ink. Signs are chosen cell by cell, breadth first from the cell with the most ink, so that shared
corners agree with the neighbours already placed; cells without ink start at a constant +-3 w whose sign
follows their neighbours, so that the sign of p flips only at cell edges, where no zero crossing is
rendered (this is how a stroke can end).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from ipm.curves.hermite import P, from_polynomial, gaussian_scale


def skeleton(mask: np.ndarray) -> np.ndarray:
    """The one-pixel centreline of a bool mask (H, W) -> (H, W) bool (Zhang-Suen thinning, scikit-image)."""
    from skimage.morphology import skeletonize

    return skeletonize(mask)


def skeleton_length(skel: np.ndarray) -> float:
    """Length in pixels of a one-pixel skeleton: 4-neighbour links count 1, diagonal links sqrt(2) where
    no 4-neighbour path of two links joins the same pixels."""
    s = skel.astype(bool)
    right = s[:, :-1] & s[:, 1:]
    down = s[:-1, :] & s[1:, :]
    dr = s[:-1, :-1] & s[1:, 1:] & ~s[:-1, 1:] & ~s[1:, :-1]
    dl = s[:-1, 1:] & s[1:, :-1] & ~s[:-1, :-1] & ~s[1:, 1:]
    return float(right.sum() + down.sum() + np.sqrt(2.0) * (dr.sum() + dl.sum()))


def estimate_half_width(ink: np.ndarray, skel: np.ndarray) -> float:
    """Stroke half-width r from the ink's area over twice the centreline's length (anti-aliased ink sums
    to the stroke's area), clamped to [0.5, 50] pixels."""
    length = max(skeleton_length(skel), 1.0)
    return float(np.clip(ink.sum() / (2.0 * length), 0.5, 50.0))


def _line(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Principal-component line through points (n, 2): (centre, unit normal, rms distance)."""
    c = pts.mean(axis=0)
    q = pts - c
    _, s, vt = np.linalg.svd(q, full_matrices=False)
    normal = vt[-1] if len(s) > 1 else np.array([0.0, 1.0])
    rms = float(np.sqrt(np.mean((q @ normal) ** 2)))
    return c, normal, rms


def _monomials(s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    one, zero = np.ones_like(s), np.zeros_like(s)
    z = np.stack([s * s, s * t, t * t, s, t, one], axis=1)
    zs = np.stack([2 * s, t, zero, one, zero, zero], axis=1)
    zt = np.stack([zero, s, 2 * t, zero, one, zero], axis=1)
    return z, zs, zt


def _taubin(pts: np.ndarray, center: np.ndarray, scale: float) -> tuple[np.ndarray, float] | None:
    """Taubin's conic through points (n, 2) in local coordinates ((x - center) / scale): (coefficients
    normalized to mean |grad f| = 1 per pixel at the points, rms of f / |grad f| in pixels), or None."""
    import scipy.linalg

    q = (pts - center) / scale
    z, zs, zt = _monomials(q[:, 0], q[:, 1])
    M = z.T @ z
    N = zs.T @ zs + zt.T @ zt
    try:
        vals, vecs = scipy.linalg.eig(M, N)
    except (np.linalg.LinAlgError, ValueError):
        return None
    vals = np.real(vals)
    ok = np.isfinite(vals) & (vals > -1e-9)
    if not ok.any():
        return None
    c = np.real(vecs[:, np.flatnonzero(ok)[np.argmin(vals[ok])]])
    f = z @ c
    g = np.hypot(zs @ c, zt @ c) / scale  # |grad f| per pixel
    gm = float(np.mean(g))
    if not np.isfinite(gm) or gm < 1e-12:
        return None
    c = c / gm
    rms = float(np.sqrt(np.mean((f / np.maximum(g, 1e-3 * gm)) ** 2)))
    return c, rms


def _gradient(model: tuple, pts: np.ndarray) -> np.ndarray:
    """Gradient (n, 2) per pixel of a cell's start model (coefficients, center, scale) at points (n, 2)."""
    (a, b, c, d, e, _), center, scale = model
    q = (pts - center) / scale
    s, t = q[:, 0], q[:, 1]
    return np.stack([2 * a * s + b * t + d, b * s + 2 * c * t + e], axis=1) / scale


def initial_data(ink: np.ndarray, skel: np.ndarray, cell: int, half_width: float) -> tuple[np.ndarray, np.ndarray]:
    """Hermite data (Ny, Nx, 2, 2, 4) float64 to start the fit from (module docstring), and which cells
    hold ink (Ny, Nx) bool (those that start from a fit to the ink)."""
    H, W = ink.shape
    ny, nx = -(-H // cell), -(-W // cell)
    far = 3.0 * gaussian_scale(half_width)
    mask = ink > 0.5
    ys, xs = np.nonzero(skel)
    spts = np.stack([xs + 0.5, ys + 0.5], axis=1).astype(np.float64)
    margin = max(cell / 2.0, 1.5 * half_width)
    data = np.zeros((ny, nx, 2, 2, 4))
    data[..., P] = far
    models: dict[tuple[int, int], tuple] = {}
    windows: dict[tuple[int, int], np.ndarray] = {}
    for cy in range(ny):
        for cx in range(nx):
            x0, y0 = cx * cell, cy * cell
            if not mask[y0:y0 + cell, x0:x0 + cell].any():
                continue
            sel = ((spts[:, 0] > x0 - margin) & (spts[:, 0] < x0 + cell + margin)
                   & (spts[:, 1] > y0 - margin) & (spts[:, 1] < y0 + cell + margin))
            pts = spts[sel]
            if len(pts) < 2:
                continue
            origin = np.array([x0, y0], float)
            c, n, rms = _line(pts)
            model = (np.array([0, 0, 0, n[0], n[1], 0.0]), c, 1.0)
            if rms > 0.6 and len(pts) >= 6:
                center = origin + cell / 2.0
                conic = _taubin(pts, center, float(cell))
                if conic is not None and conic[1] < 0.5 * rms:
                    model = (conic[0], center, float(cell))
            models[cy, cx] = model
            windows[cy, cx] = np.flatnonzero(sel)
    for (cy, cx), sign in _orient(models, windows, spts, ny, nx).items():
        coeffs, center, scale = models[cy, cx]
        data[cy, cx] = from_polynomial(sign * coeffs, cell, np.array([cx * cell, cy * cell], float), center,
                                       scale)
    inked = np.zeros((ny, nx), bool)
    for key in models:
        inked[key] = True
    return data, inked


def _neighbours(cy: int, cx: int, ny: int, nx: int):
    """Edge-adjacent cells with the index pairs of the shared corners: ((ny, nx), [((j, i) here,
    (j, i) there), ...])."""
    if cx + 1 < nx:
        yield (cy, cx + 1), [((0, 1), (0, 0)), ((1, 1), (1, 0))]
    if cx > 0:
        yield (cy, cx - 1), [((0, 0), (0, 1)), ((1, 0), (1, 1))]
    if cy + 1 < ny:
        yield (cy + 1, cx), [((1, 0), (0, 0)), ((1, 1), (0, 1))]
    if cy > 0:
        yield (cy - 1, cx), [((0, 0), (1, 0)), ((0, 1), (1, 1))]


def _orient(models: dict, windows: dict, spts: np.ndarray, ny: int, nx: int) -> dict:
    """A sign (+-1) per modelled cell, breadth first from the cell with the most ink: the one whose
    gradient agrees best, at the skeleton pixels both windows share, with the neighbours placed before."""
    sign: dict[tuple[int, int], float] = {}
    for start in sorted(models, key=lambda k: (-len(windows[k]), k)):
        if start in sign:
            continue
        sign[start] = 1.0
        queue = deque([start])
        while queue:
            cy, cx = queue.popleft()
            for (my, mx), _ in _neighbours(cy, cx, ny, nx):
                if (my, mx) not in models or (my, mx) in sign:
                    continue
                score = 0.0
                for (oy, ox), _ in _neighbours(my, mx, ny, nx):
                    if (oy, ox) in sign:
                        shared = np.intersect1d(windows[my, mx], windows[oy, ox])
                        if len(shared):
                            g = _gradient(models[my, mx], spts[shared]) * _gradient(models[oy, ox], spts[shared])
                            score += sign[oy, ox] * float(g.sum())
                sign[my, mx] = -1.0 if score < 0 else 1.0
                queue.append((my, mx))
    return sign
