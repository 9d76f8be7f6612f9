"""The one Adam loop (ipm/optim/adam.py) against torch.optim.Adam, bit for bit."""

from __future__ import annotations

import pytest
import torch

from ipm.optim.adam import Adam, minimize


def _loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return ((x - 0.3) ** 4).sum() + (x.sum() * y).sin().sum() + (y * y).sum()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_adam_equals_torch_adam_bit_for_bit(dtype):
    g = torch.Generator().manual_seed(0)
    x0, y0 = torch.randn(50, generator=g, dtype=dtype), torch.randn(3, 4, generator=g, dtype=dtype)
    a = [x0.clone().requires_grad_(True), y0.clone().requires_grad_(True)]
    b = [x0.clone().requires_grad_(True), y0.clone().requires_grad_(True)]
    ref = torch.optim.Adam(b, lr=0.01)
    for _ in range(30):
        ref.zero_grad()
        _loss(*b).backward()
        ref.step()
    minimize(a, lambda step: _loss(*a), 30, 0.01)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_minimize_schedule_and_after_step():
    x = torch.tensor([1.0, -2.0], dtype=torch.float64, requires_grad=True)
    seen = []

    def clamp(step, loss):
        seen.append((step, float(loss.detach())))
        with torch.no_grad():
            x.clamp_(min=-1.0)

    opt = minimize([x], lambda step: (x * x).sum(), 200, 0.1, schedule=lambda s: 0.1 * 0.99 ** s, after_step=clamp)
    assert [s for s, _ in seen] == list(range(200)) and seen[-1][1] < seen[0][1]
    assert opt.t == 200 and opt.lr == pytest.approx(0.1 * 0.99 ** 199)
    assert float(x.detach().abs().max()) < 0.05


def test_parameters_without_gradient_are_skipped():
    x = torch.ones(2, requires_grad=True)
    unused = torch.ones(2, requires_grad=True)
    opt = Adam([x, unused], lr=0.1)
    (x * x).sum().backward()
    opt.step()
    assert torch.equal(unused, torch.ones(2)) and (x < 1).all()
