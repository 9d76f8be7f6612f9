"""What a structure search fits to: points of the target with their inside/outside labels.

A mesh target gives points on its surface (where the fitted tree's distance should be 0), volume points
(half uniform in the padded bounding box, half near the surface, offsets of sigma 0.02 in the unit-sphere
frame) labelled inside or outside by the generalized winding number (robust to open scans), and a regular
grid of cell centres over the bounds, also labelled: the search scores candidates by their occupancy IoU on
the grid and finds what a candidate misses or adds as connected regions of grid cells.

Masks of K >= 2 views give **silhouette rays** instead: through the pixel centres of each mask reduced to
:data:`RAYS` pixels a side (area average > 1/2 is object), and where the mask's outline passes, through the
pixel centres at :data:`FINE_RAYS` a side: a coarse pixel with a fine pixel whose mask flips within
:data:`BAND` fine pixels is replaced by its fine pixels (a chair's tubes are a coarse pixel or two thick;
inside and far outside the silhouette every fine pixel agrees with its coarse one). The rays tile each
image once; the fit and the score count every ray once, so an outline weighs more than its area (measured
better on real furniture: ``results/structure_masks.md``). :data:`RAY_SAMPLES` points lie evenly along each
ray's stretch inside
the bounds; a tree's silhouette at a ray is the minimum of its distance over those points (< 0: the ray
meets the solid). The fit and the score compare silhouettes, not volumes, so a tree is not asked to fill
what the views cannot see. The grid's labels there are the visual hull (a point is inside
where every view's mask covers its projection, carved point by point in the cube ``|x| <= extent`` around
the world origin, where DESIGN.md's targets lie): they only say where a new part may go.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ipm.errors import InputError
from ipm.types import Camera, TriMesh

NEAR_SIGMA = 0.02      # offsets of the near-surface volume points (unit-sphere frame)
PAD = 0.05             # the bounds grown by this share of their diagonal
RAYS = 32              # silhouette rays per side of each view (masks)
FINE_RAYS = 64         # ... and per side near the masks' outlines (0: none)
BAND = 2               # fine pixels: a coarse pixel is split where a mask flips this close to a fine one
RAY_SAMPLES = 32       # points along each ray


@dataclass(frozen=True)
class Samples:
    """Target points (float tensors on one device) and labels. ``surface`` (S, 3) or None (masks);
    ``volume`` (V, 3) with ``inside`` (V,) bool; ``grid`` (n³, 3) cell centres of a ``shape`` grid over
    ``lo``..``hi`` with ``grid_inside`` (n³,) bool; masks: ``rays`` (R, P, 3) points along R silhouette rays
    with ``ray_hit`` (R,) bool, the ray's pixel is object."""

    surface: torch.Tensor | None
    volume: torch.Tensor
    inside: torch.Tensor
    grid: torch.Tensor
    grid_inside: torch.Tensor
    shape: tuple[int, int, int]
    lo: np.ndarray
    hi: np.ndarray
    rays: torch.Tensor | None = None
    ray_hit: torch.Tensor | None = None

    @property
    def cell(self) -> np.ndarray:
        """The grid's cell size per axis (3,)."""
        return (self.hi - self.lo) / np.asarray(self.shape)

    def to(self, device=None, dtype=torch.float32) -> Samples:
        """The samples with their point tensors in ``dtype`` on ``device``; the bool labels only move."""
        def f(t):
            return None if t is None else t.to(device=device, dtype=dtype)

        return Samples(f(self.surface), f(self.volume), self.inside.to(device), f(self.grid),
                       self.grid_inside.to(device), self.shape, self.lo, self.hi, f(self.rays),
                       None if self.ray_hit is None else self.ray_hit.to(device))


def _grid(lo: np.ndarray, hi: np.ndarray, n: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Cell centres (n_x n_y n_z, 3) of a grid of about ``n`` cells along the longest side."""
    ext = hi - lo
    counts = tuple(int(max(4, round(n * e / ext.max()))) for e in ext)
    axes = [lo[i] + (np.arange(c) + 0.5) * ext[i] / c for i, c in enumerate(counts)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), counts


def _padded(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pad = PAD * float(np.linalg.norm(hi - lo))
    return lo - pad, hi + pad


def mesh_samples(mesh: TriMesh, *, surface: int = 2000, volume: int = 6000, grid: int = 32,
                 seed: int = 0) -> Samples:
    """Samples of a mesh target (module docstring), deterministic per ``seed``."""
    from ipm.metrics import inside, mesh_arrays, sample_surface

    V, F = mesh_arrays(mesh)
    if len(F) == 0:
        raise InputError("target mesh: expected faces, got none")
    rng = np.random.default_rng(seed)
    lo, hi = _padded(V.min(0), V.max(0))
    surf = sample_surface(V, F, surface, rng)
    half = volume // 2
    near = sample_surface(V, F, volume - half, rng) + rng.normal(0.0, NEAR_SIGMA, (volume - half, 3))
    vol = np.concatenate([rng.uniform(lo, hi, (half, 3)), near])
    pts, shape = _grid(lo, hi, grid)
    grid_in = inside(pts, V, F)
    if not grid_in.any():
        raise InputError("target mesh: no point is inside it (its generalized winding number is below 0.5 "
                         "everywhere: an open or inconsistently oriented surface); fit it from masks instead "
                         "(ipm render MESH --views 4 -o DIR, then --masks DIR)")
    f64 = torch.float64
    return Samples(torch.as_tensor(surf, dtype=f64), torch.as_tensor(vol, dtype=f64),
                   torch.as_tensor(inside(vol, V, F)), torch.as_tensor(pts, dtype=f64),
                   torch.as_tensor(grid_in), shape, lo, hi)


def carve(points: torch.Tensor, masks: torch.Tensor, cameras: Sequence[Camera]) -> torch.Tensor:
    """Inside the visual hull: (N,) bool, True where every view's mask covers the point's projection (a
    point behind a camera or outside its image is outside)."""
    from ipm.render.camera import project

    keep = torch.ones(points.shape[0], dtype=torch.bool, device=points.device)
    for m, cam in zip(masks, cameras):
        xy, depth = project(points, cam.to(points.dtype))
        H, W = m.shape
        x, y = torch.floor(xy[:, 0]).long(), torch.floor(xy[:, 1]).long()
        ok = (depth > 0) & (x >= 0) & (x < W) & (y >= 0) & (y < H)
        hit = torch.zeros_like(keep)
        hit[ok] = m[y[ok], x[ok]]
        keep &= hit
    return keep


def _split(cover: torch.Tensor, factor: int, band: int) -> torch.Tensor:
    """Coarse pixels (h, w) bool to split: those holding a fine pixel of ``cover`` (factor h, factor w) bool
    whose mask flips within ``band`` fine pixels (a (2 band + 1)² window holds both values)."""
    c = cover[None, None].double()
    pool = torch.nn.functional.max_pool2d
    k = 2 * band + 1
    edge = pool(c, k, 1, band) != -pool(-c, k, 1, band)
    return pool(edge.double(), factor, factor)[0, 0] > 0


def _view_rays(m: torch.Tensor, cam: Camera, size: int,
               fine: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One view's rays: ``(origin (3,), directions (R, 3), hit (R,) bool, area (R,))``, the coarse pixels at
    ``size`` a side where the mask is flat and the fine pixels at ``fine`` a side (a multiple of ``size``; 0:
    none) near its outline; ``area``: the fine pixels a ray stands for."""
    from ipm.render.camera import crop_camera, pixel_rays

    f64 = torch.float64
    H, W = m.shape
    small = crop_camera(cam.to(f64), 0, 0, W, H, size / max(H, W))
    origin, dirs = pixel_rays(small)
    h, w = dirs.shape[:2]
    resize = torch.nn.functional.interpolate
    cover = resize(m[None, None].to(f64), size=(h, w), mode="area")[0, 0] > 0.5
    if not fine:
        return origin, dirs.reshape(-1, 3), cover.reshape(-1), torch.ones(h * w, dtype=f64)
    k = fine // size
    _, fdirs = pixel_rays(crop_camera(small, 0, 0, w, h, k))
    fcover = resize(m[None, None].to(f64), size=(k * h, k * w), mode="area")[0, 0] > 0.5
    split = _split(fcover, k, BAND)
    fsplit = split.repeat_interleave(k, 0).repeat_interleave(k, 1)
    d = torch.cat([dirs[~split], fdirs[fsplit]])
    hit = torch.cat([cover[~split], fcover[fsplit]])
    area = torch.cat([torch.full((int((~split).sum()),), float(k * k), dtype=f64),
                      torch.ones(int(fsplit.sum()), dtype=f64)])
    return origin, d, hit, area


def silhouette_rays(masks: torch.Tensor, cameras: Sequence[Camera], lo: np.ndarray, hi: np.ndarray, *,
                    size: int = RAYS, fine: int = FINE_RAYS,
                    samples: int = RAY_SAMPLES) -> tuple[torch.Tensor, torch.Tensor]:
    """Points ``(R, samples, 3)`` along every view's rays (coarse pixels at ``size`` a side, fine ones at
    ``fine`` a side near the outline, 0: none) that cross the box ``lo``..``hi`` and whether each ray's
    pixel is object ``(R,)`` bool (module docstring). A ray that misses the box cannot meet the tree; one whose
    pixel is object there is a mask the box does not explain."""
    from ipm.render.sdf_silhouette import ray_box

    f64 = torch.float64
    lo_t, hi_t = torch.as_tensor(lo, dtype=f64), torch.as_tensor(hi, dtype=f64)
    u = (torch.arange(samples, dtype=f64) + 0.5) / samples
    pts, hits = [], []
    for m, cam in zip(masks, cameras):
        origin, dirs, hit, _ = _view_rays(m, cam, size, fine)
        t0, t1, ok = ray_box(origin, dirs, lo_t, hi_t)
        t = t0[ok, None] + (t1 - t0)[ok, None] * u
        pts.append(origin + t[..., None] * dirs[ok, None, :])
        hits.append(hit[ok])
    return torch.cat(pts), torch.cat(hits)


def mask_samples(masks, cameras: Sequence[Camera], *, volume: int = 8000, grid: int = 32, extent: float = 1.2,
                 seed: int = 0, rays: int = RAYS, fine_rays: int = FINE_RAYS) -> Samples:
    """Samples of the visual hull of ``masks`` (K, H, W) in views ``cameras`` (module docstring); silhouette
    rays at ``rays`` a side and ``fine_rays`` (a multiple of ``rays``, or 0: none) near the outlines."""
    m = torch.as_tensor(np.asarray(masks)) > 0.5
    if m.dim() != 3 or m.shape[0] != len(cameras):
        raise InputError(f"masks: expected (K, H, W) with one camera each, got {tuple(m.shape)} and "
                         f"{len(cameras)} cameras")
    if m.shape[0] < 2:
        raise InputError(f"structure search from masks: expected at least 2 views, got {m.shape[0]} (one view "
                         "leaves the depth of every part free)")
    if rays < 1 or fine_rays < 0 or fine_rays % rays:
        raise InputError(f"silhouette rays: expected a positive side and a fine side that is 0 or a multiple of it, "
                         f"got {rays} and {fine_rays}")
    coarse, cshape = _grid(np.full(3, -extent), np.full(3, extent), 96)
    occ = carve(torch.as_tensor(coarse), m, cameras).numpy()
    if not occ.any():
        raise InputError("masks: the views' silhouettes have no point in common inside the cube |x| <= "
                         f"{extent} (cameras looking elsewhere, or empty masks)")
    step = 2 * extent / np.asarray(cshape)
    inner = coarse[occ]
    lo, hi = _padded(inner.min(0) - step, inner.max(0) + step)
    rng = np.random.default_rng(seed)
    half = volume // 2
    # near the hull's boundary: coarse cells inside with a neighbour outside, jittered within a cell
    full = occ.reshape(cshape)
    edge = np.zeros_like(full)
    for ax in range(3):
        for sh in (1, -1):
            edge |= full & ~np.roll(full, sh, axis=ax)
    cells = coarse[edge.ravel()]
    near = cells[rng.integers(0, len(cells), volume - half)] + rng.uniform(-1.5, 1.5, (volume - half, 3)) * step
    vol = np.concatenate([rng.uniform(lo, hi, (half, 3)), near])
    pts, shape = _grid(lo, hi, grid)
    f64 = torch.float64
    vol_t, pts_t = torch.as_tensor(vol, dtype=f64), torch.as_tensor(pts, dtype=f64)
    pts_r, hit = silhouette_rays(m, cameras, lo, hi, size=rays, fine=fine_rays)
    return Samples(None, vol_t, carve(vol_t, m, cameras), pts_t, carve(pts_t, m, cameras), shape, lo, hi, pts_r, hit)


__all__ = ["Samples", "carve", "mask_samples", "mesh_samples", "silhouette_rays"]
