"""Losses against independent computations: brute-force Chamfer, hand-counted IoU, finite differences."""

from __future__ import annotations

import pytest
import torch

from ipm import losses as L


def brute_chamfer(a, b):
    d = torch.cdist(a, b) ** 2
    return d.min(1).values.mean() + d.min(0).values.mean()


@pytest.mark.parametrize("n, m", [(300, 200), (1, 50), (64, 1)])
def test_chamfer_matches_the_min_over_all_pairs(n, m):
    g = torch.Generator().manual_seed(n + m)
    a = torch.randn(n, 3, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.randn(m, 3, generator=g, dtype=torch.float64) * 0.7 + 0.2
    value = L.chamfer_loss(a, b)
    want = brute_chamfer(a, b)
    assert float(value.detach()) == pytest.approx(float(want.detach()), rel=1e-12)
    (g1,) = torch.autograd.grad(value, a)
    (g2,) = torch.autograd.grad(want, a)
    assert torch.allclose(g1, g2, atol=1e-12)


def test_chamfer_gradient_against_finite_differences():
    g = torch.Generator().manual_seed(3)
    a = torch.randn(40, 3, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.randn(60, 3, generator=g, dtype=torch.float64)
    # generic random points: no ties between nearest neighbours, so the loss is smooth around a
    assert torch.autograd.gradcheck(lambda x: L.chamfer_loss(x, b), (a,), eps=1e-7, atol=1e-6)


def test_chamfer_of_identical_sets_is_zero_and_grows_with_a_shift():
    a = torch.rand(100, 3, dtype=torch.float64)
    assert float(L.chamfer_loss(a, a)) == 0.0
    # a set and its copy shifted far along x: every nearest neighbour is the shifted twin
    far = torch.tensor([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]], dtype=torch.float64)
    assert float(L.chamfer_loss(far, far + torch.tensor([0.5, 0, 0], dtype=torch.float64))) == pytest.approx(0.5)


def test_surface_samples_move_with_the_vertices():
    v = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64)
    f = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    s = L.SurfaceSampler.draw(v, f, 500, torch.Generator().manual_seed(0))
    assert torch.allclose(s.bary.sum(1), torch.ones(500, dtype=torch.float64)) and (s.bary >= 0).all()
    p = s.points(v)
    assert torch.allclose(s.points(v * 2.0 + 1.0), p * 2.0 + 1.0)  # affine maps commute with sampling
    with pytest.raises(ValueError, match="zero area"):
        L.SurfaceSampler.draw(torch.zeros(4, 3), f, 10)


def test_mask_losses_by_hand():
    a = torch.zeros(4, 4)
    b = torch.zeros(4, 4)
    a[:2] = 1.0          # 8 pixels
    b[1:3] = 1.0         # 8 pixels, 4 shared
    assert float(L.soft_iou_loss(a, b)) == pytest.approx(1 - 4 / 12, abs=1e-6)
    assert float(L.mse_loss(a, b)) == pytest.approx(8 / 16)


def test_occupancy_and_surface_losses():
    sdf = torch.tensor([-0.5, 0.5])
    right = L.occupancy_loss(sdf, torch.tensor([True, False]))
    wrong = L.occupancy_loss(sdf, torch.tensor([False, True]))
    assert float(right) < 1e-6 < 10.0 < float(wrong)
    assert float(L.sdf_surface_loss(torch.tensor([0.1, -0.3]))) == pytest.approx(0.2)
