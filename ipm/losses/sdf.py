"""SDF generators against a mesh: the SDF at target surface samples (should be 0) and occupancy at volume
samples (inside/outside of the target from the generalized winding number)."""

from __future__ import annotations

import torch


def sdf_surface_loss(sdf_values: torch.Tensor) -> torch.Tensor:
    """Mean absolute SDF at points sampled on the target surface (0 when the surfaces agree)."""
    return sdf_values.abs().mean()


def occupancy_loss(sdf_values: torch.Tensor, inside: torch.Tensor, sharpness: float = 50.0) -> torch.Tensor:
    """Binary cross-entropy between ``sigmoid(-sharpness * sdf)`` and the target's inside labels."""
    logits = -sharpness * sdf_values
    return torch.nn.functional.binary_cross_entropy_with_logits(logits, inside.to(sdf_values.dtype))
