"""The transport mask losses (sinkhorn, sliced): known distances, gradients against float64 finite
differences, a gradient where the masks do not overlap, the dustbin, and the weighted sums of losses."""

import math

import pytest
import torch

from ipm import losses as L
from ipm.errors import InputError
from ipm.losses.masks._transport import pooled
from ipm.optim.settings import FitSettings


def disk(cx, cy, r, n=32, dtype=torch.float64, edge=0.7):
    """A soft disk (..., n, n): centre (cx, cy) and radius r in pixels."""
    y, x = torch.meshgrid(torch.arange(n, dtype=dtype) + 0.5, torch.arange(n, dtype=dtype) + 0.5, indexing="ij")
    return torch.sigmoid((r - ((x - cx) ** 2 + (y - cy) ** 2).sqrt()) / edge)


@pytest.mark.parametrize("name", ["sinkhorn", "sliced"])
def test_zero_on_equal_masks_symmetric_and_positive(name):
    fn = L.LOSSES[name]
    a, b = disk(12, 14, 5), disk(20, 16, 6)
    assert abs(float(fn(a, a))) < 1e-6  # sinkhorn: the default 20 iterations converge to ~2e-8
    assert float(fn(a, b)) > 1e-3
    assert float(fn(a, b)) == pytest.approx(float(fn(b, a)), rel=1e-6, abs=1e-9)


def test_sinkhorn_of_a_translation_is_the_squared_shift():
    # the debiased divergence of a mass and its translate is |shift|^2 (in squared shares of the image)
    t = disk(20, 16, 5)
    for shift in (1.0, 4.0, 10.0):
        got = float(L.sinkhorn_loss(disk(20 - shift, 16, 5), t, iterations=60))
        assert got == pytest.approx((shift / 32) ** 2, rel=0.02)


def test_sliced_w1_of_a_translation_is_its_mean_projection():
    # W1 along direction u of a translation by s is |s . u|; the mean over half a turn is 2 s / pi
    t = disk(20, 16, 5)
    for shift in (2.0, 8.0):
        got = float(L.sliced_loss(disk(20 - shift, 16, 5), t, projections=256))
        assert got == pytest.approx(2.0 / math.pi * shift / 32, rel=0.02)


@pytest.mark.parametrize("name, opts", [("sinkhorn", {"iterations": 200, "size": 12, "blur": 0.15}),
                                        ("sinkhorn", {"iterations": 200, "size": 12, "blur": 0.15, "dustbin": 0.3}),
                                        ("sliced", {"projections": 16, "size": 12})])
def test_gradient_matches_float64_finite_differences(name, opts):
    fn = L.LOSSES[name]
    torch.manual_seed(0)
    t = disk(5, 7, 3, n=12)
    theta = torch.tensor([7.5, 5.0, 2.5], dtype=torch.float64, requires_grad=True)

    def f(th):
        return fn(disk(th[0], th[1], th[2], n=12), t, **opts)

    (g,) = torch.autograd.grad(f(theta), theta)
    h = 1e-5
    for i in range(3):
        e = torch.zeros(3, dtype=torch.float64)
        e[i] = h
        fd = (f(theta.detach() + e) - f(theta.detach() - e)) / (2 * h)
        assert float(g[i]) == pytest.approx(float(fd), rel=2e-3, abs=1e-7), (i, float(g[i]), float(fd))


@pytest.mark.parametrize("name", ["sinkhorn", "sliced"])
def test_masks_that_do_not_overlap_still_have_a_gradient_towards_each_other(name):
    t = disk(28, 16, 4)
    cx = torch.tensor(4.0, dtype=torch.float64, requires_grad=True)
    pred = disk(cx, 16, 4)
    assert float((pred * t).sum().detach()) < 1e-8  # no overlap: soft IoU's gradient vanishes
    (g_iou,) = torch.autograd.grad(L.soft_iou_loss(disk(cx, 16, 4), t), cx)
    assert abs(float(g_iou)) < 1e-8
    (g,) = torch.autograd.grad(L.LOSSES[name](pred, t), cx)
    assert float(g) < -1e-3  # moving right (towards the target) lowers the loss


def test_the_dustbin_leaves_an_unexplained_blob_alone():
    # the target is the disk plus a far blob the shape cannot explain; without a dustbin the transport pulls
    # the disk towards the blob, with it the disk in place is the minimum
    n = 48
    t = torch.maximum(disk(14, 24, 6, n=n), disk(42, 24, 3, n=n))
    losses = {}
    for dustbin in (None, 0.2):
        opts = {"iterations": 60, "size": 48, "dustbin": dustbin}
        losses[dustbin] = [float(L.sinkhorn_loss(disk(14 + s, 24, 6, n=n), t, **opts)) for s in (0, 2, 4)]
    plain, partial = losses[None], losses[0.2]
    assert plain[1] < plain[0]                         # balanced: moving towards the blob pays
    assert partial[0] < partial[1] < partial[2]        # partial: the disk stays where it is


def test_pooling_keeps_the_mass_and_large_images_agree_with_small_ones():
    m = disk(40, 50, 20, n=100)
    assert float(pooled(m, 32).sum()) == pytest.approx(float(m.sum()), rel=1e-12)
    assert pooled(m, 32).shape == (25, 25)
    small = float(L.sinkhorn_loss(disk(10, 16, 5), disk(20, 16, 5), size=32, iterations=40))
    large = float(L.sinkhorn_loss(disk(40, 64, 20, n=128), disk(80, 64, 20, n=128), size=32, iterations=40))
    assert large == pytest.approx(small, rel=0.05)


def test_an_empty_mask_gives_a_finite_loss_and_gradient():
    p = torch.zeros(16, 16, dtype=torch.float64, requires_grad=True)
    t = disk(8, 8, 3, n=16)
    for name in ("sinkhorn", "sliced"):
        v = L.LOSSES[name](p, t)
        (g,) = torch.autograd.grad(v, p)
        assert torch.isfinite(v) and torch.isfinite(g).all()


def test_weighted_sums_of_losses():
    assert L.parse_loss("iou+0.5*sinkhorn") == [(1.0, "iou"), (0.5, "sinkhorn")]
    assert L.parse_loss(" sliced ") == [(1.0, "sliced")]
    a, b = disk(12, 14, 5), disk(16, 14, 5)
    both = L.mask_loss("iou+0.5*sinkhorn", blur=0.05, projections=8)(a, b)
    assert float(both) == pytest.approx(float(L.soft_iou_loss(a, b) + 0.5 * L.sinkhorn_loss(a, b, blur=0.05)))
    assert L.loss_options("sinkhorn") == {"blur", "iterations", "dustbin", "size"}
    assert L.loss_options("iou") == set()


@pytest.mark.parametrize("spec", ["", "iou+", "2*", "iou*2", "1e-3*iou", "inf*iou", "iou+iou", "hausdorff"])
def test_bad_loss_expressions_are_refused_with_one_line(spec):
    with pytest.raises(InputError) as e:
        L.parse_loss(spec)
    assert str(e.value).startswith("loss: expected ") and "\n" not in str(e.value)


def test_a_dustbin_without_sinkhorn_is_refused():
    with pytest.raises(InputError, match="transport dustbin: applies to a loss with a sinkhorn term, got loss 'iou'"):
        FitSettings(loss="iou", transport={"dustbin": 0.2}).check()
    FitSettings(loss="iou+sinkhorn", transport={"dustbin": 0.2}).check()
