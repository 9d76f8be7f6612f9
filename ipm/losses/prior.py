"""A pull towards a reference point of the normalized parameter space."""

from __future__ import annotations

import torch


def prior_loss(u: torch.Tensor, u_ref: torch.Tensor) -> torch.Tensor:
    """Squared distance in normalized parameter space to a reference (a preset)."""
    return ((u - u_ref) ** 2).mean()
