"""Differentiable losses (torch only), each a pure function.

Masks (:mod:`ipm.losses.masks`, registered by name in :data:`LOSSES`): ``pred``, ``target`` are
``(..., H, W)`` in [0, 1]. Meshes (:mod:`ipm.losses.mesh`): Chamfer distance between surface samples
drawn with fixed barycentric coordinates, so samples move smoothly with the vertices. SDF generators
against a mesh (:mod:`ipm.losses.sdf`): the SDF at target surface samples (should be 0) and occupancy at
volume samples. A pull towards a preset (:mod:`ipm.losses.prior`).
"""

from __future__ import annotations

from ipm.losses.masks import LOSSES
from ipm.losses.masks.iou import soft_iou_loss
from ipm.losses.masks.mse import mse_loss
from ipm.losses.mesh import SurfaceSampler, chamfer_loss, nearest
from ipm.losses.prior import prior_loss
from ipm.losses.sdf import occupancy_loss, sdf_surface_loss

__all__ = ["LOSSES", "SurfaceSampler", "chamfer_loss", "mse_loss", "nearest", "occupancy_loss", "prior_loss",
           "sdf_surface_loss", "soft_iou_loss"]
