"""Bench method ``mesh-deform``: an icosphere deformed to the masks (the free-form mesh approach,
Kato et al. / Liu et al. style).

An icosphere (``subdivisions``), scaled to the visual hull's bounding box, whose per-vertex offsets are
fitted with Adam (:func:`ipm.optim.adam.minimize`) through the soft mesh silhouette
(:func:`ipm.render.soft.soft_silhouette`, blur annealed geometrically from ``sigma_start`` to
``sigma_end`` px²) with

    mean_k (1 - softIoU(S_k, M_k)) + laplacian · mean_i |L v_i|² / ē² + edge · var(l) / mean(l)²

``L`` the uniform graph Laplacian (``v_i`` minus the mean of its neighbours), ``ē`` the initial mean
edge length, ``l`` the edge lengths (the edge term asks for even edges without shrinking the mesh).

Budget, evaluations, priors and image size as for ``sdf-grid`` (:mod:`ipm.bench.methods.sdf_grid`):
one step renders all K views (``evaluations = steps``), the visual hull carved in
``[-extent, extent]³`` sizes the sphere, the seed does not change the result, and masks are
box-filtered to at most ``max_size`` pixels a side. Cost (2-core CPU, a real mug, 256 px masks reduced
to 128, 1000 steps, 642 vertices): about 0.04 to 0.08 s per view and step (6 views: 259 s, 2 views:
152 s).
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec
import numpy as np
import torch

from ipm.bench.methods import Prediction, Task, method
from ipm.bench.methods._fit import fit_input, loss_terms
from ipm.bench.views import DTYPE, carve, grid_axis, hull_box
from ipm.optim.adam import geometric, minimize
from ipm.types import TriMesh

NAME = "mesh-deform"


class MeshDeformSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of ``mesh-deform`` (see the module docstring)."""

    subdivisions: Annotated[int, msgspec.Meta(ge=1, le=5)] = 3                # 3: 642 vertices, 4: 2562
    extent: Annotated[float, msgspec.Meta(ge=1e-3, le=1e3)] = 1.2            # hull carved in [-extent, extent]^3
    hull_resolution: Annotated[int, msgspec.Meta(ge=8, le=256)] = 48         # ... on this many nodes per side
    lr: Annotated[float, msgspec.Meta(ge=1e-6, le=1.0)] = 0.005              # Adam step (world units)
    sigma_start: Annotated[float, msgspec.Meta(ge=1e-3, le=1e3)] = 2.0       # blur at step 0 (px^2)
    sigma_end: Annotated[float, msgspec.Meta(ge=1e-3, le=1e3)] = 0.1         # ... and at the last step
    laplacian: Annotated[float, msgspec.Meta(ge=0.0, le=1e6)] = 1.0          # weight of mean |L v|^2 / e^2
    edge: Annotated[float, msgspec.Meta(ge=0.0, le=1e6)] = 0.1               # weight of var(l) / mean(l)^2
    max_size: Annotated[int, msgspec.Meta(ge=8, le=4096)] = 128              # masks box-filtered to at most this


def mesh_edges(faces: torch.Tensor) -> torch.Tensor:
    """Unique undirected edges (E, 2) int64 of a triangle mesh ``faces`` (F, 3)."""
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return torch.unique(torch.sort(e, dim=1).values, dim=0)


def uniform_laplacian(verts: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """``v_i - mean_{j ~ i} v_j`` (V, 3) for the graph of ``edges`` (E, 2); follows ``verts``' dtype."""
    V = verts.shape[0]
    i, j = edges[:, 0], edges[:, 1]
    acc = torch.zeros_like(verts).index_add_(0, i, verts[j]).index_add_(0, j, verts[i])
    deg = torch.zeros(V, dtype=verts.dtype, device=verts.device)
    deg = deg.index_add_(0, i, torch.ones_like(i, dtype=verts.dtype)).index_add_(
        0, j, torch.ones_like(j, dtype=verts.dtype))
    return verts - acc / deg.clamp_min(1.0)[:, None]


@method(NAME, MeshDeformSettings)
def mesh_deform(task: Task, s: MeshDeformSettings, budget: int, seed: int) -> Prediction:
    """An icosphere deformed through the soft mesh silhouette (module docstring).

    settings: see :class:`MeshDeformSettings`; budget: optimizer steps (= evaluations: all K views each).
    """
    import trimesh

    from ipm.losses import soft_iou_loss
    from ipm.render.soft import soft_silhouette

    t0 = time.perf_counter()
    dev = task.cameras[0].eye.device
    target, cams = fit_input(NAME, task, budget, s.max_size)
    center, radii = hull_box(carve(task.masks, task.cameras, grid_axis(s.hull_resolution, s.extent)), s.extent)
    ico = trimesh.creation.icosphere(subdivisions=s.subdivisions)
    v0 = torch.as_tensor(np.asarray(ico.vertices) * radii + center, dtype=DTYPE, device=dev)
    faces = torch.as_tensor(np.asarray(ico.faces), dtype=torch.int64, device=dev)
    edges = mesh_edges(faces)
    e0 = float(torch.linalg.vector_norm(v0[edges[:, 0]] - v0[edges[:, 1]], dim=-1).mean())
    offset = torch.zeros_like(v0, requires_grad=True)
    terms, after_step = loss_terms(NAME, budget)

    def loss_fn(step: int) -> torch.Tensor:
        sigma = geometric(s.sigma_start, s.sigma_end, step, budget)
        v = v0 + offset
        sil = torch.stack([soft_silhouette(v, faces, c, sigma) for c in cams])
        loss_sil = soft_iou_loss(sil, target)
        lap = (uniform_laplacian(v, edges) ** 2).sum(-1).mean() / e0 ** 2
        length = torch.linalg.vector_norm(v[edges[:, 0]] - v[edges[:, 1]], dim=-1)
        even = length.var() / length.mean().clamp_min(1e-12) ** 2
        terms.update(silhouette=loss_sil.detach(), laplacian=lap.detach(), edge=even.detach())
        return loss_sil + s.laplacian * lap + s.edge * even

    minimize([offset], loss_fn, budget, s.lr, after_step=after_step)
    verts = (v0 + offset).detach().double()
    return Prediction(TriMesh(verts, faces), budget, time.perf_counter() - t0,
                      {"loss": terms["silhouette"], "steps": budget, "view_renders": budget * len(cams),
                       "verts": int(verts.shape[0])})
