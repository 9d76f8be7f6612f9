"""Exact (hard) rasterization of triangle meshes for evaluation masks, depth, normals and face ids.

Coverage is decided at pixel centers: for every image row a triangle crosses, its *span* on that row
(the x-extent of the triangle on the line through the row's pixel centers) is computed exactly, and the
pixels whose centers fall in it are covered (edges count as inside; a pixel center exactly on an edge
shared by two triangles is covered by both, which a silhouette does not mind). Spans are enumerated in
pieces of K pixels (see :func:`ipm.render.scan.span_rows`), so the work follows the covered area, with
no Python loop per triangle. Depth is interpolated perspective-correctly (1/z is affine in screen
space) and a z-buffer (``scatter_reduce`` amax of 1/z) keeps the nearest face; ties go to the lower face
index. Not differentiable (see :mod:`ipm.render.soft` for gradients).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch

from ipm.render.scan import check_mesh_tensors, span_rows, visible_triangles
from ipm.types import Camera, TriMesh

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Fragments:
    """What the hard rasterizer sees at each pixel center.

    mask: (H, W) bool, covered; depth: (H, W) float64 distance along the view axis (inf where empty);
    face: (H, W) int64 index of the visible face (-1 where empty); normal: (H, W, 3) float64 unit
    world-space normal of the visible face as wound (counter-clockwise = outward), zero where empty.
    """

    mask: torch.Tensor
    depth: torch.Tensor
    face: torch.Tensor
    normal: torch.Tensor


def face_normals(verts: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Unit normals (F, 3) of the faces (right-hand rule on the vertex order; zero for degenerate faces)."""
    v = verts[faces]
    n = torch.linalg.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-300)


@torch.no_grad()
def rasterize(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, *, near: float = 1e-3,
              chunk: int = 1 << 20) -> Fragments:
    """Hard-rasterize a mesh (see the module docstring).

    verts: (V, 3) float; faces: (F, 3) int64; camera: the view; near: faces with a vertex nearer than
    this are dropped (a warning is logged: keep cameras outside the object). Computed in float64 on the
    device of ``verts``.
    """
    check_mesh_tensors(verts, faces)
    W, H = int(camera.width), int(camera.height)
    dev = verts.device
    v64 = verts.detach().double()
    tri, tdepth, fidx = visible_triangles(v64, faces, camera, near)
    if fidx.shape[0] < faces.shape[0]:
        log.warning("%d of %d faces have a vertex behind the camera's near plane and were dropped",
                    faces.shape[0] - fidx.shape[0], faces.shape[0])
    groups, kept = span_rows(tri, 0.0, W, H)
    tri, tdepth, fidx = tri[kept], tdepth[kept], fidx[kept]
    stride = W + max((g.k for g in groups), default=0)
    n_pix = H * stride
    zbuf = torch.full((n_pix,), -1.0, dtype=torch.float64, device=dev)
    best = torch.full((n_pix,), max(fidx.shape[0], 1) - 1, dtype=torch.int64, device=dev)
    if groups:
        # 1/z = A x + B y + C over the triangle (perspective-correct interpolation)
        plane = _inverse_depth_planes(tri, 1.0 / tdepth)  # (F', 3)
        parts = []
        for rows in groups:
            kcol = torch.arange(rows.k, device=dev)[:, None]
            step = max(1, chunk // rows.k)
            for lo in range(0, rows.n_rows, step):
                hi = min(rows.n_rows, lo + step)
                t, j, i, n = rows.tri[lo:hi], rows.j[lo:hi], rows.i[lo:hi], rows.n[lo:hi]
                valid = kcol < n[None]
                pl = plane[t]
                x = (i[None] + kcol).double() + 0.5
                invz = pl[:, 0][None] * x + (pl[:, 1] * (j.double() + 0.5) + pl[:, 2])[None]
                pix = (j * stride + i)[None] + kcol
                pix, invz = pix[valid], invz[valid]
                tt = t[None].expand_as(valid)[valid]
                zbuf.scatter_reduce_(0, pix, invz, "amax")
                parts.append((pix, invz, tt))
        best.fill_(fidx.shape[0])
        for pix, invz, tt in parts:
            win = invz == zbuf[pix]
            best.scatter_reduce_(0, pix[win], tt[win], "amin")
    zbuf = zbuf.view(H, stride)[:, :W]
    best = best.view(H, stride)[:, :W]
    mask = zbuf > 0
    depth = torch.where(mask, 1.0 / zbuf.clamp_min(1e-300), torch.full_like(zbuf, float("inf")))
    face = torch.where(mask, fidx[best.clamp_max(max(fidx.shape[0] - 1, 0))] if fidx.numel() else best,
                       torch.full_like(best, -1))
    normals = face_normals(v64, faces)
    normal = torch.where(mask[..., None], normals[face.clamp_min(0)] if faces.numel() else
                         torch.zeros(H, W, 3, dtype=torch.float64, device=dev), 0.0)
    return Fragments(mask, depth, face, normal)


def _inverse_depth_planes(tri: torch.Tensor, invz: torch.Tensor) -> torch.Tensor:
    """Coefficients (F, 3) of the plane through (x, y, 1/z) at the three vertices; degenerate
    (edge-on) triangles get a constant: the mean of their vertices' 1/z."""
    p = torch.cat([tri, invz[..., None]], -1)  # (F, 3, 3)
    n = torch.linalg.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    ok = n[:, 2].abs() > 1e-12
    nz = torch.where(ok, n[:, 2], torch.ones_like(n[:, 2]))
    a = torch.where(ok, -n[:, 0] / nz, 0.0)
    b = torch.where(ok, -n[:, 1] / nz, 0.0)
    c = torch.where(ok, p[:, 0, 2] - a * p[:, 0, 0] - b * p[:, 0, 1], invz.mean(1))
    return torch.stack([a, b, c], -1)


def hard_mask(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, **kw) -> torch.Tensor:
    """Exact silhouette (H, W) bool of a mesh: pixel centers covered by some triangle."""
    return rasterize(verts, faces, camera, **kw).mask


def rasterize_mesh(mesh: TriMesh, camera: Camera, **kw) -> Fragments:
    """:func:`rasterize` for a :class:`~ipm.types.TriMesh`."""
    return rasterize(mesh.verts, mesh.faces, camera, **kw)


def view_maps(fr: Fragments, mesh: TriMesh) -> dict:
    """What one exact view shows beyond its mask: ``depth (H, W)`` view-axis depth (NaN off the object),
    ``normal (H, W, 3)``, ``mask (H, W)`` bool and ``groups (H, W)`` int64, the mesh group of the visible face
    (-1 off the object; None for a mesh without groups). What ``ipm render`` writes and the bench gives as cues."""
    depth = torch.where(fr.mask, fr.depth, torch.full_like(fr.depth, float("nan")))
    groups = None
    if mesh.groups is not None and mesh.group_names:
        g = mesh.groups.to(fr.face.device)
        groups = torch.where(fr.mask, g[fr.face.clamp_min(0)], torch.full_like(fr.face, -1))
    return {"depth": depth, "normal": fr.normal, "mask": fr.mask, "groups": groups}
