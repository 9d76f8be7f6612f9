"""``none``: the discrete values stay fixed; multi-start gradient refinement only (also what a fit
runs when there is no discrete parameter to search)."""

from __future__ import annotations

import numpy as np

from ipm.optim.discrete import Refine, Space
from ipm.optim.evaluator import BudgetExhausted, Evaluator
from ipm.optim.strategies import STRATEGIES


@STRATEGIES.register("none")
def multistart(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator, settings=None,
               starts: int = 3) -> None:
    """Discrete values fixed: refine the best few starts and the generator's start variants (``space.variants``:
    :func:`ipm.optim.pose.variant_starts`), then continue the best one. The variants are
    refined, not ranked: one look does not tell them (a stool seen from one view looks more like the chair tree's
    chair than its backless variant, and refines to a far worse loss)."""
    chosen = space.starts[:starts] + space.variants
    share = max(10, ev.remaining // (2 * max(len(chosen), 1)))
    results = []
    try:
        for i, (x, d) in enumerate(chosen):
            ev.phase = f"multistart:{i}"
            results.append((*refine(x, d, share), d))
        results.sort(key=lambda r: r[1])
        ev.phase = "refine"
        x, _, d = results[0]
        refine(x, d, ev.remaining)
    except BudgetExhausted:
        return
