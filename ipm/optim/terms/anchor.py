"""``anchor``: in single-view fits without depth, ``FitSettings.anchor`` per unit of normalized distance (L1)
that an anchored parameter (:attr:`ipm.params.Param.anchored`: an oval or square section's aspect and
squareness, which one view confuses with the camera's elevation) moves from its start."""

from __future__ import annotations

import torch

from ipm.optim.terms import TERMS, Evaluation


@TERMS.register()
class Anchor:
    """Single-view fits without depth: anchored parameters charged for leaving their start."""

    name = "anchor"
    order = 50

    def applies(self, prob) -> bool:
        return bool(prob.anchored)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        a = ev.prob.anchored
        return ev.prob.s.anchor * (ev.x[a] - ev.prob.u_ref[a].to(ev.x)).abs().sum()
