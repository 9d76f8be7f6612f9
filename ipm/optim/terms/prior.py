"""``prior``: a pull towards the starting preset in normalized space (:func:`ipm.losses.prior_loss`),
``FitSettings.prior_weight`` (off by default)."""

from __future__ import annotations

import torch

from ipm import losses as L
from ipm.optim.terms import TERMS, Evaluation


@TERMS.register()
class Prior:
    """A pull towards the starting preset in normalized space."""

    name = "prior"
    order = 40

    def applies(self, prob) -> bool:
        return prob.s.prior_weight > 0

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        x = ev.x
        return ev.prob.s.prior_weight * L.prior_loss(x[: ev.prob.n], ev.prob.u_ref.to(x.dtype))
