"""The deferred renderer's ops in C (backend "native" of :mod:`ipm.render.deferred`).

The kernel is ``ipm/native/deferred.c`` (declared in ``deferred.h``; per-pixel work in ``deferred_kernel.inc``),
built by :mod:`ipm.native` on first use like the soft silhouette's. Each op here computes what its eager twin
in :mod:`ipm.render.deferred` computes, with the same formulas in the same order, and wraps forward and
backward in a ``torch.autograd.Function``:

- :func:`zbuffer`: the exact z-buffer of :mod:`ipm.render.raster` (float64, no gradient): the same span of
  pixel centers per row (:func:`ipm.render.scan.span_rows` with no padding), the same 1/z planes, the
  largest 1/z kept and ties to the lower face index; bands of rows on torch's threads, each band's faces in
  index order, so the result does not depend on the thread count. The planes' cross products are computed
  without fused multiply-adds, which torch's may use on CPUs that have them, so depths agree with the exact
  rasterizer's to about 1e-15 relative and faces are the same but where two faces' 1/z tie to the last bit;
- :func:`barycentrics`: the triple-product barycentrics from the camera-space vertices, differentiable in
  them and in the focal length (computed in double for float32 too: the triple products cancel, and the
  eager op's float32 barycentrics are off by up to 6e-4 in the benchmark's view);
- :func:`interpolate`: attributes at the pixels, differentiable in the attributes and the barycentrics;
- :func:`antialias`: the analytic edge antialiasing, differentiable in the colors and the projected
  vertices (the backward pass finds the pixel pairs again), and :func:`silhouette_edges`, the edges it
  blends at (a hash table of the undirected edges rather than a sort).

Backward passes add into the vertices pixel after pixel in image order (one thread), so gradients are the
same bits for any thread count; the flags of :data:`ipm.native.FLAGS` make them the same on every CPU.
"""

from __future__ import annotations

import logging

import torch

from ipm.errors import InputError
from ipm.render.scan import visible_triangles
from ipm.types import Camera

log = logging.getLogger(__name__)


def _kernel():
    from ipm import native

    return native.load("deferred")


def available() -> bool:
    """Whether the C kernel is built (``ipm/native/deferred.c``, built on first use with a C compiler)."""
    return _kernel() is not None


def usable(*tensors: torch.Tensor) -> bool:
    """Whether the kernel can run on these tensors: built, on the CPU, all float32 or all float64."""
    dts = {t.dtype for t in tensors}
    return (len(dts) == 1 and dts <= {torch.float32, torch.float64}
            and all(t.device.type == "cpu" for t in tensors) and _kernel() is not None)


def _fn(name: str, dtype: torch.dtype | None = None):
    """The kernel's function ``name`` (``_f``/``_d`` added for ``dtype``), tensors passed by address and None
    as a null pointer."""
    k = _kernel()
    suffix = "" if dtype is None else ("_f" if dtype == torch.float32 else "_d")
    fn = getattr(k.lib, name + suffix)

    def call(*args):
        return fn(*(k.ptr(a.data_ptr()) if torch.is_tensor(a) else (k.ffi.NULL if a is None else a)
                    for a in args))

    return call


def _check_indices(faces: torch.Tensor, n_verts: int, face: torch.Tensor | None = None) -> None:
    """``InputError`` unless faces (F, 3) index ``n_verts`` vertices and the face map ``face`` indexes faces
    (the kernel reads what they point at; eager indexing would raise)."""
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"faces: expected (F, 3), got {tuple(faces.shape)}")
    if faces.numel() and (int(faces.min()) < 0 or int(faces.max()) >= n_verts):
        raise InputError(f"faces: expected vertex indices in [0, {n_verts}), got "
                         f"[{int(faces.min())}, {int(faces.max())}]")
    if face is not None and face.numel() and int(face.max()) >= faces.shape[0]:
        raise InputError(f"faces: expected the {int(face.max()) + 1} or more faces that were rasterized, got "
                         f"{faces.shape[0]}")


def zbuffer(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, near: float
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """Visible face (H, W) int64 (-1 where empty) and view-axis depth (H, W) float64 (inf where empty), as
    :func:`ipm.render.raster.rasterize` finds them. verts: (V, 3) float; faces: (F, 3) int64."""
    W, H = int(camera.width), int(camera.height)
    tri, tdepth, fidx = visible_triangles(verts.detach().double(), faces, camera, near)
    if fidx.shape[0] < faces.shape[0]:
        log.warning("%d of %d faces have a vertex behind the camera's near plane and were dropped",
                    faces.shape[0] - fidx.shape[0], faces.shape[0])
    depth = torch.empty(H, W, dtype=torch.float64)
    face = torch.empty(H, W, dtype=torch.int64)
    nt = max(1, min(torch.get_num_threads(), H // 16))
    if _fn("dr_zbuf")(tri.contiguous(), tdepth.contiguous(), fidx.contiguous(), fidx.shape[0], W, H, depth,
                      face, nt):
        raise MemoryError("deferred rasterize: the native kernel ran out of memory")
    return face, depth


class _Barycentrics(torch.autograd.Function):
    """bary (H, W, 3) from the camera-space vertices pc (V, 3) and the focal length fpx (0-dim), given the
    face map face (H, W) int64, faces (F, 3) int64 and the principal point (cx, cy)."""

    @staticmethod
    def forward(ctx, pc, fpx, faces, face, cx, cy):
        """Barycentrics, zero where empty."""
        H, W = face.shape
        bary = torch.empty(H, W, 3, dtype=pc.dtype)
        _fn("dr_bary_fwd", pc.dtype)(pc, faces, face, W, H, float(fpx), cx, cy, bary)
        ctx.save_for_backward(pc, fpx, faces, face)
        ctx.center = (cx, cy)
        return bary

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gbary):
        """Gradients for ``pc`` and ``fpx``."""
        pc, fpx, faces, face = ctx.saved_tensors
        H, W = face.shape
        gpc = torch.empty_like(pc)
        gf = torch.empty(1, dtype=pc.dtype)
        _fn("dr_bary_bwd", pc.dtype)(pc, pc.shape[0], faces, face, W, H, float(fpx), *ctx.center,
                                     gbary.to(pc.dtype).contiguous(), gpc, gf)
        return gpc, gf.view(()).to(fpx.dtype), None, None, None, None


def barycentrics(pc: torch.Tensor, fpx: torch.Tensor, faces: torch.Tensor, face: torch.Tensor,
                 center: tuple[float, float]) -> torch.Tensor:
    """Perspective-correct barycentrics (H, W, 3) of the pixel centers in ``face`` (H, W) (zero where -1).

    pc: (V, 3) camera-space vertices; fpx: 0-dim focal length in pixels (both differentiable, same dtype);
    faces: (F, 3) int64; center: the principal point in pixels."""
    return _Barycentrics.apply(pc.contiguous(), fpx, faces.contiguous(), face.contiguous(), float(center[0]),
                               float(center[1]))


class _Interpolate(torch.autograd.Function):
    """out (N, C) = per pixel the barycentric mix of attr (V, C) over its face; background where empty."""

    @staticmethod
    def forward(ctx, attr, bary, faces, face, background):
        """The interpolated attributes."""
        n, C = face.numel(), attr.shape[1]
        out = torch.empty(n, C, dtype=attr.dtype)
        _fn("dr_interp_fwd", attr.dtype)(attr, C, faces, face, bary, n, float(background), out)
        ctx.save_for_backward(attr, bary, faces, face)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gout):
        """Gradients for ``attr`` and ``bary`` (those asked for)."""
        attr, bary, faces, face = ctx.saved_tensors
        need_attr, need_bary = ctx.needs_input_grad[:2]
        gattr = torch.empty_like(attr) if need_attr else None
        gbary = torch.empty_like(bary) if need_bary else None
        _fn("dr_interp_bwd", attr.dtype)(attr, attr.shape[0], attr.shape[1], faces, face, bary, face.numel(),
                                         gout.to(attr.dtype).contiguous(), gattr, gbary)
        return gattr, gbary, None, None, None


def interpolate(attr: torch.Tensor, bary: torch.Tensor, faces: torch.Tensor, face: torch.Tensor,
                background: float) -> torch.Tensor:
    """``Σ_k bary_k attr[face_k]`` per pixel, (H, W, C); attr (V, C) and bary (H, W, 3) of one dtype, face
    (H, W) int64, ``background`` where it is -1."""
    _check_indices(faces, attr.shape[0], face)
    H, W = face.shape
    out = _Interpolate.apply(attr.contiguous(), bary.contiguous(), faces.contiguous(), face.contiguous(),
                             float(background))
    return out.view(H, W, -1)


class _Antialias(torch.autograd.Function):
    """The antialiased colors (H, W, C) of color (H, W, C) given the projected vertices xy (V, 2) (both
    differentiable), the face map, the z-buffer, faces and the silhouette edges (F, 3) bool."""

    @staticmethod
    def forward(ctx, color, xy, faces, face, zbuf, sil):
        """The blended image."""
        H, W, C = color.shape
        out = torch.empty_like(color)
        sil8 = sil.to(torch.uint8).contiguous()
        _fn("dr_aa_fwd", color.dtype)(color, C, face, zbuf, W, H, xy, faces, sil8, out)
        ctx.save_for_backward(color, xy, faces, face, zbuf, sil8)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gout):
        """Gradients for ``color`` and ``xy`` (the pixel pairs found again)."""
        color, xy, faces, face, zbuf, sil8 = ctx.saved_tensors
        H, W, C = color.shape
        gcolor = torch.empty_like(color)
        gxy = torch.empty_like(xy)
        _fn("dr_aa_bwd", color.dtype)(color, C, face, zbuf, W, H, xy, xy.shape[0], faces, sil8,
                                      gout.to(color.dtype).contiguous(), gcolor, gxy)
        return gcolor, gxy, None, None, None, None


def antialias(color: torch.Tensor, xy: torch.Tensor, faces: torch.Tensor, face: torch.Tensor,
              zbuf: torch.Tensor, silhouette: torch.Tensor) -> torch.Tensor:
    """Analytic edge antialiasing of color (H, W, C) (see :func:`ipm.render.deferred.antialias`); xy: (V, 2)
    projected vertices of the dtype of ``color``; face (H, W) int64; zbuf (H, W) float64; silhouette (F, 3)
    bool."""
    _check_indices(faces, xy.shape[0], face)
    if silhouette.shape != faces.shape:
        raise InputError(f"silhouette: expected {tuple(faces.shape)}, got {tuple(silhouette.shape)}")
    return _Antialias.apply(color.contiguous(), xy.contiguous(), faces.contiguous(), face.contiguous(),
                            zbuf.to(torch.float64).contiguous(), silhouette)


def silhouette_edges(verts: torch.Tensor, faces: torch.Tensor, eye: torch.Tensor) -> torch.Tensor:
    """Silhouette edges (F, 3) bool seen from ``eye`` (3,) (see :func:`ipm.render.deferred.silhouette_edges`);
    verts (V, 3) float32 or float64 (no gradient), eye of its dtype, faces (F, 3) int64."""
    _check_indices(faces, verts.shape[0])
    v = verts.detach().contiguous()
    sil = torch.empty(faces.shape[0], 3, dtype=torch.uint8)
    if _fn("dr_silhouette", v.dtype)(v, v.shape[0], faces.contiguous(), faces.shape[0],
                                     eye.detach().to(v.dtype).contiguous(), sil):
        raise MemoryError("deferred silhouette edges: the native kernel ran out of memory")
    return sil.bool()
