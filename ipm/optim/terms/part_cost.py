"""``part_cost``: a description length, ``FitSettings.part_cost`` per part the discrete values add
(:attr:`ipm.params.Param.adds`: a handle, a wing, a roof-top box), so that a part stays only where it lowers
the loss by more; a constant of the continuous values (0 by default)."""

from __future__ import annotations

from ipm.optim.terms import TERMS, Evaluation


@TERMS.register()
class PartCost:
    """A description length: a loss per part the discrete values add."""

    name = "part_cost"
    order = 60

    def applies(self, prob) -> bool:
        return True

    def __call__(self, ev: Evaluation) -> float:
        return ev.prob.part_cost(ev.discrete)
