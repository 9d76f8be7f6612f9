"""Cameras: look-at and orbit conventions, projection, rays, protocol views, cameras.json."""

from __future__ import annotations

import json
import math

import pytest
import torch

from ipm.render.camera import (
    camera_frame,
    cameras_from_json,
    heldout_views,
    input_views,
    load_cameras,
    look_at_camera,
    orbit_camera,
    pixel_rays,
    project,
    projection,
    save_cameras,
    view_matrix,
)
from ipm.types import Camera


def test_look_at_projects_target_to_image_center():
    cam = look_at_camera([1.0, 2.0, 3.0], [0.2, -0.1, 0.4], width=64, height=48)
    xy, depth = project(cam.target[None], cam)
    assert torch.allclose(xy[0], torch.tensor([32.0, 24.0], dtype=torch.float64), atol=1e-9)
    assert math.isclose(float(depth[0]), float(torch.linalg.vector_norm(cam.eye - cam.target)), rel_tol=1e-12)


def test_orbit_convention_y_up_azimuth_from_plus_z():
    c0 = orbit_camera(0.0, 0.0, 2.0)
    assert torch.allclose(c0.eye, torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64), atol=1e-12)
    c90 = orbit_camera(90.0, 0.0, 2.0)
    assert torch.allclose(c90.eye, torch.tensor([2.0, 0.0, 0.0], dtype=torch.float64), atol=1e-12)
    up = orbit_camera(0.0, 30.0, 2.0)
    assert float(up.eye[1]) > 0
    # image up is world +Y: a point above the target lands in a smaller row
    xy, _ = project(torch.tensor([[0.0, 0.5, 0.0]], dtype=torch.float64), c0)
    assert float(xy[0, 1]) < c0.height / 2
    # +X is to the right seen from +Z
    xy, _ = project(torch.tensor([[0.5, 0.0, 0.0]], dtype=torch.float64), c0)
    assert float(xy[0, 0]) > c0.width / 2


def test_view_matrix_is_rigid_and_camera_looks_down_minus_z():
    cam = orbit_camera(37.0, 21.0, 3.0, target=(0.1, 0.2, -0.3))
    V = view_matrix(cam)
    R = V[:3, :3]
    assert torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert math.isclose(float(torch.linalg.det(R)), 1.0, rel_tol=1e-12)
    p = V @ torch.cat([cam.target, torch.ones(1, dtype=torch.float64)])
    assert float(p[2]) < 0 and abs(float(p[0])) < 1e-12 and abs(float(p[1])) < 1e-12


def test_projection_matrix_agrees_with_project():
    cam = orbit_camera(-50.0, 10.0, 3.0, width=80, height=60, fov_deg=35.0)
    pts = torch.randn(20, 3, dtype=torch.float64) * 0.5
    xy, depth = project(pts, cam)
    clip = (projection(cam) @ view_matrix(cam) @ torch.cat([pts, torch.ones(20, 1, dtype=torch.float64)], 1).T).T
    ndc = clip[:, :3] / clip[:, 3:]
    px = (ndc[:, 0] + 1) / 2 * cam.width
    py = (1 - ndc[:, 1]) / 2 * cam.height
    assert torch.allclose(torch.stack([px, py], 1), xy, atol=1e-9)
    assert torch.allclose(clip[:, 3], depth, atol=1e-12)


def test_pixel_rays_pass_through_pixel_centers():
    cam = orbit_camera(20.0, 30.0, 3.0, width=7, height=5, fov_deg=50.0)
    o, d = pixel_rays(cam)
    assert d.shape == (5, 7, 3)
    assert torch.allclose(torch.linalg.vector_norm(d, dim=-1), torch.ones(5, 7, dtype=torch.float64))
    xy, _ = project(o + 2.5 * d, cam)
    cols, rows = torch.meshgrid(torch.arange(7.0), torch.arange(5.0), indexing="xy")
    assert torch.allclose(xy[..., 0], cols.double() + 0.5, atol=1e-9)
    assert torch.allclose(xy[..., 1], rows.double() + 0.5, atol=1e-9)


def test_project_gradcheck_in_every_camera_quantity():
    pts = torch.randn(4, 3, dtype=torch.float64) * 0.3
    eye = torch.tensor([0.3, 1.2, 2.8], dtype=torch.float64, requires_grad=True)
    target = torch.tensor([0.0, 0.1, 0.0], dtype=torch.float64, requires_grad=True)
    up = torch.tensor([0.1, 1.0, 0.0], dtype=torch.float64, requires_grad=True)
    fov = torch.tensor(40.0, dtype=torch.float64, requires_grad=True)
    p = pts.clone().requires_grad_(True)

    def f(eye, target, up, fov, p):
        xy, depth = project(p, Camera(eye, target, up, fov, 32, 24))
        return xy, depth

    assert torch.autograd.gradcheck(f, (eye, target, up, fov, p))


def test_orbit_is_differentiable_in_angles_and_distance():
    az = torch.tensor(30.0, dtype=torch.float64, requires_grad=True)
    el = torch.tensor(20.0, dtype=torch.float64, requires_grad=True)
    dist = torch.tensor(3.0, dtype=torch.float64, requires_grad=True)
    pts = torch.randn(3, 3, dtype=torch.float64) * 0.3
    assert torch.autograd.gradcheck(lambda a, e, d: project(pts, orbit_camera(a, e, d, width=16))[0],
                                    (az, el, dist))


def test_protocol_views():
    views = input_views(4, size=64)
    assert len(views) == 4 and all(v.width == v.height == 64 for v in views)
    for k, cam in enumerate(views):
        assert math.isclose(float(cam.fov_deg), 40.0)
        e = cam.eye
        assert math.isclose(float(torch.linalg.vector_norm(e)), 3.2, rel_tol=1e-12)
        assert math.isclose(math.degrees(math.asin(float(e[1]) / 3.2)), 25.0, abs_tol=1e-9)
        az = math.degrees(math.atan2(float(e[0]), float(e[2]))) % 360
        assert math.isclose(az, (30.0 + 90.0 * k) % 360, abs_tol=1e-9)
    held = heldout_views(32)
    assert len(held) == 16
    elev = [round(math.degrees(math.asin(float(c.eye[1]) / 3.2)), 6) for c in held]
    assert elev == [10.0, 40.0] * 8
    az = [round(math.degrees(math.atan2(float(c.eye[0]), float(c.eye[2]))) % 360, 6) for c in held]
    assert az == [11.25 + 22.5 * k for k in range(16)]


def test_cameras_json_round_trip(tmp_path):
    cams = input_views(3, size=40) + [look_at_camera([0.5, 2.0, -1.0], [0, 0, 0], fov_deg=55.0, width=30,
                                                     height=20)]
    path = save_cameras(tmp_path / "cameras.json", cams)
    data = json.loads(path.read_text())
    assert isinstance(data, list) and set(data[0]) == {"eye", "target", "up", "fov_deg", "width", "height"}
    back = load_cameras(path)
    for a, b in zip(cams, back):
        assert torch.allclose(a.eye, b.eye) and torch.allclose(a.target, b.target) and a.width == b.width
        assert torch.allclose(camera_frame(a), camera_frame(b), atol=1e-12)


@pytest.mark.parametrize("entry, message", [
    ({"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "width": 8, "height": 8}, "fov_deg"),
    ({"eye": [0, 0], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40, "width": 8, "height": 8}, "eye"),
    ({"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40, "width": 8.5, "height": 8}, "width"),
    ({"eye": [0, 0, 3], "target": [0, 0, 3], "up": [0, 1, 0], "fov_deg": 40, "width": 8, "height": 8}, "eye != target"),
    ({"eye": [0, 3, 0], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40, "width": 8, "height": 8}, "parallel"),
    ({"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 190, "width": 8, "height": 8}, "fov"),
])
def test_cameras_json_errors_name_the_entry_and_field(entry, message):
    good = {"eye": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40, "width": 8, "height": 8}
    with pytest.raises(ValueError, match=f"entry 1: .*{message}"):
        cameras_from_json([good, entry])


def test_cameras_json_must_be_a_list(tmp_path):
    with pytest.raises(ValueError, match="expected a JSON list"):
        cameras_from_json({"eye": [0, 0, 3]})
    bad = tmp_path / "cameras.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="expected JSON"):
        load_cameras(bad)


def test_orbit_rejects_pole_and_bad_distance():
    with pytest.raises(ValueError, match="elevation"):
        orbit_camera(0.0, 90.0, 3.0)
    with pytest.raises(ValueError, match="distance"):
        orbit_camera(0.0, 10.0, 0.0)
