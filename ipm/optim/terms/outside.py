"""``outside``: geometry projected outside the images where that is known to be background (a photo's crop
around its object): the silhouette loss does not see it, this charges it and pulls it back."""

from __future__ import annotations

import torch

from ipm.optim.targets import MaskTarget
from ipm.optim.terms import TERMS, Evaluation
from ipm.types import Camera

# weight of outside_share in a photo fit: 1 changed the ClearGrasp mug fit from photo IoU 0.964 to 0.919
# (its starting poses, partly outside the crop, ranked differently); 0.25 keeps it (0.966) and still holds
# the tumbler inside its crop (photo IoU 0.17-0.42 without, 0.962 with)
OUTSIDE_WEIGHT = 0.25


def outside_share(verts: torch.Tensor, cams: list[Camera]) -> torch.Tensor:
    """0-dim: how far the vertices ``(V, 3)`` project outside the images of ``cams``, in image heights,
    averaged over vertices and views (0 when all are inside)."""
    from ipm.render.camera import project

    out = []
    for c in cams:
        xy, _ = project(verts, c.to(dtype=verts.dtype, device=verts.device))
        x, y = xy[:, 0], xy[:, 1]
        d = (torch.relu(-x) + torch.relu(x - c.width) + torch.relu(-y) + torch.relu(y - c.height)) / c.height
        out.append(d.mean())
    return torch.stack(out).mean()


@TERMS.register()
class Outside:
    """Geometry projected outside the images where that is known to be background (a photo's crop)."""

    name = "outside"
    order = 20

    def applies(self, prob) -> bool:
        return isinstance(prob.target, MaskTarget) and prob.target.outside_is_background and prob.shape.has_faces

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        return OUTSIDE_WEIGHT * outside_share(ev.mesh.verts, ev.own_cameras())
