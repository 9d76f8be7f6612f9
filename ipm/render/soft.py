"""Soft silhouettes of triangle meshes on the CPU (SoftRas), differentiable in vertices and camera.

Formulation (Liu et al., "Soft Rasterizer", ICCV 2019): for pixel center ``p`` and projected triangle
``j``, ``D_j(p) = sigmoid(s * d^2 / sigma)`` with ``d`` the screen-space distance (pixels) from ``p`` to
the triangle's boundary and ``s = +1`` inside, ``-1`` outside; the silhouette is
``1 - prod_j (1 - D_j(p))``. Triangles count whichever way they face (a silhouette needs both).

How the cost follows covered pixels rather than pixels × triangles (steps 1 to 3 are the scan
conversion of :mod:`ipm.render.scan`):

1. vertices are projected; faces with a vertex nearer than ``near`` (behind the camera) are dropped
   (no near-plane clipping: keep the camera outside the object);
2. around each triangle only the pixels within the blur radius ``r = sqrt(sigma ln(1/eps))`` matter
   (beyond it ``D < eps``): for every image row, the *run* of pixel centers within distance ``r`` of
   the triangle, computed exactly (offset edges and vertex disks); triangles fully outside the image
   have no runs;
3. runs are cut into pieces and grouped by length, each group padded to one size ``K``
   (:data:`PIECE_SIZES`), so the work is a few dense ``(K, pieces)`` evaluations whose per-piece
   constants broadcast along ``K``: no Python loop per triangle, little padding, and along a run the
   screen distance is an affine function of the column (pieces running past the right image edge write
   to padding columns);
4. per pair, ``log(1 - D) = -(log(1 + exp(-d^2/sigma)) + [inside] d^2/sigma)``, which is
   ``logsigmoid(-s d^2 / sigma)`` in a form that stays finite for every ``d`` (the safe "clamp" of
   log(1 - D)), is accumulated per pixel with ``index_add_``: the product becomes a sum of logs;
5. pieces are processed in chunks of at most ``chunk`` pairs to bound memory.

The backward pass is written by hand (a ``torch.autograd.Function``) from the envelope identity: with
``w = p - a - t e`` the vector from the nearest point of the nearest edge ``a -> a + e`` (at parameter
``t`` in [0, 1]), ``d(d^2) = -2 w . ((1 - t) da + t d(a + e))``.

The default backend "native" does steps 1 to 5 in C (``ipm/native/soft.c``, declared in ``soft.h``, built
by :mod:`ipm.native` with the system's C compiler on first use in about a second and cached): it projects
the vertices (as :func:`ipm.render.camera.project`, whose matrix product torch would hand to a threaded
BLAS), gathers
the triangles (dropping those behind the near plane), finds on each row the exact run of pixel centers
within the blur radius (the ends of the row's crossing with the triangle grown by ``r``) and evaluates
runs 8 pixels at a time in vectorized loops, on torch's OpenMP threads. The forward pass sums per pixel,
image band by image band (one thread per band, the triangles in index order, so the image is the same
bit for bit for any thread count), ``log(1 + u)`` as the log of a running product (exactly renormalized:
one log per pixel rather than per pair) and returns ``-expm1(S)`` itself; the backward pass recomputes
the pairs triangle by triangle, sums the triangles' gradients per vertex and takes them through the
projection (to the vertices and to the camera's frame, eye and focal length). Its pair set is the exact
one (pairs within the radius), the eager scan's also holds the padding of its pieces, so the two differ
by about eps per pixel (the cutoff's own error). When the threads of a parallel region start late
(other processes hold the cores), the next calls run on one thread for a while, to the same result. Without
a C compiler, or for other dtypes and devices, it falls back to "eager".

The eager pair kernels are plain tensor functions. ``backend="compiled"`` runs them through
``torch.compile`` (needs a C++ compiler; the first call compiles for tens of seconds, later calls and
processes reuse the cache), which fuses each kernel into one loop. The default backend is "native", or
the value of the environment variable ``IPM_SOFT_BACKEND``.

Fitting hard masks: where a finely tessellated mesh meets its contour many triangles contribute, so
the 0.5 level of the soft silhouette lies a fraction of ``sqrt(sigma)`` outside the hard silhouette,
and a fit against hard masks at a fixed large sigma comes out slightly small. Anneal sigma towards
~0.05 px^2 at the end of a fit (tests/test_render_soft.py does) or compare soft with soft.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence

import torch

from ipm.errors import InputError
from ipm.render.camera import camera_frame, focal_pixels
from ipm.render.scan import check_mesh_tensors, span_rows, visible_triangles
from ipm.types import Camera, TriMesh

log = logging.getLogger(__name__)


def _edge_data(tri: torch.Tensor) -> torch.Tensor:
    """Per-triangle constants (27, F): for edge e (from vertex e to e+1) with start a, vector v, unit
    orientation o (edge functions >= 0 inside) and inv = 1/|v|^2, rows 9e .. 9e + 8 hold
    ax, ay, o vx, o vy, -o vy, vx inv, vy inv, -vx, -vy."""
    v = tri.roll(-1, dims=1) - tri
    area2 = v[:, 0, 0] * v[:, 1, 1] - v[:, 0, 1] * v[:, 1, 0]
    orient = torch.where(area2 < 0, -1.0, 1.0).to(tri.dtype)[:, None]
    inv = 1.0 / (v * v).sum(-1).clamp_min(torch.finfo(tri.dtype).tiny ** 0.5)
    rows = []
    for e in range(3):
        ax, ay = tri[:, e, 0], tri[:, e, 1]
        vx, vy = v[:, e, 0], v[:, e, 1]
        o = orient[:, 0]
        rows += [ax, ay, o * vx, o * vy, -o * vy, vx * inv[:, e], vy * inv[:, e], -vx, -vy]
    return torch.stack(rows)


def _constants(data: torch.Tensor, tri: torch.Tensor, yc: torch.Tensor, xc: torch.Tensor) -> torch.Tensor:
    """Per-piece constants (24, R) for pieces of triangles ``tri`` (R,) starting at pixel center (xc, yc):
    with x = x0 + k along the piece, cross = c0 + c1 k, t = clamp(t0 + t1 k, 0, 1), w = (x0 + k - t vx,
    dy - t vy), rows 8e .. 8e + 7 hold c0, c1, t0, t1, x0, dy, -vx, -vy of edge e."""
    g = data.index_select(1, tri)  # (27, R)
    out = torch.empty(24, tri.shape[0], dtype=data.dtype, device=data.device)
    for e in range(3):
        ax, ay, ox, oy, c1, t1, vyi, mvx, mvy = g[9 * e: 9 * e + 9]
        x0 = torch.sub(xc, ax, out=out[8 * e + 4])
        dy = torch.sub(yc, ay, out=out[8 * e + 5])
        torch.mul(ox, dy, out=out[8 * e]).addcmul_(c1, x0)
        torch.mul(x0, t1, out=out[8 * e + 2]).addcmul_(dy, vyi)
        out[8 * e + 1] = c1
        out[8 * e + 3] = t1
        out[8 * e + 6] = mvx
        out[8 * e + 7] = mvy
    return out


def _edge_eval(c: torch.Tensor, kcol: torch.Tensor):
    """(d2, t, wx, wy) of one edge for all pairs of the chunk, (K, R) each; c: its 8 constants (8, R)."""
    _, _, t0, t1, x0, dy, mvx, mvy = c
    t = torch.addcmul(t0, kcol, t1).clamp_(0.0, 1.0)
    wx = torch.addcmul(x0 + kcol, t, mvx)
    wy = torch.addcmul(dy, t, mvy)
    return torch.addcmul(wx * wx, wy, wy), t, wx, wy


def _pick(a: torch.Tensor, b: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """``b`` where the 0/1 mask ``m`` is 1, else ``a`` (arithmetic: cheaper than ``where`` in eager)."""
    return torch.addcmul(a, m, b - a)


def _forward_kernel(c, base, kcol, kidx, inv_sigma, need_grad: bool):
    """Pairs of one chunk of pieces. c: (24, R) from :func:`_constants`; base: (R,) flat index of each
    piece's first pixel; kcol, kidx: (K, 1) 0..K-1 as float and int64. Returns the flat pixel index
    (K, R), log(1 - D) (K, R) and, when ``need_grad``, what the backward pass needs: u = exp(-d^2/sigma),
    code = nearest edge (0/1/2) + 3 if inside, and the nearest edge's t, wx, wy, (K, R) each."""
    c = c[:, None, :]  # (24, 1, R): rows broadcast over the K pixels of each piece
    d0, t0, x0, y0 = _edge_eval(c[0:8], kcol)
    d1, t1, x1, y1 = _edge_eval(c[8:16], kcol)
    d2, t2, x2, y2 = _edge_eval(c[16:24], kcol)
    cmin = torch.minimum(torch.minimum(torch.addcmul(c[0], kcol, c[1]), torch.addcmul(c[8], kcol, c[9])),
                         torch.addcmul(c[16], kcol, c[17]))
    dt = c.dtype
    b01 = (d1 < d0).to(dt)
    best = torch.minimum(d0, d1)
    b2 = (d2 < best).to(dt)
    best = torch.minimum(best, d2)
    inside = (cmin >= 0).to(dt)
    x = best * inv_sigma
    u = torch.exp(-x.clamp(max=80.0))  # no denormals (slow on CPUs); exp(-80) is 0 for all purposes here
    # log(1 + u) rather than log1p: faster, and off by at most u < 6e-8 (float32) where 1 + u rounds to 1
    term = -torch.addcmul(torch.log(1.0 + u), inside, x)
    pix = kidx + base[None]
    if not need_grad:
        return pix, term, ()
    code = torch.addcmul(b01, b2, 2.0 - b01).add_(inside, alpha=3.0)  # nearest edge + 3 [inside]
    t = _pick(_pick(t0, t1, b01), t2, b2)
    wx = _pick(_pick(x0, x1, b01), x2, b2)
    wy = _pick(_pick(y0, y1, b01), y2, b2)
    return pix, term, (u, code, t, wx, wy)


def _backward_kernel(gS: torch.Tensor, base: torch.Tensor, kidx: torch.Tensor, u: torch.Tensor,
                     code: torch.Tensor, t: torch.Tensor, wx: torch.Tensor, wy: torch.Tensor,
                     inv_sigma: torch.Tensor) -> torch.Tensor:
    """Sums per piece (12, R): for edge e, rows 4e .. 4e + 3 hold sum g' w_x, sum g' w_y, sum g' t w_x,
    sum g' t w_y over the pairs whose nearest edge is e, with g' = -2 dL/d(d^2); gS: dL/dS (pixels,)."""
    g = torch.take(gS, kidx + base[None])
    inside = (code >= 3.0).to(code.dtype)
    idx = code - 3.0 * inside
    gg = g * ((u / (1.0 + u) - inside) * (-2.0 * inv_sigma))  # -2 dL/d term * d term / d d^2
    out = []
    for e in range(3):
        gm = gg * (idx == e).to(gg.dtype)
        ux = gm * wx
        uy = gm * wy
        out += [ux.sum(0), uy.sum(0), (ux * t).sum(0), (uy * t).sum(0)]
    return torch.stack(out)


_KERNELS: dict[str, tuple[Callable, Callable]] = {"eager": (_forward_kernel, _backward_kernel)}
BACKENDS = ("native", "eager", "compiled")


def _kernels(backend: str) -> tuple[Callable, Callable]:
    if backend not in _KERNELS:
        _KERNELS[backend] = (torch.compile(_forward_kernel, dynamic=True),
                             torch.compile(_backward_kernel, dynamic=True))
    return _KERNELS[backend]


class _SoftLogSum(torch.autograd.Function):
    """S (H, W + K) = per pixel, the sum over nearby triangles of log(1 - D); differentiable in
    tri_xy (F, 3, 2)."""

    @staticmethod
    def forward(ctx, tri_xy, groups, width, height, sigma, chunk, backend):
        """``S (H, W + K)``, the span groups in chunks of about ``chunk`` pixel-triangle pairs; keeps what
        the backward needs when ``tri_xy`` requires grad."""
        fwd, _ = _kernels(backend)
        need_grad = bool(ctx.needs_input_grad[0])
        data = _edge_data(tri_xy)
        dev, dt = tri_xy.device, tri_xy.dtype
        stride = width + max(g.k for g in groups)
        S = torch.zeros(height * stride, dtype=dt, device=dev)
        inv_sigma = torch.tensor(1.0 / sigma, dtype=dt, device=dev)
        saved = []
        for rows in groups:
            kcol = torch.arange(rows.k, dtype=dt, device=dev)[:, None]
            kidx = torch.arange(rows.k, device=dev)[:, None]
            yc = rows.j.to(dt) + 0.5
            xc = rows.i.to(dt) + 0.5
            base = rows.j * stride + rows.i
            step = max(1, chunk // rows.k)
            for lo in range(0, rows.n_rows, step):
                hi = min(rows.n_rows, lo + step)
                c = _constants(data, rows.tri[lo:hi], yc[lo:hi], xc[lo:hi])
                pix, term, keep = fwd(c, base[lo:hi], kcol, kidx, inv_sigma, need_grad)
                S.index_add_(0, pix.view(-1), term.view(-1))
                if need_grad:
                    saved.append((rows.tri[lo:hi], base[lo:hi], kidx, keep))
        ctx.saved = saved
        ctx.n_tri, ctx.backend, ctx.inv_sigma = tri_xy.shape[0], backend, inv_sigma
        return S.view(height, stride)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gS):
        """``dL/d tri_xy (F, 3, 2)`` from the kept pairs: each edge's sums go to its start and end vertices."""
        _, bwd = _kernels(ctx.backend)
        gS = gS.contiguous().view(-1)
        grad = torch.zeros(ctx.n_tri, 3, 2, dtype=gS.dtype, device=gS.device)
        for tri, base, kidx, keep in ctx.saved:
            sums = bwd(gS, base, kidx, *keep, ctx.inv_sigma).view(3, 4, -1)  # per edge: sx, sy, tx, ty (R,)
            sx, sy, tx, ty = sums.unbind(1)
            start = torch.stack([sx - tx, sy - ty], -1)  # (3, R, 2): to each edge's start vertex
            end = torch.stack([tx, ty], -1).roll(1, dims=0)  # edge e ends at vertex e + 1
            grad.index_add_(0, tri, (start + end).transpose(0, 1))
        return grad, None, None, None, None, None, None


class _SoftNative(torch.autograd.Function):
    """The soft silhouette (H, W) by the C kernel (backend "native", on torch's OpenMP threads), projection
    included: verts (V, 3), the camera's frame R (3, 3), eye (3,) and focal length fpx () (differentiable;
    see :func:`ipm.render.camera.project`), faces (F, 3) int64, the principal point (cx, cy) and ``near``
    (faces with a vertex nearer are dropped). The backward pass recomputes the pairs (no storage)."""

    @staticmethod
    def forward(ctx, verts, R, eye, fpx, faces, cx, cy, near, width, height, sigma, radius):
        """The silhouette ``(H, W)``; ``InputError`` for face indices out of range, ``MemoryError`` when the
        kernel runs out of memory."""
        dt, n_verts, n_faces = verts.dtype, verts.shape[0], faces.shape[0]
        v = verts.detach()
        cam = torch.cat([R.detach().reshape(9), eye.detach().reshape(3), fpx.detach().reshape(1),
                         torch.tensor([cx, cy], dtype=dt)])
        far = 1e3 * (max(width, height) + 2 + radius)  # as span_rows: only guard non-finite values
        tri = torch.empty(n_faces, 6, dtype=dt)
        rows = torch.empty(n_faces, 2, dtype=torch.int32)
        S = torch.empty(height, width + _VEC, dtype=dt)
        sil = torch.empty(height, width, dtype=dt)
        rc = _native_fn(dt, "fwd")(v, *v.stride(), n_verts, cam, near, faces, *faces.stride(), n_faces, width, height,
                                   radius, sigma, far, tri, rows, S, sil, *_native_threads(n_faces))
        if rc == -1:
            raise InputError(f"faces: expected vertex indices in [0, {n_verts}), got "
                             f"[{int(faces.min())}, {int(faces.max())}]")  # as check_mesh_tensors
        if rc:
            raise MemoryError("soft silhouette: the native kernel ran out of memory")
        ctx.saved = (v, cam, faces, tri, rows, S)
        ctx.args = (width, height, radius, sigma)
        return sil

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gsil):
        """Gradients for ``verts``, ``R``, ``eye`` and ``fpx`` by the C kernel (pairs recomputed); none for the rest."""
        v, cam, faces, tri, rows, S = ctx.saved
        width, height, radius, sigma = ctx.args
        dt, n_verts, n_faces = v.dtype, v.shape[0], faces.shape[0]
        gsil = gsil.to(dt).contiguous()
        gS = torch.empty(height, width + _VEC, dtype=dt)
        gtri = torch.empty(n_faces, 6, dtype=dt)
        gxy = torch.empty(n_verts, 2, dtype=dt)
        gverts = torch.empty(n_verts, 3, dtype=dt)
        gcam = torch.empty(13, dtype=dt)
        _native_fn(dt, "bwd")(v, *v.stride(), n_verts, cam, faces, *faces.stride(), n_faces, width, height, radius,
                              sigma, tri, rows, S, gsil, gS, gtri, gxy, gverts, gcam, *_native_threads(n_faces))
        return (gverts, gcam[:9].view(3, 3), gcam[9:12], gcam[12], None, None, None, None, None, None, None, None)


_VEC = 8  # VEC of ipm/native/soft_kernel.inc: padding columns of S and gS
_ADAPT_THREADS = True  # False: exactly the thread count asked for (tests)


def _native_threads(n_faces: int) -> tuple[int, int]:
    """(threads, whether the kernel may use fewer under contention (soft_threads in ipm/native/soft_kernel.inc))."""
    return max(1, min(torch.get_num_threads(), n_faces // 256)), int(_ADAPT_THREADS)


def _native_fn(dtype: torch.dtype, which: str):
    """The kernel's function ``soft_{which}_{f,d}`` for ``dtype``, with every tensor argument passed as its
    address (``ipm/native/soft.h`` declares the rest)."""
    k = _kernel()
    fn = getattr(k.lib, f"soft_{which}_{'f' if dtype == torch.float32 else 'd'}")

    def call(*args):
        return fn(*(k.ptr(a.data_ptr()) if torch.is_tensor(a) else a for a in args))

    return call


def native_available() -> bool:
    """Whether the C kernel of backend "native" is built (:mod:`ipm.native`: ``ipm/native/soft.c``, built on
    first use with a C compiler, about a second, and cached)."""
    return _kernel() is not None


def _kernel():
    from ipm import native

    return native.load("soft")


def blur_radius(sigma: float, eps: float) -> float:
    """Distance (pixels) beyond which ``D = sigmoid(-d^2 / sigma) < eps``."""
    return math.sqrt(sigma * math.log(1.0 / eps))


def soft_silhouette(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, sigma: float = 1.0, *,
                    eps: float = 1e-6, near: float = 1e-3, chunk: int = 1 << 18,
                    backend: str | None = None) -> torch.Tensor:
    """Soft silhouette (H, W) in [0, 1] of a triangle mesh (SoftRas; see the module docstring).

    verts: (V, 3) float32 or float64 (gradients flow to it and to the camera's tensors);
    faces: (F, 3) int64; camera: the view (its tensors are cast to the dtype and device of ``verts``);
    sigma: blur in squared pixels (at distance ``sqrt(sigma)`` px outside a triangle, D = sigmoid(-1));
    eps: pairs with ``D < eps`` are skipped (the dense formula differs by about eps per pixel at most);
    near: faces with a vertex nearer than this (world units along the view axis) are dropped;
    chunk: pairs evaluated at once (bounds memory; eager and compiled); backend: "native" (the C kernel;
    float32 and float64 on the CPU, else and without a C compiler "eager"), "eager" or "compiled"
    (torch.compile), default ``$IPM_SOFT_BACKEND`` or "native".
    Returns a tensor with the dtype and device of ``verts``.
    """
    backend = backend or os.environ.get("IPM_SOFT_BACKEND") or "native"
    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    native = (backend == "native" and torch.is_tensor(verts) and verts.device.type == "cpu"
              and verts.dtype in (torch.float32, torch.float64) and _kernel() is not None)
    if native and torch.is_tensor(faces) and faces.shape[-1:] == (3,) and faces.ndim == 2:
        check_mesh_tensors(verts, faces[:0])  # the kernel checks the vertex indices (it reads every face anyway)
    else:
        check_mesh_tensors(verts, faces)
    if not sigma > 0:
        raise InputError(f"sigma: expected a positive blur (squared pixels), got {sigma}")
    if not 0 < eps < 0.5:
        raise InputError(f"eps: expected a cutoff in (0, 0.5), got {eps}")
    W, H = int(camera.width), int(camera.height)
    if native:
        # the kernel projects (as camera.project), gathers the triangles and drops those behind the near
        # plane (as visible_triangles)
        cam = camera.to(dtype=verts.dtype, device=verts.device)
        cx, cy = cam.principal_point
        return _SoftNative.apply(verts, camera_frame(cam).to(verts.dtype), cam.eye.to(verts.dtype),
                                 focal_pixels(cam).to(verts.dtype), faces.to(torch.int64), float(cx), float(cy),
                                 float(near), W, H, float(sigma), blur_radius(sigma, eps))
    if backend == "native":
        backend = "eager"
    tri, _, _ = visible_triangles(verts, faces, camera, near)
    groups, kept = span_rows(tri, blur_radius(sigma, eps), W, H, backend)
    if not groups:
        return verts.sum() * 0 + torch.zeros(H, W, dtype=verts.dtype, device=verts.device)
    S = _SoftLogSum.apply(tri[kept], groups, W, H, float(sigma), int(chunk), backend)
    return -torch.expm1(S[:, :W])


def soft_silhouettes(mesh: TriMesh | tuple[torch.Tensor, torch.Tensor], cameras: Sequence[Camera],
                     sigma: float = 1.0, **kw) -> torch.Tensor:
    """Soft silhouettes (N, H, W) of one mesh in N views of one size (see :func:`soft_silhouette`)."""
    verts, faces = (mesh.verts, mesh.faces) if isinstance(mesh, TriMesh) else mesh
    if not cameras:
        raise InputError("cameras: expected at least one camera, got none")
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1:
        raise InputError(f"cameras: expected one image size, got {sorted(sizes)}")
    return torch.stack([soft_silhouette(verts, faces, c, sigma, **kw) for c in cameras])
