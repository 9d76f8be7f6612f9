"""``silhouette``: the mask loss (``FitSettings.loss``: soft IoU, MSE, the transport losses, or a weighted sum)
between the soft silhouettes and the target masks; records each view's exact-threshold IoU and pixels, the
silhouettes' areas and centroids, and the soft IoU."""

from __future__ import annotations

import torch

from ipm import losses as L
from ipm.optim.targets import MaskTarget
from ipm.optim.terms import TERMS, Evaluation


def centroids(masks: torch.Tensor) -> list[list[float]]:
    """Pixel centroids (x, y) of soft masks ``(K, H, W)`` (pixel centers at +0.5, row 0 at the top)."""
    K, H, W = masks.shape
    ys = torch.arange(H, dtype=masks.dtype, device=masks.device) + 0.5
    xs = torch.arange(W, dtype=masks.dtype, device=masks.device) + 0.5
    a = masks.sum((-2, -1)).clamp(min=1e-9)
    cx = (masks.sum(-2) * xs).sum(-1) / a
    cy = (masks.sum(-1) * ys).sum(-1) / a
    return [[round(float(x), 4), round(float(y), 4)] for x, y in zip(cx, cy)]


@TERMS.register()
class Silhouette:
    """The mask loss between the soft silhouettes and the target masks."""

    name = "silhouette"
    order = 10

    def applies(self, prob) -> bool:
        return isinstance(prob.target, MaskTarget)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        pred = ev.silhouettes
        tgt = ev.prob.target.masks.to(pred.dtype)
        loss = ev.prob.mask_loss(pred, tgt)
        with torch.no_grad():
            hard = pred > 0.5
            t = tgt > 0.5
            inter = (hard & t).sum((-2, -1)).double()
            union = (hard | t).sum((-2, -1)).double().clamp(min=1)
            ev.extras["iou"] = [round(float(v), 5) for v in inter / union]
            ev.extras["iou_px"] = [[int(a), int(b)] for a, b in zip(inter, union)]
            ev.extras["area"] = [float(v) for v in pred.sum((-2, -1))]
            ev.extras["centroid"] = centroids(pred)
            ev.extras["soft_iou"] = round(float(L.soft_iou_loss(pred, tgt).neg().add(1)), 5)
        return loss
