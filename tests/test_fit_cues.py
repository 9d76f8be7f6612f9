"""Fits to cues beyond silhouettes: depth, part labels and photos (ipm.losses.cues, ipm.io.fit_targets,
the cue terms of ipm.optim.problem, sizes per count, the tie rule with cues, and the CLI's bad inputs)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from ipm.generators import get_generator
from ipm.io.fit_targets import TargetFiles, load_target, uncrop_camera
from ipm.losses import cues as C
from ipm.optim.problem import Problem
from ipm.optim.settings import FitSettings
from ipm.render.camera import orbit_camera, project, save_cameras
from tests.conftest import real_path, require_file, run_cli

PHOTOS = "photos/cleargrasp_cups"


# -- the losses ----------------------------------------------------------------------------------------

def test_depth_loss_is_zero_on_agreement_and_charges_uncovered_pixels():
    t = torch.full((8, 8), 2.0, dtype=torch.float64)
    t[0, 0] = math.nan
    obj = torch.ones(8, 8, dtype=torch.bool)
    cov = torch.ones(8, 8, dtype=torch.bool)
    assert float(C.depth_loss(t.nan_to_num(0.0), cov, t, obj, 2.0)) == 0.0
    # 10 % of the distance everywhere: about 1 (the module's scale)
    assert float(C.depth_loss(t.nan_to_num(0.0) * 1.1, cov, t, obj, 2.0)) == pytest.approx(0.95, abs=1e-9)
    # an uncovered object pixel costs what an error of a tenth of the distance costs
    cov2 = cov.clone()
    cov2[4, 4] = False
    assert float(C.depth_loss(t.nan_to_num(0.0), cov2, t, obj, 2.0)) == pytest.approx(1 / 63)
    assert C.depth_agreement(t.nan_to_num(0.0), cov2, t, obj, 2.0) == 62


def test_fit_light_recovers_a_lambert_light_in_closed_form():
    g = torch.Generator().manual_seed(0)
    n = torch.randn(500, 3, generator=g, dtype=torch.float64)
    n = n / n.norm(dim=1, keepdim=True)
    light = torch.tensor([0.3, 0.8, 0.52], dtype=torch.float64)
    light = light / light.norm()
    grey = 0.15 + 0.7 * (n @ light).clamp_min(0)
    pred, ambient, L = C.fit_light(n, grey)
    assert float(ambient) == pytest.approx(0.15, abs=1e-5)
    assert torch.allclose(L, 0.7 * light, atol=1e-5)
    assert float((pred - grey).abs().max()) < 1e-5


def test_shading_loss_gradient_matches_finite_differences():
    g = torch.Generator().manual_seed(1)
    n = torch.randn(6, 6, 3, generator=g, dtype=torch.float64)
    grey = torch.rand(6, 6, generator=g, dtype=torch.float64)
    pix = torch.ones(6, 6, dtype=torch.bool)

    def f(n):
        return C.shading_loss(n / n.norm(dim=-1, keepdim=True), grey, pix)[0]

    assert torch.autograd.gradcheck(f, (n.requires_grad_(True),), eps=1e-6, atol=1e-6)


def test_parts_loss_is_zero_for_equal_labels_and_one_without_overlap():
    a = torch.zeros(1, 32, 32, dtype=torch.float64)
    a[0, 4:8, 4:8] = 1
    b = torch.zeros_like(a)
    b[0, 20:24, 20:24] = 1
    assert float(C.parts_loss(a, a)) == pytest.approx(0.0, abs=1e-12)
    assert float(C.parts_loss(a, b)) == pytest.approx(1.0, abs=1e-9)
    shifted = torch.roll(a, 1, dims=-1)
    assert 0.0 < float(C.parts_loss(a, shifted)) < 0.5  # blurred: one pixel off still overlaps


# -- sizes per count -----------------------------------------------------------------------------------

def test_sizes_per_count_keep_the_total_when_the_count_changes():
    g = get_generator("building")
    m = torch.ones(1, 16, 16)
    m[0, 0, 0] = 0
    prob = Problem(g, _mask_target(m), FitSettings(preset="panel5", discrete="memetic"))
    x = prob.x0()
    for floors in (4, 5, 6):
        v = prob.values(x, {"floors": floors})
        assert v["floors"] * v["floor_height"] == pytest.approx(5 * 2.8)
    assert prob.values(x, {"floors": 7})["floor_height"] == 2.2  # 2.0 would be below the bound: clamped
    assert prob.values(x, {"sections": 2})["section_width"] == pytest.approx(32.0)
    # the canonical frame (bounding box at the start values) is the same for every floor count
    assert prob.frame({"floors": 6})[1] == pytest.approx(prob.frame({"floors": 5})[1])
    # a preset of other counts is encoded so that it decodes to its own sizes
    th = torch.tensor([2.5], dtype=torch.float64)
    theta = prob.theta0.clone()
    theta[0] = th
    back = prob.carry(prob.carry(theta, {"floors": 9}, inverse=True), {"floors": 9})
    assert float(back[0]) == pytest.approx(2.5)



def test_sizes_per_count_are_held_for_the_reference_counts():
    """The default start (5 storeys, 4 sections) cannot hold a 27-storey block's 3 m storeys nor its 10 sections of
    20 m: every storey comes out at the 2.2 m bound, the facade at 160 m. Held for the block's own counts (a learned proposal's), the block decodes to itself and
    other counts keep the total about the reference."""
    from ipm.optim.pose import proposed
    from ipm.proposals.propose import Proposal

    g = get_generator("building")
    m = torch.ones(1, 16, 16)
    m[0, 0, 0] = 0
    block = {**g.values(None, {}), "floors": 27, "floor_height": 3.0, "sections": 10, "section_width": 20.0}
    default = Problem(g, _mask_target(m), FitSettings())
    x, d = proposed(default, [Proposal(block, 1.0, 0.0)], default.x0())[0]
    assert default.values(x, d)["floor_height"] == 2.2
    assert default.values(x, d)["section_width"] == pytest.approx(16.0)  # 40 m held for 4 sections
    prob = Problem(g, _mask_target(m), FitSettings(), reference=block)
    x, d = proposed(prob, [Proposal(block, 1.0, 0.0)], prob.x0())[0]
    got = prob.values(x, d)
    assert (got["floors"], got["sections"]) == (27, 10)
    assert got["floor_height"] == pytest.approx(3.0) and got["section_width"] == pytest.approx(20.0)
    assert prob.values(x, {**d, "floors": 30})["floor_height"] == pytest.approx(3.0 * 27 / 30)
    # the start is held for the reference too: it decodes to itself where the reference is within the ratio
    near = Problem(g, _mask_target(m), FitSettings(), reference={"floors": 6, "sections": 5})
    assert near.values(near.x0(), near.d0)["floor_height"] == pytest.approx(2.8)
    assert near.frame(near.d0)[1] == pytest.approx(default.frame(default.d0)[1])
    assert prob.values(prob.x0(), prob.d0)["floor_height"] == 5.0  # 27 storeys: the start's 5 are squeezed
    # a count the fit does not search, or searches in a narrower range, is held for what it can be
    fixed = Problem(g, _mask_target(m), FitSettings(fix={"floors": 5}), reference=block)
    assert fixed.ref == {"floors": 5, "sections": 10}
    narrow = Problem(g, _mask_target(m), FitSettings(ranges={"floors": [1, 12]}, discrete="enumerate"),
                     reference=block)
    assert narrow.ref["floors"] == 12
    # a size the fit does not move is what it was told, at every count
    held = Problem(g, _mask_target(m), FitSettings(fix={"floor_height": 3.0}), reference=block)
    assert all(held.values(held.x0(), {"floors": f})["floor_height"] == 3.0 for f in (2, 5, 27))

def test_a_point_of_one_problem_is_adopted_by_another_as_the_same_shape():
    """Two fits of the building held for other reference counts (the default start's, a 6-storey proposal's): the
    same search vector means other storey heights in each, and ``adopt`` re-encodes one's point for the other so
    that it makes the same generator values and the same mesh in the world."""
    g = get_generator("building")
    m = torch.ones(1, 16, 16)
    m[0, 0, 0] = 0
    default = Problem(g, _mask_target(m), FitSettings(), dtype=torch.float64)
    tall = Problem(g, _mask_target(m), FitSettings(), reference={"floors": 6, "sections": 6}, dtype=torch.float64)
    d = {**default.d0, "floors": 7, "sections": 5}
    x = default.x0(yaw=35.0, scale=0.8, t=(0.1, -0.05, 0.2))
    assert tall.values(x, d)["floor_height"] != pytest.approx(default.values(x, d)["floor_height"])
    y = tall.adopt(default, x, d)
    want, got = default.values(x, d), tall.values(y, d)
    assert {k: got[k] for k in want} == pytest.approx(want)
    torch.testing.assert_close(tall.mesh_world(y, d).verts, default.mesh_world(x, d).verts, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="adopt: expected a problem of building"):
        tall.adopt(Problem(get_generator("dishes"), _mask_target(m), FitSettings()), x, d)


def _mask_target(m):
    from ipm.optim.targets import MaskTarget

    return MaskTarget(m, [orbit_camera(30.0, 25.0, 3.2, width=m.shape[-1], height=m.shape[-2])])


# -- part labels: the building's counts ---------------------------------------------------------------

def _panel5(folder, size: int):
    """panel5 with 7 floors and 4 windows, one front-left view (``size`` px): masks, depth, all part labels
    (ipm render) and a window mask as a user would draw it (255 on windows)."""
    cams = folder / "cams.json"
    save_cameras(cams, [orbit_camera(-35.0, 15.0, 3.2, fov_deg=40.0, width=size, height=size)])
    code, _, err = _cli(["render", "building", "--preset", "panel5", "--set", "floors=7", "--set", "windows=4",
                         "--cameras", str(cams), "--no-previews", "-o", str(folder / "r")])
    assert code == 0, err
    from PIL import Image

    labels = np.asarray(Image.open(folder / "r" / "part_000.png"))
    names = json.loads((folder / "r" / "parts.json").read_text())["labels"]
    win = [int(k) for k, v in names.items() if v == "windows"][0]
    (folder / "w").mkdir()
    Image.fromarray(np.where(labels == win, 255, 0).astype(np.uint8)).save(folder / "w" / "part_000.png")
    (folder / "w" / "parts.json").write_text(json.dumps({"labels": {"255": "windows"}}))
    return folder


@pytest.fixture(scope="module")
def panel5(tmp_path_factory):
    return _panel5(tmp_path_factory.mktemp("panel5"), 160)


@pytest.fixture(scope="module")
def panel5_192(tmp_path_factory):
    """At 192 px a window is about 4 px tall; at 160 px memetic settled on 8 floors (one run, budget 1000)."""
    return _panel5(tmp_path_factory.mktemp("panel5_192"), 192)


def _cli(args):
    """``ipm ARGS`` in this process (fixtures of module scope have no capsys): (exit code, "", "")."""
    from ipm.cli import main

    try:
        main([str(a) for a in args])
    except SystemExit as e:
        return e.code, "", ""
    return 0, "", ""


def _true_pose_x(prob, g, floors, windows):
    """The search vector of panel5 with these counts at the pose ipm render put it in (its bounding box
    centered, farthest vertex at 1)."""
    d = {**prob.d0, "floors": floors, "windows": windows}
    vals = g.values("panel5", {"floors": floors, "windows": windows})
    th, _ = g.split(vals, torch.float64)
    v = g.mesh(th, d).verts.double()
    c = 0.5 * (v.min(0).values + v.max(0).values)
    r = float((v - c).norm(dim=1).max())
    c0, L0 = prob.frame(d)
    scale = L0 / (2 * r)
    t = -scale * (c - c0) * 2 / L0
    return prob.x0(theta=prob.carry(th, d, inverse=True), scale=scale, t=tuple(float(a) for a in t)), d


def test_window_labels_tell_the_floor_and_window_counts_apart(panel5):
    """At the true pose and sizes, the counts of the target (7 floors, 4 windows) fit the window mask best:
    the silhouette alone cannot tell 7 floors of 2.8 m from 6 of 3.27 (sizes per count keep the outline)."""
    g = get_generator("building")
    target, _ = load_target(TargetFiles(masks=str(panel5 / "r"), parts=str(panel5 / "w")))
    assert target.part_names == ("windows",)
    prob = Problem(g, target, FitSettings(preset="panel5", discrete="memetic"))
    x, d = _true_pose_x(prob, g, 7, 4)
    best, extras = prob.objective(x, d, False)[::2]
    assert extras["iou"][0] > 0.9
    inter, union = extras["parts_px"][0][0]
    assert inter / union > 0.95
    for floors, windows in ((6, 4), (8, 4), (7, 3), (7, 5)):
        loss = prob.objective(x, {**d, "floors": floors, "windows": windows}, False)[0]
        assert float(loss) > float(best) + 0.05, (floors, windows)


@pytest.mark.slow
@pytest.mark.parametrize(("strategy", "budget"), [("enumerate", 500), ("memetic", 1000)])
def test_window_mask_recovers_the_floor_and_window_counts(panel5_192, tmp_path, capsys, strategy, budget):
    """The requirement the silhouette alone could not meet: from one view, silhouette + window mask, the
    pose scale free, both searches end on 7 floors and 4 windows (out of 5-9 and 3-5)."""
    # the wings and roof-top boxes (none in the target) are held at their defaults with the other switches:
    # this test is about the counts the window mask tells apart
    g = get_generator("building")
    hold = [a for p in g.spec.discrete if p.name.startswith("wing") or p.name == "roof_boxes"
            for a in ("--fix", f"{p.name}={p.default}")]
    code, out, err = run_cli(["fit", "building", "--preset", "panel5", "--masks", panel5_192 / "r",
                              "--parts", panel5_192 / "w",
                              "--discrete", strategy, "--range", "floors=5:9", "--range", "windows=3:5",
                              "--fix", "sections=4", "--fix", "balcony_pattern=1", "--fix", "roof_type=0",
                              "--fix", "has_door=1", "--fix", "back_windows=1", *hold, "--budget", budget,
                              "--threads", 1, "--json", "-o", tmp_path / "fit"], capsys)
    assert code == 0, err
    params = json.loads((tmp_path / "fit" / "params.json").read_text())["params"]
    assert (params["floors"], params["windows"]) == (7, 4)
    # the polish with the finer blur can give back some input-view IoU (0.93 to 0.98 measured)
    assert json.loads(out)["iou_mean"] > 0.9


def test_part_label_gradient_matches_finite_differences(panel5):
    g = get_generator("building")
    target, _ = load_target(TargetFiles(masks=str(panel5 / "r"), parts=str(panel5 / "w")),
                            dtype=torch.float64)
    prob = Problem(g, target, FitSettings(preset="panel5", discrete="none", depth_weight=0.0),
                   dtype=torch.float64)
    x, d = _true_pose_x(prob, g, 7, 4)
    x = x.clone()
    x[: prob.n] = (x[: prob.n] + 0.02).clamp(0, 1)  # off the optimum
    _, grad, _ = prob.objective(x, d, True)
    torch.manual_seed(0)
    for _ in range(2):
        v = torch.randn(prob.n, dtype=torch.float64)
        v = torch.cat([v / v.norm(), torch.zeros(prob.m - prob.n, dtype=torch.float64)])
        h = 1e-5
        fd = (float(prob.objective(x + h * v, d, False)[0]) - float(prob.objective(x - h * v, d, False)[0])) / (2 * h)
        assert float(grad @ v) == pytest.approx(fd, rel=0.05, abs=1e-3)


# -- depth: a handle inside the silhouette ----------------------------------------------------------------

def test_depth_shows_a_handle_the_silhouette_hides(tmp_path):
    """A mug whose handle points at the camera: with and without the handle the silhouettes are nearly the
    same, the depth maps are not, and the tie rule's pixel counts see it."""
    code, _, err = _cli(["render", "dishes", "--preset", "mug", "--set", "handle_azimuth=-60", "--views", "1",
                         "--size", "128", "--no-previews", "-o", str(tmp_path / "m")])
    assert code == 0, err
    g = get_generator("dishes")
    target, _ = load_target(TargetFiles(masks=str(tmp_path / "m"), depth=str(tmp_path / "m")))
    prob = Problem(g, target, FitSettings(preset="mug", discrete="memetic"))
    theta = prob.theta0.clone()
    theta[[p.name for p in g.spec.continuous].index("handle_azimuth")] = -60.0
    v = g.mesh(theta, prob.d0).verts.double()
    c = 0.5 * (v.min(0).values + v.max(0).values)
    r = float((v - c).norm(dim=1).max())
    c0, L0 = prob.frame(prob.d0)
    scale = L0 / (2 * r)
    x = prob.x0(theta=theta, scale=scale, t=tuple(float(a) for a in -scale * (c - c0) * 2 / L0))
    with_h = prob.objective(x, {"has_handle": 1}, False)
    x0 = prob.repose(x, {"has_handle": 1}, {"has_handle": 0})
    without = prob.objective(x0, {"has_handle": 0}, False)
    n = int((target.masks > 0.5).sum())
    iou_moved = sum(abs(a - b) for a, b in zip(with_h[2]["iou_px"][0], without[2]["iou_px"][0]))
    depth_moved = abs(with_h[2]["depth_px"][0] - without[2]["depth_px"][0])
    assert depth_moved > 0.05 * n > 10 * iou_moved
    assert float(without[0]) > float(with_h[0]) + 0.05


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["enumerate", "memetic"])
def test_depth_finds_the_hidden_handle(tmp_path, capsys, strategy):
    """One view, silhouette + depth, started from the handle-less default: the fit switches the handle on
    and points it at the camera. The body is a body of revolution, so only the handle's direction in the
    world (pose yaw + handle azimuth) is determined; it must be within 15 degrees of the target's."""
    code, _, err = _cli(["render", "dishes", "--preset", "mug", "--set", "handle_azimuth=-60", "--views", "1",
                         "--size", "128", "--no-previews", "-o", str(tmp_path / "m")])
    assert code == 0, err
    capsys.readouterr()  # the render's report
    code, out, err = run_cli(["fit", "dishes", "--masks", tmp_path / "m", "--depth", tmp_path / "m",
                              "--discrete", strategy, "--budget", 600, "--threads", 1, "--json",
                              "-o", tmp_path / "fit"], capsys)
    assert code == 0, err
    fitted = json.loads((tmp_path / "fit" / "params.json").read_text())
    assert fitted["params"]["has_handle"] == 1
    world = fitted["pose"]["yaw_deg"] + fitted["params"]["handle_azimuth"]
    assert abs((world - (-60.0) + 180.0) % 360.0 - 180.0) <= 15.0
    assert json.loads(out)["iou_mean"] > 0.95


# -- photos -----------------------------------------------------------------------------------------------

def test_photo_target_crops_and_scales_the_cleargrasp_mug():
    photo = real_path(f"{PHOTOS}/000000130-opaque-rgb-img.jpg")
    folder = photo.parent
    for name in ("000000130-opaque-depth-mm.png", "camera_intrinsics.yaml"):
        require_file(folder / name)
    files = TargetFiles(image=str(photo), box=(380, 255, 600, 495), depth=str(folder / "000000130-opaque-depth-mm.png"),
                        intrinsics=str(folder / "camera_intrinsics.yaml"), size=96)
    target, ph = load_target(files, camera="fit")
    assert target.masks.shape == (1, 96, 96) and target.known_intrinsics
    assert target.outside_is_background  # the mug is well inside the photo
    assert target.cues == ("depth", "image")
    # metres per scene unit: the mug's median depth sits at the protocol's distance
    d = ph.depth[ph.mask > 0.5]
    assert ph.unit == pytest.approx(float(np.nanmedian(d)) / 3.2)
    # the crop's camera maps a world point where the photo's camera does, through the window
    cam = target.cameras[0].to(torch.float64)
    full = uncrop_camera(cam, ph)
    p = torch.tensor([[0.1, 0.2, -0.3], [0.0, 0.0, 0.0]], dtype=torch.float64)
    xy_crop, _ = project(p, cam)
    xy_full, _ = project(p, full)
    x0, y0, _ = ph.window
    assert torch.allclose(xy_crop, (xy_full - torch.tensor([x0, y0], dtype=torch.float64)) * ph.scale, atol=1e-6)
    assert full.principal_point == pytest.approx((642.0, 359.0))


def test_photo_and_depth_fit_the_real_mug(tmp_path, capsys):
    """The issue's real case: the teal mug of the ClearGrasp scene from its photo, a box, its depth map and
    the camera's intrinsics. The table under it holds the camera's elevation (with it free the fit
    settled 10 degrees off and the depth error stayed above 6 mm); the polish gets 0.4 of the budget.

    The margins are those that hold under every perturbation of benchmarks/perturbation.py (issue #28):
    this fit has two modes, the handle fitted on the right (photo IoU 0.96, loss 0.12) or hidden in front
    of the body (0.91, loss 0.19), and which one it reaches depends on the last bits of torch's kernels
    (torch without SIMD, and every float64 run tried, end in the second), so the test asserts what both
    share, not 0.95 (results/perturbation.md)."""
    photo = real_path(f"{PHOTOS}/000000130-opaque-rgb-img.jpg")
    folder = photo.parent
    out = tmp_path / "run"
    code, stdout, err = run_cli(
        ["fit", "dishes", "--preset", "mug", "--image", str(photo), "--box", "380,255,600,495",
         "--depth", str(require_file(folder / "000000130-opaque-depth-mm.png")),
         "--intrinsics", str(require_file(folder / "camera_intrinsics.yaml")), "--image-weight", "0",
         "--size", "128", "--budget", "1000", "--polish", "0.4", "--discrete", "enumerate", "--json",
         "-o", str(out)], capsys)
    assert code == 0, err
    scores = json.loads(stdout)
    assert scores["ground_elevation_deg"] == pytest.approx(45.8, abs=1.0)
    assert scores["photo_iou"] >= 0.90 and scores["depth_median_mm"] <= 5.5, scores
    params = json.loads((out / "params.json").read_text())["params"]
    assert params["has_handle"] == 1
    assert (out / "overlay_photo.png").is_file()


def test_outside_share_charges_geometry_outside_the_view_and_pulls_it_back():
    from ipm.optim.problem import outside_share

    cam = orbit_camera(0.0, 0.0, 3.0, fov_deg=40.0, width=64, height=48)
    inside = torch.tensor([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0]], dtype=torch.float64)
    assert float(outside_share(inside, [cam])) == 0.0
    far = torch.tensor([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]], dtype=torch.float64, requires_grad=True)
    share = outside_share(far, [cam])
    xy, _ = project(far[1:].detach(), cam)
    # one vertex of two, (x - width) pixels out, in image heights
    assert float(share.detach()) == pytest.approx(float(xy[0, 0] - 64) / 48 / 2, rel=1e-9)
    share.backward()
    assert float(far.grad[1, 0]) > 0 and float(far.grad[0].abs().sum()) == 0.0  # descent moves it back in


# -- bad inputs: one line, exit 2, nothing written --------------------------------------------------------

def _bad(args, capsys, tmp_path, needle):
    out = tmp_path / "run"
    code, _, err = run_cli(["fit", *args, "--budget", "3", "-o", str(out)], capsys)
    assert code == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("ipm: error:")]
    assert len(lines) == 1 and needle in lines[0], err
    assert not out.exists()


def test_bad_cue_inputs(tmp_path, capsys):
    code, _, err = run_cli(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "32", "--no-previews",
                            "-o", str(tmp_path / "m")], capsys)
    assert code == 0, err
    m = tmp_path / "m"
    small = tmp_path / "small"
    small.mkdir()
    np.save(small / "depth_000.npy", np.ones((16, 16), dtype=np.float32))
    _bad(["dishes", "--masks", str(m), "--depth", str(small)], capsys, tmp_path, "of one size")
    empty = tmp_path / "empty"
    empty.mkdir()
    np.save(empty / "depth_000.npy", np.full((32, 32), np.nan, dtype=np.float32))
    _bad(["dishes", "--masks", str(m), "--depth", str(empty)], capsys, tmp_path, "valid depth")
    labels = tmp_path / "labels"
    labels.mkdir()
    from PIL import Image

    Image.fromarray(np.zeros((32, 32), dtype=np.uint8)).save(labels / "part_000.png")
    (labels / "parts.json").write_text(json.dumps({"labels": {"1": "lid"}}))
    _bad(["dishes", "--masks", str(m), "--parts", str(labels)], capsys, tmp_path, "lid: not a part of dishes")
    _bad(["dishes", "--image", str(m / "view_000.png")], capsys, tmp_path, "--mask")
    _bad(["dishes", "--masks", str(m), "--mask", str(m / "view_000.png")], capsys, tmp_path, "--image")
    _bad(["building", "--masks", str(m), "--discrete", "enumerate"], capsys, tmp_path, "at most 64 combinations")
    _bad(["chair", "--masks", str(m), "--depth", str(m)], capsys, tmp_path, "mesh generator")
