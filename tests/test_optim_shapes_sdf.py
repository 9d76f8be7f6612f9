"""The SDF shape adapter's two silhouette paths (FitSettings.sdf_silhouette): the iso-surface mesh against the
sphere-traced reference in a fit's terms (tree parameters and pose), the grid kept while only the pose moves."""

from __future__ import annotations

import pytest
import torch

from ipm.generators import get_generator
from ipm.optim.settings import FitSettings
from ipm.optim.shapes import POLISH_SIGMA_FACTOR, Pose, SdfShape
from ipm.render.camera import input_views

DT = torch.float64
CAMS = input_views(1, 96)


def setup(mode: str):
    gen = get_generator("mug")
    shape = SdfShape(gen, FitSettings(sdf_silhouette=mode), DT)
    theta = gen.spec.to_vector(gen.spec.defaults(), dtype=DT)
    verts = shape.vertices(theta, {})
    center = (verts.amin(0) + verts.amax(0)) / 2
    size = float((verts.amax(0) - verts.amin(0)).max())
    return shape, theta, center, size


def pose_of(x: torch.Tensor, center: torch.Tensor, size: float) -> Pose:
    """x: (5,) = translation (3), yaw (degrees), scale."""
    return Pose(x[:3], x[3], x[4], center, size)


def test_the_polish_blurs_follow_the_path():
    assert setup("mesh")[0].polish_sigma == POLISH_SIGMA_FACTOR
    assert setup("trace")[0].polish_sigma == 1.0


def test_mesh_and_traced_silhouettes_and_gradients_agree():
    """Hard masks at IoU >= 0.97; the soft IoU loss's gradient in the tree parameters and the pose at cosine
    >= 0.9, the mesh at 0.1 px^2 (sigma_factor 0.1 of 1 px^2) and the tracer at its half pixel."""
    pose0 = torch.tensor([0.05, -0.02, 0.03, 8.0, 0.9], dtype=DT)
    sils, grads = [], []
    target = None
    for mode, factor in (("trace", 1.0), ("mesh", 0.1)):
        shape, theta, center, size = setup(mode)
        if target is None:
            with torch.no_grad():
                target = (shape.silhouettes(theta * 1.1, {}, pose_of(torch.tensor([0.0, 0, 0, 0, 1], dtype=DT),
                                                                     center, size), CAMS, 1.0) > 0.5).to(DT)
        x = torch.cat([theta, pose0]).requires_grad_(True)
        n = len(theta)
        sil = shape.silhouettes(x[:n], {}, pose_of(x[n:], center, size), CAMS, factor)
        loss = 1 - (sil * target).sum() / (sil + target - sil * target).sum()
        (g,) = torch.autograd.grad(loss, x)
        sils.append(sil.detach() > 0.5)
        grads.append(g)
    a, b = sils
    assert float((a & b).sum() / (a | b).sum()) >= 0.97
    ga, gb = grads
    cos = float(ga @ gb / (ga.norm() * gb.norm()))
    assert cos >= 0.9, (cos, ga, gb)


@pytest.mark.parametrize("moves", ["pose", "theta"])
def test_the_grid_is_kept_while_only_the_pose_moves(moves, monkeypatch):
    from ipm.render import sdf_mesh_silhouette as M

    calls = []
    real = M.iso_surface
    monkeypatch.setattr(M, "iso_surface", lambda *a, **k: calls.append(1) or real(*a, **k))
    shape, theta, center, size = setup("mesh")
    for i in range(3):
        th = theta * (1 + 0.01 * i) if moves == "theta" else theta
        p = torch.tensor([0.01 * i, 0, 0, 3.0 * i, 1.0], dtype=DT)
        shape.silhouettes(th, {}, pose_of(p, center, size), CAMS, 1.0)
    assert len(calls) == (1 if moves == "pose" else 3)
