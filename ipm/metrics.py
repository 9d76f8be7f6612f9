"""Evaluation metrics (not differentiable): mask IoU, volumetric IoU, Chamfer-L1 and F-score.

Conventions from DESIGN.md's evaluation protocol (v2): targets are normalized to the unit bounding
sphere (bounding-box center at the origin, farthest vertex at distance 1) and predictions are scored
where the method placed them (``normalize=False``; ``normalize=True`` normalizes both meshes the same
way first, for comparisons of shapes alone); F-score at tau in normalized units with 10,000 surface
samples each way and exact point-to-surface distances (libigl); 3D IoU of solid occupancy on a 64^3
grid over the union of both bounding boxes, inside = generalized winding number > 0.5 (robust to
non-watertight scans; Jacobson et al., "Robust inside-outside segmentation using generalized winding
numbers", SIGGRAPH 2013, via libigl's fast winding number).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ipm.errors import InputError
from ipm.types import TriMesh


def mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V (n, 3) float64, F (m, 3) int64) from a TriMesh or a trimesh.Trimesh."""
    if isinstance(mesh, TriMesh):
        V, F = mesh.verts.detach().cpu().double().numpy(), mesh.faces.cpu().numpy()
    else:
        V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    if len(F) == 0:
        raise InputError("expected a mesh with faces, got one with none")
    return np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int64)


def as_mask(mask) -> np.ndarray:
    """A mask (any shape; numpy array or torch tensor) as a bool array: bool as is, floats thresholded at
    0.5 (soft masks), integers nonzero."""
    if hasattr(mask, "detach"):
        mask = mask.detach().cpu().numpy()
    arr = np.asarray(mask)
    return arr > 0.5 if arr.dtype.kind == "f" else arr.astype(bool)


def mask_iou(a, b) -> float:
    """Intersection over union of two masks of one shape (see :func:`as_mask`; boolean occupancy grids
    too); 1.0 when both are empty."""
    a, b = as_mask(a), as_mask(b)
    if a.shape != b.shape:
        raise InputError(f"masks: expected equal shapes, got {a.shape} and {b.shape}")
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


def touches_border(mask: np.ndarray) -> bool:
    """Whether a boolean mask (H, W) has a foreground pixel in its first or last row or column (the
    object may be clipped by the image)."""
    m = np.asarray(mask, dtype=bool)
    return bool(m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())


def unit_sphere_frame(V: np.ndarray) -> tuple[np.ndarray, float]:
    """(center (3,), scale) of the protocol's normalization: ``(V - center) * scale`` puts the
    bounding-box center at the origin and the farthest vertex at distance 1 (the unit bounding sphere).

    V: (n, 3) float, n >= 1. Raises ``InputError`` when every vertex is at one point."""
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        raise InputError(f"normalize: expected vertices (n, 3) with n >= 1, got {V.shape}")
    center = 0.5 * (V.min(0) + V.max(0))
    radius = float(np.sqrt(((V - center) ** 2).sum(1).max()))
    if not radius > 0:
        raise InputError("normalize: expected a mesh with a nonzero extent, got all vertices at one point")
    return center, 1.0 / radius


def normalize_vertices(V: np.ndarray) -> np.ndarray:
    """Vertices (n, 3) in the protocol's frame: bounding-box center at the origin, farthest vertex at
    distance 1 (:func:`unit_sphere_frame`)."""
    center, scale = unit_sphere_frame(V)
    return (np.asarray(V, dtype=np.float64) - center) * scale


def sample_surface(V: np.ndarray, F: np.ndarray, n: int, rng: np.random.Generator, *,
                   return_faces: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """``n`` points (n, 3) float64 uniformly on the surface of the mesh ``V (v, 3)``, ``F (f, 3)``: a face
    drawn by area, then uniform barycentrics (the same algorithm as ``trimesh.sample.sample_surface``,
    kept here because the bench's scores are defined by this exact sequence of draws from ``rng``).
    With ``return_faces`` also the face index (n,) int64 of each point. Not differentiable (the torch
    sampler for losses, which moves its samples with the vertices, is :class:`ipm.losses.SurfaceSampler`)."""
    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise InputError(f"expected a mesh with positive area, got area {area.sum()}")
    idx = rng.choice(len(F), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[idx]
    pts = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    return (pts, idx) if return_faces else pts


def point_to_surface(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance from each point to the triangle mesh (libigl AABB tree)."""
    import igl

    d2, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(points, dtype=np.float64), V, F)
    return np.sqrt(np.maximum(d2, 0.0))


def inside(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Generalized winding number > 0.5 (robust for open or self-intersecting scans)."""
    import igl

    w = igl.fast_winding_number(V, F, np.ascontiguousarray(points, dtype=np.float64))
    return np.abs(w) > 0.5


@dataclass(frozen=True)
class ShapeScores:
    """Scores of a predicted mesh against a target (in DESIGN.md's order)."""

    fscore_002: float
    fscore_005: float
    chamfer_l1: float
    iou_3d: float

    def to_json(self) -> dict:
        """The scores under their report names (``fscore@0.02``, ``fscore@0.05``, ``chamfer_l1``, ``iou_3d``)."""
        return {"fscore@0.02": self.fscore_002, "fscore@0.05": self.fscore_005,
                "chamfer_l1": self.chamfer_l1, "iou_3d": self.iou_3d}


def fscore(pred, target, tau: float, *, n: int = 10_000, seed: int = 0, normalize: bool = True) -> float:
    """F-score at ``tau`` (Tatarchenko et al. 2019): harmonic mean of precision (predicted samples
    within tau of the target surface) and recall (target samples within tau of the prediction)."""
    return _surface_scores(pred, target, (tau,), n=n, seed=seed, normalize=normalize)[0][0]


def _surface_scores(pred, target, taus, *, n: int, seed: int, normalize: bool):
    Vp, Fp = mesh_arrays(pred)
    Vt, Ft = mesh_arrays(target)
    if normalize:
        Vp, Vt = normalize_vertices(Vp), normalize_vertices(Vt)
    rng = np.random.default_rng(seed)
    sp, st = sample_surface(Vp, Fp, n, rng), sample_surface(Vt, Ft, n, rng)
    d_pt = point_to_surface(sp, Vt, Ft)   # precision side
    d_tp = point_to_surface(st, Vp, Fp)   # recall side
    out = []
    for tau in taus:
        prec, rec = float((d_pt < tau).mean()), float((d_tp < tau).mean())
        out.append(0.0 if prec + rec == 0 else 2 * prec * rec / (prec + rec))
    chamfer = 0.5 * (float(d_pt.mean()) + float(d_tp.mean()))
    return out, chamfer, (Vp, Fp, Vt, Ft)


def iou_3d(pred, target, *, resolution: int = 64, normalize: bool = True) -> float:
    """Volumetric IoU of winding-number occupancy on a grid over the union of both bounding boxes."""
    Vp, Fp = mesh_arrays(pred)
    Vt, Ft = mesh_arrays(target)
    if normalize:
        Vp, Vt = normalize_vertices(Vp), normalize_vertices(Vt)
    return _iou_grid(Vp, Fp, Vt, Ft, resolution)


def _iou_grid(Vp, Fp, Vt, Ft, resolution: int) -> float:
    lo = np.minimum(Vp.min(0), Vt.min(0))
    hi = np.maximum(Vp.max(0), Vt.max(0))
    axes = [lo[i] + (np.arange(resolution) + 0.5) * (hi[i] - lo[i]) / resolution for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return mask_iou(inside(grid, Vp, Fp), inside(grid, Vt, Ft))


def volume_iou(a, b) -> float:
    """Exact volumetric IoU of two closed meshes (TriMesh or trimesh.Trimesh): vol(A ∩ B) / vol(A ∪ B) by
    manifold3d's booleans. Duplicate vertices (an STL's triangle soup) are welded first; a mesh that is
    not a closed 2-manifold after that is an :class:`InputError`."""
    A, B = _manifold(a, "first"), _manifold(b, "second")
    both = (A ^ B).volume()  # one boolean: vol(A ∪ B) = vol(A) + vol(B) - vol(A ∩ B)
    union = A.volume() + B.volume() - both
    return float(both / union) if union > 0 else 1.0


def _manifold(mesh, which: str):
    import manifold3d as m3d
    import trimesh

    V, F = mesh_arrays(mesh)
    tm = trimesh.Trimesh(V, F, process=True)  # welds the corners an STL repeats
    solid = m3d.Manifold(m3d.Mesh(vert_properties=np.asarray(tm.vertices, np.float32),
                                  tri_verts=np.asarray(tm.faces, np.uint32)))
    if solid.status() != m3d.Error.NoError:
        raise InputError(f"volume IoU: expected the {which} mesh closed and manifold, got {solid.status().name}")
    return solid


def shape_scores(pred, target, *, n: int = 10_000, seed: int = 0, resolution: int = 64,
                 normalize: bool = True) -> ShapeScores:
    """F-score at 0.02 and 0.05, Chamfer-L1 (mean of both directions) and 3D IoU, in DESIGN.md's order."""
    (f2, f5), chamfer, (Vp, Fp, Vt, Ft) = _surface_scores(pred, target, (0.02, 0.05), n=n, seed=seed,
                                                           normalize=normalize)
    return ShapeScores(f2, f5, chamfer, _iou_grid(Vp, Fp, Vt, Ft, resolution))
