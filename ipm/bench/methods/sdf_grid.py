"""Bench method ``sdf-grid``: a dense signed distance grid fitted to the masks (our stand-in for
DiffSDF's approach).

A signed distance grid ``g`` of ``resolution``³ nodes over ``[-extent, extent]³``, read by trilinear
interpolation (``grid_sample``; outside the box the distance to the box is added, so ``f`` stays a
bound there). Initialized from the visual hull of the masks (``init = "hull"``: signed Euclidean
distance transform of the carved grid) or as an ellipsoid filling the hull's bounding box
(``init = "sphere"``). Each step renders every input view with the SDF silhouette renderer
(:func:`ipm.render.sdf_silhouette.sdf_silhouette`, blur annealed geometrically from ``sigma_start``
to ``sigma_end`` times half a pixel's footprint), and minimizes with Adam
(:func:`ipm.optim.adam.minimize`)

    mean_k (1 - softIoU(S_k, M_k)) + eikonal · mean_band (|∇g| - 1)² + smooth · h² · mean_band (Δg)²

with ``∇g`` central differences and ``Δg`` the 7-point Laplacian on the grid (``h`` the node
spacing), both averaged over the nodes within ``band`` spacings of the surface (far from the surface
the values do not matter and the medial axis makes them non-smooth anyway). Meshed by marching cubes
on the grid upsampled (trilinearly) to ``mesh_resolution``; components with less than ``min_share``
of the faces (specks where a few nodes dipped below zero) are dropped.

Budget and evaluations: ``budget`` is the number of optimizer steps. One step renders *all* K input
views once and computes the loss and its gradient, which is what one evaluation of the generator fits
(:class:`ipm.optim.evaluator.Evaluator`) is, so ``Prediction.evaluations = steps`` and equal budgets mean
equal numbers of steps; ``info["view_renders"] = steps · K`` counts the single-view renders.

Priors (DESIGN.md asks fits to say so): the object lies inside ``[-extent, extent]³`` (the protocol
normalizes targets to the unit bounding sphere at the origin, extent 1.2 leaves a margin), and the
visual hull of the masks is the initial shape (``init = "hull"``) or sizes it. No randomness is
involved: the seed does not change the result.

Image size: masks larger than ``max_size`` pixels a side (default 128) are box-filtered down by an
integer factor (:func:`ipm.bench.views.fit_views`), which keeps the protocol's 256 px tractable on a
CPU. Computation runs in float32 on the cameras' device.

Cost (2-core CPU shared with another benchmark, so indicative only; a real mug, masks 256 px reduced
to 128, 1000 steps): about 0.07 s per view and step (6 views: 416 s). The SDF silhouette renderer is
fast enough for a grid (it sphere-traces without gradients and evaluates the grid once more with them,
about 25 to 35 grid lookups per ray), so there is no special grid path.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated, Literal

import msgspec
import numpy as np
import torch
import torch.nn.functional as F

from ipm.bench.methods import Prediction, Task, method
from ipm.bench.methods._fit import fit_input, loss_terms
from ipm.bench.views import DTYPE, carve, grid_axis, hull_box
from ipm.errors import InputError, MethodFailed
from ipm.optim.adam import geometric, minimize
from ipm.types import TriMesh

NAME = "sdf-grid"


class SdfGridSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of ``sdf-grid`` (see the module docstring)."""

    resolution: Annotated[int, msgspec.Meta(ge=8, le=160)] = 40              # grid nodes per side
    extent: Annotated[float, msgspec.Meta(ge=1e-3, le=1e3)] = 1.2            # the grid spans [-extent, extent]^3
    init: Literal["hull", "sphere"] = "hull"
    lr: Annotated[float, msgspec.Meta(ge=1e-6, le=1.0)] = 0.01               # Adam step (world units of distance)
    sigma_start: Annotated[float, msgspec.Meta(ge=1e-3, le=1e3)] = 4.0       # blur at step 0, in half pixel footprints
    sigma_end: Annotated[float, msgspec.Meta(ge=1e-3, le=1e3)] = 1.0         # ... and at the last step
    eikonal: Annotated[float, msgspec.Meta(ge=0.0, le=1e3)] = 0.1            # weight of mean (|grad g| - 1)^2
    smooth: Annotated[float, msgspec.Meta(ge=0.0, le=1e3)] = 0.01            # weight of mean (h lap g)^2
    band: Annotated[float, msgspec.Meta(ge=0.5, le=1e3)] = 3.0               # regularizers act within band * h of g = 0
    mesh_resolution: Annotated[int, msgspec.Meta(ge=8, le=384)] = 96         # marching cubes on the grid upsampled
    min_share: Annotated[float, msgspec.Meta(ge=0.0, le=0.5)] = 0.01         # smaller mesh components are dropped
    max_size: Annotated[int, msgspec.Meta(ge=8, le=4096)] = 128              # masks box-filtered to at most this


def grid_sdf(grid: torch.Tensor, extent: float) -> Callable[[torch.Tensor], torch.Tensor]:
    """The SDF ``f(points (N, 3)) -> (N,)`` of a node grid ``(n, n, n)`` indexed ``[x, y, z]`` over
    ``[-extent, extent]³``: trilinear inside the box, plus the distance to the box outside it.
    Differentiable in ``grid`` and in the points."""
    g = grid[None, None]  # (1, 1, X, Y, Z): grid_sample reads its last coordinate along X

    def f(p: torch.Tensor) -> torch.Tensor:
        q = p.clamp(-extent, extent)
        u = (q / extent).flip(-1).to(grid.dtype)  # (z, y, x) order for (D, H, W) = (X, Y, Z)
        s = F.grid_sample(g, u.view(1, -1, 1, 1, 3), mode="bilinear", align_corners=True).view(-1)
        return s.to(p.dtype) + torch.linalg.vector_norm(p - q, dim=-1)

    return f


def signed_distance_grid(occ: torch.Tensor, extent: float) -> torch.Tensor:
    """Signed distance (n, n, n) float64 of a node occupancy grid (negative inside), from Euclidean
    distance transforms, with the surface half a node spacing outside the occupied nodes."""
    from scipy.ndimage import distance_transform_edt

    n = occ.shape[0]
    h = 2 * extent / (n - 1)
    o = occ.cpu().numpy()
    d_out = distance_transform_edt(~o) * h
    d_in = distance_transform_edt(np.pad(o, 1))[1:-1, 1:-1, 1:-1] * h  # the box border counts as outside
    sdf = np.where(o, -(d_in - h / 2), d_out - h / 2)
    return torch.as_tensor(sdf, device=occ.device)


def ellipsoid_grid(center: np.ndarray, radii: np.ndarray, n: int, extent: float, device=None) -> torch.Tensor:
    """An approximate signed distance (n, n, n) float64 of an ellipsoid: ``(|x / r| - 1) min(r)`` (exact
    for a sphere, a bound up to the ratio of the radii otherwise)."""
    ax = grid_axis(n, extent, device=device)
    pts = torch.stack(torch.meshgrid(ax, ax, ax, indexing="ij"), -1)
    c = torch.as_tensor(center, dtype=pts.dtype, device=device)
    r = torch.as_tensor(radii, dtype=pts.dtype, device=device)
    return (torch.linalg.vector_norm((pts - c) / r, dim=-1) - 1.0) * r.min()


def grid_regularizers(g: torch.Tensor, h: float, band: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(eikonal, smoothness) of a node grid ``g`` (n, n, n) with spacing ``h``: means over the interior
    nodes within ``band * h`` of the zero level of ``(|∇g| - 1)²`` (central differences) and of
    ``(h Δg)²`` (7-point Laplacian). 0-dim tensors."""
    c = g[1:-1, 1:-1, 1:-1]
    dx = (g[2:, 1:-1, 1:-1] - g[:-2, 1:-1, 1:-1]) / (2 * h)
    dy = (g[1:-1, 2:, 1:-1] - g[1:-1, :-2, 1:-1]) / (2 * h)
    dz = (g[1:-1, 1:-1, 2:] - g[1:-1, 1:-1, :-2]) / (2 * h)
    grad = torch.sqrt(dx * dx + dy * dy + dz * dz + 1e-12)
    lap = (g[2:, 1:-1, 1:-1] + g[:-2, 1:-1, 1:-1] + g[1:-1, 2:, 1:-1] + g[1:-1, :-2, 1:-1]
           + g[1:-1, 1:-1, 2:] + g[1:-1, 1:-1, :-2] - 6 * c) / h
    w = (c.detach().abs() < band * h).to(g.dtype)
    denom = w.sum().clamp_min(1.0)
    return (w * (grad - 1) ** 2).sum() / denom, (w * lap * lap).sum() / denom


def mesh_from_grid(values: np.ndarray, extent: float, name: str, min_share: float = 0.0) -> TriMesh:
    """Marching cubes of the zero level of ``values`` (n, n, n) (negative inside) on nodes over
    ``[-extent, extent]³``; padded with an outside layer so the surface closes at the box; components
    with less than ``min_share`` of the faces are dropped (:func:`drop_specks`)."""
    from skimage.measure import marching_cubes

    n = values.shape[0]
    h = 2 * extent / (n - 1)
    if not (values < 0).any():
        raise InputError(f"{name}: the fitted shape is empty (no grid node inside)")
    if (values < 0).all():
        raise InputError(f"{name}: the fitted shape fills the whole box (no grid node outside)")
    padded = np.pad(values.astype(np.float32), 1, constant_values=max(float(values.max()), h))
    verts, faces, _, _ = marching_cubes(padded, 0.0, spacing=(h, h, h))
    verts = verts - h - extent  # skimage's default winding is outward for values increasing outwards
    verts, faces = drop_specks(verts, faces.astype(np.int64), min_share)
    return TriMesh(torch.as_tensor(verts, dtype=torch.float64), torch.as_tensor(faces))


def drop_specks(verts: np.ndarray, faces: np.ndarray, min_share: float) -> tuple[np.ndarray, np.ndarray]:
    """Remove connected components (by shared vertex positions) with fewer than ``min_share`` of the faces:
    the specks a grid fit leaves where a few nodes dipped below zero. verts (V, 3), faces (F, 3) int64;
    unreferenced vertices are dropped too."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if min_share <= 0 or len(faces) == 0:
        return verts, faces
    V = len(verts)
    # connectivity by position: marching cubes repeats vertices that fall exactly on grid nodes
    _, same = np.unique(np.round(verts, 9), axis=0, return_inverse=True)
    same = same.reshape(-1)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], np.stack([np.arange(V), same + V], 1)])
    graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(2 * V, 2 * V))
    _, label = connected_components(graph, directed=False)
    counts = np.bincount(label[faces[:, 0]], minlength=label.max() + 1)
    keep = counts[label[faces[:, 0]]] >= min_share * len(faces)
    faces = faces[keep]
    used = np.unique(faces)
    remap = np.full(V, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return verts[used], remap[faces]


@method(NAME, SdfGridSettings)
def sdf_grid(task: Task, s: SdfGridSettings, budget: int, seed: int) -> Prediction:
    """Dense SDF grid fitted to the masks through the SDF silhouette renderer (module docstring).

    settings: see :class:`SdfGridSettings`; budget: optimizer steps (= evaluations: all K views each).
    """
    from ipm.losses import soft_iou_loss
    from ipm.render.sdf_silhouette import default_sigma, sdf_silhouette

    t0 = time.perf_counter()
    dev = task.cameras[0].eye.device
    target, cams = fit_input(NAME, task, budget, s.max_size)
    n, ext = s.resolution, s.extent
    h = 2 * ext / (n - 1)
    occ = carve(task.masks, task.cameras, grid_axis(n, ext))
    if s.init == "hull":
        if not occ.any():
            raise MethodFailed("visual hull is empty: the masks do not agree on any grid node")
        g0 = signed_distance_grid(occ, ext)
    else:
        center, radii = hull_box(occ, ext)
        g0 = ellipsoid_grid(center, radii, n, ext, dev)
    grid = g0.to(DTYPE).clone().requires_grad_(True)
    lo, hi = [-ext] * 3, [ext] * 3
    base = [default_sigma(c, lo, hi) for c in cams]
    terms, after_step = loss_terms(NAME, budget)

    def loss_fn(step: int) -> torch.Tensor:
        k = geometric(s.sigma_start, s.sigma_end, step, budget)
        f = grid_sdf(grid, ext)
        sil = torch.stack([sdf_silhouette(f, c, lo, hi, sigma=k * b, dtype=DTYPE) for c, b in zip(cams, base)])
        loss_sil = soft_iou_loss(sil, target)
        eik, lap = grid_regularizers(grid, h, s.band)
        terms.update(silhouette=loss_sil.detach(), eikonal=eik.detach(), smooth=lap.detach())
        return loss_sil + s.eikonal * eik + s.smooth * lap

    minimize([grid], loss_fn, budget, s.lr, after_step=after_step)
    g = grid.detach().double()
    if s.mesh_resolution != n:
        g = F.interpolate(g[None, None], size=(s.mesh_resolution,) * 3, mode="trilinear", align_corners=True)[0, 0]
    mesh = mesh_from_grid(g.cpu().numpy(), ext, NAME, s.min_share)
    return Prediction(mesh, budget, time.perf_counter() - t0,
                      {"loss": terms["silhouette"], "steps": budget, "view_renders": budget * len(cams),
                       "init": s.init, "hull_nodes": int(occ.sum())})
