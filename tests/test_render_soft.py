"""Soft mesh silhouettes: equal to the dense reference, correct gradients, hard masks in the limit, and
gradients that lead a single-view fit to the right pose."""

from __future__ import annotations

import pytest
import torch
from conftest import real_path
from reference_soft import reference_soft_silhouette

from ipm.io.meshes import load_mesh
from ipm.render.camera import input_views, look_at_camera, orbit_camera
from ipm.render.raster import hard_mask
from ipm.render.soft import soft_silhouette
from ipm.types import Camera


def random_mesh(seed: int, n_verts: int = 30, n_faces: int = 40, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    verts = (torch.rand(n_verts, 3, generator=g, dtype=dtype) - 0.5) * 1.6
    faces = torch.randint(0, n_verts, (n_faces, 3), generator=g)
    return verts, faces


def random_camera(seed: int, width: int = 48, height: int = 40) -> Camera:
    g = torch.Generator().manual_seed(seed + 100)
    az, el = (torch.rand(2, generator=g, dtype=torch.float64) * torch.tensor([360.0, 100.0]) - torch.tensor([0, 50]))
    dist = 2.2 + float(torch.rand((), generator=g, dtype=torch.float64))
    fov = 30.0 + 30.0 * float(torch.rand((), generator=g, dtype=torch.float64))
    return orbit_camera(float(az), float(el), dist, fov_deg=fov, width=width, height=height)


@pytest.mark.parametrize("seed", range(6))
def test_matches_dense_reference(seed):
    verts, faces = random_mesh(seed)
    cam = random_camera(seed)
    sigma = [0.3, 1.0, 2.5][seed % 3]
    fast = soft_silhouette(verts, faces, cam, sigma=sigma)
    ref = reference_soft_silhouette(verts, faces, cam, sigma)
    assert fast.shape == (40, 48) and fast.dtype == torch.float64
    assert (fast - ref).abs().max() <= 1e-5
    assert ref.max() > 0.5  # the mesh is in view


def test_matches_reference_with_a_camera_close_up_and_triangles_off_screen():
    verts, faces = random_mesh(7, 60, 120)
    cam = look_at_camera([0.3, 0.2, 1.4], [0.0, 0.0, 0.0], fov_deg=60.0, width=40, height=30)
    fast = soft_silhouette(verts, faces, cam, sigma=1.5)
    ref = reference_soft_silhouette(verts, faces, cam, 1.5)
    assert (fast - ref).abs().max() <= 1e-5


def test_float32_close_to_float64():
    verts, faces = random_mesh(3, 40, 60)
    cam = random_camera(3, 64, 64)
    a = soft_silhouette(verts, faces, cam, sigma=1.0)
    b = soft_silhouette(verts.float(), faces, cam, sigma=1.0)
    assert b.dtype == torch.float32 and (a - b.double()).abs().max() < 1e-4


def test_gradcheck_vertices():
    verts, faces = random_mesh(11, 8, 5)
    cam = orbit_camera(20.0, 15.0, 3.0, width=12, height=10, fov_deg=45.0)
    v = verts.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: soft_silhouette(x, faces, cam, sigma=3.0, eps=1e-12), (v,),
                                    atol=1e-6)


def test_gradcheck_camera():
    verts, faces = random_mesh(12, 8, 5)
    eye = torch.tensor([0.8, 1.0, 2.6], dtype=torch.float64, requires_grad=True)
    target = torch.tensor([0.05, 0.0, -0.05], dtype=torch.float64, requires_grad=True)
    up = torch.tensor([0.0, 1.0, 0.1], dtype=torch.float64, requires_grad=True)
    fov = torch.tensor(45.0, dtype=torch.float64, requires_grad=True)

    def f(eye, target, up, fov):
        return soft_silhouette(verts, faces, Camera(eye, target, up, fov, 12, 10), sigma=3.0, eps=1e-12)

    assert torch.autograd.gradcheck(f, (eye, target, up, fov), atol=1e-6)


def test_out_of_view_mesh_gives_zeros_and_zero_gradients():
    verts, faces = random_mesh(1)
    cam = look_at_camera([0.0, 0.0, 5.0], [0.0, 0.0, 10.0], width=16, height=16)  # looking away
    v = verts.clone().requires_grad_(True)
    s = soft_silhouette(v, faces, cam)
    assert s.shape == (16, 16) and float(s.detach().abs().max()) == 0.0
    s.sum().backward()
    assert v.grad is not None and float(v.grad.abs().max()) == 0.0


@pytest.mark.parametrize("name", ["vessels/probcomp_mug.obj", "buildings/denhaag_84A7976B_lod2.obj"])
def test_small_sigma_thresholded_is_the_hard_mask(name):
    up = "z" if name.startswith("buildings") else "y"
    mesh = load_mesh(real_path(name), up=up)
    cam = input_views(1, size=96)[0]
    soft = soft_silhouette(mesh.verts, mesh.faces, cam, sigma=0.01) > 0.5
    hard = hard_mask(mesh.verts, mesh.faces, cam)
    iou = float((soft & hard).sum() / (soft | hard).sum())
    assert iou >= 0.99, iou


def _fit(mesh, cam, make, start, steps, lr):
    """Adam on 1 - soft IoU against the hard mask, with the blur annealed from 2 to 0.05 px^2."""
    target = hard_mask(mesh.verts, mesh.faces, cam).float()
    verts = mesh.verts.float()
    param = start.clone().requires_grad_(True)
    opt = torch.optim.Adam([param], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for it in range(steps):
        sigma = 2.0 * (0.05 / 2.0) ** (it / (steps - 1))
        sil = soft_silhouette(make(verts, param), mesh.faces, cam, sigma=sigma)
        inter = (sil * target).sum()
        loss = 1.0 - inter / (sil.sum() + target.sum() - inter)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return param.detach()


@pytest.mark.slow
def test_single_view_fit_recovers_translation():
    mesh = load_mesh(real_path("vessels/probcomp_mug.obj"))  # normalized: size 2
    cam = input_views(1, size=128)[0]
    t = _fit(mesh, cam, lambda v, t: v + t, torch.tensor([0.15, -0.12, 0.10]), 120, 0.03)
    assert float(torch.linalg.vector_norm(t)) <= 0.01 * 2.0, t


@pytest.mark.slow
def test_single_view_fit_recovers_scale():
    mesh = load_mesh(real_path("vessels/probcomp_mug.obj"))
    cam = input_views(1, size=128)[0]
    s = _fit(mesh, cam, lambda v, s: v * s, torch.tensor(0.85), 80, 0.02)
    assert abs(float(s) - 1.0) <= 0.01, float(s)


def test_bad_inputs():
    verts, faces = random_mesh(0)
    cam = orbit_camera(0.0, 10.0, 3.0, width=8)
    with pytest.raises(ValueError, match=r"verts: expected a float tensor \(V, 3\)"):
        soft_silhouette(verts[:, :2], faces, cam)
    with pytest.raises(ValueError, match="faces: expected an integer tensor"):
        soft_silhouette(verts, faces.double(), cam)
    with pytest.raises(ValueError, match="vertex indices"):
        soft_silhouette(verts, faces + 100, cam)
    with pytest.raises(ValueError, match="sigma"):
        soft_silhouette(verts, faces, cam, sigma=0.0)
