"""The plane an object stands on, from a depth photo (ipm.io.ground), and a fit's camera held at its
elevation (MaskTarget.ground_elevation in ipm.optim.problem and ipm.optim.pose)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ipm.io.ground import support_plane
from tests.conftest import real_path

F, W, H, CX, CY = 300.0, 320, 240, 161.0, 118.0


def _scene(elev_deg: float, roll_deg: float = 0.0, height: float = 0.4, wall: bool = False):
    """Depth (H, W) of a camera ``height`` above a plane (or, ``wall``, facing a vertical one), pitched down
    by ``elev_deg`` and rolled by ``roll_deg``, with a box-shaped object in the middle 0.05 in front of it;
    and the object's mask."""
    e, r = math.radians(elev_deg), math.radians(roll_deg)
    n = np.array([math.sin(r) * math.cos(e), -math.cos(r) * math.cos(e), -math.sin(e)])
    if wall:  # a plane facing the camera: its normal along -z
        n = np.array([0.0, 0.0, -1.0])
    ys, xs = np.mgrid[0:H, 0:W]
    rays = np.stack([(xs + 0.5 - CX) / F, (ys + 0.5 - CY) / F, np.ones_like(xs, dtype=float)], -1)
    t = -height / (rays @ n)
    depth = np.where(t > 0, t, np.nan)
    mask = np.zeros((H, W), dtype=np.float32)
    mask[90:170, 130:190] = 1.0
    depth[mask > 0.5] -= 0.05
    return depth, mask


@pytest.mark.parametrize("elev", [10.0, 30.0, 60.0])
def test_the_plane_gives_the_cameras_elevation(elev):
    depth, mask = _scene(elev)
    plane = support_plane(depth, mask, F, F, CX, CY)
    assert plane is not None and plane.share > 0.99
    assert plane.elevation_deg == pytest.approx(elev, abs=1e-6)
    assert plane.roll_deg == pytest.approx(0.0, abs=1e-6)
    assert plane.residual < 1e-9


def test_the_plane_reports_the_photos_roll():
    depth, mask = _scene(35.0, roll_deg=8.0)
    plane = support_plane(depth, mask, F, F, CX, CY)
    assert plane.elevation_deg == pytest.approx(35.0, abs=1e-6)
    assert plane.roll_deg == pytest.approx(8.0, abs=1e-6)


def test_noisy_depth_still_gives_the_elevation_within_a_degree():
    depth, mask = _scene(40.0)
    rng = np.random.default_rng(0)
    depth = depth + rng.normal(0, 0.002, depth.shape)  # 2 mm of sensor noise at about 0.6 m
    depth[rng.random(depth.shape) < 0.2] = np.nan      # a fifth of the pixels without a reading
    plane = support_plane(depth, mask, F, F, CX, CY)
    assert plane.elevation_deg == pytest.approx(40.0, abs=1.0)


def test_no_plane_where_there_is_no_floor():
    # a wall facing the camera: a plane, but not one the object can stand on
    depth, mask = _scene(30.0, wall=True)
    assert support_plane(depth, mask, F, F, CX, CY) is None
    # depth without structure
    rng = np.random.default_rng(1)
    assert support_plane(rng.uniform(0.3, 2.0, (H, W)), mask, F, F, CX, CY) is None
    # no reading around the object
    assert support_plane(np.full((H, W), np.nan), mask, F, F, CX, CY) is None


def test_the_cleargrasp_table_is_measured():
    import cv2

    folder = real_path("photos/cleargrasp_cups/000000130-opaque-depth-mm.png").parent
    depth = cv2.imread(str(folder / "000000130-opaque-depth-mm.png"), cv2.IMREAD_UNCHANGED).astype(float) / 1000
    depth[depth <= 0] = np.nan
    mask = np.zeros(depth.shape, dtype=np.float32)
    mask[255:495, 380:600] = 1.0  # the mug's box
    plane = support_plane(depth, mask, 921.0, 921.0, 642.0, 359.0)
    # the table seen at about 46 degrees, level in the photo (the camera_intrinsics.yaml values)
    assert plane is not None and plane.elevation_deg == pytest.approx(45.8, abs=1.0)
    assert abs(plane.roll_deg) < 2.0


def test_a_known_ground_holds_the_fitted_cameras_elevation():
    from ipm.generators import get_generator
    from ipm.optim.encoding import POSE_SIZE
    from ipm.optim.problem import Problem
    from ipm.optim.settings import FitSettings
    from ipm.optim.targets import MaskTarget
    from ipm.render.camera import orbit_camera

    cam = orbit_camera(0.0, 25.0, 3.2, fov_deg=40.0, width=32, height=32)
    mask = torch.zeros(1, 32, 32)
    mask[0, 8:24, 10:22] = 1.0
    gen = get_generator("dishes")
    free = Problem(gen, MaskTarget(mask, [cam], known_intrinsics=True), FitSettings(camera="fit", preset="mug"))
    held = Problem(gen, MaskTarget(mask, [cam], known_intrinsics=True, ground_elevation=41.5),
                   FitSettings(camera="fit", preset="mug"))
    x = held.x0(camera=(20.0, 3.0, 30.0))
    assert float(held.camera_triple(x)[0]) == pytest.approx(41.5)
    assert float(free.camera_triple(x)[0]) == pytest.approx(20.0)
    # the pose report gives the camera as rendered: the ground's elevation, the intrinsics' FOV
    assert held.pose_json(x)["camera"]["elevation_deg"] == pytest.approx(41.5)
    assert held.pose_json(x)["camera"]["fov_deg"] == pytest.approx(40.0)
    _, g, _ = held.objective(x, dict(held.d0), need_grad=True)
    i = held.n + POSE_SIZE
    assert float(g[i]) == 0.0 and float(g[i + 1]) != 0.0  # the elevation held, the distance fitted
