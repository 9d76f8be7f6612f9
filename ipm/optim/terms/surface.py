"""``surface``: for a mesh target, the shape's distance to the target's surface (and, for a field, its inside):
the shape adapter's :meth:`~ipm.optim.shapes.Shape.target_loss` (Chamfer between surface samples for a mesh
generator; the field at the target's surface and its occupancy at volume samples for an SDF generator)."""

from __future__ import annotations

import torch

from ipm.optim.targets import MeshTarget
from ipm.optim.terms import TERMS, Evaluation


@TERMS.register()
class Surface:
    """For a mesh target: the distance to its surface (and, for a field, its inside)."""

    name = "surface"
    order = 10

    def applies(self, prob) -> bool:
        return isinstance(prob.target, MeshTarget)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        return ev.prob.shape.target_loss(ev.theta, ev.full, ev.pose, ev.prob.target)
