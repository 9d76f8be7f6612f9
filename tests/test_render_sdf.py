"""SDF silhouettes: agree with the hard mask of the marching-cubes mesh, gradients match finite
differences; sphere-traced depth and normals."""

from __future__ import annotations

import math

import pytest
import torch

from ipm.generators import get_generator
from ipm.render.camera import orbit_camera, pixel_rays
from ipm.render.raster import hard_mask
from ipm.render.sdf_silhouette import sdf_depth_normals, sdf_silhouette
from ipm.sdf.meshing import mesh_sdf
from ipm.types import Camera


def sphere(center: torch.Tensor, radius: torch.Tensor):
    return lambda p: torch.linalg.vector_norm(p - center.to(p.dtype), dim=-1) - radius.to(p.dtype)


@pytest.mark.parametrize("name", ["csg", "mug"])
def test_silhouette_matches_hard_mask_of_the_mesh(name):
    tree = get_generator(name).tree
    lo, hi = tree.bounds()
    cam = orbit_camera(30.0, 25.0, 3.2, width=96, height=96)
    sil = sdf_silhouette(lambda p: tree.sdf(None, p), cam, lo, hi)
    mesh = mesh_sdf(lambda p: tree.sdf(None, p), lo, hi, 160)
    hard = hard_mask(mesh.verts, mesh.faces, cam)
    soft = sil > 0.5
    iou = float((soft & hard).sum() / (soft | hard).sum())
    assert iou >= 0.98, iou
    assert sil.min() >= 0 and sil.max() <= 1


def test_gradients_flow_to_tree_parameters():
    g = get_generator("csg")
    tree = g.tree
    lo, hi = tree.bounds()
    theta = tree.theta(torch.float32).requires_grad_(True)
    cam = orbit_camera(30.0, 25.0, 3.2, width=48, height=48)
    sil = sdf_silhouette(lambda p: tree.sdf(theta, p), cam, lo, hi)
    sil.sum().backward()
    assert theta.grad is not None and torch.isfinite(theta.grad).all() and theta.grad.abs().sum() > 0


def test_gradients_equal_those_of_the_exact_minimum():
    """For a sphere the minimum along each ray is known (closest approach minus radius): the silhouette
    and its gradients in the radius and in the camera (eye, fov) must match that closed form."""
    c = torch.tensor([0.1, -0.05, 0.0], dtype=torch.float64)
    sigma = 0.05

    def camera(eye, fov):
        return Camera(eye, torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
                      fov, 24, 24)

    def ours(r, eye, fov):
        return sdf_silhouette(sphere(c, r), camera(eye, fov), [-1] * 3, [1] * 3, sigma=sigma,
                              dtype=torch.float64, refine=40)

    def exact(r, eye, fov):
        o, d = pixel_rays(camera(eye, fov))
        t = ((c - o) * d).sum(-1)
        b = torch.linalg.vector_norm(o + t[..., None] * d - c, dim=-1)
        return torch.sigmoid(-(b - r) / sigma)

    args = [torch.tensor(0.6, dtype=torch.float64), torch.tensor([0.3, 0.4, 3.0], dtype=torch.float64),
            torch.tensor(40.0, dtype=torch.float64)]
    a = [x.clone().requires_grad_(True) for x in args]
    b = [x.clone().requires_grad_(True) for x in args]
    sa, sb = ours(*a), exact(*b)
    assert (sa - sb).abs().max() < 1e-5  # rays farther than 12 sigma are not refined (sil < 6e-6)
    w = torch.rand(24, 24, dtype=torch.float64)
    (sa * w).sum().backward()
    (sb * w).sum().backward()
    for x, y in zip(a, b):
        assert torch.allclose(x.grad, y.grad, rtol=1e-4, atol=1e-3), (x.grad, y.grad)


def test_depth_and_normals_of_a_sphere():
    r = torch.tensor(0.5, dtype=torch.float64)
    cam = orbit_camera(0.0, 0.0, 3.0, width=33, height=33)
    pic = sdf_depth_normals(sphere(torch.zeros(3, dtype=torch.float64), r), cam, [-1] * 3, [1] * 3,
                            dtype=torch.float64)
    assert bool(pic.mask[16, 16]) and not bool(pic.mask[0, 0])
    assert math.isclose(float(pic.depth[16, 16]), 2.5, abs_tol=1e-3)
    assert torch.allclose(pic.normal[16, 16], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-3)
    assert math.isinf(float(pic.depth[0, 0]))
    # the mask is the disk of the sphere's silhouette: tan(half-angle) = r / sqrt(d^2 - r^2)
    f = 33 / (2 * math.tan(math.radians(20.0)))
    rad_px = f * 0.5 / math.sqrt(3.0**2 - 0.5**2)
    assert abs(float(pic.mask.sum()) - math.pi * rad_px**2) < 0.06 * math.pi * rad_px**2


def test_bad_box():
    cam = orbit_camera(0.0, 0.0, 3.0, width=8)
    with pytest.raises(ValueError, match="lo < hi"):
        sdf_silhouette(lambda p: p.norm(dim=-1) - 0.5, cam, [0, 0, 0], [0, 1, 1])
