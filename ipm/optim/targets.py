"""What a fit matches: silhouettes seen by known cameras, or a mesh."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ipm.errors import InputError
from ipm.types import Camera, TriMesh


@dataclass
class MaskTarget:
    """Silhouettes to match: ``masks (K, H, W)`` float in [0, 1] and one camera per view (``camera="fit"``
    uses only their image sizes)."""

    masks: torch.Tensor
    cameras: list[Camera]

    def __post_init__(self):
        if self.masks.ndim != 3:
            raise InputError(f"masks: expected (K, H, W), got {tuple(self.masks.shape)}")
        if len(self.cameras) != self.masks.shape[0]:
            raise InputError(f"expected one camera per mask, got {len(self.cameras)} cameras for "
                             f"{self.masks.shape[0]} masks")
        for i, m in enumerate(self.masks):
            frac = float((m > 0.5).float().mean())
            if frac == 0.0:
                raise InputError(f"mask {i} is empty: expected some foreground pixels, got none")
            if frac == 1.0:
                raise InputError(f"mask {i} is all foreground: expected the object inside the image, got no background")


@dataclass
class MeshTarget:
    """A mesh to match (normalized to DESIGN.md's frame when loaded); ``samples`` surface points."""

    mesh: TriMesh
    samples: int = 4000

    def __post_init__(self):
        if self.samples < 1:
            raise InputError(f"mesh target samples: expected at least 1, got {self.samples}")
