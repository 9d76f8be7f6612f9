"""The soft silhouette's C kernel (backend "native") against the eager kernels and the dense reference:
same images and gradients (up to the eps cutoff, which the two place slightly differently), any thread
count, and the fallback to eager where it cannot be built."""

from __future__ import annotations

import pytest
import torch
from reference_soft import reference_soft_silhouette
from test_render_soft import random_camera, random_mesh

from ipm.render import soft
from ipm.render.camera import look_at_camera
from ipm.render.soft import soft_silhouette
from ipm.types import Camera

pytestmark = pytest.mark.skipif(not soft.native_available(), reason="no C compiler for the native kernel")


def _image_and_grad(verts, faces, cam, backend, **kw):
    v = verts.clone().requires_grad_(True)
    s = soft_silhouette(v, faces, cam, backend=backend, **kw)
    w = torch.rand(s.shape, generator=torch.Generator().manual_seed(1), dtype=s.dtype)
    (s * w).sum().backward()
    return s.detach(), v.grad


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_native_matches_eager(seed, dtype):
    verts, faces = random_mesh(seed, 60, 200, dtype=dtype)
    cam = random_camera(seed, 56, 48)
    sigma = [0.3, 1.0, 2.5, 1.0][seed]
    s0, g0 = _image_and_grad(verts, faces, cam, "eager", sigma=sigma)
    s1, g1 = _image_and_grad(verts, faces, cam, "native", sigma=sigma)
    assert s1.dtype == dtype and s1.shape == (48, 56)
    assert (s0 - s1).abs().max() <= 2e-5
    assert (g0 - g1).norm() <= 1e-4 * g0.norm()


def test_native_and_eager_match_the_reference_off_screen_and_close_up():
    verts, faces = random_mesh(7, 60, 120)
    cam = look_at_camera([0.3, 0.2, 1.4], [0.0, 0.0, 0.0], fov_deg=60.0, width=40, height=30)
    ref = reference_soft_silhouette(verts, faces, cam, 1.5)
    for backend in ("native", "eager"):
        assert (soft_silhouette(verts, faces, cam, sigma=1.5, backend=backend) - ref).abs().max() <= 1e-5


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_degenerate_triangles_match_the_reference(dtype):
    """Segments (repeated or collinear vertices) and slivers: the rows' pixel runs (from the triangle
    grown by the blur radius) must still hold every pixel within reach."""
    line = torch.tensor([[-0.6, -0.2, 0.1], [0.0, 0.1, 0.0], [0.5, 0.35, -0.05], [0.3, -0.5, 0.2]], dtype=dtype)
    sliver = line[2] + torch.tensor([1e-7, -1e-7, 0.0], dtype=dtype)
    verts = torch.cat([line, sliver[None]])
    faces = torch.tensor([[0, 0, 1], [0, 1, 2], [2, 1, 0], [3, 2, 2], [0, 2, 4], [1, 4, 0]])
    cam = look_at_camera([0.2, 0.3, 2.0], [0.0, 0.0, 0.0], fov_deg=50.0, width=40, height=36)
    for sigma in (0.5, 2.0):
        ref = reference_soft_silhouette(verts.double(), faces, cam, sigma)
        assert ref.max() > 0.3
        assert (soft_silhouette(verts, faces, cam, sigma=sigma, backend="native") - ref).abs().max() <= 2e-5


def test_thread_counts_agree(monkeypatch):
    monkeypatch.setattr(soft, "_ADAPT_THREADS", False)  # no fallback to one thread on a busy machine
    verts, faces = random_mesh(5, 400, 1500, dtype=torch.float32)
    cam = random_camera(5, 64, 100)  # 100 rows: bands of 13 rows on two threads, 9 on three
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        s1, g1 = _image_and_grad(verts, faces, cam, "native")
        for n in (2, 3):
            torch.set_num_threads(n)
            s2, g2 = _image_and_grad(verts, faces, cam, "native")
            # the image: the same sums in the same order (bands of rows); gradients: per triangle, then per
            # vertex in face order, also the same
            assert torch.equal(s1, s2) and torch.equal(g1, g2)
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_camera_gradients_match_eager(dtype):
    """The kernel projects the vertices itself: gradients for the camera's tensors as through
    camera.project (off-center principal point, a vertex behind the near plane)."""
    verts, faces = random_mesh(6, 60, 200, dtype=dtype)
    verts[0] = torch.tensor([0.4, 0.3, 2.5], dtype=dtype)  # behind the camera: its faces are dropped
    grads = []
    for backend in ("eager", "native"):
        eye = torch.tensor([0.3, 0.5, 2.2], dtype=dtype, requires_grad=True)
        target = torch.tensor([0.05, 0.0, -0.05], dtype=dtype, requires_grad=True)
        up = torch.tensor([0.0, 1.0, 0.1], dtype=dtype, requires_grad=True)
        fov = torch.tensor(50.0, dtype=dtype, requires_grad=True)
        v = verts.clone().requires_grad_(True)
        s = soft_silhouette(v, faces, Camera(eye, target, up, fov, 40, 32, cx=18.5, cy=17.0), backend=backend)
        (s * torch.rand(s.shape, generator=torch.Generator().manual_seed(2), dtype=dtype)).sum().backward()
        grads.append([eye.grad, target.grad, up.grad, fov.grad, v.grad])
    for g0, g1 in zip(*grads):
        assert (g0 - g1).norm() <= 2e-4 * g0.norm() + 1e-9


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_strided_and_int32_faces(dtype):
    verts, faces = random_mesh(3, 80, 300, dtype=dtype)
    cam = random_camera(3, 40, 36)
    s0, g0 = _image_and_grad(verts, faces, cam, "native")
    for f in (faces.t().contiguous().t(), faces.to(torch.int32), torch.stack([faces, faces], 1)[:, 0]):
        s1, g1 = _image_and_grad(verts, f, cam, "native")
        assert torch.equal(s0, s1) and torch.equal(g0, g1)


def test_non_finite_vertices_stay_finite():
    verts, faces = random_mesh(4, 60, 200)
    cam = random_camera(4, 40, 36)
    verts[3] = float("nan")
    verts[7, 0] = float("inf")
    for backend_threads in (1, 2):
        before = torch.get_num_threads()
        try:
            torch.set_num_threads(backend_threads)
            s = soft_silhouette(verts, faces, cam, backend="native")
        finally:
            torch.set_num_threads(before)
        assert torch.isfinite(s).all() and ((s >= 0) & (s <= 1)).all()


def test_falls_back_to_eager_without_the_kernel(monkeypatch):
    verts, faces = random_mesh(2)
    cam = random_camera(2)
    expected = soft_silhouette(verts, faces, cam, backend="eager")
    monkeypatch.setattr(soft, "_kernel", lambda: None)
    assert torch.equal(soft_silhouette(verts, faces, cam, backend="native"), expected)
    assert torch.equal(soft_silhouette(verts, faces, cam), expected)


def test_the_kernel_gives_the_same_bits_whatever_instructions_it_is_built_for(tmp_path, monkeypatch):
    """Issue #28: built for this CPU (-march=native) and for the plainest x86-64 (SSE2, no FMA), the kernel's
    images and gradients agree bit for bit: no flag lets the vector width or fused multiply-adds change the
    arithmetic, so another CPU computes the same silhouettes."""
    import platform

    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("compares x86-64 instruction sets")
    from ipm import native

    flags = native.FLAGS
    assert not any(f in ("-ffast-math", "-Ofast", "-ffp-contract=fast", "-funsafe-math-optimizations")
                   for cflags, _ in flags for f in cflags)
    assert all("-ffp-contract=off" in cflags for cflags, _ in flags)
    verts, faces = random_mesh(3, 400, 1500, dtype=torch.float32)
    cam = random_camera(3, 96, 80)
    out = {}
    try:
        for march in ("-march=native", "-march=x86-64"):
            built = tuple(([f if not f.startswith("-march=") else march for f in cflags], libs)
                          for cflags, libs in flags)
            monkeypatch.setattr(native, "FLAGS", built)
            monkeypatch.setenv("IPM_CACHE_DIR", str(tmp_path / march))
            native.forget("soft")
            for dtype in (torch.float32, torch.float64):
                out[march, dtype] = _image_and_grad(verts.to(dtype), faces, cam, "native", sigma=1.0)
    finally:
        native.forget("soft")
    for dtype in (torch.float32, torch.float64):
        (s0, g0), (s1, g1) = out["-march=native", dtype], out["-march=x86-64", dtype]
        assert torch.equal(s0, s1) and torch.equal(g0, g1), dtype


def test_the_kernels_header_declares_what_its_source_defines():
    """ipm/native/soft.h is the one declaration of the kernel's functions: the C source includes it (so the
    compiler checks the definitions against it) and cffi binds the library from it."""
    from ipm import native

    decl = native.declarations("soft")
    for name in ("soft_fwd_f", "soft_fwd_d", "soft_bwd_f", "soft_bwd_d"):
        assert f"{name}(" in decl
        assert callable(getattr(native.load("soft").lib, name))
    assert '#include "soft.h"' in (native.HERE / "soft.c").read_text()
    assert not any(ln.lstrip().startswith("#") for ln in decl.splitlines())
