"""Issue-level fits of the real generators to masks and meshes (small images and budgets, but the issue's scores)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ipm.generators import get_generator
from ipm.metrics import mask_iou
from ipm.optim.fit import FitSettings, MaskTarget, run_fit
from ipm.render.camera import heldout_views, input_views
from ipm.render.raster import rasterize_mesh
from ipm.types import TriMesh


def normalized_mesh(gen: str, preset: str, overrides=None) -> TriMesh:
    """The generator's mesh, bounding-box center at the origin and longest side 2: the frame these fits
    were calibrated in (the protocol's unit bounding sphere draws a mug smaller, so the same image sizes
    would give the fits fewer pixels)."""
    g = get_generator(gen)
    m = g.to_mesh(g.values(preset, overrides))
    V = m.verts.double().numpy()
    V = (V - 0.5 * (V.min(0) + V.max(0))) * (2.0 / (V.max(0) - V.min(0)).max())
    return TriMesh(torch.as_tensor(V), m.faces)


def mask_target(mesh: TriMesh, cams) -> MaskTarget:
    masks = torch.stack([rasterize_mesh(mesh, c).mask.float() for c in cams])
    return MaskTarget(masks, [c.to(torch.float32) for c in cams])


@pytest.mark.slow
def test_teacup_start_recovers_a_mug_from_two_views():
    """Masks of the dishes mug from 2 views; a memetic fit from the teacup preset keeps the handle and
    reaches exact mask IoU >= 0.98 on both views and >= 0.95 on 8 held-out views."""
    size = 96
    target = normalized_mesh("dishes", "mug")
    cams = input_views(2, size)
    res, prob, best = run_fit(get_generator("dishes"), mask_target(target, cams),
                              FitSettings(budget=400, seed=0, preset="teacup", discrete="memetic", polish=0.25))
    assert best["discrete"]["has_handle"] == 1
    fit = prob.mesh_world(best["x"].double(), best["discrete"]).detach()
    seen = [mask_iou(rasterize_mesh(fit, c).mask.numpy(), rasterize_mesh(target, c).mask.numpy()) for c in cams]
    held = [mask_iou(rasterize_mesh(fit, c).mask.numpy(), rasterize_mesh(target, c).mask.numpy())
            for c in heldout_views(size)[::2]]
    assert min(seen) >= 0.98, seen
    assert np.mean(held) >= 0.95, held


@pytest.mark.slow
def test_unknown_camera_single_view(tmp_path):
    """One view of a cup at an elevation and FOV the fit is not told (no cameras.json): ``camera="fit"``
    recovers elevation, distance and FOV with the shape and reaches exact mask IoU >= 0.97."""
    import ipm
    from ipm.io.masks import save_mask_set
    from ipm.render.camera import orbit_camera

    target = normalized_mesh("dishes", "mug", {"height": 0.9, "handle_reach": 0.35})
    cam = orbit_camera(60.0, 38.0, 3.0, fov_deg=50.0, width=96, height=96)
    save_mask_set(tmp_path / "masks", [rasterize_mesh(target, cam).mask], [cam])
    (tmp_path / "masks" / "cameras.json").unlink()
    res = ipm.fit("dishes", masks=tmp_path / "masks", camera="fit", preset="mug", discrete="none", budget=300,
                  seed=0, run_dir=tmp_path / "run")
    assert res.scores["iou_mean"] >= 0.97, res.scores


@pytest.mark.slow
def test_dishes_fit_to_the_real_mug_scan_by_chamfer():
    """Issue #5: the dishes generator fitted to the ocrtoc mug scan (Z up, normalized) by Chamfer from
    its ``mug`` preset reaches F-score >= 0.8 at tau = 0.02 and >= 0.98 at tau = 0.05 (exact
    point-to-surface distances), scored in the target's frame, where the fit placed it. (Renormalizing
    the result by its own bounding box, as protocol v1 did with every prediction, moves
    it by a few percent, which alone costs 0.08 to 0.2 of F-score at 0.02: results/perf/fit_mesh.md.)
    The scan's interior is a thick lower wall, which the per-height ``wall_thicken_i`` parameters
    follow."""
    from conftest import real_path

    from ipm.io.fit_targets import TargetFiles, load_target
    from ipm.metrics import fscore

    target, _ = load_target(TargetFiles(target_mesh=str(real_path("vessels/ocrtoc_mug.ply")), up="z"))
    res, prob, best = run_fit(get_generator("dishes"), target,
                              FitSettings(budget=1500, seed=0, preset="mug", discrete="none"))
    fit = prob.mesh_world(best["x"].double(), best["discrete"]).detach()
    f2, f5 = (fscore(fit, target.mesh, tau, normalize=False) for tau in (0.02, 0.05))
    assert f2 >= 0.8 and f5 >= 0.98, (f2, f5)


@pytest.mark.slow
def test_handle_found_from_a_start_without_one():
    """A tall mug with its handle in view, fitted from the generator's defaults (no handle: a body of
    revolution, which looks the same from every yaw). ``enumerate`` must switch the handle on: the pose
    grid is ranked again with the handle, instead of reusing poses that could not tell where it goes."""
    size = 256  # at 96 and 128 px the handle branch stalls at IoU 0.92 (handle misplaced) within 500
    target = normalized_mesh("dishes", "mug", {"height": 1.3, "handle_reach": 0.4, "handle_azimuth": 40.0})
    cams = input_views(1, size)
    res, prob, best = run_fit(get_generator("dishes"), mask_target(target, cams),
                              FitSettings(budget=500, seed=0, discrete="enumerate"))
    assert best["discrete"]["has_handle"] == 1
    fit = prob.mesh_world(best["x"].double(), best["discrete"]).detach()
    iou = mask_iou(rasterize_mesh(fit, cams[0]).mask.numpy(), rasterize_mesh(target, cams[0]).mask.numpy())
    assert iou >= 0.97, iou
