"""Mean squared error of the masks."""

from __future__ import annotations

import torch

from ipm.losses.masks import LOSSES


@LOSSES.register("mse")
def mse_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of masks ``pred, target (..., H, W)``; 0-dim."""
    return ((pred - target) ** 2).mean()
