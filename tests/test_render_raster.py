"""Hard rasterizer: agrees with trimesh ray casting at pixel centers on real meshes (mask, depth, face),
exact edge-function coverage, z-buffer order, normals."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import real_path

from ipm.io.meshes import load_mesh
from ipm.render.camera import input_views, orbit_camera, pixel_rays, project
from ipm.render.raster import face_normals, hard_mask, rasterize

REAL = [("vessels/probcomp_mug.obj", "y"), ("vessels/trimesh_fuze_bottle.obj", "y"),
        ("buildings/denhaag_84A7976B_lod2.obj", "z"), ("buildings/rotterdam_F4B0DABD_lod2.obj", "z")]


@pytest.mark.parametrize("name, up", REAL)
def test_agrees_with_trimesh_ray_casting(name, up):
    mesh = load_mesh(real_path(name), up=up)
    tm = mesh.to_trimesh()
    size = 64
    for cam in (input_views(1, size)[0], orbit_camera(200.0, -15.0, 3.2, width=size, height=size)):
        fr = rasterize(mesh.verts, mesh.faces, cam)
        o, d = pixel_rays(cam)
        dirs = d.reshape(-1, 3).numpy()
        origins = np.repeat(o.numpy()[None], len(dirs), 0)
        loc, ray, tri = tm.ray.intersects_location(origins, dirs, multiple_hits=False)
        hit = np.zeros(size * size, dtype=bool)
        hit[ray] = True
        mask = fr.mask.numpy().reshape(-1)
        iou = (mask & hit).sum() / (mask | hit).sum()
        assert iou >= 0.995, (name, iou)
        # depth along the view axis at the pixels both see
        both = mask[ray]
        _, depth = project(torch.from_numpy(loc[both]), cam)
        assert np.allclose(fr.depth.numpy().reshape(-1)[ray[both]], depth.numpy(), rtol=1e-6, atol=1e-6)
        same_face = fr.face.numpy().reshape(-1)[ray[both]] == tri[both]
        assert same_face.mean() > 0.97


def test_single_triangle_coverage_is_the_edge_function_test():
    verts = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.4, 0.0], [0.1, 0.6, 0.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2]])
    cam = orbit_camera(10.0, 5.0, 3.0, width=40, height=30)
    m = hard_mask(verts, faces, cam)
    xy, _ = project(verts, cam)
    ys, xs = torch.meshgrid(torch.arange(30.0) + 0.5, torch.arange(40.0) + 0.5, indexing="ij")
    p = torch.stack([xs, ys], -1).double()

    def edge(u, v):
        return (v - u)[0] * (p - u)[..., 1] - (v - u)[1] * (p - u)[..., 0]

    w = torch.stack([edge(xy[0], xy[1]), edge(xy[1], xy[2]), edge(xy[2], xy[0])])
    inside = (w >= 0).all(0) | (w <= 0).all(0)
    assert torch.equal(m, inside) and int(m.sum()) > 50


def test_z_buffer_keeps_the_nearest_face_and_normals():
    quad = torch.tensor([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=torch.float64)
    verts = torch.cat([quad * 0.5 + torch.tensor([0, 0, 0.5]), quad, ])
    faces = torch.tensor([[4, 5, 6], [4, 6, 7], [0, 1, 2], [0, 2, 3]])  # far quad first
    cam = orbit_camera(0.0, 0.0, 3.0, width=32, height=32)
    fr = rasterize(verts, faces, cam)
    assert int(fr.face[16, 16]) in (2, 3) and int(fr.face[1, 16]) in (0, 1)
    assert abs(float(fr.depth[16, 16]) - 2.5) < 1e-9 and abs(float(fr.depth[1, 16]) - 3.0) < 1e-9
    assert torch.allclose(fr.normal[16, 16], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    assert int(fr.face[0, 0]) == -1 and torch.isinf(fr.depth[0, 0]) and not bool(fr.mask[0, 0])
    n = face_normals(verts, faces)
    assert torch.allclose(n, torch.tensor([[0.0, 0.0, 1.0]] * 4, dtype=torch.float64))


def test_faces_behind_the_camera_are_dropped_with_a_warning(caplog):
    verts = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0], [0, 0, 5.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2], [0, 1, 3]])
    cam = orbit_camera(0.0, 0.0, 3.0, width=16, height=16)
    with caplog.at_level("WARNING"):
        fr = rasterize(verts, faces, cam)
    assert "behind the camera" in caplog.text
    assert set(torch.unique(fr.face).tolist()) == {-1, 0}


def test_empty_mesh_gives_an_empty_mask():
    cam = orbit_camera(0.0, 0.0, 3.0, width=8, height=6)
    m = hard_mask(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.int64), cam)
    assert m.shape == (6, 8) and not bool(m.any())
