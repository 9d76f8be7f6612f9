"""Marching cubes over an SDF, evaluating it only near the surface.

The grid over the (padded) bounds is cut into blocks of 8 cells, and those into sub-blocks of 2 cells.
The SDF is evaluated at every block center; a block whose ``|f(center)|`` exceeds its half-diagonal
cannot contain surface (the SDF is exact or a bound, so ``|f|`` never overestimates the distance),
and all its samples take the center's sign. Sub-blocks of the remaining blocks are tested the same
way, and only the corner samples of the sub-blocks that may hold surface are evaluated (each sample
once). Every cell crossed by the surface lies in such a sub-block, so marching cubes (scikit-image,
restricted to those samples with its ``mask``) sees exact values wherever it places a vertex.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
import torch

from ipm.errors import InputError
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
    """``InputError`` unless ``resolution`` is an int >= 8 whose grid over ``[lo, hi]`` has at most
    :data:`MAX_SAMPLES` samples (the message names the largest resolution that fits)."""
    if not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise InputError(f"resolution: expected an integer >= 8, got {resolution}")
    _, _, shape = grid_shape(lo, hi, resolution)
    n = int(np.prod(shape, dtype=np.int64))
    if n > MAX_SAMPLES:
        raise InputError(f"resolution {resolution} needs {n:,} samples, more than the {MAX_SAMPLES:,} "
                         f"that fit in memory here; use a resolution up to about "
                         f"{int(resolution * (MAX_SAMPLES / n) ** (1 / 3))}")


def _offsets(k: int, device) -> torch.Tensor:
    r = torch.arange(k, device=device)
    return torch.stack(torch.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)


@torch.no_grad()
def sample_narrow_band(f: Callable[[torch.Tensor], torch.Tensor], lo: np.ndarray, hi: np.ndarray,
                       resolution: int, *, dtype=torch.float32, device=None, chunk: int = 1 << 20):
    """Sample ``f`` on a grid, exactly only near the surface.

    Returns (volume (X, Y, Z) float32 numpy, mask of exactly evaluated samples (X, Y, Z) bool,
    origin (3,), spacing h). Samples away from the surface hold ``+-2h`` or ``+-8h`` with the right sign.
    """
    B1, B2 = 8, 2
    k = B1 // B2
    check_resolution(resolution, lo, hi)
    origin, h, shape = grid_shape(np.asarray(lo, float), np.asarray(hi, float), resolution)
    nb = [int(np.ceil((s - 1) / B1)) for s in shape]            # blocks per axis
    shape = tuple(n * B1 + 1 for n in nb)                       # grow the far padding to whole blocks
    org = torch.as_tensor(origin, dtype=dtype, device=device)
    safety = 1.01

    # Level 1: block centers.
    idx1 = _offsets(max(nb), device)
    idx1 = idx1[(idx1 < torch.tensor(nb, device=device)).all(1)]
    f1 = _eval_chunked(f, org + (idx1.to(dtype) + 0.5) * (B1 * h), chunk)
    grid1 = torch.empty(nb, dtype=dtype, device=device)
    grid1[idx1[:, 0], idx1[:, 1], idx1[:, 2]] = f1
    act1 = (f1.abs() <= safety * 0.5 * np.sqrt(3.0) * B1 * h)

    # Level 2: sub-block centers inside the active blocks.
    sub = (idx1[act1][:, None, :] * k + _offsets(k, device)[None]).reshape(-1, 3)
    f2 = _eval_chunked(f, org + (sub.to(dtype) + 0.5) * (B2 * h), chunk) if len(sub) else f1[:0]
    n2 = [n * k for n in nb]
    sign2 = torch.sign(grid1)[:, None, :, None, :, None].expand(nb[0], k, nb[1], k, nb[2], k)
    sign2 = (sign2.reshape(n2) * B1 * h).contiguous()
    sign2[sub[:, 0], sub[:, 1], sub[:, 2]] = torch.sign(f2) * (B2 * h)
    act2 = f2.abs() <= safety * 0.5 * np.sqrt(3.0) * B2 * h

    # Far values: each sample takes its sub-block's value; the last sample plane copies its neighbour.
    core = sign2[:, None, :, None, :, None].expand(n2[0], B2, n2[1], B2, n2[2], B2)
    core = core.reshape(n2[0] * B2, n2[1] * B2, n2[2] * B2)
    vol = torch.nn.functional.pad(core[None, None], (0, 1, 0, 1, 0, 1), mode="replicate")[0, 0]

    # Exact samples: the corners of the active sub-blocks, each evaluated once.
    need = torch.zeros(shape, dtype=torch.bool, device=device)
    corners = (sub[act2][:, None, :] * B2 + _offsets(B2 + 1, device)[None]).reshape(-1, 3)
    need[corners[:, 0], corners[:, 1], corners[:, 2]] = True
    at = need.nonzero()
    if len(at):
        vol[at[:, 0], at[:, 1], at[:, 2]] = _eval_chunked(f, org + at.to(dtype) * h, chunk).to(vol.dtype)
    log.debug("narrow band: %d of %d samples evaluated", len(at) + len(f1) + len(f2), vol.numel())
    return vol.cpu().numpy(), need.cpu().numpy(), origin, h


def _eval_chunked(f, pts: torch.Tensor, chunk: int) -> torch.Tensor:
    return torch.cat([f(pts[i:i + chunk]) for i in range(0, len(pts), chunk)]) if len(pts) else pts[:, 0]


def mesh_sdf(f: Callable[[torch.Tensor], torch.Tensor], lo: np.ndarray, hi: np.ndarray,
             resolution: int = 128, *, dtype=torch.float32, device=None) -> TriMesh:
    """Marching-cubes mesh of ``{f < 0}`` inside the box ``[lo, hi]``.

    f: points (N, 3) -> distances (N,); resolution: samples along the longest side.
    Returns a TriMesh (float64 vertices, outward-facing triangles); empty if the shape is empty.
    """
    from skimage.measure import marching_cubes

    vol, mask, origin, h = sample_narrow_band(f, lo, hi, resolution, dtype=dtype, device=device)
    if vol.min() >= 0 or vol.max() <= 0:
        return TriMesh(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.int64))
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h), gradient_direction="descent",
                                        mask=mask, allow_degenerate=False)
    verts = verts.astype(np.float64) + origin
    return TriMesh(torch.from_numpy(verts), torch.from_numpy(faces.astype(np.int64)))
