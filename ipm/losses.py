"""Differentiable losses (torch only). Each is a pure function; ``LOSSES`` names the mask losses.

Masks: ``pred``, ``target`` are ``(..., H, W)`` in [0, 1]. Meshes: Chamfer distance between surface
samples drawn with fixed barycentric coordinates, so samples move smoothly with the vertices.
SDF generators against a mesh: the SDF at target surface samples (should be 0) and occupancy at
volume samples (inside/outside of the target from the generalized winding number).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch


def soft_iou_loss(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """``1 - sum(p t) / sum(p + t - p t)`` per mask, averaged over leading axes. Range [0, 1]."""
    inter = (pred * target).sum((-2, -1))
    union = (pred + target - pred * target).sum((-2, -1))
    return (1.0 - inter / (union + eps)).mean()


def mse_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of the masks."""
    return ((pred - target) ** 2).mean()


LOSSES: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {
    "iou": soft_iou_loss,
    "mse": mse_loss,
}


@dataclass(frozen=True)
class SurfaceSampler:
    """Fixed samples on a mesh's faces: face indices ``(S,)`` and barycentric weights ``(S, 3)``.

    Drawn once (area-weighted at the mesh's initial shape); ``points(verts)`` then moves the samples
    with the vertices, differentiably.
    """

    faces: torch.Tensor
    bary: torch.Tensor

    @staticmethod
    def draw(verts: torch.Tensor, faces: torch.Tensor, n: int, generator: torch.Generator | None = None
             ) -> SurfaceSampler:
        v = verts.detach()
        tri = v[faces]
        area = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1).norm(dim=-1)
        if not torch.isfinite(area).all() or area.sum() <= 0:
            raise ValueError("expected a mesh with positive area, got zero area")
        idx = torch.multinomial(area / area.sum(), n, replacement=True, generator=generator)
        uv = torch.rand(n, 2, generator=generator, dtype=v.dtype).to(v.device)
        flip = uv.sum(1) > 1
        uv[flip] = 1 - uv[flip]
        bary = torch.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
        return SurfaceSampler(faces[idx], bary)

    def points(self, verts: torch.Tensor) -> torch.Tensor:
        """``(S, 3)`` sample positions on the current vertices."""
        tri = verts[self.faces]
        return (tri * self.bary[..., None].to(verts.dtype)).sum(1)


def chamfer_loss(a: torch.Tensor, b: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
    """Symmetric Chamfer distance (mean of squared nearest-neighbour distances, both ways) between
    point sets ``a: (N, 3)`` and ``b: (M, 3)``; chunked so memory stays O(chunk * M)."""
    def one_way(x, y):
        mins = [torch.cdist(x[i:i + chunk], y).min(1).values for i in range(0, len(x), chunk)]
        return (torch.cat(mins) ** 2).mean()

    return one_way(a, b) + one_way(b, a)


def sdf_surface_loss(sdf_values: torch.Tensor) -> torch.Tensor:
    """Mean absolute SDF at points sampled on the target surface (0 when the surfaces agree)."""
    return sdf_values.abs().mean()


def occupancy_loss(sdf_values: torch.Tensor, inside: torch.Tensor, sharpness: float = 50.0) -> torch.Tensor:
    """Binary cross-entropy between ``sigmoid(-sharpness * sdf)`` and the target's inside labels."""
    logits = -sharpness * sdf_values
    return torch.nn.functional.binary_cross_entropy_with_logits(logits, inside.to(sdf_values.dtype))


def prior_loss(u: torch.Tensor, u_ref: torch.Tensor) -> torch.Tensor:
    """Squared distance in normalized parameter space to a reference (a preset)."""
    return ((u - u_ref) ** 2).mean()
