"""One Adam loop for tensors: :class:`Adam` (the optimizer) and :func:`minimize` (the loop).

:class:`Adam` computes exactly what ``torch.optim.Adam`` (default settings, no weight decay) computes on
the CPU, operation for operation, so results do not depend on which of the two ran
(tests/test_optim_adam.py compares them bit for bit). It exists because ``torch.optim`` imports
``torch._dynamo`` on first use, which costs seconds at the command line.

Kingma and Ba, "Adam: a method for stochastic optimization", ICLR 2015.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch


class Adam:
    """Adam on a list of leaf tensors (updated in place).

    params: the tensors (``requires_grad``); lr: step size, may be changed between steps;
    betas, eps: as in ``torch.optim.Adam``.
    """

    def __init__(self, params: Sequence[torch.Tensor], lr: float, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8):
        self.params, self.lr, self.betas, self.eps = list(params), lr, betas, eps
        self.m = [torch.zeros_like(p) for p in self.params]
        self.v = [torch.zeros_like(p) for p in self.params]
        self.t = 0

    def zero_grad(self) -> None:
        """Drop the parameters' gradients (set to None, as ``torch.optim`` does by default)."""
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update from the gradients in ``p.grad`` (tensors without a gradient are skipped)."""
        self.t += 1
        b1, b2 = self.betas
        step = float(self.t)
        step_size = self.lr / (1 - b1 ** step)
        c2_sqrt = (1 - b2 ** step) ** 0.5
        for p, m, v in zip(self.params, self.m, self.v):
            if p.grad is None:
                continue
            m.lerp_(p.grad, 1 - b1)
            v.mul_(b2).addcmul_(p.grad, p.grad, value=1 - b2)
            p.addcdiv_(m, (v.sqrt() / c2_sqrt).add_(self.eps), value=-step_size)


def minimize(params: Sequence[torch.Tensor], loss_fn: Callable[[int], torch.Tensor], steps: int, lr: float, *,
             schedule: Callable[[int], float] | None = None,
             after_step: Callable[[int, torch.Tensor], None] | None = None) -> Adam:
    """Run ``steps`` Adam steps on ``params``: each step evaluates ``loss_fn(step)`` (a 0-dim tensor),
    back-propagates and updates the parameters in place.

    schedule: the learning rate of each step (default: ``lr`` throughout); after_step: called with the
    step and its loss after each update (projections, logging, progress). Returns the optimizer.
    """
    opt = Adam(params, lr=lr)
    for step in range(steps):
        if schedule is not None:
            opt.lr = schedule(step)
        loss = loss_fn(step)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if after_step is not None:
            after_step(step, loss)
    return opt


def geometric(start: float, end: float, step: int, steps: int) -> float:
    """Geometric interpolation from ``start`` (step 0) to ``end`` (step ``steps - 1``): a learning-rate or
    blur schedule for :func:`minimize`."""
    t = min(max(step / max(steps - 1, 1), 0.0), 1.0)
    return float(start * (end / start) ** t)
