"""What every conversion shares: input checks, the normalized and welded target mesh, vertex normals,
occupancy samples, and the result type."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ipm.errors import InputError
from ipm.generators.base import Generator
from ipm.types import TriMesh

# progress(done, total, info): done/total in the converter's own unit (steps, functions, ...)
Progress = Callable[[int, int, dict], None]


@dataclass(frozen=True)
class Target:
    """A conversion target in the protocol's frame (bounding-box center at the origin, farthest vertex at
    distance 1: DESIGN.md v2).

    verts: (V, 3) float64, welded (texture seams merged) and only those used by a face
    faces: (F, 3) int64, zero-area triangles dropped, counter-clockwise seen from outside
    normals: (V, 3) float64 unit area-weighted vertex normals
    center: (3,) and scale: how the input was normalized (``normalized = (input - center) * scale``)
    """

    verts: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    center: np.ndarray
    scale: float

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal (normalized units)."""
        return float(np.linalg.norm(self.verts.max(0) - self.verts.min(0)))

    def mesh(self) -> TriMesh:
        """The target as a float64 :class:`TriMesh` in the normalized frame (arrays shared, not copied)."""
        return TriMesh(torch.from_numpy(self.verts), torch.from_numpy(self.faces))


@dataclass
class Conversion:
    """What a converter returns.

    generator: the Generator holding the result (its spec defaults are the converted values)
    values: the converted parameter values
    data: the JSON document to write (loads back with the generator's ``from_json``/``from_file``)
    stats: numbers to report (counts, deviations, IoU, seconds)
    """

    generator: Generator
    values: dict
    data: dict
    stats: dict = field(default_factory=dict)


def as_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """``(V (n, 3) float64, F (m, 3) int64)`` from a TriMesh, a trimesh.Trimesh or a (V, F) pair."""
    if isinstance(mesh, TriMesh):
        V, F = mesh.verts.detach().cpu().double().numpy(), mesh.faces.detach().cpu().numpy()
    elif isinstance(mesh, tuple) and len(mesh) == 2:
        V, F = np.asarray(mesh[0], dtype=np.float64), np.asarray(mesh[1])
    elif hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    else:
        raise InputError(f"expected a TriMesh, a trimesh.Trimesh or (verts, faces), got {type(mesh).__name__}")
    V = V.reshape(-1, 3) if V.size else np.zeros((0, 3))
    F = F.reshape(-1, 3).astype(np.int64) if F.size else np.zeros((0, 3), dtype=np.int64)
    return V, F


def prepare(mesh) -> Target:
    """Check, weld, clean and normalize a target mesh; ``InputError`` ("expected ..., got ...") if it has
    no faces, non-finite or out-of-range indices, or no area."""
    from ipm.metrics import unit_sphere_frame

    V, F = as_arrays(mesh)
    if len(F) == 0:
        raise InputError(f"expected a mesh with faces, got one with {len(V)} vertices and no faces")
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"expected face indices in [0, {len(V) - 1}], got {F.min()}..{F.max()}")
    if not np.isfinite(V).all():
        raise InputError("expected finite vertex coordinates, got NaN or inf")
    used = np.unique(F)
    try:
        center, scale = unit_sphere_frame(V[used])
    except ValueError:
        raise InputError("expected a mesh with a nonzero extent, got all vertices at one point") from None
    Vn = (V[used] - center) * scale
    Vall = np.zeros_like(V)
    Vall[used] = Vn
    # weld texture seams: equal positions (to 1e-9 of the size) become one vertex
    key = np.round(Vall / 1e-9).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    Fw = inv[F]
    tri = Vall[first][Fw]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = (area2 > 1e-14) & (Fw[:, 0] != Fw[:, 1]) & (Fw[:, 1] != Fw[:, 2]) & (Fw[:, 0] != Fw[:, 2])
    if not keep.any():
        raise InputError("expected a mesh with positive surface area, got only degenerate triangles")
    Fw = Fw[keep]
    used2, Fc = np.unique(Fw, return_inverse=True)
    Vc = Vall[first][used2]
    Fc = Fc.reshape(-1, 3).astype(np.int64)
    if _signed_volume(Vc, Fc) < 0:       # inside-out files: make the faces face outwards
        Fc = Fc[:, ::-1].copy()
    return Target(np.ascontiguousarray(Vc), np.ascontiguousarray(Fc), vertex_normals(Vc, Fc), center, scale)


def _signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    t = V[F]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(V, 3)``; isolated directions fall back to +Y."""
    t = V[F]
    fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])          # length = 2 * area
    n = np.zeros_like(V)
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 1e-300, n / np.maximum(norm, 1e-300), np.array([0.0, 1.0, 0.0]))


def surface_with_normals(target: Target, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` area-weighted surface samples ``(n, 3)`` (:func:`ipm.metrics.sample_surface`) and their unit
    face normals ``(n, 3)``."""
    from ipm.metrics import sample_surface

    pts, fi = sample_surface(target.verts, target.faces, n, rng, return_faces=True)
    t = target.verts[target.faces[fi]]
    fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return pts, fn / np.linalg.norm(fn, axis=1)[:, None]


def occupancy_samples(target: Target, n_uniform: int, n_near: int, rng: np.random.Generator,
                      sigmas: tuple[float, ...] = (0.01, 0.05), pad: float = 0.1,
                      box: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(n_uniform + n_near, 3)`` float64 (uniform in ``box``, by default the target's bounding box
    grown by ``pad``, and surface samples moved by Gaussian noise of each sigma) with inside labels
    ``(N,)`` bool (generalized winding number)."""
    from ipm.metrics import inside, sample_surface

    lo, hi = box if box is not None else (target.verts.min(0) - pad, target.verts.max(0) + pad)
    uni = rng.uniform(lo, hi, size=(n_uniform, 3))
    near = []
    for k, s in enumerate(sigmas):
        m = n_near // len(sigmas) + (1 if k < n_near % len(sigmas) else 0)
        near.append(sample_surface(target.verts, target.faces, m, rng) + rng.normal(scale=s, size=(m, 3)))
    pts = np.vstack([uni, *near])
    return pts, inside(pts, target.verts, target.faces)


def farthest_points(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(k,)`` of a farthest-point sample of ``points (N, 3)`` (random first point)."""
    k = min(k, len(points))
    idx = np.empty(k, dtype=np.int64)
    idx[0] = rng.integers(len(points))
    d = np.linalg.norm(points - points[idx[0]], axis=1)
    for i in range(1, k):
        idx[i] = int(np.argmax(d))
        d = np.minimum(d, np.linalg.norm(points - points[idx[i]], axis=1))
    return idx


def check_positive_int(name: str, value, lo: int = 1) -> int:
    """``int(value)`` if it is an integer >= ``lo`` (bools refused), else ``InputError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InputError(f"{name}: expected an integer >= {lo}, got {value!r}")
    return int(value)


def check_positive(name: str, value) -> float:
    """``float(value)`` if it is a finite number > 0, else ``InputError`` naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a positive number, got {value!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise InputError(f"{name}: expected a positive number, got {value!r}")
    return v


# A converted shape is meshed on a dense float32 grid of about resolution³ samples (4 bytes each, plus a
# margin of a few samples a side): refuse up front, before any conversion work, grids above this size.
MAX_GRID_BYTES = 2 * 1024**3


def check_mesh_resolution(resolution) -> int:
    """``resolution`` if a ``resolution``³ float32 meshing grid fits in :data:`MAX_GRID_BYTES` (2 GiB);
    :class:`InputError` with the limit and the largest resolution that fits otherwise."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 8:
        raise InputError(f"resolution: expected an integer >= 8, got {resolution!r}")
    need = (int(resolution) + 4) ** 3 * 4
    if need > MAX_GRID_BYTES:
        top = int(round((MAX_GRID_BYTES / 4) ** (1 / 3))) - 4
        while (top + 5) ** 3 * 4 <= MAX_GRID_BYTES:
            top += 1
        while (top + 4) ** 3 * 4 > MAX_GRID_BYTES:
            top -= 1
        raise InputError(f"resolution: expected at most {top} (a float32 grid of resolution³ samples must fit in "
                         f"{MAX_GRID_BYTES / 1024**3:g} GiB), got {resolution} ({need / 1024**3:.4g} GiB)")
    return int(resolution)
