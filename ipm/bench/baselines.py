"""Free-form multi-view baselines for ``ipm bench``: a dense SDF grid and a deformed icosphere.

Both fit the K input masks only (cameras known), on the CPU, with Adam, and register themselves in the
bench method registry (:data:`ipm.bench.methods.METHODS`) by importing this module:

``sdf-grid`` (our stand-in for DiffSDF's approach)
    A signed distance grid ``g`` of ``resolution``³ nodes over ``[-extent, extent]³``, read by trilinear
    interpolation (``grid_sample``; outside the box the distance to the box is added, so ``f`` stays a
    bound there). Initialized from the visual hull of the masks (``init = "hull"``: signed Euclidean
    distance transform of the carved grid) or as an ellipsoid filling the hull's bounding box
    (``init = "sphere"``). Each step renders every input view with the SDF silhouette renderer
    (:func:`ipm.render.sdf_silhouette.sdf_silhouette`, blur annealed geometrically from ``sigma_start``
    to ``sigma_end`` times half a pixel's footprint), and minimizes

        mean_k (1 - softIoU(S_k, M_k)) + eikonal · mean_band (|∇g| - 1)² + smooth · h² · mean_band (Δg)²

    with ``∇g`` central differences and ``Δg`` the 7-point Laplacian on the grid (``h`` the node
    spacing), both averaged over the nodes within ``band`` spacings of the surface (far from the surface
    the values do not matter and the medial axis makes them non-smooth anyway). Meshed by marching cubes
    on the grid upsampled (trilinearly) to ``mesh_resolution``; components with less than ``min_share``
    of the faces (specks where a few nodes dipped below zero) are dropped.

``mesh-deform`` (the free-form mesh approach, Kato et al. / Liu et al. style)
    An icosphere (``subdivisions``), scaled to the visual hull's bounding box, whose per-vertex offsets are
    fitted through the soft mesh silhouette (:func:`ipm.render.soft.soft_silhouette`, blur annealed
    geometrically from ``sigma_start`` to ``sigma_end`` px²) with

        mean_k (1 - softIoU(S_k, M_k)) + laplacian · mean_i |L v_i|² / ē² + edge · var(l) / mean(l)²

    ``L`` the uniform graph Laplacian (``v_i`` minus the mean of its neighbours), ``ē`` the initial mean
    edge length, ``l`` the edge lengths (the edge term asks for even edges without shrinking the mesh).

Budget and evaluations: ``budget`` is the number of optimizer steps. One step renders *all* K input
views once and computes the loss and its gradient, which is what one evaluation of the generator fits
(:class:`ipm.optim.evaluator.Evaluator`) is, so ``Prediction.evaluations = steps`` and equal budgets mean
equal numbers of steps; ``info["view_renders"] = steps · K`` counts the single-view renders.

Priors (DESIGN.md asks fits to say so): the object lies inside ``[-extent, extent]³`` (the protocol
normalizes targets to the unit bounding sphere at the origin, extent 1.2 leaves a margin), and
the visual hull of the masks seeds the shape (both methods) or is the initial shape (``sdf-grid`` with
``init = "hull"``). No randomness is involved: the seed does not change the result.

Image size: masks larger than ``max_size`` pixels a side (default 128) are box-filtered down by an
integer factor (soft targets, cameras with the same field of view; :func:`fit_views`), which keeps
the protocol's 256 px tractable on a CPU. Computation runs in float32 on the cameras' device.

Cost (2-core CPU shared with another benchmark, so indicative only; a real mug, masks 256 px reduced
to 128, 1000 steps): sdf-grid about 0.07 s per view and step (6 views: 416 s), mesh-deform (642
vertices) about 0.04 to 0.08 (6 views: 259 s, 2 views: 152 s). The SDF silhouette renderer is fast
enough for a grid (it sphere-traces without gradients and evaluates the grid once more with them, about
25 to 35 grid lookups per ray), so there is no special grid path.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ipm.bench.methods import Prediction, Task, method
from ipm.params import check_fields
from ipm.types import Camera, TriMesh

log = logging.getLogger(__name__)

DTYPE = torch.float32


# -- settings ----------------------------------------------------------------------------------------

def _settings(cls: type, name: str, settings: dict):
    """Build the settings dataclass ``cls`` from a bench settings dict; ``ValueError`` for unknown names,
    wrong types, and (through ``cls.check``) out-of-range values."""
    check_fields(cls, settings, name, "setting(s)")
    values = {}
    for key, v in settings.items():
        default = getattr(cls, key)
        if isinstance(default, bool) or isinstance(v, bool):
            ok = isinstance(v, type(default))
        elif isinstance(default, float):
            ok = isinstance(v, (int, float))
            v = float(v) if ok else v
        else:
            ok = isinstance(v, type(default))
        if not ok:
            raise ValueError(f"{name}: setting {key}: expected {type(default).__name__}, got {v!r}")
        values[key] = v
    s = cls(**values)
    s.check(name)
    return s


def _in_range(name: str, key: str, value: float, lo: float, hi: float) -> None:
    if not lo <= value <= hi:
        raise ValueError(f"{name}: setting {key}: expected a value in [{lo}, {hi}], got {value}")


def _check_task(name: str, task: Task, budget: int) -> None:
    masks = np.asarray(task.masks)
    if masks.ndim != 3:
        raise ValueError(f"{name}: expected masks (K, H, W), got shape {masks.shape}")
    if len(task.cameras) != masks.shape[0]:
        raise ValueError(f"{name}: expected one camera per mask, got {len(task.cameras)} cameras for "
                         f"{masks.shape[0]} masks")
    for c in task.cameras:
        if (c.height, c.width) != masks.shape[1:]:
            raise ValueError(f"{name}: expected cameras of the masks' size {masks.shape[2]}x{masks.shape[1]}, "
                             f"got {c.width}x{c.height}")
    empty = [i for i, m in enumerate(masks) if not m.any()]
    if empty:
        raise ValueError(f"{name}: expected a foreground in every mask, got empty mask(s) {empty}")
    if not isinstance(budget, int) or budget < 1:
        raise ValueError(f"{name}: budget: expected at least 1 optimizer step, got {budget!r}")


def fit_views(masks: np.ndarray, cameras: list[Camera], max_size: int, dtype: torch.dtype = DTYPE
              ) -> tuple[torch.Tensor, list[Camera]]:
    """The masks as soft targets (K, h, w) in ``dtype`` and their cameras, reduced by the smallest integer
    factor that divides both image sides and brings the longer one to at most ``max_size`` (box filter:
    a reduced pixel is the covered fraction of its full-size pixels; the camera keeps its field of
    view, so reduced pixel centers fall on the centers of the full-size blocks). Factor 1 if none
    divides."""
    K, H, W = masks.shape
    dev = cameras[0].eye.device
    target = torch.as_tensor(np.asarray(masks), dtype=dtype, device=dev)
    f = next((f for f in range(max(1, math.ceil(max(H, W) / max_size)), max(H, W) + 1)
              if H % f == 0 and W % f == 0), 1)
    cams = [c.to(dtype) for c in cameras]
    if f == 1:
        return target, cams
    target = F.avg_pool2d(target[:, None], f)[:, 0]
    return target, [Camera(c.eye, c.target, c.up, c.fov_deg, W // f, H // f) for c in cams]


def _geometric(start: float, end: float, i: int, n: int) -> float:
    """Geometric interpolation from ``start`` (i = 0) to ``end`` (i = n - 1)."""
    return start * (end / start) ** (i / max(n - 1, 1))


# -- visual hull on a grid ---------------------------------------------------------------------------

def grid_axis(n: int, extent: float, dtype=torch.float64, device=None) -> torch.Tensor:
    """``n`` node coordinates (n,) from ``-extent`` to ``extent``."""
    return torch.linspace(-extent, extent, n, dtype=dtype, device=device)


def carve(masks: np.ndarray, cameras: list[Camera], n: int, extent: float) -> torch.Tensor:
    """Visual hull on the nodes of an ``n``³ grid over ``[-extent, extent]³``: (n, n, n) bool, indexed
    ``[x, y, z]``, true where the node projects inside every mask (outside the image counts as
    background). masks: (K, H, W) bool; cameras: K cameras. Follows the cameras' device."""
    from ipm.render.camera import project

    dev = cameras[0].eye.device
    ax = grid_axis(n, extent, device=dev)
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
    """Center and half extents (3,) each of the nodes set in ``occ`` (n, n, n); ``ValueError`` if none."""
    idx = torch.nonzero(occ)
    if idx.numel() == 0:
        raise ValueError("visual hull is empty: the masks do not agree on any grid node")
    n = occ.shape[0]
    h = 2 * extent / (n - 1)
    lo = idx.amin(0).double().cpu().numpy() * h - extent - h / 2
    hi = idx.amax(0).double().cpu().numpy() * h - extent + h / 2
    return (lo + hi) / 2, (hi - lo) / 2


def _mesh_from_grid(values: np.ndarray, extent: float, name: str, min_share: float = 0.0) -> TriMesh:
    """Marching cubes of the zero level of ``values`` (n, n, n) (negative inside) on nodes over
    ``[-extent, extent]³``; padded with an outside layer so the surface closes at the box; components
    with less than ``min_share`` of the faces are dropped (:func:`drop_specks`)."""
    from skimage.measure import marching_cubes

    n = values.shape[0]
    h = 2 * extent / (n - 1)
    if not (values < 0).any():
        raise ValueError(f"{name}: the fitted shape is empty (no grid node inside)")
    if (values < 0).all():
        raise ValueError(f"{name}: the fitted shape fills the whole box (no grid node outside)")
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


# -- sdf-grid ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SdfGridSettings:
    """Settings of ``sdf-grid`` (see the module docstring)."""

    resolution: int = 40          # grid nodes per side
    extent: float = 1.2           # the grid spans [-extent, extent]^3 (world units)
    init: str = "hull"            # hull | sphere
    lr: float = 0.01              # Adam step (world units of distance)
    sigma_start: float = 4.0      # silhouette blur at the first step, in half pixel footprints
    sigma_end: float = 1.0        # ... and at the last step
    eikonal: float = 0.1          # weight of mean (|grad g| - 1)^2
    smooth: float = 0.01          # weight of mean (h lap g)^2
    band: float = 3.0             # regularizers act on nodes within band * h of the surface
    mesh_resolution: int = 96     # marching cubes on the grid upsampled to this many nodes per side
    min_share: float = 0.01       # mesh components with less than this share of the faces are dropped
    max_size: int = 128           # larger masks are box-filtered down to at most this many pixels a side

    def check(self, name: str) -> None:
        _in_range(name, "resolution", self.resolution, 8, 160)
        _in_range(name, "extent", self.extent, 1e-3, 1e3)
        if self.init not in ("hull", "sphere"):
            raise ValueError(f"{name}: setting init: expected hull or sphere, got {self.init!r}")
        _in_range(name, "lr", self.lr, 1e-6, 1.0)
        _in_range(name, "sigma_start", self.sigma_start, 1e-3, 1e3)
        _in_range(name, "sigma_end", self.sigma_end, 1e-3, 1e3)
        _in_range(name, "eikonal", self.eikonal, 0.0, 1e3)
        _in_range(name, "smooth", self.smooth, 0.0, 1e3)
        _in_range(name, "band", self.band, 0.5, 1e3)
        _in_range(name, "mesh_resolution", self.mesh_resolution, 8, 384)
        _in_range(name, "min_share", self.min_share, 0.0, 0.5)
        _in_range(name, "max_size", self.max_size, 8, 4096)


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


@method("sdf-grid")
def sdf_grid(task: Task, settings: dict, budget: int, seed: int) -> Prediction:
    """Dense SDF grid fitted to the masks through the SDF silhouette renderer (module docstring).

    settings: see :class:`SdfGridSettings`; budget: optimizer steps (= evaluations: all K views each).
    """
    from ipm.losses import soft_iou_loss
    from ipm.render.sdf_silhouette import default_sigma, sdf_silhouette

    name = "sdf-grid"
    s = _settings(SdfGridSettings, name, settings)
    _check_task(name, task, budget)
    t0 = time.perf_counter()
    dev = task.cameras[0].eye.device
    target, cams = fit_views(task.masks, task.cameras, s.max_size)
    n, ext = s.resolution, s.extent
    h = 2 * ext / (n - 1)
    occ = carve(task.masks, task.cameras, n, ext)
    if s.init == "hull":
        if not occ.any():
            raise ValueError("visual hull is empty: the masks do not agree on any grid node")
        g0 = signed_distance_grid(occ, ext)
    else:
        center, radii = hull_box(occ, ext)
        g0 = ellipsoid_grid(center, radii, n, ext, dev)
    grid = g0.to(DTYPE).clone().requires_grad_(True)
    opt = torch.optim.Adam([grid], lr=s.lr)
    lo, hi = [-ext] * 3, [ext] * 3
    base = [default_sigma(c, lo, hi) for c in cams]
    sil_loss = math.nan
    for step in range(budget):
        k = _geometric(s.sigma_start, s.sigma_end, step, budget)
        f = grid_sdf(grid, ext)
        sil = torch.stack([sdf_silhouette(f, c, lo, hi, sigma=k * b, dtype=DTYPE) for c, b in zip(cams, base)])
        loss_sil = soft_iou_loss(sil, target)
        eik, lap = grid_regularizers(grid, h, s.band)
        loss = loss_sil + s.eikonal * eik + s.smooth * lap
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sil_loss = float(loss_sil.detach())
        if step % 25 == 0 or step == budget - 1:
            log.debug("sdf-grid step %d: silhouette %.4f eikonal %.4f smooth %.4f", step, sil_loss,
                      float(eik.detach()), float(lap.detach()))
    g = grid.detach().double()
    if s.mesh_resolution != n:
        g = F.interpolate(g[None, None], size=(s.mesh_resolution,) * 3, mode="trilinear", align_corners=True)[0, 0]
    mesh = _mesh_from_grid(g.cpu().numpy(), ext, name, s.min_share)
    return Prediction(mesh, budget, time.perf_counter() - t0,
                      {"loss": sil_loss, "steps": budget, "view_renders": budget * len(cams),
                       "init": s.init, "hull_nodes": int(occ.sum())})


# -- mesh-deform -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MeshDeformSettings:
    """Settings of ``mesh-deform`` (see the module docstring)."""

    subdivisions: int = 3         # icosphere subdivisions (3: 642 vertices, 4: 2562)
    extent: float = 1.2           # the visual hull that sizes the sphere is carved in [-extent, extent]^3
    hull_resolution: int = 48     # ... on this many nodes per side
    lr: float = 0.005             # Adam step (world units)
    sigma_start: float = 2.0      # soft rasterizer blur at the first step (px^2)
    sigma_end: float = 0.1        # ... and at the last step
    laplacian: float = 1.0        # weight of mean |L v|^2 / e^2 (uniform Laplacian)
    edge: float = 0.1             # weight of var(l) / mean(l)^2 (edge lengths)
    max_size: int = 128           # larger masks are box-filtered down to at most this many pixels a side

    def check(self, name: str) -> None:
        _in_range(name, "subdivisions", self.subdivisions, 1, 5)
        _in_range(name, "extent", self.extent, 1e-3, 1e3)
        _in_range(name, "hull_resolution", self.hull_resolution, 8, 256)
        _in_range(name, "lr", self.lr, 1e-6, 1.0)
        _in_range(name, "sigma_start", self.sigma_start, 1e-3, 1e3)
        _in_range(name, "sigma_end", self.sigma_end, 1e-3, 1e3)
        _in_range(name, "laplacian", self.laplacian, 0.0, 1e6)
        _in_range(name, "edge", self.edge, 0.0, 1e6)
        _in_range(name, "max_size", self.max_size, 8, 4096)


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


@method("mesh-deform")
def mesh_deform(task: Task, settings: dict, budget: int, seed: int) -> Prediction:
    """An icosphere deformed through the soft mesh silhouette (module docstring).

    settings: see :class:`MeshDeformSettings`; budget: optimizer steps (= evaluations: all K views each).
    """
    import trimesh

    from ipm.losses import soft_iou_loss
    from ipm.render.soft import soft_silhouette

    name = "mesh-deform"
    s = _settings(MeshDeformSettings, name, settings)
    _check_task(name, task, budget)
    t0 = time.perf_counter()
    dev = task.cameras[0].eye.device
    target, cams = fit_views(task.masks, task.cameras, s.max_size)
    center, radii = hull_box(carve(task.masks, task.cameras, s.hull_resolution, s.extent), s.extent)
    ico = trimesh.creation.icosphere(subdivisions=s.subdivisions)
    v0 = torch.as_tensor(np.asarray(ico.vertices) * radii + center, dtype=DTYPE, device=dev)
    faces = torch.as_tensor(np.asarray(ico.faces), dtype=torch.int64, device=dev)
    edges = mesh_edges(faces)
    e0 = float(torch.linalg.vector_norm(v0[edges[:, 0]] - v0[edges[:, 1]], dim=-1).mean())
    offset = torch.zeros_like(v0, requires_grad=True)
    opt = torch.optim.Adam([offset], lr=s.lr)
    sil_loss = math.nan
    for step in range(budget):
        sigma = _geometric(s.sigma_start, s.sigma_end, step, budget)
        v = v0 + offset
        sil = torch.stack([soft_silhouette(v, faces, c, sigma) for c in cams])
        loss_sil = soft_iou_loss(sil, target)
        lap = (uniform_laplacian(v, edges) ** 2).sum(-1).mean() / e0 ** 2
        length = torch.linalg.vector_norm(v[edges[:, 0]] - v[edges[:, 1]], dim=-1)
        even = length.var() / length.mean().clamp_min(1e-12) ** 2
        loss = loss_sil + s.laplacian * lap + s.edge * even
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sil_loss = float(loss_sil.detach())
        if step % 25 == 0 or step == budget - 1:
            log.debug("mesh-deform step %d: silhouette %.4f laplacian %.4f edge %.4f", step, sil_loss,
                      float(lap.detach()), float(even.detach()))
    verts = (v0 + offset).detach().double()
    return Prediction(TriMesh(verts, faces), budget, time.perf_counter() - t0,
                      {"loss": sil_loss, "steps": budget, "view_renders": budget * len(cams),
                       "verts": int(verts.shape[0])})
