"""Pictures for people: target-vs-fit overlays, contact sheets, loss plots.

Images are built with Pillow (loss plots included: :mod:`ipm.viz.plots`).
"""

from ipm.viz.overlay import mask_iou, overlay
from ipm.viz.plots import plot_losses
from ipm.viz.sheet import contact_sheet, to_image

__all__ = ["contact_sheet", "mask_iou", "overlay", "plot_losses", "to_image"]
