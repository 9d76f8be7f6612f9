"""Evaluation metrics (not differentiable): mask IoU, volumetric IoU, Chamfer-L1 and F-score.

Conventions from DESIGN.md's evaluation protocol: meshes are compared after normalization (bounding
box centered at the origin, longest side 2); F-score at tau in normalized units with 10,000 surface
samples each way and exact point-to-surface distances (libigl); 3D IoU of solid occupancy on a 64^3
grid over the union of both bounding boxes, inside = generalized winding number > 0.5 (robust to
non-watertight scans; Jacobson et al., "Robust inside-outside segmentation using generalized winding
numbers", SIGGRAPH 2013, via libigl's fast winding number).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ipm.types import TriMesh


def _np_mesh(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V (n, 3) float64, F (m, 3) int64) from a TriMesh or a trimesh.Trimesh."""
    if isinstance(mesh, TriMesh):
        V, F = mesh.verts.detach().cpu().double().numpy(), mesh.faces.cpu().numpy()
    else:
        V, F = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    if len(F) == 0:
        raise ValueError("expected a mesh with faces, got one with none")
    return np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int64)


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two boolean masks of the same shape (1.0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape:
        raise ValueError(f"masks: expected equal shapes, got {a.shape} and {b.shape}")
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


def normalize_vertices(V: np.ndarray) -> np.ndarray:
    """Bounding-box center to the origin, longest side 2."""
    lo, hi = V.min(0), V.max(0)
    scale = 2.0 / max(float((hi - lo).max()), 1e-12)
    return (V - 0.5 * (lo + hi)) * scale


def sample_surface(V: np.ndarray, F: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points uniformly on the surface (area-weighted triangles, uniform barycentrics)."""
    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if area.sum() <= 0:
        raise ValueError("expected a mesh with positive area, got zero area")
    idx = rng.choice(len(F), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[idx]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


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
    """Scores of a predicted mesh against a target (both normalized first)."""

    fscore_002: float
    fscore_005: float
    chamfer_l1: float
    iou_3d: float

    def to_json(self) -> dict:
        return {"fscore@0.02": self.fscore_002, "fscore@0.05": self.fscore_005,
                "chamfer_l1": self.chamfer_l1, "iou_3d": self.iou_3d}


def fscore(pred, target, tau: float, *, n: int = 10_000, seed: int = 0, normalize: bool = True) -> float:
    """F-score at ``tau`` (Tatarchenko et al. 2019): harmonic mean of precision (predicted samples
    within tau of the target surface) and recall (target samples within tau of the prediction)."""
    return _surface_scores(pred, target, (tau,), n=n, seed=seed, normalize=normalize)[0][0]


def _surface_scores(pred, target, taus, *, n: int, seed: int, normalize: bool):
    Vp, Fp = _np_mesh(pred)
    Vt, Ft = _np_mesh(target)
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
    Vp, Fp = _np_mesh(pred)
    Vt, Ft = _np_mesh(target)
    if normalize:
        Vp, Vt = normalize_vertices(Vp), normalize_vertices(Vt)
    return _iou_grid(Vp, Fp, Vt, Ft, resolution)


def _iou_grid(Vp, Fp, Vt, Ft, resolution: int) -> float:
    lo = np.minimum(Vp.min(0), Vt.min(0))
    hi = np.maximum(Vp.max(0), Vt.max(0))
    axes = [lo[i] + (np.arange(resolution) + 0.5) * (hi[i] - lo[i]) / resolution for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    a, b = inside(grid, Vp, Fp), inside(grid, Vt, Ft)
    union = np.logical_or(a, b).sum()
    return 1.0 if union == 0 else float(np.logical_and(a, b).sum() / union)


def shape_scores(pred, target, *, n: int = 10_000, seed: int = 0, resolution: int = 64,
                 normalize: bool = True) -> ShapeScores:
    """F-score at 0.02 and 0.05, Chamfer-L1 (mean of both directions) and 3D IoU, in DESIGN.md's order."""
    (f2, f5), chamfer, (Vp, Fp, Vt, Ft) = _surface_scores(pred, target, (0.02, 0.05), n=n, seed=seed,
                                                           normalize=normalize)
    return ShapeScores(f2, f5, chamfer, _iou_grid(Vp, Fp, Vt, Ft, resolution))
