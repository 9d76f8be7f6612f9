"""Differentiable losses (torch only), each a pure function.

Masks (:mod:`ipm.losses.masks`, registered by name in :data:`LOSSES`): ``pred``, ``target`` are
``(..., H, W)`` in [0, 1]; the transport losses (``sinkhorn``, ``sliced``) read them as mass on the pixel
grid and have a gradient where the masks do not overlap. Meshes (:mod:`ipm.losses.mesh`): Chamfer distance
between surface samples drawn with fixed barycentric coordinates, so samples move smoothly with the vertices.
SDF generators against a mesh (:mod:`ipm.losses.sdf`): the SDF at target surface samples (should be 0) and occupancy at
volume samples. A pull towards a preset (:mod:`ipm.losses.prior`).
"""

from __future__ import annotations

from ipm.losses.masks import LOSSES, loss_options, mask_loss, parse_loss
from ipm.losses.masks._transport import TransportSettings
from ipm.losses.masks.iou import soft_iou_loss
from ipm.losses.masks.mse import mse_loss
from ipm.losses.masks.sinkhorn import sinkhorn_loss
from ipm.losses.masks.sliced import sliced_loss
from ipm.losses.mesh import SurfaceSampler, chamfer_loss, nearest
from ipm.losses.prior import prior_loss
from ipm.losses.sdf import occupancy_loss, sdf_surface_loss

__all__ = ["LOSSES", "SurfaceSampler", "TransportSettings", "chamfer_loss", "loss_options", "mask_loss", "mse_loss",
           "nearest", "occupancy_loss", "parse_loss", "prior_loss", "sdf_surface_loss", "sinkhorn_loss", "sliced_loss",
           "soft_iou_loss"]
