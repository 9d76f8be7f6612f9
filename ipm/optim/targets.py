"""What a fit matches: silhouettes seen by known cameras (with optional depth, part labels and a photo per
view), or a mesh."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ipm.errors import InputError
from ipm.types import Camera, TriMesh


@dataclass
class MaskTarget:
    """Silhouettes to match, and what else the views show.

    masks: (K, H, W) float in [0, 1] (soft masks allowed; > 0.5 is the object); cameras: one per view
    (``camera="fit"`` uses only their image sizes and principal points);
    depth: optional (K, H, W) view-axis depth in scene units, NaN where there is no reading;
    parts: optional (K, H, W) int64, ``k`` where the pixel shows the part ``part_names[k]``, -1 where it
    shows none of the named parts (background or another part);
    image: optional (K, H, W) grey photo in [0, 1] (shading is compared on the object's pixels);
    known_intrinsics: with ``camera="fit"``, the cameras' field of view and principal point are known
    (only the camera's elevation and distance are fitted);
    ground_elevation: with ``camera="fit"``, the camera's elevation in degrees where it is known (from the
    plane the object stands on, :mod:`ipm.io.ground`): it is then held, not fitted;
    outside_is_background: what projects outside the images is known to be background (a photo's crop
    away from the photo's edges), and geometry there is charged (:func:`ipm.optim.problem.outside_share`).
    """

    masks: torch.Tensor
    cameras: list[Camera]
    depth: torch.Tensor | None = None
    parts: torch.Tensor | None = None
    part_names: tuple[str, ...] = ()
    image: torch.Tensor | None = None
    known_intrinsics: bool = False
    ground_elevation: float | None = None
    outside_is_background: bool = False

    @property
    def cues(self) -> tuple[str, ...]:
        """The cues given besides the masks, in the order "depth", "parts", "image"."""
        return tuple(n for n in ("depth", "parts", "image") if getattr(self, n) is not None)

    def __post_init__(self):
        if self.masks.ndim != 3:
            raise InputError(f"masks: expected (K, H, W), got {tuple(self.masks.shape)}")
        if len(self.cameras) != self.masks.shape[0]:
            raise InputError(f"expected one camera per mask, got {len(self.cameras)} cameras for "
                             f"{self.masks.shape[0]} masks")
        shape = tuple(self.masks.shape)
        for name in self.cues:
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise InputError(f"{name}: expected one map per mask of the masks' size {shape}, got {got}")
        if self.depth is not None:
            for i, d in enumerate(self.depth):
                if not bool((torch.isfinite(d) & (self.masks[i] > 0.5)).any()):
                    raise InputError(f"depth {i}: expected a valid depth on some of the object's pixels, got none")
        if self.parts is not None:
            if not self.part_names:
                raise InputError("parts: expected the names of the labels, got none")
            if int(self.parts.max()) >= len(self.part_names) or int(self.parts.min()) < -1:
                raise InputError(f"parts: expected labels in [-1, {len(self.part_names) - 1}], got "
                                 f"[{int(self.parts.min())}, {int(self.parts.max())}]")
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
