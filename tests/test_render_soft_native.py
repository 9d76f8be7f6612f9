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


def test_thread_counts_agree():
    verts, faces = random_mesh(5, 400, 1500, dtype=torch.float32)
    cam = random_camera(5, 64, 64)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        s1, g1 = _image_and_grad(verts, faces, cam, "native")
        torch.set_num_threads(2)
        s2, g2 = _image_and_grad(verts, faces, cam, "native")
    finally:
        torch.set_num_threads(before)
    assert (s1 - s2).abs().max() <= 1e-6 and (g1 - g2).norm() <= 1e-5 * g1.norm()  # summation order


def test_falls_back_to_eager_without_the_kernel(monkeypatch):
    verts, faces = random_mesh(2)
    cam = random_camera(2)
    expected = soft_silhouette(verts, faces, cam, backend="eager")
    monkeypatch.setattr(soft, "_NATIVE", [None])
    assert torch.equal(soft_silhouette(verts, faces, cam, backend="native"), expected)
    assert torch.equal(soft_silhouette(verts, faces, cam), expected)
