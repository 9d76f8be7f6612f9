"""Marching cubes over an SDF, evaluating it only near the surface.

The grid over the (padded) bounds is cut into blocks of ``block`` cells. A first pass evaluates the SDF
at every block center; a block whose ``|f(center)|`` exceeds its half-diagonal cannot contain surface
(the SDF is exact or a bound, so ``|f|`` never overestimates the distance), and all its samples take
the center's sign. Only the remaining blocks are sampled densely. scikit-image's marching cubes then
runs on the cells of those blocks only (its ``mask``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
import torch

from ipm.types import TriMesh

log = logging.getLogger(__name__)

# A dense float32 grid costs 4 bytes a sample; refuse grids that would not fit comfortably.
MAX_SAMPLES = 1024**3 // 2


def grid_shape(lo: np.ndarray, hi: np.ndarray, resolution: int, pad: int = 2):
    """Samples per axis and spacing for ``resolution`` samples along the longest side of the box."""
    ext = np.maximum(hi - lo, 1e-9)
    h = float(ext.max()) / max(resolution - 1, 1)
    origin = lo - pad * h
    shape = tuple(int(np.ceil(e / h)) + 1 + 2 * pad for e in ext)
    return origin, h, shape


def check_resolution(resolution: int, lo: np.ndarray, hi: np.ndarray) -> None:
    if not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise ValueError(f"resolution: expected an integer >= 8, got {resolution}")
    _, _, shape = grid_shape(lo, hi, resolution)
    n = int(np.prod(shape, dtype=np.int64))
    if n > MAX_SAMPLES:
        raise ValueError(f"resolution {resolution} needs {n:,} samples, more than the {MAX_SAMPLES:,} "
                         f"that fit in memory here; use a resolution up to about "
                         f"{int(resolution * (MAX_SAMPLES / n) ** (1 / 3))}")


@torch.no_grad()
def sample_narrow_band(f: Callable[[torch.Tensor], torch.Tensor], lo: np.ndarray, hi: np.ndarray,
                       resolution: int, *, block: int = 8, dtype=torch.float32, device=None,
                       chunk: int = 1 << 21):
    """Sample ``f`` on a grid, densely only near the surface.

    Returns (volume (X, Y, Z) float32 numpy, active cell mask (X-1, Y-1, Z-1) bool, origin (3,), h).
    """
    check_resolution(resolution, lo, hi)
    origin, h, shape = grid_shape(np.asarray(lo, float), np.asarray(hi, float), resolution)
    nb = [int(np.ceil((s - 1) / block)) for s in shape]  # blocks of cells per axis
    # Pass 1: block centers.
    bi = [torch.arange(n, device=device, dtype=dtype) for n in nb]
    centers = torch.stack(torch.meshgrid(*bi, indexing="ij"), -1).reshape(-1, 3)
    org = torch.as_tensor(origin, dtype=dtype, device=device)
    cpts = org + (centers + 0.5) * (block * h)
    fc = _eval_chunked(f, cpts, chunk).reshape(nb)
    radius = 0.5 * np.sqrt(3.0) * block * h * 1.01 + 1e-7
    active = fc.abs() <= radius
    # Far samples: the sign of their block center (inactive blocks hold no surface).
    far = torch.where(fc > 0, torch.full_like(fc, block * h), torch.full_like(fc, -block * h))
    vol = far.repeat_interleave(block, 0).repeat_interleave(block, 1).repeat_interleave(block, 2)
    vol = torch.nn.functional.pad(vol[None, None], (0, 1, 0, 1, 0, 1), mode="replicate")[0, 0]
    vol = vol[: shape[0], : shape[1], : shape[2]].contiguous()
    # Pass 2: dense samples of the active blocks ((block + 1)^3 each, faces shared).
    act = active.nonzero()
    if len(act):
        loc = torch.arange(block + 1, device=device)
        offs = torch.stack(torch.meshgrid(loc, loc, loc, indexing="ij"), -1).reshape(-1, 3)
        step = max(1, chunk // offs.shape[0])
        lim = torch.tensor(shape, device=device) - 1
        for s in range(0, len(act), step):
            idx = (act[s:s + step, None, :] * block + offs[None]).reshape(-1, 3)
            idx = torch.minimum(idx, lim)
            pts = org + idx.to(dtype) * h
            vol[idx[:, 0], idx[:, 1], idx[:, 2]] = f(pts).to(vol.dtype)
    cells = active.repeat_interleave(block, 0).repeat_interleave(block, 1).repeat_interleave(block, 2)
    cells = cells[: shape[0] - 1, : shape[1] - 1, : shape[2] - 1]
    log.debug("narrow band: %d of %d blocks active", len(act), active.numel())
    return vol.cpu().numpy(), cells.cpu().numpy(), origin, h


def _eval_chunked(f, pts: torch.Tensor, chunk: int) -> torch.Tensor:
    return torch.cat([f(pts[i:i + chunk]) for i in range(0, len(pts), chunk)]) if len(pts) else pts[:, 0]


def mesh_sdf(f: Callable[[torch.Tensor], torch.Tensor], lo: np.ndarray, hi: np.ndarray,
             resolution: int = 128, *, dtype=torch.float32, device=None) -> TriMesh:
    """Marching-cubes mesh of ``{f < 0}`` inside the box ``[lo, hi]``.

    f: points (N, 3) -> distances (N,); resolution: samples along the longest side.
    Returns a TriMesh (float64 vertices, outward-facing triangles); empty if the shape is empty.
    """
    from skimage.measure import marching_cubes

    vol, cells, origin, h = sample_narrow_band(f, lo, hi, resolution, dtype=dtype, device=device)
    if vol.min() >= 0 or vol.max() <= 0:
        return TriMesh(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.int64))
    # skimage's mask is per sample; a sample belongs to the band if any of its cells does.
    mask = np.zeros(vol.shape, dtype=bool)
    mask[:-1, :-1, :-1] |= cells
    mask[1:, :-1, :-1] |= cells
    mask[:-1, 1:, :-1] |= cells
    mask[:-1, :-1, 1:] |= cells
    mask[1:, 1:, :-1] |= cells
    mask[1:, :-1, 1:] |= cells
    mask[:-1, 1:, 1:] |= cells
    mask[1:, 1:, 1:] |= cells
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h), gradient_direction="descent",
                                        mask=mask, allow_degenerate=False)
    verts = verts.astype(np.float64) + origin
    return TriMesh(torch.from_numpy(verts), torch.from_numpy(faces.astype(np.int64)))
