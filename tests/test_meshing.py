"""Marching cubes of SDF trees: an independent oracle (manifold3d's exact CSG volumes), watertightness,
and the narrow band against a dense evaluation."""

from __future__ import annotations

import manifold3d as m3d  # a required dependency: the oracle of these tests
import numpy as np
import pytest
import torch

from ipm import sdf
from ipm.sdf.meshing import check_resolution, grid_shape, mesh_sdf
from ipm.sdf.tree import Tree

SEG = 256
UP = [-90.0, 0.0, 0.0]  # manifold3d builds cylinders and revolutions along Z; ours are along Y


def _m_cyl(r, h, r_top=None):
    return m3d.Manifold.cylinder(h, r, r if r_top is None else r_top, SEG, True).rotate(UP)


def csg_classic():
    cyl = sdf.cylinder(0.3, 1.2)
    ours = (sdf.sphere(0.65) & sdf.box(1, 1, 1)) - sdf.union_n(
        children=(cyl, cyl.rotate(90, 90, 0), cyl.rotate(90, 90, 90)))
    c = _m_cyl(0.3, 1.2)
    ref = (m3d.Manifold.sphere(0.65, SEG) ^ m3d.Manifold.cube([1, 1, 1], True)) - (
        c + c.rotate([90, 0, 0]) + c.rotate([0, 0, 90]))
    return ours, ref


def lifts():
    ours = sdf.rect(0.3, 0.8).translate2d(0.5, 0.0).revolve(0.0) | sdf.circle(0.3).extrude(0.4)
    ring = m3d.CrossSection.square([0.3, 0.8], True).translate([0.5, 0.0]).revolve(SEG).rotate(UP)
    disc = m3d.CrossSection.circle(0.3, SEG).extrude(0.4).translate([0, 0, -0.2])
    return ours, ring + disc


def box_minus_sphere():
    ours = sdf.box(1.0, 0.8, 0.6) - sdf.sphere(0.45).translate(0.5, 0.4, 0.0)
    ref = m3d.Manifold.cube([1.0, 0.8, 0.6], True) - m3d.Manifold.sphere(0.45, SEG).translate([0.5, 0.4, 0.0])
    return ours, ref


def cylinder_and_rotated_box():
    ours = sdf.cylinder(0.4, 1.0) | sdf.box(1.2, 0.3, 0.3).rotate(30.0, 0.0, 0.0)
    ref = _m_cyl(0.4, 1.0) + m3d.Manifold.cube([1.2, 0.3, 0.3], True).rotate([0, 30, 0])
    return ours, ref


def cone_box_torus():
    ours = (sdf.cone(0.6, 0.1, 1.2) & sdf.box(0.9, 0.9, 0.9)) - sdf.torus(0.4, 0.1)
    torus = m3d.CrossSection.circle(0.1, SEG).translate([0.4, 0.0]).revolve(SEG).rotate(UP)
    ref = (_m_cyl(0.6, 1.2, 0.1) ^ m3d.Manifold.cube([0.9, 0.9, 0.9], True)) - torus
    return ours, ref


CASES = [csg_classic, lifts, box_minus_sphere, cylinder_and_rotated_box, cone_box_torus]


@pytest.mark.parametrize("case", CASES, ids=[c.__name__ for c in CASES])
def test_volume_matches_manifold3d(case):
    node, ref = case()
    tree = Tree(node)
    mesh = mesh_sdf(lambda p: tree.sdf(None, p), *tree.bounds(), resolution=256)
    tm = mesh.to_trimesh()
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0
    assert tm.volume == pytest.approx(ref.volume(), rel=0.01)


def test_narrow_band_equals_dense_marching_cubes():
    from skimage.measure import marching_cubes

    tree = Tree(csg_classic()[0])
    lo, hi = tree.bounds()
    mesh = mesh_sdf(lambda p: tree.sdf(None, p), lo, hi, resolution=64)
    origin, h, shape = grid_shape(lo, hi, 64)
    axes = [torch.arange(n, dtype=torch.float32) * h + float(o) for n, o in zip(shape, origin)]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)
    vol = tree.sdf(None, grid.reshape(-1, 3)).reshape(shape).numpy()
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h), gradient_direction="descent",
                                        allow_degenerate=False)
    ours = np.sort(np.round(mesh.verts.numpy(), 6), axis=0)
    dense = np.sort(np.round(verts + origin, 6), axis=0)
    assert ours.shape == dense.shape and np.allclose(ours, dense, atol=1e-5)


def test_empty_shape_gives_empty_mesh():
    tree = Tree(sdf.sphere(0.5) - sdf.sphere(1.0))
    mesh = mesh_sdf(lambda p: tree.sdf(None, p), np.array([-1.0] * 3), np.array([1.0] * 3), 32)
    assert mesh.n_faces == 0


def test_resolution_limits():
    lo, hi = np.zeros(3), np.ones(3)
    with pytest.raises(ValueError, match="expected an integer >= 8"):
        check_resolution(4, lo, hi)
    with pytest.raises(ValueError, match="fit in memory"):
        check_resolution(5000, lo, hi)
