"""What the silhouette baselines share about their input views: the masks reduced to a workable size
(:func:`fit_views`, and the cues with them: :func:`fit_cues`), the checks of a task (:func:`check_task`)
and the visual hull on a grid (:func:`carve`, :func:`hull_box`)."""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from ipm.errors import InputError, MethodFailed
from ipm.types import Camera

DTYPE = torch.float32


def check_task(name: str, masks: np.ndarray, cameras: list[Camera], budget: int) -> None:
    """:class:`InputError` unless ``masks`` are (K, H, W) with one camera of their size each, every mask
    has a foreground, and ``budget`` is at least one step. ``name`` prefixes the message."""
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise InputError(f"{name}: expected masks (K, H, W), got shape {masks.shape}")
    if len(cameras) != masks.shape[0]:
        raise InputError(f"{name}: expected one camera per mask, got {len(cameras)} cameras for "
                         f"{masks.shape[0]} masks")
    for c in cameras:
        if (c.height, c.width) != masks.shape[1:]:
            raise InputError(f"{name}: expected cameras of the masks' size {masks.shape[2]}x{masks.shape[1]}, "
                             f"got {c.width}x{c.height}")
    empty = [i for i, m in enumerate(masks) if not m.any()]
    if empty:
        raise InputError(f"{name}: expected a foreground in every mask, got empty mask(s) {empty}")
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise InputError(f"{name}: budget: expected at least 1 optimizer step, got {budget!r}")


def fit_views(masks: np.ndarray, cameras: list[Camera], max_size: int, dtype: torch.dtype = DTYPE
              ) -> tuple[torch.Tensor, list[Camera]]:
    """The masks as soft targets (K, h, w) in ``dtype`` and their cameras, reduced by the smallest integer
    factor that divides both image sides and brings the longer one to at most ``max_size`` (box filter:
    a reduced pixel is the covered fraction of its full-size pixels; the camera keeps its field of
    view, so reduced pixel centers fall on the centers of the full-size blocks: reduced coordinates are
    ``x / f``, and a set principal point becomes ``(cx / f, cy / f)``). Factor 1 if none divides."""
    K, H, W = masks.shape
    dev = cameras[0].eye.device
    target = torch.as_tensor(np.asarray(masks), dtype=dtype, device=dev)
    f = reduction(H, W, max_size)
    cams = [c.to(dtype) for c in cameras]
    if f == 1:
        return target, cams
    target = F.avg_pool2d(target[:, None], f)[:, 0]
    return target, [Camera(c.eye, c.target, c.up, c.fov_deg, W // f, H // f,
                           None if c.cx is None else c.cx / f, None if c.cy is None else c.cy / f) for c in cams]


def reduction(H: int, W: int, max_size: int) -> int:
    """The factor :func:`fit_views` reduces an ``H`` x ``W`` image by: the smallest integer dividing both
    sides that brings the longer one to at most ``max_size`` (1 if none does)."""
    return next((f for f in range(max(1, math.ceil(max(H, W) / max_size)), max(H, W) + 1)
                 if H % f == 0 and W % f == 0), 1)


def fit_cues(depth: np.ndarray | None, parts: np.ndarray | None, max_size: int, dtype: torch.dtype = DTYPE,
             device=None) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """Depth maps (K, H, W) (NaN: no reading) and part labels (K, H, W) int (-1: none) reduced with the
    masks (:func:`fit_views`, same blocks): a block's depth is the mean of its readings (NaN without
    any), its label the most common one in it (ties to the lower label, -1 first). Either may be None."""
    out = []
    for a in (depth, parts):
        if a is None:
            out.append(None)
            continue
        t = torch.as_tensor(np.asarray(a), device=device)
        K, H, W = t.shape
        f = reduction(H, W, max_size)
        if a is depth:
            t = t.to(dtype)
            if f > 1:
                ok = torch.isfinite(t)
                n = F.avg_pool2d(ok[:, None].to(dtype), f)[:, 0]
                s = F.avg_pool2d(torch.where(ok, t, 0.0)[:, None], f)[:, 0]
                t = torch.where(n > 0, s / n.clamp_min(1e-12), torch.nan)
        elif f > 1:
            labels = torch.arange(-1, int(t.max()) + 1, device=t.device)
            share = torch.stack([F.avg_pool2d((t == v)[:, None].to(DTYPE), f)[:, 0] for v in labels])
            t = labels[share.argmax(0)]
        else:
            t = t.to(torch.int64)
        out.append(t)
    return out[0], out[1]


def grid_axis(n: int, extent: float, dtype=torch.float64, device=None) -> torch.Tensor:
    """``n`` node coordinates (n,) from ``-extent`` to ``extent``."""
    return torch.linspace(-extent, extent, n, dtype=dtype, device=device)


def carve(masks: np.ndarray, cameras: list[Camera], axis: torch.Tensor) -> torch.Tensor:
    """Visual hull (Laurentini) on the nodes of the grid ``axis``³: (n, n, n) bool, indexed ``[x, y, z]``,
    true where the node projects inside every mask (outside the image counts as background).
    masks: (K, H, W) bool; cameras: K cameras; axis: (n,) float64 node coordinates (:func:`grid_axis`).
    Follows the cameras' device."""
    from ipm.render.camera import project

    dev = cameras[0].eye.device
    ax = axis.to(device=dev, dtype=torch.float64)
    n = ax.shape[0]
    pts = torch.stack(torch.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    keep = torch.ones(pts.shape[0], dtype=torch.bool, device=dev)
    for mask, cam in zip(masks, cameras):
        xy, depth = project(pts, cam.to(torch.float64))
        px, py = torch.floor(xy[:, 0]).long(), torch.floor(xy[:, 1]).long()
        H, W = mask.shape
        inside = (px >= 0) & (px < W) & (py >= 0) & (py < H) & (depth > 0)
        m = torch.as_tensor(np.asarray(mask, dtype=bool), device=dev)
        hit = torch.zeros_like(keep)
        hit[inside] = m[py[inside], px[inside]]
        keep &= hit
    return keep.reshape(n, n, n)


def hull_box(occ: torch.Tensor, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Center and half extents (3,) each of the nodes set in ``occ`` (n, n, n) over ``[-extent, extent]³``;
    :class:`InputError` if none is set (the masks do not agree on any node)."""
    idx = torch.nonzero(occ)
    if idx.numel() == 0:
        raise MethodFailed("visual hull is empty: the masks do not agree on any grid node")
    n = occ.shape[0]
    h = 2 * extent / (n - 1)
    lo = idx.amin(0).double().cpu().numpy() * h - extent - h / 2
    hi = idx.amax(0).double().cpu().numpy() * h - extent + h / 2
    return (lo + hi) / 2, (hi - lo) / 2
