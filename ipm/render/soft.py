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

The default backend "native" does steps 1 to 5 in C (:data:`_NATIVE_C`, built with the system's C
compiler on first use in about a second and cached; loaded with ctypes): it projects the vertices (as
:func:`ipm.render.camera.project`, whose matrix product torch would hand to a threaded BLAS), gathers
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
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

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


class _SoftNative(torch.autograd.Function):
    """The soft silhouette (H, W) by the C kernel (backend "native", on torch's OpenMP threads), projection
    included: verts (V, 3), the camera's frame R (3, 3), eye (3,) and focal length fpx () (differentiable;
    see :func:`ipm.render.camera.project`), faces (F, 3) int64, the principal point (cx, cy) and ``near``
    (faces with a vertex nearer are dropped). The backward pass recomputes the pairs (no storage)."""

    @staticmethod
    def forward(ctx, verts, R, eye, fpx, faces, cx, cy, near, width, height, sigma, radius):
        dt, n_verts, n_faces = verts.dtype, verts.shape[0], faces.shape[0]
        v = verts.detach()
        cam = torch.cat([R.detach().reshape(9), eye.detach().reshape(3), fpx.detach().reshape(1),
                         torch.tensor([cx, cy], dtype=dt)])
        far = 1e3 * (max(width, height) + 2 + radius)  # as span_rows: only guard non-finite values
        tri = torch.empty(n_faces, 6, dtype=dt)
        rows = torch.empty(n_faces, 2, dtype=torch.int32)
        S = torch.empty(height, width + _VEC, dtype=dt)
        sil = torch.empty(height, width, dtype=dt)
        rc = _native_fn(dt, "fwd")(v.data_ptr(), *v.stride(), n_verts, cam.data_ptr(), near, faces.data_ptr(),
                                   *faces.stride(), n_faces, width, height, radius, sigma, far, tri.data_ptr(),
                                   rows.data_ptr(), S.data_ptr(), sil.data_ptr(), *_native_threads(n_faces))
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
        v, cam, faces, tri, rows, S = ctx.saved
        width, height, radius, sigma = ctx.args
        dt, n_verts, n_faces = v.dtype, v.shape[0], faces.shape[0]
        gsil = gsil.to(dt).contiguous()
        gS = torch.empty(height, width + _VEC, dtype=dt)
        gtri = torch.empty(n_faces, 6, dtype=dt)
        gxy = torch.empty(n_verts, 2, dtype=dt)
        gverts = torch.empty(n_verts, 3, dtype=dt)
        gcam = torch.empty(13, dtype=dt)
        _native_fn(dt, "bwd")(v.data_ptr(), *v.stride(), n_verts, cam.data_ptr(), faces.data_ptr(), *faces.stride(),
                              n_faces, width, height, radius, sigma, tri.data_ptr(), rows.data_ptr(), S.data_ptr(),
                              gsil.data_ptr(), gS.data_ptr(), gtri.data_ptr(), gxy.data_ptr(), gverts.data_ptr(),
                              gcam.data_ptr(), *_native_threads(n_faces))
        return (gverts, gcam[:9].view(3, 3), gcam[9:12], gcam[12], None, None, None, None, None, None, None, None)


_VEC = 8  # VEC of _NATIVE_C: padding columns of S and gS
_ADAPT_THREADS = True  # False: exactly the thread count asked for (tests)


def _native_threads(n_faces: int) -> tuple[int, int]:
    """(threads, whether the kernel may use fewer under contention (see soft_threads in _NATIVE_C))."""
    return max(1, min(torch.get_num_threads(), n_faces // 256)), int(_ADAPT_THREADS)


def _native_fn(dtype: torch.dtype, which: str):
    return getattr(_native_lib(), f"soft_{which}_{'f' if dtype == torch.float32 else 'd'}")


_LOCK = threading.Lock()
_NATIVE: list = []  # [the loaded library, or None when it cannot be built]
# Compile flags that give the same bits on every CPU (issue #28): IEEE arithmetic as written, with no fused
# multiply-adds the compiler picks (-ffp-contract=off) and no reassociation (no -ffast-math: with it the
# vector width, which -march=native sets per CPU, decided the order of sums); the float kernel's exp is its
# own polynomial (expneg), the same operations everywhere. -march=native then only chooses how fast: built
# for AVX-512 and for AVX2 (-march=x86-64-v3) the kernel gave the same image and gradient bit for bit, at
# 4.4 and 6.5 ms for the 6k-face dishes mug at 128^2 forward + backward, one thread, where -ffast-math and
# -march=native took 3.1 ms (AMD EPYC, 2026-11-27, best of 15; tests/test_render_soft_native.py checks
# the flags).
_IEEE = ["-fno-math-errno", "-fno-trapping-math", "-ffp-contract=off", "-fopenmp"]
_NATIVE_FLAGS = ((["-O3", "-march=native", *_IEEE], ["-fopenmp", "-lm"]),
                 (["-O3", *_IEEE], ["-fopenmp", "-lm"]))


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
    src = "".join(_NATIVE_INSTANCE.format(**kw) + _NATIVE_C for kw in _NATIVE_TYPES)
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
    p, i64, i32, f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int, ctypes.c_double
    for x in "fd":
        fwd, bwd = getattr(dll, f"soft_fwd_{x}"), getattr(dll, f"soft_bwd_{x}")
        fwd.argtypes = [p, i64, i64, i64, p, f64, p, i64, i64, i64, i32, i32, f64, f64, f64, p, p, p, p, i32, i32]
        bwd.argtypes = [p, i64, i64, i64, p, p, i64, i64, i64, i32, i32, f64, f64, p, p, p, p, p, p, p, p, p,
                        i32, i32]
        fwd.restype, bwd.restype = ctypes.c_int, None
    return dll


# the two instances of _NATIVE_C: float (exp(-x) inlined, see expneg) and double
_NATIVE_TYPES = (
    {"real": "float", "suffix": "f", "exp": "expf", "expm1": "expm1f", "log": "logf",
     "tiny": "1.0842021724855044e-19f", "uint": "uint32_t", "expbits": "0x7f800000u", "signbit": "0x80000000u",
     "fastexp": 1},
    {"real": "double", "suffix": "d", "exp": "exp", "expm1": "expm1", "log": "log",
     "tiny": "1.4916681462400413e-154", "uint": "uint64_t", "expbits": "0x7ff0000000000000ull",
     "signbit": "0x8000000000000000ull", "fastexp": 0},
)


_NATIVE_INSTANCE = """
#undef REAL
#undef NAME
#undef EXP
#undef EXPM1
#undef LOG
#undef TINY
#undef UINT
#undef EXPBITS
#undef SIGNBIT
#undef FASTEXP
#undef VEC
#undef RUNS
#undef EDGE
#undef PAIR_GEOMETRY
#undef FOR_TRIANGLE_RUNS
#define REAL {real}
#define NAME(x) x##_{suffix}
#define EXP {exp}
#define EXPM1 {expm1}
#define LOG {log}
#define TINY {tiny}
#define UINT {uint}
#define EXPBITS {expbits}
#define SIGNBIT {signbit}
#define FASTEXP {fastexp}
"""

_NATIVE_C = r"""/* The soft silhouette in C (ipm/render/soft.py, backend "native"), from the vertices and the camera
   (the projection is done here too). Pixels are evaluated a row run at a time (the run: the pixels
   within reach, exactly), VEC consecutive pixels at once (one vector; lanes past the run, or out of
   reach, count for nothing) read and written in place: S and gS rows have VEC padding columns. The
   forward pass splits the image into bands of rows, each summed by one thread over its triangles in
   index order: every pixel's sum has the same terms in the same order whatever the bands and
   threads, so the image is the same bit for bit. The backward pass goes by triangles (each gradient
   is its own sum), then sums them per vertex in face order. Compiled once per REAL (float, double);
   the formulas are those of the eager kernels. */
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define VEC 8

#ifndef SOFT_SHARED
#define SOFT_SHARED
#include <stdatomic.h>
/* Threads under contention. A parallel region ends when all its threads are done, and when other
   processes hold the cores a thread can wait a scheduler time slice (milliseconds) for one, while
   libgomp's waiting threads spin. So when a thread of a region starts late (by 0.5 ms), the next calls
   run on one thread (the results do not depend on the thread count): 2, 4, ... up to 64 calls while it
   goes on, then the thread count asked for again. Only regions that follow one of ours by less than
   1 ms count: libgomp's threads sleep after a few milliseconds without work, and waking one can take
   milliseconds too (measured on a virtual machine), which is no sign of contention. */
#define MAXT 256
static atomic_int soft_skip, soft_streak;
static _Atomic double soft_last_end;

static int soft_threads(int nt) {
    if (nt <= 1) return 1;
    if (atomic_load_explicit(&soft_skip, memory_order_relaxed) > 0) {
        atomic_fetch_sub_explicit(&soft_skip, 1, memory_order_relaxed);
        return 1;
    }
    return nt < MAXT ? nt : MAXT;
}

/* after a region of nt threads that began at t0, thread i starting at start[i] */
static void soft_started(int nt, const double *start, double t0) {
    if (nt <= 1) return;
    double prev = atomic_exchange_explicit(&soft_last_end, omp_get_wtime(), memory_order_relaxed);
    if (t0 - prev > 1e-3) return;
    double late = 0;
    for (int i = 0; i < nt; i++) late = start[i] - t0 > late ? start[i] - t0 : late;
    int streak = atomic_load_explicit(&soft_streak, memory_order_relaxed);
    streak = late > 5e-4 ? (streak < 6 ? streak + 1 : 6) : 0;
    atomic_store_explicit(&soft_streak, streak, memory_order_relaxed);
    if (streak) atomic_store_explicit(&soft_skip, 1 << streak, memory_order_relaxed);
}
#endif


#if FASTEXP
/* exp(-x) for 0 <= x <= 80 in float (Cephes' expf: x = n ln 2 + f, |f| <= ln 2 / 2, exp(f) by its
   polynomial, 2^n by the exponent bits; about 1 ulp), inlined so that the pair loops stay vectorized */
static inline float NAME(expneg)(float x) {
    float a = -x, n = rintf(a * 1.44269504088896341f);
    /* Cody and Waite's two-part ln 2 (its first part has few bits: n * 0.693359375 is exact), not a
       fused multiply-add, which not every CPU has: the same result on all of them */
    float f = a - n * 0.693359375f;
    f = f - n * -2.12194440e-4f;
    float p = 1.9875691500e-4f;
    p = p * f + 1.3981999507e-3f;
    p = p * f + 8.3334519073e-3f;
    p = p * f + 4.1665795894e-2f;
    p = p * f + 1.6666665459e-1f;
    p = p * f + 5.0000001201e-1f;
    p = p * (f * f) + f + 1.0f;
    int32_t e = ((int32_t)n + 127) << 23;
    float s;
    memcpy(&s, &e, sizeof s);
    return p * s;
}
#else
static inline REAL NAME(expneg)(REAL x) { return EXP(-x); }
#endif

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

/* v with NaN as far and values beyond +-far (infinities too) as +-far, like span_rows; by the bits:
   -ffast-math lets the compiler assume finite values */
static inline REAL NAME(guard)(REAL v, REAL far) {
    UINT b;
    memcpy(&b, &v, sizeof b);
    if ((b & EXPBITS) == EXPBITS) return (b & ~(EXPBITS | SIGNBIT)) ? far : ((b & SIGNBIT) ? -far : far);
    return v > far ? far : (v < -far ? -far : v);
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

/* the pixels within reach of a triangle, row by row, exactly: the set within distance r of a triangle
   is convex and bounded by its edges moved out by r and arcs about its vertices, so on a row its ends are
   the extreme crossings of the row with the moved edges and the vertices' circles (every crossing lies in
   the set); a margin of 1e-3 px covers rounding */
#define RUNS 16  /* rows at a time */
typedef struct { double vx[3], vy[3], sx[3], sy[3], dx[3], inv[3], ok[3]; } NAME(Hull);

static void NAME(hull_of)(const REAL *p, double r, NAME(Hull) *Q) {
    /* the normals (dy, -dx) point out of triangles of positive area (and to both sides of a segment:
       its edges run both ways) */
    double area2 = ((double)p[2] - p[0]) * ((double)p[5] - p[1]) - ((double)p[3] - p[1]) * ((double)p[4] - p[0]);
    double out = area2 < 0 ? -r : r;
    for (int e = 0; e < 3; e++) {
        double ax = p[2 * e], ay = p[2 * e + 1];
        double dx = p[2 * ((e + 1) % 3)] - ax, dy = p[2 * ((e + 1) % 3) + 1] - ay;
        double len = sqrt(dx * dx + dy * dy);
        double nx = len > 0 ? out * dy / len : 0, ny = len > 0 ? -out * dx / len : 0;
        Q->vx[e] = ax; Q->vy[e] = ay;
        Q->sx[e] = ax + nx;
        Q->sy[e] = ay + ny;
        Q->dx[e] = dx;
        Q->ok[e] = dy != 0 ? 1 : 0;
        Q->inv[e] = dy != 0 ? 1 / dy : 0;
    }
}

/* columns i0[k] .. i1[k] (i0 > i1 for none) of row j + k within reach, k < RUNS */
static void NAME(runs_of)(const NAME(Hull) *Q, int64_t j, double r, int W, int64_t *i0, int64_t *i1) {
    double r2 = r * r, big = 1e300;
#pragma omp simd
    for (int k = 0; k < RUNS; k++) {
        double yc = (double)(j + k) + 0.5, lo = big, hi = -big;
        for (int v = 0; v < 3; v++) {
            double dy = Q->vy[v] - yc, h2 = r2 - dy * dy;
            double h = sqrt(h2 > 0 ? h2 : 0);
            double a = Q->vx[v] - h, b = Q->vx[v] + h;
            lo = h2 >= 0 && a < lo ? a : lo;
            hi = h2 >= 0 && b > hi ? b : hi;
        }
        for (int s = 0; s < 3; s++) {
            double t = (yc - Q->sy[s]) * Q->inv[s];
            double x = Q->sx[s] + t * Q->dx[s];
            int in = Q->ok[s] > 0 && t >= 0 && t <= 1;
            lo = in && x < lo ? x : lo;
            hi = in && x > hi ? x : hi;
        }
        double a = ceil(lo - 0.5 - 1e-3), b = floor(hi - 0.5 + 1e-3);
        a = a < 0 ? 0 : a;
        b = b > W - 1 ? W - 1 : b;
        int none = !(lo <= hi) || a > b;
        i0[k] = none ? 1 : (int64_t)a;
        i1[k] = none ? 0 : (int64_t)b;
    }
}

/* per pair (pixel center (fx + k, fy)): per edge e its squared distance d_e, t_e and w_e = (wx_e, wy_e);
   the nearest edge (squared distance best; on ties the first), whether the pixel is inside, whether the
   pair counts (keep: lane k < n, and inside or within reach), x = best / sigma and u = exp(-x). Written
   out per edge: the compiler vectorizes the loop over k only when nothing in it branches. */
#define EDGE(e)                                                                                    \
    REAL x0_##e = (fx + (REAL)k) - E->ax[e], dy_##e = fy - E->ay[e];                               \
    REAL c_##e = E->ox[e] * dy_##e + E->c1[e] * x0_##e;                                            \
    REAL t_##e = x0_##e * E->t1[e] + dy_##e * E->vyi[e];                                           \
    t_##e = t_##e < 0 ? 0 : (t_##e > 1 ? 1 : t_##e);                                               \
    REAL wx_##e = x0_##e - t_##e * E->vx[e], wy_##e = dy_##e - t_##e * E->vy[e];                   \
    REAL d_##e = wx_##e * wx_##e + wy_##e * wy_##e;
#define PAIR_GEOMETRY                                                                              \
    EDGE(0) EDGE(1) EDGE(2)                                                                        \
    REAL best01 = d_1 < d_0 ? d_1 : d_0, best = d_2 < best01 ? d_2 : best01;                       \
    REAL cmin = c_1 < c_0 ? c_1 : c_0;                                                             \
    cmin = c_2 < cmin ? c_2 : cmin;                                                                \
    REAL inside = cmin >= 0 ? 1 : 0;                                                               \
    REAL keep = (cmin >= 0 || best <= r2) && k < n ? 1 : 0;                                        \
    REAL x = best * inv_sigma;                                                                     \
    REAL u = NAME(expneg)(x < 80 ? x : 80);

/* one vector of a row run, for the pairs k < n that count: out[k] += log(1 - D), in two parts: the
   product of the factors 1 / (1 + u) (the reciprocal kept in prod[k], between 1 and 2: halved with
   out[k] -= ln 2 when it reaches 2, exactly) and the rest (-x inside); log(prod) is taken once per pixel
   at the end */
static inline void NAME(fwd_vec)(const NAME(Edges) *E, REAL fx, REAL fy, int n, REAL r2, REAL inv_sigma,
                                 REAL *out, REAL *prod) {
#pragma omp simd simdlen(VEC)
    for (int k = 0; k < VEC; k++) {
        PAIR_GEOMETRY
        REAL q = prod[k] * (1 + keep * u);
        REAL half = q >= 2 ? 1 : 0;
        prod[k] = q * (1 - (REAL)0.5 * half);
        out[k] -= keep * inside * x + half * (REAL)0.69314718055994530942;
    }
}

/* one vector of a row run, backward: acc[q][k] += the pair's share of the gradient of vertex q / 2,
   coordinate q % 2, given gS (dL/dS) along the run */
static inline void NAME(bwd_vec)(const NAME(Edges) *E, REAL fx, REAL fy, int n, REAL r2, REAL inv_sigma,
                                 const REAL *gS, REAL acc[6][VEC]) {
#pragma omp simd simdlen(VEC)
    for (int k = 0; k < VEC; k++) {
        PAIR_GEOMETRY
        REAL gg = (u / (1 + u) - inside) * (-2 * inv_sigma);  /* -2 d log(1 - D) / d(d^2) */
        REAL gs = gS[k];
        gg = keep * gs * gg;
        /* the nearest edge's masks, t and w */
        int s1 = d_1 < d_0, s2 = d_2 < best01;
        REAL m2 = s2 ? 1 : 0, m1 = s1 ? 1 - m2 : 0, m0 = 1 - m1 - m2;
        REAL bt = s2 ? t_2 : (s1 ? t_1 : t_0);
        REAL ux = gg * (s2 ? wx_2 : (s1 ? wx_1 : wx_0)), uy = gg * (s2 ? wy_2 : (s1 ? wy_1 : wy_0));
        /* edge e runs from vertex e to vertex e + 1: d(d^2) = -2 w . ((1 - t) da + t db) */
        REAL a = 1 - bt;
        REAL w0 = m0 * a + m2 * bt, w1 = m1 * a + m0 * bt, w2 = m2 * a + m1 * bt;
        acc[0][k] += w0 * ux; acc[1][k] += w0 * uy;
        acc[2][k] += w1 * ux; acc[3][k] += w1 * uy;
        acc[4][k] += w2 * ux; acc[5][k] += w2 * uy;
    }
}

/* for the triangle p in rows ja .. jb: its edges E, and for each vector of its row runs (row j, first
   pixel i, run end b; rows of stride W + VEC) the statements given last (the forward and the backward
   pass walk the same pixels) */
#define FOR_TRIANGLE_RUNS(p, ja, jb, W, r, ...)                                                      \
    NAME(Edges) E;                                                                                 \
    NAME(edges_of)(p, &E);                                                                         \
    NAME(Hull) Q;                                                                                  \
    NAME(hull_of)(p, r, &Q);                                                                       \
    int64_t i0[RUNS], i1[RUNS], stride = (W) + VEC;                                                \
    for (int64_t jj = (ja); jj <= (jb); jj += RUNS) {                                              \
        NAME(runs_of)(&Q, jj, r, W, i0, i1);                                                       \
        for (int64_t j = jj; j <= (jb) && j < jj + RUNS; j++) {                                    \
            int64_t a = i0[j - jj], b = i1[j - jj];                                                \
            for (int64_t i = a; i <= b; i += VEC) { __VA_ARGS__ }                                  \
        }                                                                                          \
    }

/* the rows ja .. jb of triangle p: S (rows of stride W + VEC) += log(1 - D) per pixel (with P) */
static void NAME(fwd_rows)(const REAL *p, int64_t ja, int64_t jb, int W, double r, REAL r2, REAL inv_sigma,
                           REAL *S, REAL *P) {
    FOR_TRIANGLE_RUNS(p, ja, jb, W, r,
        NAME(fwd_vec)(&E, (REAL)i + (REAL)0.5, (REAL)j + (REAL)0.5, (int)(b - i + 1), r2, inv_sigma,
                      S + j * stride + i, P + j * stride + i);)
}

/* band rows ja .. jb: S = the sum of log(1 - D) over the triangles list[0 .. n - 1], sil = -expm1(S) */
static void NAME(fwd_band)(const REAL *tri, const int32_t *rows, const int64_t *list, int64_t n, int64_t ja,
                           int64_t jb, int W, double r, REAL r2, REAL inv_sigma, REAL *S, REAL *P, REAL *sil) {
    int64_t stride = W + VEC;
    memset(S + ja * stride, 0, (jb - ja + 1) * stride * sizeof *S);
    for (int64_t i = ja * stride; i < (jb + 1) * stride; i++) P[i] = 1;
    for (int64_t q = 0; q < n; q++) {
        int64_t f = list[q];
        int64_t j0 = rows[2 * f] > ja ? rows[2 * f] : ja, j1 = rows[2 * f + 1] < jb ? rows[2 * f + 1] : jb;
        NAME(fwd_rows)(tri + 6 * f, j0, j1, W, r, r2, inv_sigma, S, P);
    }
    for (int64_t j = ja; j <= jb; j++) {
        REAL *s = S + j * stride, *p = P + j * stride, *o = sil + j * W;
#pragma omp simd
        for (int64_t i = 0; i < W; i++) {
            REAL v = s[i] - LOG(p[i]);
            s[i] = v;
            o[i] = -EXPM1(v);
        }
    }
}

/* The camera (ipm.render.camera.project, fused here; its matrix product would go to a threaded BLAS):
   R (3, 3) the rows of the camera's frame, eye (3,), focal length fpx and principal point (cx, cy) in
   pixels. Vertex q of verts (V, 3) with strides vs0, vs1: pc = R (v - eye), depth = -pc_z,
   x = cx + fpx pc_x / z, y = cy - fpx pc_y / z with z = depth, or 1e-9 where |depth| <= 1e-9. */
typedef struct { REAL R[9], eye[3], fpx, cx, cy; } NAME(Cam);

static inline void NAME(to_camera)(const NAME(Cam) *C, const REAL *verts, int64_t vs0, int64_t vs1, int64_t q,
                                   REAL *d, REAL *pc, REAL *inv, int *big) {
    for (int k = 0; k < 3; k++) d[k] = verts[q * vs0 + k * vs1] - C->eye[k];
    for (int j = 0; j < 3; j++) pc[j] = C->R[3 * j] * d[0] + C->R[3 * j + 1] * d[1] + C->R[3 * j + 2] * d[2];
    REAL depth = -pc[2], eps = (REAL)1e-9;
    *big = depth > eps || depth < -eps;
    *inv = 1 / (*big ? depth : eps);
}

static inline int NAME(is_nan)(REAL v) {  /* by the bits: -ffast-math lets the compiler assume no NaN */
    UINT b;
    memcpy(&b, &v, sizeof b);
    return (b & EXPBITS) == EXPBITS && (b & ~(EXPBITS | SIGNBIT));
}

/* Forward. verts (V, 3) with strides vs0, vs1 and the camera C (see NAME(Cam)): vertices nearer than
   `near` drop their faces; faces (F, 3) with strides fs0, fs1 (returns -1 if an index is out of range,
   -2 if out of memory, else 0). Writes tri (F, 6) the projected triangles as the kernel sees them (guarded
   against non-finite values), rows (F, 2) the rows they reach (j0 > j1 for none), S (H, W + VEC) per
   pixel the sum of log(1 - D), and sil (H, W) = -expm1(S); bands of rows on nt threads (one parallel
   region, no barrier inside: the triangles are sorted into bands first). */
int NAME(soft_fwd)(const REAL *verts, int64_t vs0, int64_t vs1, int64_t V, const REAL *cam, double near,
                   const int64_t *faces, int64_t fs0, int64_t fs1, int64_t F, int W, int H, double r,
                   double sigma, double far, REAL *tri, int32_t *rows, REAL *S, REAL *sil, int nt, int adapt) {
    REAL r2 = (REAL)(r * r), inv_sigma = (REAL)(1.0 / sigma), farr = (REAL)far;
    nt = adapt ? soft_threads(nt) : (nt < MAXT ? nt : MAXT);
    /* about 4 bands per thread (a triangle reaching two bands is set up twice); one thread: one band */
    int band = nt > 1 ? (H + 4 * nt - 1) / (4 * nt) : H;
    band = band < 8 ? 8 : (band > H ? H : band);
    band = band > 0 ? band : 1;
    int64_t stride = W + VEC, nb = (H + band - 1) / band;
    int64_t *start = calloc(nb + 1, sizeof *start), *order = malloc(nb * sizeof *order), *list = 0, *fill = 0;
    REAL *P = malloc(H * stride * sizeof *P), *xy = malloc((2 * V + 1) * sizeof *xy);
    uint8_t *ok = malloc(V + 1);
    int bad = 0;
    if (!start || !order || !P || !xy || !ok) { bad = -2; goto done; }
    const NAME(Cam) *C = (const NAME(Cam) *)cam;
    for (int64_t q = 0; q < V; q++) {
        REAL d[3], pc[3], inv;
        int big;
        NAME(to_camera)(C, verts, vs0, vs1, q, d, pc, &inv, &big);
        xy[2 * q] = C->cx + C->fpx * pc[0] * inv;
        xy[2 * q + 1] = C->cy - C->fpx * pc[1] * inv;
        ok[q] = !NAME(is_nan)(pc[2]) && -pc[2] >= (REAL)near;
    }
    for (int64_t f = 0; f < F; f++) {
        REAL *p = tri + 6 * f;
        int32_t *rg = rows + 2 * f;
        int in = 1;
        for (int v = 0; v < 3; v++) {
            int64_t q = faces[f * fs0 + v * fs1];
            if (q < 0 || q >= V) { bad = -1; in = 0; p[2 * v] = p[2 * v + 1] = 0; continue; }
            in = in && ok[q];
            p[2 * v] = NAME(guard)(xy[2 * q], farr);
            p[2 * v + 1] = NAME(guard)(xy[2 * q + 1], farr);
        }
        int64_t j0, j1;
        if (in && NAME(rows_of)(p, r, H, &j0, &j1) > 0) {
            rg[0] = (int32_t)j0; rg[1] = (int32_t)j1;
            for (int64_t b = j0 / band; b <= j1 / band; b++) start[b + 1]++;
        } else {
            rg[0] = 1; rg[1] = 0;
        }
    }
    /* per band, the triangles reaching it, in index order; the bands with the most first */
    for (int64_t b = 0; b < nb; b++) {
        int64_t m = start[b + 1], k = b;
        for (; k > 0 && start[order[k - 1] + 1] < m; k--) order[k] = order[k - 1];
        order[k] = b;
    }
    for (int64_t b = 0; b < nb; b++) start[b + 1] += start[b];
    list = malloc((start[nb] + 1) * sizeof *list);
    fill = malloc((nb + 1) * sizeof *fill);
    if (!list || !fill) { bad = -2; goto done; }
    memcpy(fill, start, (nb + 1) * sizeof *fill);
    for (int64_t f = 0; f < F; f++)
        if (rows[2 * f] <= rows[2 * f + 1])
            for (int64_t b = rows[2 * f] / band; b <= rows[2 * f + 1] / band; b++) list[fill[b]++] = f;
    double t0 = omp_get_wtime(), started[MAXT];
#pragma omp parallel num_threads(nt) if (nt > 1)
    {
        started[omp_get_thread_num()] = omp_get_wtime();
#pragma omp for schedule(dynamic, 1) nowait
        for (int64_t o = 0; o < nb; o++) {
            int64_t b = order[o], ja = b * band, jb = ja + band - 1 < H - 1 ? ja + band - 1 : H - 1;
            NAME(fwd_band)(tri, rows, list + start[b], start[b + 1] - start[b], ja, jb, W, r, r2, inv_sigma, S,
                           P, sil);
        }
    }
    if (adapt) soft_started(nt, started, t0);
done:
    free(fill);
    free(list);
    free(order);
    free(start);
    free(P);
    free(xy);
    free(ok);
    return bad;
}

/* triangle p, reaching rows ja .. jb: g (6) = d(sum_p gS[p] S[p]) / dp */
static void NAME(bwd_tri)(const REAL *p, int64_t ja, int64_t jb, int W, double r, REAL r2, REAL inv_sigma,
                          const REAL *gS, REAL *g) {
    REAL acc[6][VEC];
    memset(acc, 0, sizeof acc);
    if (ja <= jb) {
        FOR_TRIANGLE_RUNS(p, ja, jb, W, r,
            NAME(bwd_vec)(&E, (REAL)i + (REAL)0.5, (REAL)j + (REAL)0.5, (int)(b - i + 1), r2, inv_sigma,
                          gS + j * stride + i, acc);)
    }
    for (int q = 0; q < 6; q++) {
        REAL s = 0;
        for (int k = 0; k < VEC; k++) s += acc[q][k];
        g[q] = s;
    }
}

/* Backward. tri, rows, S (H, W + VEC): from soft_fwd; gsil (H, W) = dL/dsil with sil = -expm1(S); gS
   (H, W + VEC), gtri (F, 6) and gxy (V, 2): scratch; verts, cam, faces as for soft_fwd. Writes gverts
   (V, 3) = dL/dverts and gcam (13) = dL/dcam (R, eye, fpx; cx and cy are constants). The triangles'
   gradients are summed per vertex in face order. One parallel region (blocks of triangles), no barrier
   inside. */
void NAME(soft_bwd)(const REAL *verts, int64_t vs0, int64_t vs1, int64_t V, const REAL *cam,
                    const int64_t *faces, int64_t fs0, int64_t fs1, int64_t F, int W, int H, double r,
                    double sigma, const REAL *tri, const int32_t *rows, const REAL *S, const REAL *gsil,
                    REAL *gS, REAL *gtri, REAL *gxy, REAL *gverts, REAL *gcam, int nt, int adapt) {
    REAL r2 = (REAL)(r * r), inv_sigma = (REAL)(1.0 / sigma);
    int64_t stride = W + VEC;
    for (int64_t j = 0; j < H; j++) {
        const REAL *s = S + j * stride, *g = gsil + j * W;
        REAL *o = gS + j * stride;
#pragma omp simd
        for (int64_t i = 0; i < W; i++) o[i] = -g[i] * EXP(s[i]);  /* d(-expm1(S)) = -exp(S) dS */
        for (int64_t i = W; i < stride; i++) o[i] = 0;
    }
    nt = adapt ? soft_threads(nt) : (nt < MAXT ? nt : MAXT);
    double t0 = omp_get_wtime(), started[MAXT];
#pragma omp parallel num_threads(nt) if (nt > 1)
    {
        started[omp_get_thread_num()] = omp_get_wtime();
#pragma omp for schedule(dynamic, 16) nowait
        for (int64_t f = 0; f < F; f++)
            NAME(bwd_tri)(tri + 6 * f, rows[2 * f], rows[2 * f + 1], W, r, r2, inv_sigma, gS, gtri + 6 * f);
    }
    if (adapt) soft_started(nt, started, t0);
    memset(gxy, 0, 2 * V * sizeof *gxy);
    for (int64_t f = 0; f < F; f++)
        for (int v = 0; v < 3; v++) {
            int64_t q = faces[f * fs0 + v * fs1];
            gxy[2 * q] += gtri[6 * f + 2 * v];
            gxy[2 * q + 1] += gtri[6 * f + 2 * v + 1];
        }
    /* through the projection: pc = R d, d = v - eye, x = cx + fpx pc_x inv, y = cy - fpx pc_y inv,
       inv = 1 / z, z = -pc_z (a constant where |pc_z| <= 1e-9) */
    const NAME(Cam) *C = (const NAME(Cam) *)cam;
    double gR[9] = {0}, geye[3] = {0}, gfpx = 0;
    for (int64_t q = 0; q < V; q++) {
        REAL gx = gxy[2 * q], gy = gxy[2 * q + 1], *gv = gverts + 3 * q;
        if (gx == 0 && gy == 0) { gv[0] = gv[1] = gv[2] = 0; continue; }  /* in no face, or none seen */
        REAL d[3], pc[3], inv, gpc[3];
        int big;
        NAME(to_camera)(C, verts, vs0, vs1, q, d, pc, &inv, &big);
        REAL a = gx * pc[0] - gy * pc[1];
        gpc[0] = gx * C->fpx * inv;
        gpc[1] = -gy * C->fpx * inv;
        gpc[2] = big ? C->fpx * a * inv * inv : 0;  /* d inv / d pc_z = inv^2 */
        gfpx += a * inv;
        for (int k = 0; k < 3; k++) {
            gv[k] = C->R[k] * gpc[0] + C->R[3 + k] * gpc[1] + C->R[6 + k] * gpc[2];
            geye[k] -= gv[k];
            for (int j = 0; j < 3; j++) gR[3 * j + k] += (double)gpc[j] * d[k];
        }
    }
    for (int k = 0; k < 9; k++) gcam[k] = (REAL)gR[k];
    for (int k = 0; k < 3; k++) gcam[9 + k] = (REAL)geye[k];
    gcam[12] = (REAL)gfpx;
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
    backend = backend or os.environ.get("IPM_SOFT_BACKEND") or "native"
    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    native = (backend == "native" and torch.is_tensor(verts) and verts.device.type == "cpu"
              and verts.dtype in (torch.float32, torch.float64) and _native_lib() is not None)
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
