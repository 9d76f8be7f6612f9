"""A differentiable deferred renderer on the CPU: nvdiffrast's ops as small pure functions.

Laine et al., "Modular Primitives for High-Performance Differentiable Rendering" (SIGGRAPH Asia 2020)
split a differentiable renderer into a few composable operations; we follow it:

1. :func:`rasterize` -- per pixel the visible face (the exact z-buffer of :mod:`ipm.render.raster`, no
   gradient) and the perspective-correct barycentrics of the pixel center in that face, computed
   *differentiably* from the vertex positions and the camera (nvdiffrast's ``rasterize`` returns
   barycentrics whose gradient flows to the clip-space positions the same way).
2. :func:`interpolate` -- any per-vertex attribute at the pixels, differentiable in the attribute and,
   through the barycentrics, in the vertex positions. Helpers: :func:`depth`, :func:`face_normal_image`,
   :func:`vertex_normal_image`, :func:`part_labels`.
3. :func:`antialias` -- analytic edge antialiasing (the paper's antialiasing section): where two
   neighbouring pixels see different faces and the front one's triangle has a silhouette edge between
   their centers, the colors are blended by where the edge crosses the segment, which makes the image a
   differentiable function of the vertex positions at silhouette and occlusion boundaries.
4. :func:`shade` -- Lambert under one directional light plus ambient.

:func:`render_deferred` strings them together for a :class:`~ipm.types.TriMesh`.

Barycentrics (op 1). With the camera at the origin of camera space, the ray through a pixel center has
direction ``d = ((x - cx)/f, -(y - cy)/f, -1)`` (principal point ``(cx, cy)``, the image center unless
the camera sets it) and it meets the plane of the triangle ``P0 P1 P2`` at
the point whose barycentrics are proportional to the signed volumes of the tetrahedra it spans with the
edges: ``b_i ∝ d · (P_j × P_k)`` for ``(i, j, k)`` cyclic, with sum ``d · ((P1 - P0) × (P2 - P0))``
(Cramer's rule on the ray-plane system in triple-product form, as in
Möller and Trumbore 1997). These are exactly the perspective-correct
barycentrics (the hit point is ``Σ b_i P_i``), so interpolating camera-space depth reproduces the depth
of the ray hit, which is what the exact rasterizer's 1/z plane gives.

Backends (``$IPM_DEFERRED_BACKEND``, else :data:`DEFAULT_BACKEND`): "native" runs the z-buffer, the barycentrics,
:func:`interpolate`, :func:`silhouette_edges` and :func:`antialias` forward and backward in C
(:mod:`ipm.render.deferred_native`, ``ipm/native/deferred.c``) with the formulas written out here, with
results that do not depend on the CPU or the thread count, about three times as fast; "eager" is the
pure-torch path, which "native" falls back to without a C compiler, off the CPU or for other dtypes. Normals,
part labels and shading are small torch expressions either way. The default stays "eager" for now: the two
agree to about 1e-15, but the reference photo fit (tests/test_reference_fits.py) sits on a knife edge that this
difference tips, from photo IoU 0.966 to 0.911 (the same two outcomes results/perturbation.md found under other
kernels), so switching the default waits for that fit to be made robust.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch

from ipm.errors import InputError
from ipm.render import deferred_native as native
from ipm.render import raster
from ipm.render.camera import focal_pixels, project, to_camera_space
from ipm.render.scan import check_mesh_tensors
from ipm.types import Camera, TriMesh

BACKENDS = ("native", "eager")
DEFAULT_BACKEND = "eager"  # module docstring: why not "native" yet


def _native(backend: str | None, *tensors: torch.Tensor) -> bool:
    """Whether to run an op natively: ``backend`` (default ``$IPM_DEFERRED_BACKEND`` or :data:`DEFAULT_BACKEND`) is
    "native" and the kernel can take ``tensors`` (:func:`ipm.render.deferred_native.usable`)."""
    backend = backend or os.environ.get("IPM_DEFERRED_BACKEND") or DEFAULT_BACKEND
    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    return backend == "native" and native.usable(*tensors)


@dataclass(frozen=True)
class Raster:
    """What :func:`rasterize` sees at each pixel center.

    face: (H, W) int64 visible face index, -1 where empty (no gradient);
    bary: (H, W, 3) float perspective-correct barycentrics of the pixel center in ``face`` (zero where
    empty), differentiable in the vertex positions and the camera;
    mask: (H, W) bool, covered;
    zbuf: (H, W) float64 view-axis depth of the exact rasterizer, inf where empty (no gradient: used to
    order pixel pairs in :func:`antialias`; use :func:`depth` for a differentiable depth);
    backend: the backend that rasterized, which :func:`interpolate` and :func:`antialias` use unless told.
    """

    face: torch.Tensor
    bary: torch.Tensor
    mask: torch.Tensor
    zbuf: torch.Tensor
    backend: str = "eager"

    @property
    def shape(self) -> tuple[int, int]:
        """Image size ``(H, W)``."""
        return int(self.face.shape[0]), int(self.face.shape[1])


def rasterize(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, *, near: float = 1e-3,
              backend: str | None = None) -> Raster:
    """Visible face per pixel (no gradient) and differentiable perspective-correct barycentrics.

    verts: (V, 3) float; faces: (F, 3) int64; camera: the view (its tensors may require grad); backend:
    "native" or "eager" (module docstring). Visibility is :func:`ipm.render.raster.rasterize` (pixel
    centers, z-buffer, ties to the lower face index, faces crossing ``near`` dropped). Barycentrics use the
    triple-product formula of the module docstring, in the dtype and on the device of ``verts``.
    """
    check_mesh_tensors(verts, faces)
    if _native(backend, verts):
        faces = faces.to(torch.int64)
        face, zbuf = native.zbuffer(verts, faces, camera, near)
        f = focal_pixels(camera).to(verts.dtype)
        bary = native.barycentrics(to_camera_space(verts, camera), f, faces, face, camera.principal_point)
        return Raster(face, bary, face >= 0, zbuf, "native")
    fr = raster.rasterize(verts, faces, camera, near=near)
    H, W = fr.face.shape
    dt, dev = verts.dtype, verts.device
    pix = fr.mask.reshape(-1).nonzero().squeeze(1)  # (N,)
    tri = faces[fr.face.reshape(-1)[pix]]  # (N, 3)
    pc = to_camera_space(verts, camera)  # (V, 3)
    f = focal_pixels(camera).to(dt)
    x = (pix % W).to(dt) + 0.5
    y = torch.div(pix, W, rounding_mode="floor").to(dt) + 0.5
    cx, cy = camera.principal_point
    d = torch.stack([(x - cx) / f, -(y - cy) / f, -torch.ones_like(x)], -1)  # (N, 3)
    p0, p1, p2 = pc[tri[:, 0]], pc[tri[:, 1]], pc[tri[:, 2]]
    w = torch.stack([
        (d * torch.linalg.cross(p1, p2)).sum(-1),
        (d * torch.linalg.cross(p2, p0)).sum(-1),
        (d * torch.linalg.cross(p0, p1)).sum(-1),
    ], -1)
    s = w.sum(-1, keepdim=True)
    # a covered pixel's face is not edge-on to its ray; the guard only keeps values finite
    tiny = torch.finfo(dt).tiny
    s = torch.where(s.abs() > tiny, s, torch.full_like(s, tiny))
    b = w / s
    bary = torch.zeros(H * W, 3, dtype=dt, device=dev).index_put((pix,), b).view(H, W, 3)
    return Raster(fr.face, bary, fr.mask, fr.depth)


def interpolate(attr: torch.Tensor, rast: Raster, faces: torch.Tensor,
                background: float | torch.Tensor = 0.0, *, backend: str | None = None) -> torch.Tensor:
    """A per-vertex attribute at the pixels: ``Σ_i bary_i attr[face_i]``.

    attr: (V, C) float; rast: from :func:`rasterize`; faces: (F, 3) int64 (the same as rasterized);
    backend: "native" (where ``attr`` and ``rast.bary`` share a dtype and ``background`` is a number),
    "eager", or None for the rasterizer's (``rast.backend``). Returns (H, W, C) in the dtype of ``attr``
    and ``bary`` promoted; ``background`` where empty. Differentiable in ``attr`` and (through
    ``rast.bary``) in the vertex positions and camera.
    """
    if attr.ndim != 2:
        raise InputError(f"interpolate: expected attr (V, C), got {tuple(attr.shape)}")
    if not torch.is_tensor(background) and _native(backend or rast.backend, attr, rast.bary):
        return native.interpolate(attr, rast.bary, faces.to(torch.int64), rast.face, background)
    H, W = rast.shape
    pix = rast.mask.reshape(-1).nonzero().squeeze(1)
    tri = faces[rast.face.reshape(-1)[pix]]  # (N, 3)
    b = rast.bary.reshape(-1, 3)[pix]  # (N, 3)
    vals = (b[..., None] * attr[tri]).sum(1)  # (N, C)
    out = torch.full((H * W, attr.shape[1]), 0.0, dtype=vals.dtype, device=vals.device)
    if torch.is_tensor(background) or background != 0.0:
        out = out + torch.as_tensor(background, dtype=vals.dtype, device=vals.device)
    return out.index_put((pix,), vals).view(H, W, -1)


def depth(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, rast: Raster,
          background: float = 0.0) -> torch.Tensor:
    """View-axis distance (H, W) of the visible surface (``background`` where empty; default 0 so
    that sums stay finite -- the exact rasterizer uses inf)."""
    z = -to_camera_space(verts, camera)[:, 2:]
    return interpolate(z, rast, faces, background)[..., 0]


def face_normals(verts: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Unit normals (F, 3) of the faces (right-hand rule; degenerate faces get ~0), differentiable."""
    v = verts[faces]
    n = torch.linalg.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-30)


def vertex_normals(verts: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted vertex normals (V, 3): the normalized sum of the adjacent faces' cross products."""
    v = verts[faces]
    n = torch.linalg.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])  # (F, 3), |n| = 2 area
    acc = torch.zeros_like(verts).index_add(0, faces.reshape(-1), n.repeat_interleave(3, 0))
    return acc / torch.linalg.vector_norm(acc, dim=-1, keepdim=True).clamp_min(1e-30)


def face_normal_image(verts: torch.Tensor, faces: torch.Tensor, rast: Raster) -> torch.Tensor:
    """Flat world-space normals (H, W, 3) of the visible faces (zero where empty), differentiable in
    ``verts`` (the face ids are not)."""
    return _per_face(face_normals(verts, faces), rast, 0.0)


def vertex_normal_image(verts: torch.Tensor, faces: torch.Tensor, rast: Raster) -> torch.Tensor:
    """Smooth world-space normals (H, W, 3): interpolated :func:`vertex_normals`, renormalized (zero
    where empty)."""
    n = interpolate(vertex_normals(verts, faces), rast, faces)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-30)


def part_labels(groups: torch.Tensor | None, rast: Raster) -> torch.Tensor:
    """Part index (H, W) int64 of the visible face (``groups[face]``; 0 for every face when ``groups`` is
    None), -1 where empty."""
    if groups is None:
        return torch.where(rast.mask, 0, -1).to(torch.int64)
    return _per_face(groups[:, None], rast, -1)[..., 0]


def _per_face(values: torch.Tensor, rast: Raster, background) -> torch.Tensor:
    """(F, C) face values at the pixels (H, W, C), ``background`` where empty (safe for F = 0)."""
    H, W = rast.shape
    pix = rast.mask.reshape(-1).nonzero().squeeze(1)
    out = torch.full((H * W, values.shape[1]), background, dtype=values.dtype, device=values.device)
    return out.index_put((pix,), values[rast.face.reshape(-1)[pix]]).view(H, W, -1)


def shade(normal: torch.Tensor, mask: torch.Tensor, light_dir: torch.Tensor | None = None,
          intensity: float | torch.Tensor = 0.8, ambient: float | torch.Tensor = 0.2) -> torch.Tensor:
    """Lambert shading ``ambient + intensity * max(0, n · l)`` (grey, (H, W)), 0 where ``~mask``.

    normal: (H, W, 3) unit world normals; mask: (H, W) bool; light_dir: (3,) direction *towards* the
    light (normalized here; default (0, 0, 1)); intensity, ambient: floats or 0-dim tensors (all three
    differentiable).
    """
    if normal.shape[-1:] != (3,) or normal.shape[:-1] != mask.shape:
        raise InputError(f"shade: expected normal (H, W, 3) and mask (H, W), got {tuple(normal.shape)} "
                         f"and {tuple(mask.shape)}")
    if light_dir is None:
        light_dir = torch.tensor([0.0, 0.0, 1.0], dtype=normal.dtype, device=normal.device)
    lv = light_dir.to(normal.dtype)
    lv = lv / torch.linalg.vector_norm(lv).clamp_min(1e-30)
    lam = (normal * lv).sum(-1).clamp_min(0.0)
    return torch.where(mask, ambient + intensity * lam, 0.0)


# -- antialiasing ------------------------------------------------------------------------------------

def silhouette_edges(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, *,
                     backend: str | None = None) -> torch.Tensor:
    """Which face edges are silhouettes from this camera: (F, 3) bool, edge i from vertex i to i+1.

    An edge of a face is a silhouette if no other face sharing it (by vertex indices) faces the camera
    the same way (front or back): boundary edges, and edges between a front- and a back-facing face.
    nvdiffrast's antialias finds the neighbouring face through its topology hash for the same test. No gradient.
    backend: "native", "eager" or None (``$IPM_DEFERRED_BACKEND`` or :data:`DEFAULT_BACKEND`).
    """
    F = faces.shape[0]
    dev = faces.device
    if _native(backend, verts):
        return native.silhouette_edges(verts, faces.to(torch.int64), camera.eye)
    with torch.no_grad():
        v = verts.detach()
        n = torch.linalg.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
        view = v[faces[:, 0]] - camera.eye.detach().to(v.dtype)
        front = (n * view).sum(-1) < 0  # (F,)
    a = faces
    b = faces.roll(-1, 1)
    lo, hi = torch.minimum(a, b).reshape(-1), torch.maximum(a, b).reshape(-1)  # (3F,)
    n_v = int(faces.max()) + 1 if F else 1
    key = lo * n_v + hi
    fr = front.repeat_interleave(3)
    # count, per undirected edge, the front-facing and back-facing faces on it
    uniq, inv = torch.unique(key, return_inverse=True)
    n_front = torch.zeros(uniq.shape[0], dtype=torch.int64, device=dev).index_add(0, inv, fr.long())
    n_all = torch.zeros(uniq.shape[0], dtype=torch.int64, device=dev).index_add(
        0, inv, torch.ones_like(inv))
    same = torch.where(fr, n_front[inv], n_all[inv] - n_front[inv])  # faces facing like this one, incl. it
    return (same == 1).view(F, 3)


def antialias(color: torch.Tensor, rast: Raster, verts: torch.Tensor, faces: torch.Tensor, camera: Camera,
              silhouette: torch.Tensor | None = None, *, backend: str | None = None) -> torch.Tensor:
    """Analytic edge antialiasing after nvdiffrast (Laine et al. 2020, antialiasing section).

    color: (H, W, C) float (or (H, W)); rast: from :func:`rasterize`; verts (V, 3), faces (F, 3), camera:
    as rasterized; silhouette: optional (F, 3) bool from :func:`silhouette_edges` (computed when None);
    backend: "native" (where ``color`` and ``verts`` share a dtype), "eager", or None for the rasterizer's
    (``rast.backend``). Returns an image of the shape of ``color``.

    For every horizontally or vertically adjacent pixel pair with different face ids, take the pixel
    whose surface is nearer (or the only covered one), ``p``, and the other, ``q``. If a silhouette edge
    of ``p``'s triangle crosses the segment between the centers at distance ``t`` in [0, 1] from ``p``
    (only edges more vertical than horizontal for horizontal pairs, and vice versa, so each edge is
    handled in one direction), then ``p``'s triangle covers the part ``[-1/2, t]`` of the pair's
    one-dimensional footprint ``[-1/2, 3/2]``: for ``t > 1/2`` pixel ``q`` gets ``t - 1/2`` of ``p``'s
    color, for ``t < 1/2`` pixel ``p`` gets ``1/2 - t`` of ``q``'s color. Blending the colors as they come
    in (not the blended ones) and summing the contributions of all pairs, as nvdiffrast does. ``t``
    depends on the projected vertices, so the result is differentiable in ``verts`` and the camera at
    silhouette and occlusion boundaries, and in ``color`` everywhere. For a straight edge the sum of an
    antialiased mask over a column (or row) equals the exact covered length, so the image sum follows
    the projected area.
    """
    squeeze = color.ndim == 2
    c = color[..., None] if squeeze else color
    H, W = rast.shape
    if c.shape[:2] != (H, W):
        raise InputError(f"antialias: expected color ({H}, {W}, C), got {tuple(color.shape)}")
    if silhouette is None:
        silhouette = silhouette_edges(verts, faces, camera, backend=backend or rast.backend)
    xy, _ = project(verts, camera)  # (V, 2)
    if _native(backend or rast.backend, c, xy):
        out = native.antialias(c, xy, faces.to(torch.int64), rast.face, rast.zbuf, silhouette)
        return out[..., 0] if squeeze else out
    flat = c.reshape(H * W, -1)
    out = flat
    face = rast.face.reshape(-1)
    z = rast.zbuf.reshape(-1)
    idx = torch.arange(H * W, device=face.device).view(H, W)
    for axis in (1, 0):  # horizontal pairs, then vertical pairs
        a = (idx[:, :-1] if axis == 1 else idx[:-1]).reshape(-1)
        b = (idx[:, 1:] if axis == 1 else idx[1:]).reshape(-1)
        keep = face[a] != face[b]
        a, b = a[keep], b[keep]
        a_front = z[a] < z[b]  # inf for empty pixels, so the covered one wins
        p = torch.where(a_front, a, b)
        q = torch.where(a_front, b, a)
        fp = face[p]
        tri = faces[fp]  # (N, 3)
        e0 = xy[tri]  # (N, 3, 2) edge starts
        e1 = xy[tri.roll(-1, 1)]  # (N, 3, 2) edge ends
        sil = silhouette[fp]  # (N, 3)
        # pixel centers; u runs along the pair's axis, w across it
        pc = torch.stack([(p % W).to(xy.dtype) + 0.5, torch.div(p, W, rounding_mode="floor").to(xy.dtype)
                          + 0.5], -1)
        qc = torch.stack([(q % W).to(xy.dtype) + 0.5, torch.div(q, W, rounding_mode="floor").to(xy.dtype)
                          + 0.5], -1)
        u_ax, w_ax = (0, 1) if axis == 1 else (1, 0)
        du = e1[..., u_ax] - e0[..., u_ax]
        dw = e1[..., w_ax] - e0[..., w_ax]
        w0 = pc[:, None, w_ax]
        steep = dw.abs() > du.abs() if axis == 1 else dw.abs() >= du.abs()
        spans = ((e0[..., w_ax] - w0) * (e1[..., w_ax] - w0) <= 0) & steep & sil
        dw_safe = torch.where(spans, dw, torch.ones_like(dw))
        cross_u = e0[..., u_ax] + (w0 - e0[..., w_ax]) / dw_safe * du  # (N, 3)
        sgn = (qc[:, u_ax] - pc[:, u_ax])[:, None]  # +-1
        t = (cross_u - pc[:, None, u_ax]) * sgn
        ok = spans & (t >= 0) & (t <= 1)
        # the nearest qualifying edge to p's center
        t_sel = torch.where(ok, t, torch.full_like(t, 2.0))
        j = t_sel.detach().argmin(1)
        has = ok.any(1)
        t = t.gather(1, j[:, None]).squeeze(1)[has]
        p, q = p[has], q[has]
        cp, cq = flat[p], flat[q]
        t = t[:, None].to(flat.dtype)
        to_q = (t - 0.5).clamp_min(0.0) * (cp - cq)
        to_p = (0.5 - t).clamp_min(0.0) * (cq - cp)
        out = out.index_add(0, q, to_q).index_add(0, p, to_p)
    out = out.view(c.shape)
    return out[..., 0] if squeeze else out


# -- convenience -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DeferredSettings:
    """Settings of :func:`render_deferred`.

    smooth: interpolated vertex normals instead of flat face normals; light_dir: (3,) direction towards
    the light, or None for a headlight (``eye - target``); intensity, ambient: see :func:`shade` (floats
    or 0-dim tensors, differentiable); antialias: antialias the image and mask (:func:`antialias`, what
    makes them differentiable at silhouettes); near: see :func:`rasterize`; backend: "native", "eager" or
    None for ``$IPM_DEFERRED_BACKEND`` or :data:`DEFAULT_BACKEND` (module docstring).
    """

    smooth: bool = False
    light_dir: torch.Tensor | None = None
    intensity: float | torch.Tensor = 0.8
    ambient: float | torch.Tensor = 0.2
    antialias: bool = True
    near: float = 1e-3
    backend: str | None = None

    def __post_init__(self) -> None:
        if not self.near > 0:
            raise InputError(f"deferred settings near: expected a positive value, got {self.near}")
        if self.light_dir is not None and tuple(self.light_dir.shape) != (3,):
            raise InputError(f"deferred settings light_dir: expected (3,), got {tuple(self.light_dir.shape)}")
        if self.backend is not None and self.backend not in BACKENDS:
            raise InputError(f"deferred settings backend: expected one of {', '.join(BACKENDS)}, got "
                             f"{self.backend!r}")


@dataclass(frozen=True)
class Deferred:
    """Outputs of :func:`render_deferred`.

    depth: (H, W) view-axis depth (0 where empty); normal: (H, W, 3) world normals (zero where empty);
    parts: (H, W) int64 part index, -1 where empty; image: (H, W) grey Lambert shading (antialiased
    unless disabled); mask: (H, W) float coverage (antialiased unless disabled); raster: the
    :class:`Raster` they were computed from.
    """

    depth: torch.Tensor
    normal: torch.Tensor
    parts: torch.Tensor
    image: torch.Tensor
    mask: torch.Tensor
    raster: Raster


def render_deferred(mesh: TriMesh, camera: Camera, settings: DeferredSettings | None = None) -> Deferred:
    """Depth, normals, part labels, shaded image and mask of a mesh through the four ops.

    mesh: verts (V, 3) float (may require grad), faces, groups (part labels); camera: the view;
    settings: :class:`DeferredSettings` (defaults when None). Outputs follow the dtype and device of
    ``mesh.verts``.
    """
    s = settings or DeferredSettings()
    verts, faces = mesh.verts, mesh.faces
    rast = rasterize(verts, faces, camera, near=s.near, backend=s.backend)
    normal = (vertex_normal_image if s.smooth else face_normal_image)(verts, faces, rast)
    light_dir = s.light_dir if s.light_dir is not None else (camera.eye - camera.target)
    img = shade(normal, rast.mask, light_dir.to(device=verts.device), s.intensity, s.ambient)
    mask = rast.mask.to(verts.dtype)
    if s.antialias:
        sil = silhouette_edges(verts, faces, camera, backend=rast.backend)
        both = antialias(torch.stack([img, mask], -1), rast, verts, faces, camera, sil)
        img, mask = both[..., 0], both[..., 1]
    return Deferred(depth(verts, faces, camera, rast), normal, part_labels(mesh.groups, rast), img, mask,
                    rast)
