"""Principal point and known intrinsics: off-center cameras in every camera-to-pixel map, crops,
intrinsics files (JSON, ClearGrasp YAML), cameras.json with cx, cy."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from conftest import require_file

from ipm.bench.views import fit_views
from ipm.errors import InputError
from ipm.render import deferred, raster
from ipm.render.camera import (
    Intrinsics,
    cameras_from_json,
    crop_camera,
    detach_camera,
    focal_pixels,
    intrinsics_camera,
    load_cameras,
    load_intrinsics,
    look_at_camera,
    orbit_camera,
    pixel_rays,
    project,
    projection,
    save_cameras,
    view_matrix,
)
from ipm.render.soft import soft_silhouette
from ipm.types import Camera, TriMesh

CLEARGRASP = (Path(__file__).parents[1] / ".." / "shared" / "data" / "real" / "photos" / "cleargrasp_cups"
              / "camera_intrinsics.yaml")
F64 = torch.float64


def off_center(width=40, height=30, cx=13.7, cy=21.2, **kw) -> Camera:
    return orbit_camera(-35.0, 20.0, 3.0, fov_deg=45.0, width=width, height=height, cx=cx, cy=cy, **kw)


def scene() -> TriMesh:
    """A sphere and a tilted box: generic edges (no pixel center lies on one)."""
    s = trimesh.creation.icosphere(subdivisions=2, radius=0.55)
    s.apply_translation([-0.31, 0.07, 0.02])
    b = trimesh.creation.box(extents=[0.5, 0.8, 0.4])
    b.apply_transform(trimesh.transformations.euler_matrix(0.3, 0.7, -0.2))
    b.apply_translation([0.43, -0.12, 0.11])
    return TriMesh.concat([TriMesh.from_trimesh(s), TriMesh.from_trimesh(b)])


# -- the camera value --------------------------------------------------------------------------------

def test_principal_point_defaults_to_the_image_center_and_travels_with_the_camera():
    c = orbit_camera(10.0, 20.0, width=40, height=30)
    assert (c.cx, c.cy) == (None, None) and c.principal_point == (20.0, 15.0)
    o = off_center()
    assert o.principal_point == (13.7, 21.2)
    for d in (o.to(torch.float32), detach_camera(o)):
        assert d.principal_point == (13.7, 21.2)
    # positional construction without cx, cy still works
    assert Camera(o.eye, o.target, o.up, o.fov_deg, 40, 30).principal_point == (20.0, 15.0)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "1", True, [1.0]])
def test_camera_refuses_a_bad_principal_point(bad):
    with pytest.raises(InputError, match="camera cx: expected a finite number"):
        Camera([0, 0, 3.0], [0, 0, 0.0], [0, 1, 0.0], 40.0, 32, 24, cx=bad)


def test_look_at_puts_the_target_on_the_principal_point():
    cam = look_at_camera([1.0, 2.0, 3.0], [0.2, -0.1, 0.4], width=64, height=48, cx=40.25, cy=10.5)
    xy, _ = project(cam.target[None], cam)
    assert torch.allclose(xy[0], torch.tensor([40.25, 10.5], dtype=F64), atol=1e-9)


# -- every map between camera space and pixels -------------------------------------------------------

def test_project_and_pixel_rays_round_trip_off_center():
    cam = off_center(width=9, height=7, cx=2.3, cy=5.9)
    o, d = pixel_rays(cam)
    t = 1.0 + torch.rand(7, 9, 1, dtype=F64) * 3
    xy, depth = project(o + t * d, cam)
    cols, rows = torch.meshgrid(torch.arange(9.0, dtype=F64), torch.arange(7.0, dtype=F64), indexing="xy")
    assert torch.allclose(xy[..., 0], cols + 0.5, atol=1e-9, rtol=0)
    assert torch.allclose(xy[..., 1], rows + 0.5, atol=1e-9, rtol=0)
    assert bool((depth > 0).all())
    # the centered camera's rays differ: the principal point is used
    _, d0 = pixel_rays(orbit_camera(-35.0, 20.0, 3.0, fov_deg=45.0, width=9, height=7))
    assert not torch.allclose(d, d0, atol=1e-3)


def test_projection_matrix_agrees_with_project_off_center():
    cam = off_center(width=80, height=60, cx=61.5, cy=12.25)
    pts = torch.randn(20, 3, dtype=F64) * 0.5
    xy, depth = project(pts, cam)
    clip = (projection(cam) @ view_matrix(cam) @ torch.cat([pts, torch.ones(20, 1, dtype=F64)], 1).T).T
    ndc = clip[:, :3] / clip[:, 3:]
    px = (ndc[:, 0] + 1) / 2 * cam.width
    py = (1 - ndc[:, 1]) / 2 * cam.height
    assert torch.allclose(torch.stack([px, py], 1), xy, atol=1e-9, rtol=0)
    assert torch.allclose(clip[:, 3], depth, atol=1e-12)


def test_crop_camera_maps_pixels_affinely():
    cam = off_center(width=64, height=48, cx=30.3, cy=27.9)
    pts = torch.randn(50, 3, dtype=F64) * 0.6
    xy, depth = project(pts, cam)
    for x0, y0, w, h, s in [(5, 11, 24, 18, 1.0), (-3, 4, 40, 30, 0.5), (10, 2, 21, 13, 1.7), (0, 0, 64, 48, 0.25)]:
        c = crop_camera(cam, x0, y0, w, h, s)
        assert (c.width, c.height) == (max(1, round(w * s)), max(1, round(h * s)))
        assert math.isclose(float(focal_pixels(c)), float(focal_pixels(cam)) * s, rel_tol=1e-12)
        xy2, depth2 = project(pts, c)
        want = (xy - torch.tensor([x0, y0], dtype=F64)) * s
        assert torch.allclose(xy2, want, atol=1e-9, rtol=0)
        assert torch.allclose(depth2, depth, atol=1e-12)


def test_crop_camera_bad_input():
    cam = off_center()
    for args, msg in [((0.5, 0, 4, 4), "x0: expected an integer"), ((0, 0, 0, 4), "positive size"),
                      ((0, 0, 4, 4, 0.0), "scale: expected a positive"),
                      ((0, 0, 4, 4, float("nan")), "scale: expected a positive")]:
        with pytest.raises(InputError, match=msg):
            crop_camera(cam, *args)


def _big_and_crop(x0=5, y0=11, w=24, h=18, big_cx=None, big_cy=None):
    big = orbit_camera(-35.0, 20.0, 2.6, fov_deg=45.0, width=2 * w, height=2 * h, cx=big_cx, cy=big_cy)
    return big, crop_camera(big, x0, y0, w, h), (slice(y0, y0 + h), slice(x0, x0 + w))


@pytest.mark.parametrize("big_cx, big_cy", [(None, None), (21.37, 19.05)])
def test_rasterizers_off_center_equal_a_crop_of_a_bigger_image(big_cx, big_cy):
    m = scene()
    big, cam, win = _big_and_crop(big_cx=big_cx, big_cy=big_cy)
    assert cam.principal_point != (cam.width / 2, cam.height / 2)
    fb = raster.rasterize(m.verts, m.faces, big)
    fc = raster.rasterize(m.verts, m.faces, cam)
    assert fc.mask.any() and not fc.mask.all()
    assert torch.equal(fc.mask, fb.mask[win])
    assert torch.equal(fc.face, fb.face[win])
    assert torch.allclose(fc.depth[fc.mask], fb.depth[win][fc.mask], rtol=1e-10)
    rb = deferred.rasterize(m.verts, m.faces, big)
    rc = deferred.rasterize(m.verts, m.faces, cam)
    assert torch.equal(rc.face, rb.face[win]) and torch.equal(rc.mask, rb.mask[win])
    assert torch.allclose(rc.bary, rb.bary[win], atol=1e-9, rtol=0)
    db = deferred.depth(m.verts, m.faces, big, rb)
    dc = deferred.depth(m.verts, m.faces, cam, rc)
    assert torch.allclose(dc, db[win], atol=1e-9, rtol=0)


def test_soft_silhouette_off_center_equals_a_crop_of_a_bigger_image():
    m = scene()
    big, cam, win = _big_and_crop(big_cx=21.37, big_cy=19.05)
    sb = soft_silhouette(m.verts, m.faces, big, sigma=2.0)
    sc = soft_silhouette(m.verts, m.faces, cam, sigma=2.0)
    assert float(sc.max()) > 0.9 and float(sc.min()) < 0.1
    assert torch.allclose(sc, sb[win], atol=1e-5, rtol=0)


def test_gradients_reach_the_vertices_off_center():
    m = scene()
    cam = off_center()
    v = m.verts.clone().requires_grad_(True)
    soft_silhouette(v, m.faces, cam, sigma=2.0).sum().backward()
    assert torch.isfinite(v.grad).all() and float(v.grad.abs().sum()) > 0
    v.grad = None
    r = deferred.rasterize(v, m.faces, cam)
    deferred.depth(v, m.faces, cam, r).sum().backward()
    assert torch.isfinite(v.grad).all() and float(v.grad.abs().sum()) > 0


def test_fit_views_divides_the_principal_point():
    m = scene()
    cam = off_center(width=40, height=30, cx=13.7, cy=21.2)
    mask = raster.rasterize(m.verts, m.faces, cam).mask.numpy()
    target, (small,) = fit_views(mask[None], [cam], max_size=20, dtype=F64)
    assert target.shape == (1, 15, 20) and (small.width, small.height) == (20, 15)
    assert small.principal_point == pytest.approx((13.7 / 2, 21.2 / 2))
    pts = torch.randn(30, 3, dtype=F64) * 0.5
    assert torch.allclose(project(pts, small)[0], project(pts, cam)[0] / 2, atol=1e-9, rtol=0)
    _, (plain,) = fit_views(mask[None], [orbit_camera(0.0, 20.0, width=40, height=30)], max_size=20)
    assert (plain.cx, plain.cy) == (None, None)


# -- cameras.json -----------------------------------------------------------------------------------

def test_cameras_json_round_trip_with_principal_point(tmp_path):
    cams = [off_center(), orbit_camera(50.0, 10.0, width=40, height=30)]
    path = save_cameras(tmp_path / "cameras.json", cams)
    data = json.loads(path.read_text())
    assert (data[0]["cx"], data[0]["cy"]) == (13.7, 21.2)
    assert "cx" not in data[1] and "cy" not in data[1]
    back = load_cameras(path)
    assert [c.principal_point for c in back] == [c.principal_point for c in cams]
    assert (back[1].cx, back[1].cy) == (None, None)


@pytest.mark.parametrize("field, value", [("cx", "12"), ("cy", True), ("cx", [1]), ("cy", None)])
def test_cameras_json_refuses_a_bad_principal_point(field, value):
    entry = off_center().to_json()
    entry[field] = value
    with pytest.raises(InputError, match=rf"^views\.json: entry 1: {field}: expected a number"):
        cameras_from_json([orbit_camera(0.0, 10.0).to_json(), entry], "views.json")


def test_cameras_json_refuses_a_nan_principal_point(tmp_path):
    p = tmp_path / "cameras.json"
    p.write_text(json.dumps([off_center().to_json()]).replace("13.7", "NaN"))
    with pytest.raises(InputError, match="entry 0: cx: expected a number"):
        load_cameras(p)


# -- intrinsics -------------------------------------------------------------------------------------

def test_cleargrasp_yaml():
    intr = load_intrinsics(require_file(CLEARGRASP))
    assert intr == Intrinsics(921.0, 921.0, 642.0, 359.0, 1280, 720)
    assert math.isclose(intr.fov_deg, math.degrees(2 * math.atan(360 / 921)), rel_tol=1e-12)
    cam = intrinsics_camera(intr, [0.0, 0.5, 3.0], [0.0, 0.0, 0.0])
    assert (cam.width, cam.height, cam.principal_point) == (1280, 720, (642.0, 359.0))
    assert math.isclose(float(focal_pixels(cam)), 921.0, rel_tol=1e-12)
    xy, _ = project(cam.target[None], cam)
    assert torch.allclose(xy[0], torch.tensor([642.0, 359.0], dtype=F64), atol=1e-9)
    orb = orbit_camera(30.0, 20.0, 3.0, fov_deg=intr.fov_deg, width=intr.width, height=intr.height,
                       cx=intr.cx, cy=intr.cy)
    assert orb.principal_point == (642.0, 359.0)
    assert math.isclose(float(focal_pixels(orb)), 921.0, rel_tol=1e-12)


def test_json_intrinsics_flat_and_K(tmp_path):
    flat = tmp_path / "flat.json"
    flat.write_text(json.dumps({"fx": 600, "fy": 600, "cx": 330.5, "cy": 242, "width": 640, "height": 480}))
    k = tmp_path / "k.json"
    k.write_text(json.dumps({"K": [[600, 0, 330.5], [0, 600, 242], [0, 0, 1]], "width": 640, "height": 480}))
    yml = tmp_path / "cam.yml"
    yml.write_text("K: [[600, 0, 330.5], [0, 600, 242], [0, 0, 1]]\nwidth: 640\nheight: 480\n")
    want = Intrinsics(600, 600, 330.5, 242, 640, 480)
    assert load_intrinsics(flat) == load_intrinsics(k) == load_intrinsics(yml) == want
    assert want.K == [[600.0, 0.0, 330.5], [0.0, 600.0, 242.0], [0.0, 0.0, 1.0]]


def test_nearly_square_pixels_use_fy_and_warn(tmp_path, caplog):
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"fx": 925.0, "fy": 921.0, "cx": 640, "cy": 360, "width": 1280, "height": 720}))
    with caplog.at_level(logging.WARNING, logger="ipm"):
        intr = load_intrinsics(p)
    assert "using fy" in caplog.text
    assert math.isclose(float(focal_pixels(intrinsics_camera(intr, [0, 0, 3.0], [0, 0, 0.0]))), 921.0,
                        rel_tol=1e-12)


GOOD = {"fx": 921, "fy": 921, "cx": 642, "cy": 359, "width": 1280, "height": 720}


def _without(key):
    return {k: v for k, v in GOOD.items() if k != key}


BAD_JSON = [
    (_without("cy"), "missing cy"),
    (_without("height"), "missing height (or yres)"),
    ({**GOOD, "fx": "921"}, "fx: expected a finite number"),
    ({**GOOD, "cx": None}, "cx: expected a finite number"),
    ({**GOOD, "fx": -921}, "fx: expected a positive focal length"),
    ({**GOOD, "fy": 0}, "fy: expected a positive focal length"),
    ({**GOOD, "width": 0}, "width: expected a positive integer"),
    ({**GOOD, "height": 720.5}, "height: expected a positive integer"),
    ({**GOOD, "fx": 800}, "non-square pixels are not supported: fx=800, fy=921; expected fx within 1% of fy"),
    ({**GOOD, "K": [[921, 0, 642], [0, 921, 359], [0, 0, 1]]}, "either K or fx, fy, cx, cy"),
    ({"K": [[921, 0, 642], [0, 921, 359]], "width": 1280, "height": 720}, "K: expected a 3x3 list"),
    ({"K": [[921, 2, 642], [0, 921, 359], [0, 0, 1]], "width": 1280, "height": 720}, r"no skew"),
    ([GOOD], "got list"),
]


@pytest.mark.parametrize("data, msg", BAD_JSON)
def test_bad_json_intrinsics(tmp_path, data, msg):
    p = tmp_path / "intr.json"
    p.write_text(json.dumps(data))
    _refused(p, msg)


@pytest.mark.parametrize("name, text, msg", [
    ("cam.yaml", "fx: 921\nfy: 921\ncx: 642\ncy: [359\nxres: 1280\nyres: 720\n", "expected YAML, got a parse error"),
    ("cam.yaml", "fx: 921\nfy: 921\ncx: 642\ncy: 359\nxres: 1280\n", "missing height (or yres)"),
    ("cam.yaml", "fx: 921\nfy: abc\ncx: 642\ncy: 359\nxres: 1280\nyres: 720\n", "fy: expected a finite number"),
    ("cam.yaml", "fx: .nan\nfy: 921\ncx: 642\ncy: 359\nxres: 1280\nyres: 720\n", "fx: expected a finite number"),
    ("cam.yaml", "# nothing\n", "got an empty file"),
    ("cam.yml", "- 1\n- 2\n", "got list"),
    ("cam.txt", "fx: 921\n", "expected a .json, .yaml, .yml file"),
    ("cam", "fx: 921\n", "expected a .json, .yaml, .yml file"),
    ("cam.json", "{\"fx\": 921,", "not valid JSON"),
])
def test_bad_intrinsics_files(tmp_path, name, text, msg):
    p = tmp_path / name
    p.write_text(text)
    _refused(p, msg)


def test_missing_or_binary_intrinsics_file(tmp_path):
    _refused(tmp_path / "nope.yaml", "not found")
    b = tmp_path / "bin.yaml"
    b.write_bytes(b"\xff\xfe\x00\x81")
    _refused(b, "expected UTF-8 text")


def _refused(path: Path, msg: str) -> None:
    with pytest.raises(InputError) as e:
        load_intrinsics(path)
    text = str(e.value)
    assert str(path) in text and msg in text and "\n" not in text, text


def test_intrinsics_direct_validation():
    with pytest.raises(InputError, match="non-square pixels"):
        Intrinsics(900.0, 921.0, 640, 360, 1280, 720)
    with pytest.raises(InputError, match="width: expected a positive integer"):
        Intrinsics(921.0, 921.0, 640, 360, -1, 720)
    assert np.isclose(Intrinsics(500, 500, 0, 0, 100, 1000).fov_deg, 90.0)
