"""2D fits: a 2D SDF tree fitted to a binary image as the shape itself or as a body of revolution's profile
(ipm.optim.fit2d, ipm fit TREE.json --shape IMAGE)."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from ipm.cli import app
from ipm.errors import InputError
from ipm.optim.fit2d import Fit2DSettings, field_2d, fit_2d, lifted
from ipm.sdf.tree import load_tree, tree_from_json

RECT_CIRCLE = {"node": "union", "children": [
    {"node": "rect", "params": {"size_x": 1.2, "size_y": 0.5}},
    {"node": "translate2d", "params": {"x": 0.4, "y": 0.2}, "children": [{"node": "circle", "params": {"radius": 0.35}}]}]}


def polygon(points):
    params = {}
    for i, (x, y) in enumerate(points):
        params[f"x{i}"], params[f"y{i}"] = x, y
    return {"node": "polygon", "size": len(points), "params": params}


VASE = [(0, 0), (0.5, 0), (0.62, 0.3), (0.55, 0.65), (0.3, 0.9), (0.22, 1.2), (0.3, 1.35), (0, 1.35)]
BOX = [(0, 0), (0.4, 0), (0.4, 0.3), (0.4, 0.6), (0.4, 0.9), (0.4, 1.0), (0.4, 1.2), (0, 1.2)]


def test_the_shape_field_is_the_tree_in_the_pose():
    tree = tree_from_json({"node": "circle", "params": {"radius": 0.5}}, dim=None)
    pose = torch.tensor([30.0, 20.0, math.log(10.0), 0.7], dtype=torch.float64)
    d = field_2d(tree, tree.theta(), pose, (40, 50), "shape")
    y, x = np.mgrid[0:40, 0:50] + 0.5
    want = np.hypot(x - 30.0, y - 20.0) - 5.0  # radius 0.5 at 10 pixels per unit, in pixels
    assert np.abs(d.numpy() - want).max() < 1e-9


def test_a_profile_silhouette_hides_the_axis_behind_the_wall():
    # a cup's wall (radii 0.4 to 0.5): seen from the side, the wall in front covers the axis
    wall = tree_from_json({"node": "translate2d", "params": {"x": 0.45, "y": 0.5},
                           "children": [{"node": "rect", "params": {"size_x": 0.1, "size_y": 1.0}}]}, dim=None)
    pose = torch.tensor([40.0, 70.0, math.log(50.0), 0.0], dtype=torch.float64)
    d = field_2d(wall, wall.theta(), pose, (80, 80), "profile")
    assert d[45, 40] < 0           # on the axis, half way up: inside the silhouette
    assert d[45, 40 + 24] < 0      # 0.48 out: on the wall
    assert d[45, 40 + 27] > 0      # 0.54 out: outside
    assert d[5, 40] > 0            # above the cup


def test_the_profile_silhouette_matches_the_rasterized_solid_of_revolution():
    from ipm.generators.sdftree import SdfTreeGenerator
    from ipm.render.camera import orbit_camera
    from ipm.render.raster import rasterize_mesh
    from ipm.types import TriMesh

    true3d = tree_from_json({"node": "revolve", "params": {"offset": 0.0}, "children": [polygon(VASE)]})
    gen = SdfTreeGenerator(true3d)
    m = gen.to_mesh(gen.spec.defaults(), resolution=96)
    # far away and narrow: nearly orthographic; 2.094 units across 160 pixels
    cam = orbit_camera(0.0, 0.0, 60.0, target=(0, 0.675, 0), fov_deg=2.0, width=160)
    mask = rasterize_mesh(TriMesh(m.verts.double(), m.faces), cam.to(torch.float64)).mask.numpy()
    prof = tree_from_json(polygon(VASE), dim=None)
    k = 160 / (2 * 60 * math.tan(math.radians(1.0)))
    pose = torch.tensor([80.0, 80.0 + 0.675 * k, math.log(k), 0.0], dtype=torch.float64)
    pred = (field_2d(prof, prof.theta(), pose, (160, 160), "profile") < 0).numpy()
    assert (pred & mask).sum() / (pred | mask).sum() > 0.98


@pytest.mark.parametrize("mode", ["shape", "profile"])
def test_field_gradients_match_float64_finite_differences(mode):
    # the profile's base and top tilted: below a flat base every radius is equally far, and the running
    # minimum over radii then has ties, where it is not differentiable (any tied pixel is a subgradient)
    tilted = [(0, -0.05), (0.5, 0.04), (0.62, 0.3), (0.55, 0.65), (0.3, 0.9), (0.22, 1.2), (0.3, 1.37), (0, 1.3)]
    tree = tree_from_json(RECT_CIRCLE if mode == "shape" else polygon(tilted), dim=None)

    def f(theta, pose):
        d = field_2d(tree, theta, pose, (12, 14), mode)
        return torch.sigmoid(-d / 0.7)

    theta = tree.theta().requires_grad_(True)
    # off the pixel grid's symmetries: a pixel equally far from two edges of the polygon is a kink of its
    # distance, where finite differences straddle two slopes
    pose = torch.tensor([6.13, 9.07 if mode == "profile" else 6.0, math.log(5.3), 0.2 if mode == "shape" else 0.0],
                        dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(f, (theta, pose), eps=1e-6, atol=1e-6)


def _draw(tree_json, pose, size=128, mode="shape"):
    t = tree_from_json(tree_json, dim=None)
    return (field_2d(t, t.theta(), torch.tensor(pose, dtype=torch.float64), (size, size), mode) < 0).numpy()


def test_a_shape_is_recovered_in_its_pose():
    mask = _draw(RECT_CIRCLE, [70.0, 60.0, math.log(40.0), 0.3])
    start = tree_from_json(RECT_CIRCLE, dim=None)
    start = start.with_values({n: 0.8 * v for n, v in start.values().items()})
    r = fit_2d(start, mask, Fit2DSettings(steps=300))
    assert r.iou > 0.97, r.iou
    assert r.pose["rotation_deg"] == pytest.approx(math.degrees(0.3), abs=3.0)
    # the size is shared between the parameters and the pose's scale: their product is the truth
    v = r.tree.values()
    assert v["n1_rect.size_x"] * r.pose["scale"] == pytest.approx(1.2 * 40.0, rel=0.05)
    # deterministic
    assert fit_2d(start, mask, Fit2DSettings(steps=300)).tree.values() == v


def test_a_profile_is_recovered_and_revolved():
    mask = _draw(polygon(VASE), [80.0, 140.0, math.log(80.0), 0.0], size=160, mode="profile")
    r = fit_2d(tree_from_json(polygon(BOX), dim=None), mask, Fit2DSettings(mode="profile", steps=300))
    assert r.iou > 0.97, r.iou
    data = lifted(r)
    assert data["tree"]["node"] == "revolve"
    assert tree_from_json(data).dim == 3
    with pytest.raises(InputError, match="extrude with a height"):
        lifted(fit_2d(tree_from_json(RECT_CIRCLE, dim=None), _draw(RECT_CIRCLE, [64, 64, 3.5, 0]),
                      Fit2DSettings(steps=2, starts=1)))


@pytest.mark.parametrize("mask, message", [
    (np.zeros((20, 20), bool), "the mask is empty"),
    (np.ones((20, 20), bool), "all shape"),
    (np.ones((2, 20), bool), "at least 4 x 4"),
])
def test_bad_masks_are_refused(mask, message):
    with pytest.raises(InputError, match=message):
        fit_2d(tree_from_json(RECT_CIRCLE, dim=None), mask)


def test_bad_settings_and_trees_are_refused():
    with pytest.raises(InputError, match="2D fit settings"):
        Fit2DSettings(steps=0).check()
    with pytest.raises(InputError, match="loss: expected"):
        Fit2DSettings(loss="l2").check()
    with pytest.raises(InputError, match="a 2D root"):
        fit_2d(tree_from_json({"node": "sphere"}), np.eye(8, dtype=bool))


def _files(tmp_path):
    tree = tmp_path / "profile.json"
    tree.write_text(json.dumps({"tree": polygon(BOX)}))
    from PIL import Image

    img = tmp_path / "side.png"
    mask = _draw(polygon(VASE), [48.0, 88.0, math.log(50.0), 0.0], size=96, mode="profile")
    Image.fromarray((mask * 255).astype(np.uint8)).save(img)
    return tree, img


def test_cli_profile_fit_writes_a_tree_that_generates(tmp_path):
    tree, img = _files(tmp_path)
    out = tmp_path / "run"
    r = CliRunner().invoke(app, ["fit", str(tree), "--shape", str(img), "--profile", "--steps", "150", "-o", str(out),
                                 "--json"])
    assert r.exit_code == 0, r.output
    res = json.loads(r.stdout)
    assert res["iou"] > 0.95
    assert sorted(p.name for p in out.iterdir()) == ["lifted.json", "mesh.obj", "overlay.png", "result.json",
                                                     "tree.json"]
    assert load_tree(out / "tree.json", dim=None).dim == 2
    # the lifted tree is a generator like any other
    mesh = tmp_path / "again.obj"
    r = CliRunner().invoke(app, ["generate", str(out / "lifted.json"), "-o", str(mesh), "--resolution", "48"])
    assert r.exit_code == 0, r.output
    assert mesh.stat().st_size > 1000


@pytest.mark.parametrize("args, message", [
    (["--profile"], "expected with a 2D fit's --shape IMAGE"),
    (["--shape", "{img}", "--profile", "--extrude", "0.5"], "give one of them"),
    (["--shape", "{img}", "--extrude", "-1"], "expected a positive height"),
    (["--shape", "{tree}"], "expected a PNG image"),
    (["--shape", "{img}", "--masks", "{tmp}"], "a 2D fit takes no other target"),
    (["--shape", "{img}", "--loss", "l2"], "loss: expected"),
])
def test_cli_bad_2d_inputs_exit_2_with_one_line(tmp_path, args, message):
    tree, img = _files(tmp_path)
    args = [a.format(img=img, tree=tree, tmp=tmp_path) for a in args]
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "ipm", "fit", str(tree), *args, "-o", str(out)], capture_output=True,
                       text=True)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], r.stderr
    assert not out.exists()


def test_cli_a_3d_tree_is_refused_for_a_shape(tmp_path):
    _, img = _files(tmp_path)
    tree = tmp_path / "ball.json"
    tree.write_text(json.dumps({"tree": {"node": "sphere"}}))
    r = subprocess.run([sys.executable, "-m", "ipm", "fit", str(tree), "--shape", str(img), "-o",
                        str(tmp_path / "run")], capture_output=True, text=True)
    assert r.returncode == 2 and "expected a tree with a 2D root" in r.stderr, r.stderr


def test_a_profile_placed_in_the_view_world_matches_the_solid():
    from ipm.generators.sdftree import SdfTreeGenerator
    from ipm.metrics import fscore
    from ipm.optim.fit2d import profile_start
    from ipm.render.camera import orbit_camera
    from ipm.render.raster import rasterize_mesh
    from ipm.types import TriMesh

    gen = SdfTreeGenerator(tree_from_json({"node": "translate", "params": {"x": 0.1, "y": -0.6, "z": 0.0},
                                           "children": [{"node": "revolve", "params": {"offset": 0.0},
                                                         "children": [polygon(VASE)]}]}))
    truth = gen.to_mesh(gen.spec.defaults(), resolution=96)
    size, dist, fov = 128, 60.0, 2.2
    cam = orbit_camera(0.0, 0.0, dist, fov_deg=fov, width=size)
    mask = rasterize_mesh(TriMesh(truth.verts.double(), truth.faces), cam.to(torch.float64)).mask.numpy()
    start = profile_start(mask, 10)
    assert start.dim == 2 and len(start.spec.continuous) == 20
    r = fit_2d(start, mask, Fit2DSettings(mode="profile", steps=250))
    k = size / (2 * dist * math.tan(math.radians(fov / 2)))
    placed = SdfTreeGenerator(tree_from_json(lifted(r, pixels_per_unit=k, center_px=(size / 2, size / 2))))
    solid = placed.to_mesh(placed.spec.defaults(), resolution=96)
    assert fscore(solid, truth, 0.03, normalize=False) > 0.9
    with pytest.raises(InputError, match="takes a profile fit and the view's centre"):
        lifted(r, pixels_per_unit=k)
