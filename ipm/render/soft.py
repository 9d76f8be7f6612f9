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

The default backend "native" does steps 2 to 5 in C (:data:`_NATIVE_C`, built with the system's C
compiler on first use in about a second and cached; loaded with ctypes): per triangle, the pixels of
each row within the blur radius (from its edges clipped to the row's slab, then the exact distance
test) are evaluated in vectorized loops and summed per pixel, on torch's OpenMP threads; the backward
pass recomputes the pairs. Its pair set is the exact one (pairs within the radius), the eager scan's
also holds the padding of its pieces, so the two differ by about eps per pixel (the cutoff's own error).
Without a C compiler, or for other dtypes and devices, it falls back to "eager".

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
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import torch

from ipm.errors import InputError
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

class _SoftLogSumNative(torch.autograd.Function):
    """S (H, W) = per pixel, the sum over nearby triangles of log(1 - D), by the C kernel (backend
    "native", on torch's OpenMP threads); differentiable in tri_xy (F, 3, 2). The backward pass recomputes
    the pairs (no storage)."""

    @staticmethod
    def forward(ctx, tri_xy, width, height, sigma, radius):
        far = 1e3 * (max(width, height) + 2 + radius)  # as span_rows: only guard non-finite values
        t = tri_xy.detach().nan_to_num(far, far, -far).clamp(-far, far).contiguous()
        n = max(1, min(torch.get_num_threads(), t.shape[0] // 256))
        S = torch.zeros(n, height * width, dtype=t.dtype)
        _native_fn(t)(t.data_ptr(), t.shape[0], width, height, radius, sigma, None, None, None, S.data_ptr(), n)
        ctx.tri, ctx.args = t, (width, height, radius, sigma)
        return (S.sum(0) if n > 1 else S[0]).view(height, width)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gS):
        t, (width, height, radius, sigma) = ctx.tri, ctx.args
        gS = gS.to(t.dtype).contiguous()
        grad = torch.zeros_like(t)
        n = max(1, min(torch.get_num_threads(), t.shape[0] // 256))
        _native_fn(t)(t.data_ptr(), t.shape[0], width, height, radius, sigma, None, gS.data_ptr(),
                      grad.data_ptr(), None, n)
        return grad, None, None, None, None


def _native_fn(t: torch.Tensor):
    lib = _native_lib()
    return lib.soft_par_f if t.dtype == torch.float32 else lib.soft_par_d


_LOCK = threading.Lock()
_NATIVE: list = []  # [the loaded library, or None when it cannot be built]
# compile flags: vectorized exp and log need -ffast-math at compile time (glibc's libmvec); the link
# step goes without it (it would set flush-to-zero for the whole process); plain -O3 as the fallback
_NATIVE_FLAGS = ((["-O3", "-march=native", "-ffast-math", "-fopenmp"], ["-fopenmp", "-lmvec", "-lm"]),
                 (["-O3", "-march=native", "-fopenmp"], ["-fopenmp", "-lm"]))


def native_available() -> bool:
    """Whether the C kernel of backend "native" is built (builds it on first use: a C compiler, ``$CC``
    or ``cc``, about a second; cached under ``$IPM_CACHE_DIR`` or ``~/.cache/ipm``)."""
    return _native_lib() is not None


def _native_lib():
    with _LOCK:
        if not _NATIVE:
            try:
                _NATIVE.append(_build_native())
            except (OSError, RuntimeError) as e:
                log.info("soft silhouette: the native kernel is unavailable (%s); using eager", e)
                _NATIVE.append(None)
        return _NATIVE[0]


def _build_native():
    import ctypes
    import hashlib
    import platform
    import shutil
    import subprocess
    import tempfile

    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise RuntimeError(f"no C compiler {cc!r}")
    src = "".join(_NATIVE_INSTANCE.format(real=r, suffix=x, exp=e, log=lg, tiny=tn) + _NATIVE_C
                  for r, x, e, lg, tn in (("float", "f", "expf", "logf", "1.0842021724855044e-19f"),
                                          ("double", "d", "exp", "log", "1.4916681462400413e-154")))
    cpu = ""
    try:
        cpu = next((ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags")), "")
    except OSError:
        pass
    key = hashlib.sha256("\0".join([src, cc, repr(_NATIVE_FLAGS), cpu, platform.machine()]).encode())
    cache = Path(os.environ.get("IPM_CACHE_DIR") or Path.home() / ".cache" / "ipm")
    lib = cache / f"soft_native_{key.hexdigest()[:16]}.so"
    if not lib.is_file():
        cache.mkdir(parents=True, exist_ok=True)
        errors = []
        with tempfile.TemporaryDirectory(dir=cache) as tmp:
            (Path(tmp) / "soft.c").write_text(src)
            for cflags, libs in _NATIVE_FLAGS:
                obj, so = Path(tmp) / "soft.o", Path(tmp) / "soft.so"
                r = subprocess.run([cc, *cflags, "-fPIC", "-c", str(Path(tmp) / "soft.c"), "-o", str(obj)],
                                   capture_output=True, text=True)
                if r.returncode == 0:
                    r = subprocess.run([cc, "-shared", str(obj), "-o", str(so), *libs], capture_output=True,
                                       text=True)
                if r.returncode == 0:
                    os.replace(so, lib)  # atomic: concurrent builders write the same file
                    break
                errors.append(r.stderr.strip().splitlines()[-1:] or ["?"])
            else:
                raise RuntimeError(f"{cc} failed: {errors}")
        log.info("soft silhouette: built the native kernel %s", lib)
    dll = ctypes.CDLL(str(lib))
    for fn in (dll.soft_par_f, dll.soft_par_d):
        fn.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_int, ctypes.c_double,
                       ctypes.c_double, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                       ctypes.c_int]
        fn.restype = None
    return dll


_NATIVE_INSTANCE = """
#undef REAL
#undef NAME
#undef EXP
#undef LOG
#undef TINY
#undef PAIR_GEOMETRY
#define REAL {real}
#define NAME(x) x##_{suffix}
#define EXP {exp}
#define LOG {log}
#define TINY {tiny}
"""

_NATIVE_C = r"""/* The soft silhouette's pair loop in C (ipm/render/soft.py, backend "native"): one triangle at a time,
   its pairs gathered row by row into a buffer that one loop evaluates (vectorized by the compiler).
   Compiled once per REAL (float, double); the formulas are those of the eager kernels. */
#include <math.h>
#include <omp.h>
#include <stdint.h>

#define CAP 256
#define VEC 16  /* divides CAP */

typedef struct { REAL ax[3], ay[3], ox[3], c1[3], t1[3], vyi[3], vx[3], vy[3]; } NAME(Edges);

static void NAME(edges_of)(const REAL *p, NAME(Edges) *E) {
    REAL vx[3], vy[3];
    for (int e = 0; e < 3; e++) {
        vx[e] = p[2 * ((e + 1) % 3)] - p[2 * e];
        vy[e] = p[2 * ((e + 1) % 3) + 1] - p[2 * e + 1];
    }
    REAL o = (vx[0] * vy[1] - vy[0] * vx[1]) < 0 ? -1 : 1;
    for (int e = 0; e < 3; e++) {
        REAL n2 = vx[e] * vx[e] + vy[e] * vy[e];
        REAL inv = 1 / (n2 > TINY ? n2 : TINY);
        E->ax[e] = p[2 * e]; E->ay[e] = p[2 * e + 1];
        E->ox[e] = o * vx[e]; E->c1[e] = -o * vy[e];
        E->t1[e] = vx[e] * inv; E->vyi[e] = vy[e] * inv;
        E->vx[e] = vx[e]; E->vy[e] = vy[e];
    }
}

/* rows j0 .. j1 within reach of the triangle (the count; <= 0 for none) */
static int64_t NAME(rows_of)(const REAL *p, double r, int H, int64_t *j0, int64_t *j1) {
    double ymin = fmin(p[1], fmin(p[3], p[5])), ymax = fmax(p[1], fmax(p[3], p[5]));
    double a = ceil(ymin - r - 0.5), b = floor(ymax + r - 0.5);
    if (a > H - 1 || b < 0) return 0;
    *j0 = a < 0 ? 0 : (int64_t)a;
    *j1 = b > H - 1 ? H - 1 : (int64_t)b;
    return *j1 - *j0 + 1;
}

/* the edges for cols_of: start x, start y, dx, 1 / dy (0 for flat edges), flat */
typedef struct { double ax[3], ay[3], dx[3], inv_dy[3]; int flat[3]; } NAME(Slab);

static void NAME(slab_of)(const REAL *p, NAME(Slab) *L) {
    for (int e = 0; e < 3; e++) {
        double ax = p[2 * e], ay = p[2 * e + 1], dy = p[2 * ((e + 1) % 3) + 1] - ay;
        L->ax[e] = ax; L->ay[e] = ay; L->dx[e] = p[2 * ((e + 1) % 3)] - ax;
        L->flat[e] = dy == 0;
        L->inv_dy[e] = dy == 0 ? 0 : 1 / dy;
    }
}

/* columns i0 .. i1 of the row at yc within reach: the x-extent of the triangle inside the slab
   |y - yc| <= r (attained on its edges clipped to the slab), widened by r; 0 if none */
static int NAME(cols_of)(const NAME(Slab) *L, double yc, double r, int W, int64_t *i0, int64_t *i1) {
    double lo = INFINITY, hi = -INFINITY, y0 = yc - r, y1 = yc + r;
    for (int e = 0; e < 3; e++) {
        double ay = L->ay[e], s0, s1;
        if (L->flat[e]) {
            if (ay < y0 || ay > y1) continue;
            s0 = 0; s1 = 1;
        } else {
            s0 = (y0 - ay) * L->inv_dy[e]; s1 = (y1 - ay) * L->inv_dy[e];
            if (s0 > s1) { double s = s0; s0 = s1; s1 = s; }
            s0 = s0 < 0 ? 0 : s0;
            s1 = s1 > 1 ? 1 : s1;
            if (s0 > s1) continue;
        }
        double xa = L->ax[e] + s0 * L->dx[e], xb = L->ax[e] + s1 * L->dx[e];
        if (xa > xb) { double x = xa; xa = xb; xb = x; }
        lo = xa < lo ? xa : lo;
        hi = xb > hi ? xb : hi;
    }
    if (!(lo <= hi)) return 0;
    double a = ceil(lo - r - 0.5), b = floor(hi + r - 0.5);
    if (a > W - 1 || b < 0) return 0;
    *i0 = a < 0 ? 0 : (int64_t)a;
    *i1 = b > W - 1 ? W - 1 : (int64_t)b;
    return 1;
}

/* per pair k: the nearest edge (squared distance best, index near, its t and w = (bwx, bwy)), whether
   the pixel is inside, whether it is within reach (keep), x = best / sigma and u = exp(-x) */
#define PAIR_GEOMETRY                                                                              \
    REAL best = 0, bt = 0, bwx = 0, bwy = 0, cmin = 0;                                             \
    int near = 0;                                                                                  \
    for (int e = 0; e < 3; e++) {                                                                  \
        REAL x0 = px[k] - E->ax[e], dy = py[k] - E->ay[e];                                         \
        REAL c = E->ox[e] * dy + E->c1[e] * x0;                                                    \
        REAL t = x0 * E->t1[e] + dy * E->vyi[e];                                                   \
        t = t < 0 ? 0 : (t > 1 ? 1 : t);                                                           \
        REAL wx = x0 - t * E->vx[e], wy = dy - t * E->vy[e];                                       \
        REAL d2 = wx * wx + wy * wy;                                                               \
        int take = e == 0 || d2 < best;                                                            \
        best = take ? d2 : best; bt = take ? t : bt; bwx = take ? wx : bwx; bwy = take ? wy : bwy; \
        near = take ? e : near;                                                                    \
        cmin = (e == 0 || c < cmin) ? c : cmin;                                                    \
    }                                                                                              \
    REAL inside = cmin >= 0 ? 1 : 0;                                                               \
    REAL keep = (cmin >= 0 || best <= r2) && k < n ? 1 : 0;                                                 \
    REAL x = best * inv_sigma;                                                                     \
    REAL u = EXP(-(x < 80 ? x : 80));

/* the buffers hold n pairs; loops run to m, n rounded up to whole vectors (no scalar remainder: it
   would call the scalar exp and log), the pairs past n count for nothing */
static void NAME(fwd_flush)(const NAME(Edges) *E, const REAL *px, const REAL *py, const int64_t *idx,
                            int n, REAL r2, REAL inv_sigma, REAL *S) {
    REAL term[CAP];
    int m = (n + VEC - 1) / VEC * VEC;
#pragma omp simd
    for (int k = 0; k < m; k++) {
        PAIR_GEOMETRY
        term[k] = -keep * (LOG(1 + u) + inside * x);
    }
    for (int k = 0; k < n; k++) S[idx[k]] += term[k];
}

static void NAME(bwd_flush)(const NAME(Edges) *E, const REAL *px, const REAL *py, const int64_t *idx,
                            int n, REAL r2, REAL inv_sigma, const REAL *gS, REAL *g) {
    REAL gk[CAP];
    int m = (n + VEC - 1) / VEC * VEC;
    for (int k = 0; k < n; k++) gk[k] = gS[idx[k]];
    for (int k = n; k < m; k++) gk[k] = 0;
    REAL sx0 = 0, sy0 = 0, tx0 = 0, ty0 = 0, sx1 = 0, sy1 = 0, tx1 = 0, ty1 = 0;
    REAL sx2 = 0, sy2 = 0, tx2 = 0, ty2 = 0;
#pragma omp simd reduction(+ : sx0, sy0, tx0, ty0, sx1, sy1, tx1, ty1, sx2, sy2, tx2, ty2)
    for (int k = 0; k < m; k++) {
        PAIR_GEOMETRY
        REAL gg = keep * gk[k] * ((u / (1 + u) - inside) * (-2 * inv_sigma));  /* -2 dL/d(d^2) */
        REAL ux = gg * bwx, uy = gg * bwy;
        REAL m0 = near == 0 ? 1 : 0, m1 = near == 1 ? 1 : 0, m2 = near == 2 ? 1 : 0;
        sx0 += m0 * ux; sy0 += m0 * uy; tx0 += m0 * ux * bt; ty0 += m0 * uy * bt;
        sx1 += m1 * ux; sy1 += m1 * uy; tx1 += m1 * ux * bt; ty1 += m1 * uy * bt;
        sx2 += m2 * ux; sy2 += m2 * uy; tx2 += m2 * ux * bt; ty2 += m2 * uy * bt;
    }
    /* edge e runs from vertex e to vertex e + 1: d(d^2) = -2 w . ((1 - t) da + t db) */
    g[0] += sx0 - tx0 + tx2; g[1] += sy0 - ty0 + ty2;
    g[2] += sx1 - tx1 + tx0; g[3] += sy1 - ty1 + ty0;
    g[4] += sx2 - tx2 + tx1; g[5] += sy2 - ty2 + ty1;
}

/* Triangles lo .. hi - 1 of tri (F, 3, 2). Forward (gS == 0): S (H * W) += per pixel, the sum of
   log(1 - D). Backward: grad rows lo .. hi - 1 = d(sum_p gS[p] S[p]) / d tri. */
void NAME(soft)(const REAL *tri, int64_t lo, int64_t hi, int W, int H, double r, double sigma, REAL *S,
                const REAL *gS, REAL *grad) {
    REAL px[CAP] = {0}, py[CAP] = {0};
    int64_t idx[CAP];
    REAL r2 = (REAL)(r * r), inv_sigma = (REAL)(1.0 / sigma);
    for (int64_t f = lo; f < hi; f++) {
        const REAL *p = tri + 6 * f;
        REAL *g = gS ? grad + 6 * f : 0;
        if (g) for (int q = 0; q < 6; q++) g[q] = 0;
        int64_t j0, j1, i0, i1;
        if (NAME(rows_of)(p, r, H, &j0, &j1) <= 0) continue;
        NAME(Edges) E;
        NAME(edges_of)(p, &E);
        NAME(Slab) L;
        NAME(slab_of)(p, &L);
        int n = 0;
        for (int64_t j = j0; j <= j1; j++) {
            if (!NAME(cols_of)(&L, (double)j + 0.5, r, W, &i0, &i1)) continue;
            for (int64_t i = i0; i <= i1; i++) {
                px[n] = (REAL)i + (REAL)0.5; py[n] = (REAL)j + (REAL)0.5; idx[n] = j * W + i;
                if (++n == CAP) {
                    if (g) NAME(bwd_flush)(&E, px, py, idx, n, r2, inv_sigma, gS, g);
                    else NAME(fwd_flush)(&E, px, py, idx, n, r2, inv_sigma, S);
                    n = 0;
                }
            }
        }
        if (n && g) NAME(bwd_flush)(&E, px, py, idx, n, r2, inv_sigma, gS, g);
        else if (n) NAME(fwd_flush)(&E, px, py, idx, n, r2, inv_sigma, S);
    }
}

/* All F triangles on nt threads of the OpenMP pool (torch's own: the process loads one libgomp), in
   blocks of 64: the forward pass statically (each thread sums into its own buffer, then the buffers
   are added in thread order: the same result every run), the backward pass dynamically (each triangle's
   gradient is its own sum: any schedule gives the same result). */
void NAME(soft_par)(const REAL *tri, int64_t F, int W, int H, double r, double sigma, REAL *S,
                    const REAL *gS, REAL *grad, REAL *buffers, int nt) {
    int64_t nb = (F + 63) / 64;
    if (gS) {
#pragma omp parallel for schedule(dynamic, 1) num_threads(nt)
        for (int64_t b = 0; b < nb; b++)
            NAME(soft)(tri, 64 * b, 64 * b + 64 < F ? 64 * b + 64 : F, W, H, r, sigma, 0, gS, grad);
        return;
    }
#pragma omp parallel num_threads(nt)
    {
        REAL *mine = buffers + (int64_t)omp_get_thread_num() * W * H;
#pragma omp for schedule(static, 4)
        for (int64_t b = 0; b < nb; b++)
            NAME(soft)(tri, 64 * b, 64 * b + 64 < F ? 64 * b + 64 : F, W, H, r, sigma, mine, 0, 0);
    }
}
"""


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
    check_mesh_tensors(verts, faces)
    backend = backend or os.environ.get("IPM_SOFT_BACKEND") or "native"
    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    if not sigma > 0:
        raise InputError(f"sigma: expected a positive blur (squared pixels), got {sigma}")
    if not 0 < eps < 0.5:
        raise InputError(f"eps: expected a cutoff in (0, 0.5), got {eps}")
    W, H = int(camera.width), int(camera.height)
    tri, _, _ = visible_triangles(verts, faces, camera, near)
    if backend == "native":
        if (verts.device.type == "cpu" and verts.dtype in (torch.float32, torch.float64)
                and _native_lib() is not None):
            S = _SoftLogSumNative.apply(tri, W, H, float(sigma), blur_radius(sigma, eps))
            return -torch.expm1(S)
        backend = "eager"
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
