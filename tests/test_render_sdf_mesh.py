"""SDF silhouettes through the iso-surface mesh: against the sphere-traced reference (values, hard masks,
gradient directions), against float64 central differences of themselves, the implicit-function-theorem
vertex velocity against marching-cubes vertices of spheres and boxes that grow, an empty level set."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ipm import sdf
from ipm.generators import get_generator
from ipm.render.camera import orbit_camera
from ipm.render.sdf_mesh_silhouette import (
    iso_surface,
    mesh_silhouette,
    pixel_footprint,
    sdf_mesh_silhouette,
    surface_vertices,
)
from ipm.render.sdf_silhouette import sdf_silhouette
from ipm.sdf.tree import Tree

CAM = orbit_camera(30.0, 25.0, 3.2, width=96, height=96)


def unit_field(tree: Tree, theta=None):
    """(f, lo, hi): ``tree`` moved and scaled so that its box's longest side is 2, centred at the origin."""
    lo, hi = tree.bounds()
    c, k = (lo + hi) / 2, float(np.max(hi - lo)) / 2

    def f(p):
        return tree.sdf(theta, p * k + torch.as_tensor(c, dtype=p.dtype)) / k

    return f, (lo - c) / k, (hi - c) / k


def random_tree(seed: int) -> Tree:
    """Two to four boxes, spheres, capsules or tori, translated and joined by union or smooth union."""
    rng = np.random.default_rng(seed)
    make = [lambda: sdf.sphere(rng.uniform(0.25, 0.5)), lambda: sdf.box(*rng.uniform(0.3, 0.8, 3)),
            lambda: sdf.capsule(rng.uniform(0.1, 0.2), rng.uniform(0.3, 0.8)),
            lambda: sdf.torus(rng.uniform(0.3, 0.5), rng.uniform(0.08, 0.15))]
    parts = [make[rng.integers(len(make))]().translate(*rng.uniform(-0.4, 0.4, 3))
             for _ in range(rng.integers(2, 5))]
    if rng.random() < 0.5:
        return Tree(sdf.union_n(children=tuple(parts)))
    node = parts[0]
    for p in parts[1:]:
        node = sdf.smooth_union(0.1, children=(node, p))
    return Tree(node)


def iou(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a & b).sum() / (a | b).sum())


CASES = [("preset", name) for name in ("csg", "mug", "vase", "wind_rose")] + [("random", s) for s in range(4)]


@pytest.mark.parametrize("kind, which", CASES, ids=[f"{k}-{w}" for k, w in CASES])
def test_silhouettes_agree_with_the_sphere_traced_ones(kind, which):
    """On a grid of one pixel: hard masks at IoU >= 0.98, soft values within 0.07 on average (the blurs differ
    in shape: sigmoid(-d^2 / 0.1 px^2) summed over faces against sigmoid(-distance / half a pixel))."""
    tree = get_generator(which).tree if kind == "preset" else random_tree(which)
    f, lo, hi = unit_field(tree)
    traced = sdf_silhouette(f, CAM, lo, hi)
    h = pixel_footprint(CAM, (lo + hi) / 2)
    with torch.no_grad():
        fine = sdf_mesh_silhouette(f, CAM, lo, hi, sigma=0.01, spacing=h)
        soft = sdf_mesh_silhouette(f, CAM, lo, hi, sigma=0.1, spacing=h)
    assert fine.min() >= 0 and fine.max() <= 1
    assert iou(fine > 0.5, traced > 0.5) >= 0.98
    assert float((soft - traced).abs().mean()) < 0.07


@pytest.mark.parametrize("name", ["chair", "wind_rose"])
def test_thin_parts_need_a_finer_grid(name):
    """The chair's legs and slats and the wind rose's points are 2 to 4 px wide here: the default grid
    (:data:`~ipm.render.sdf_mesh_silhouette.CELL_PX`, 2.5 px) keeps them at IoU 0.95 (0.96 at 2 px), a grid of
    1 px at 0.98."""
    f, lo, hi = unit_field(get_generator(name).tree)
    traced = sdf_silhouette(f, CAM, lo, hi) > 0.5
    h = pixel_footprint(CAM, (lo + hi) / 2)
    with torch.no_grad():
        coarse = sdf_mesh_silhouette(f, CAM, lo, hi, sigma=0.01) > 0.5
        fine = sdf_mesh_silhouette(f, CAM, lo, hi, sigma=0.01, spacing=h) > 0.5
    assert iou(coarse, traced) >= 0.94
    assert iou(fine, traced) >= 0.98


def central_difference(mesh_at, q: torch.Tensor, dq: float, verts: torch.Tensor) -> torch.Tensor:
    """``(V, 3)``: the motion per unit of ``q`` of the marching-cubes vertices at ``verts`` (each matched to the
    nearest vertex of the meshes at ``q +- dq``: the one on the same grid edge)."""
    from scipy.spatial import cKDTree

    ends = []
    for s in (q + dq, q - dq):
        m = mesh_at(s).verts
        _, i = cKDTree(m.numpy()).query(verts.numpy())
        ends.append(m[torch.as_tensor(i)])
    return (ends[0] - ends[1]) / (2 * dq)


def sphere_field(r: torch.Tensor, gain: float = 1.0):
    """A sphere of radius ``r`` at the origin; ``gain != 1`` makes the field a scaled distance (|grad| = gain)."""
    return lambda p: gain * (torch.linalg.vector_norm(p, dim=-1) - r.to(p.dtype))


@pytest.mark.parametrize("gain", [1.0, 2.5])
def test_vertex_velocity_is_the_normal_for_a_growing_sphere(gain):
    """d v / d r = n for every vertex of a sphere, whatever the field's gradient norm (``gain``); the marching
    cubes vertices of spheres of radius r +- dr move by dr along it."""
    r, dr, h = torch.tensor(0.6, dtype=torch.float64), 1e-4, 0.05
    mesh = iso_surface(sphere_field(r, gain), [-1] * 3, [1] * 3, h, dtype=torch.float64)
    assert torch.equal(surface_vertices(sphere_field(r.clone().requires_grad_(True), gain), mesh.verts), mesh.verts)
    vel = torch.autograd.functional.jacobian(lambda s: surface_vertices(sphere_field(s, gain), mesh.verts), r)
    n = mesh.verts / mesh.verts.norm(dim=-1, keepdim=True)
    # the vertices lie on the sphere to the interpolation's error, the velocity is the field's normal there
    assert torch.allclose(vel, n, atol=1e-9)
    fd = central_difference(lambda s: iso_surface(sphere_field(s, gain), [-1] * 3, [1] * 3, h,
                                                  dtype=torch.float64), r, dr, mesh.verts)
    moved = (fd * n).sum(-1)  # the normal part of their motion along their grid edge
    # linear interpolation along an edge nearly tangent to the sphere is off: judge the edges within 45 degrees
    aligned = (fd / fd.norm(dim=-1, keepdim=True).clamp_min(1e-12) * n).sum(-1).abs() > 0.7
    assert aligned.float().mean() > 0.4
    assert abs(float(moved[aligned].median()) - 1) < 0.01
    assert float(((moved[aligned] - 1).abs() < 0.05).float().mean()) > 0.95


def test_vertex_velocity_of_a_box_growing_along_one_axis():
    """A box's half-size along x: the vertices on its +-x faces move along their normal at speed 1, the others
    (normal y or z) not at all, as the marching-cubes vertices of boxes of size +- ds do."""
    def field(hx):  # an exact box with half-sizes (hx, 0.4, 0.3) (IQ's box)
        def f(p):
            q = p.abs() - torch.stack([hx.to(p.dtype), torch.tensor(0.4, dtype=p.dtype),
                                       torch.tensor(0.3, dtype=p.dtype)])
            return torch.linalg.vector_norm(q.clamp_min(0), dim=-1) + q.amax(-1).clamp_max(0)
        return f

    hx, d, h = torch.tensor(0.5, dtype=torch.float64), 1e-4, 0.045
    mesh = iso_surface(field(hx), [-1] * 3, [1] * 3, h, dtype=torch.float64)
    vel = torch.autograd.functional.jacobian(lambda s: surface_vertices(field(s), mesh.verts), hx)  # (V, 3)
    v = mesh.verts
    on_x = (v[:, 0].abs() - 0.5).abs() < 1e-9
    flat = on_x & ((v[:, 1].abs() < 0.4 - h) & (v[:, 2].abs() < 0.3 - h))
    assert flat.sum() > 10
    assert torch.allclose(vel[flat, 0].abs(), torch.ones(int(flat.sum()), dtype=v.dtype), atol=1e-6)
    inner_y = ((v[:, 1].abs() - 0.4).abs() < 1e-9) & (v[:, 0].abs() < 0.5 - h)
    assert torch.allclose(vel[inner_y], torch.zeros_like(vel[inner_y]), atol=1e-9)
    fd = central_difference(lambda s: iso_surface(field(s), [-1] * 3, [1] * 3, h, dtype=torch.float64), hx, d, v)
    assert torch.allclose(fd[flat, 0].abs(), vel[flat, 0].abs(), atol=1e-3)


def tree_loss(tree: Tree, theta: torch.Tensor, t: torch.Tensor, render, target: torch.Tensor) -> torch.Tensor:
    """Soft IoU loss of the tree moved by ``t`` against ``target`` (H, W)."""
    f0, lo, hi = unit_field(tree, theta)
    pad = 0.3

    def f(p):
        return f0(p - t.to(p.dtype))

    sil = render(f, CAM.to(dtype=theta.dtype), lo - pad, hi + pad)
    return 1 - (sil * target).sum() / (sil + target - sil * target).sum()


def capsules() -> Tree:
    return Tree(sdf.smooth_union(0.1, children=(sdf.capsule(0.25, 0.6), sdf.sphere(0.35).translate(0.3, 0.2, 0.0))))


def test_gradients_match_central_differences_of_the_path_itself():
    tree = capsules()
    theta0 = tree.theta(torch.float64)
    dt = torch.float64
    target = sdf_silhouette(unit_field(tree, theta0 * 1.1)[0], CAM.to(dtype=dt), [-1.3] * 3, [1.3] * 3,
                            dtype=dt) > 0.5
    target = target.to(dt)

    def render(f, cam, lo, hi):
        return sdf_mesh_silhouette(f, cam, lo, hi, sigma=1.0, spacing=0.04, dtype=dt)

    x = torch.cat([theta0, torch.tensor([0.05, -0.03, 0.02], dtype=dt)]).requires_grad_(True)
    n = len(theta0)

    def loss(z):
        return tree_loss(tree, z[:n], z[n:], render, target)

    (g,) = torch.autograd.grad(loss(x), x)
    eps = 1e-4
    with torch.no_grad():
        fd = torch.stack([(loss(x.detach() + eps * e) - loss(x.detach() - eps * e)) / (2 * eps)
                      for e in torch.eye(len(x), dtype=dt)])
    cos = float(g @ fd / (g.norm() * fd.norm()))
    assert cos >= 0.95, (cos, g, fd)


def test_gradients_point_where_the_reference_gradients_do():
    """Tree parameters and translation: the soft IoU loss's gradient through the mesh and by sphere tracing, at
    blurs of about the same width (0.1 px^2; the tracer's half a pixel)."""
    tree = capsules()
    dt = torch.float64
    theta0 = tree.theta(dt)
    target = (sdf_silhouette(unit_field(tree, theta0 * 1.15)[0], CAM.to(dtype=dt), [-1.3] * 3, [1.3] * 3,
                             dtype=dt) > 0.5).to(dt)
    grads = []
    for render in (lambda f, c, lo, hi: sdf_mesh_silhouette(f, c, lo, hi, sigma=0.1, dtype=dt),
                   lambda f, c, lo, hi: sdf_silhouette(f, c, lo, hi, dtype=dt)):
        x = torch.cat([theta0, torch.tensor([0.06, -0.04, 0.03], dtype=dt)]).requires_grad_(True)
        (g,) = torch.autograd.grad(tree_loss(tree, x[:len(theta0)], x[len(theta0):], render, target), x)
        grads.append(g)
    a, b = grads
    cos = float(a @ b / (a.norm() * b.norm()))
    assert cos >= 0.9, (cos, a, b)


def test_an_empty_level_set_falls_back_to_tracing_with_a_gradient():
    r = torch.tensor(-0.05, dtype=torch.float64, requires_grad=True)  # no surface: |p| > r everywhere
    sil = sdf_mesh_silhouette(sphere_field(r), CAM, [-1] * 3, [1] * 3, sigma=1.0, dtype=torch.float64)
    assert sil.shape == (96, 96) and torch.isfinite(sil).all() and float(sil.detach().max()) < 0.5
    (g,) = torch.autograd.grad(sil.sum(), r)
    assert torch.isfinite(g) and float(g) > 0  # a larger radius shows more


def test_the_deep_interior_is_one_and_the_faces_left_out_change_nothing():
    f, lo, hi = unit_field(get_generator("mug").tree)
    mesh = iso_surface(f, lo, hi, 0.04)
    from ipm.render.soft import soft_silhouette

    for sigma in (1.0, 0.03):
        full = soft_silhouette(mesh.verts.float(), mesh.faces, CAM, sigma=sigma)
        ours = mesh_silhouette(mesh.verts.float(), mesh.faces, CAM, sigma)
        changed = (ours - full).abs() > 1e-6
        assert bool((ours[changed] == 1).all())  # only deep pixels, set to 1
        assert float((full[changed] > 0.5).float().mean()) == 1.0
