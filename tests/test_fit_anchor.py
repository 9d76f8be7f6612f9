"""Anchored parameters (Param.anchored): single-view fits charge FitSettings.anchor per unit of their
normalized distance from the start."""

from __future__ import annotations

import pytest
import torch

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.optim.problem import Problem
from ipm.optim.settings import FitSettings
from ipm.optim.targets import MaskTarget
from ipm.render.camera import orbit_camera


def _problem(anchor: float, views: int = 1, preset: str = "mug", depth: bool = False) -> Problem:
    cams = [orbit_camera(30.0 + 90.0 * k, 25.0, 3.2, fov_deg=40.0, width=32, height=32) for k in range(views)]
    masks = torch.zeros(views, 32, 32)
    masks[:, 8:26, 10:22] = 1.0
    target = MaskTarget(masks, cams, depth=torch.where(masks > 0.5, 3.0, 0.0) if depth else None)
    return Problem(get_generator("dishes"), target, FitSettings(preset=preset, anchor=anchor))


def _names(prob: Problem) -> list[str]:
    cont = [p.name for p in prob.gen.spec.continuous]
    return [cont[prob.free[i]] for i in prob.anchored]


def test_the_section_is_anchored_in_single_view_fits_without_depth_only():
    assert _names(_problem(0.02)) == ["section_squareness", "section_aspect"]
    assert _names(_problem(0.02, views=2)) == []
    assert _names(_problem(0.02, depth=True)) == []  # depth measures what one silhouette confuses
    assert _names(_problem(0.0)) == []


@pytest.mark.parametrize("preset", ["mug", "tumbler"])
def test_the_anchor_charges_the_l1_distance_from_the_start(preset):
    free, anchored = _problem(0.0, preset=preset), _problem(0.05, preset=preset)
    x0 = anchored.x0()
    d = dict(anchored.d0)
    l0, _, _ = free.objective(x0, d, need_grad=False)
    l1, _, _ = anchored.objective(x0, d, need_grad=False)
    assert float(l1 - l0) == pytest.approx(0.0, abs=1e-9)  # nothing at the start (the tumbler's square too)
    x = x0.clone()
    a = anchored.anchored
    x[a[0]] += 0.1
    x[a[1]] -= 0.2
    l0, g0, _ = free.objective(x, d, need_grad=True)
    l1, g1, _ = anchored.objective(x, d, need_grad=True)
    assert float(l1 - l0) == pytest.approx(0.05 * 0.3, rel=1e-6)
    dg = (g1 - g0)[a]
    assert torch.allclose(dg, torch.tensor([0.05, -0.05], dtype=dg.dtype), atol=1e-9)
    rest = [i for i in range(len(x)) if i not in a]
    assert torch.allclose(g1[rest], g0[rest], atol=1e-12)


def test_anchor_is_checked_and_old_runs_replay_without_it():
    from ipm.fitting import _settings_from_json

    with pytest.raises(InputError, match="anchor"):
        FitSettings(anchor=-0.1).check()
    assert _settings_from_json({"budget": 10}).anchor == 0.0
    assert FitSettings().anchor > 0
