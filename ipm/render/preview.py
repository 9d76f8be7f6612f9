"""Shaded previews: Lambert shading with a headlight over the hard rasterizer (meshes) or sphere tracing
(SDFs), optional colors per face group, written as PNG with Pillow.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.render.camera import orbit_camera, pixel_rays
from ipm.render.raster import rasterize
from ipm.types import Camera, TriMesh

BASE_COLOR = (0.72, 0.76, 0.84)
BACKGROUND = (255, 255, 255)
# Colors of face groups (walls, windows, handle, ...), cycled.
PALETTE = (
    (0.85, 0.60, 0.45), (0.45, 0.62, 0.85), (0.55, 0.78, 0.50), (0.88, 0.80, 0.45),
    (0.70, 0.55, 0.82), (0.45, 0.80, 0.78), (0.90, 0.55, 0.62), (0.65, 0.65, 0.65),
)


def preview_camera(mesh: TriMesh, size: int = 512, azimuth: float = 30.0, elevation: float = 25.0) -> Camera:
    """A camera framing the mesh like the protocol frames a normalized one: looking at the bounding-box
    center from 1.6 times its longest side, FOV 40 degrees."""
    if mesh.n_verts == 0:
        return orbit_camera(azimuth, elevation, 3.2, width=size, height=size)
    v = mesh.verts.detach().double().cpu()
    lo, hi = v.amin(0), v.amax(0)
    extent = float((hi - lo).max()) or 1.0
    return orbit_camera(azimuth, elevation, 1.6 * extent, target=((lo + hi) / 2).tolist(), width=size,
                        height=size)


def shade(mask: torch.Tensor, normal: torch.Tensor, camera: Camera, base: np.ndarray | None = None,
          ambient: float = 0.25, background: Sequence[int] = BACKGROUND) -> np.ndarray:
    """Lambert shading with a light at the eye: (H, W, 3) uint8.

    mask: (H, W) bool; normal: (H, W, 3) world-space normals (either orientation: shading is two-sided);
    base: (H, W, 3) float colors in [0, 1] (default: one light gray-blue).
    """
    _, dirs = pixel_rays(camera.to(dtype=torch.float64))
    n = normal.detach().double().cpu()
    lam = (n * dirs.detach().cpu()).sum(-1).abs().numpy()
    m = mask.detach().cpu().numpy()
    if base is None:
        base = np.broadcast_to(np.asarray(BASE_COLOR), m.shape + (3,))
    rgb = base * (ambient + (1.0 - ambient) * lam)[..., None]
    out = np.empty(m.shape + (3,), dtype=np.uint8)
    out[:] = np.asarray(background, dtype=np.uint8)
    out[m] = np.clip(rgb[m] * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return out


def render_preview(mesh: TriMesh, camera: Camera | None = None, *, size: int = 512,
                   colors: Sequence[Sequence[float]] | None = None, group_colors: bool = True) -> np.ndarray:
    """Shaded picture (H, W, 3) uint8 of a mesh; faces colored by ``mesh.groups`` when present.

    colors: RGB triples in [0, 1] for the groups (default: :data:`PALETTE`, cycled).
    """
    camera = camera or preview_camera(mesh, size)
    fr = rasterize(mesh.verts, mesh.faces, camera)
    return shade_fragments(fr, camera, mesh if group_colors else None, colors)


def shade_fragments(fr, camera: Camera, mesh: TriMesh | None = None,
                    colors: Sequence[Sequence[float]] | None = None) -> np.ndarray:
    """:func:`shade` rasterized fragments; with a mesh that has ``groups``, color faces by group."""
    base = None
    if mesh is not None and mesh.groups is not None and mesh.n_faces:
        pal = np.asarray(colors if colors is not None else PALETTE, dtype=np.float64)
        g = mesh.groups.detach().cpu().numpy()[fr.face.clamp_min(0).cpu().numpy()]
        base = pal[g % len(pal)]
    return shade(fr.mask, fr.normal, camera, base)


def render_sdf_preview(f, camera: Camera, lo, hi, **kw) -> np.ndarray:
    """Shaded picture (H, W, 3) uint8 of the solid ``{f < 0}`` by sphere tracing."""
    from ipm.render.sdf_silhouette import sdf_depth_normals

    pic = sdf_depth_normals(f, camera, lo, hi, **kw)
    return shade(pic.mask, pic.normal, camera)


def save_png(path: str | Path, image: np.ndarray) -> Path:
    """Write an (H, W, 3) or (H, W) uint8 array as PNG, atomically."""
    from PIL import Image

    from ipm.files import atomic_path

    arr = np.asarray(image)
    if arr.dtype != np.uint8 or arr.ndim not in (2, 3):
        raise InputError(f"image: expected a uint8 (H, W) or (H, W, 3) array, got {arr.dtype} {arr.shape}")
    with atomic_path(path) as tmp:
        Image.fromarray(arr).save(tmp, format="PNG")
    return Path(path)


def write_preview(mesh: TriMesh, path: str | Path, camera: Camera | None = None, *, size: int = 512) -> Path:
    """Render :func:`render_preview` and write it to ``path`` (PNG)."""
    return save_png(path, render_preview(mesh, camera, size=size))
