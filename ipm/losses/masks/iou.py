"""Soft intersection over union."""

from __future__ import annotations

import torch

from ipm.losses.masks import LOSSES


@LOSSES.register("iou")
def soft_iou_loss(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """``1 - sum(p t) / sum(p + t - p t)`` per mask of ``pred, target (..., H, W)``, averaged over leading
    axes; 0-dim, range [0, 1]."""
    inter = (pred * target).sum((-2, -1))
    union = (pred + target - pred * target).sum((-2, -1))
    return (1.0 - inter / (union + eps)).mean()
