"""``enumerate``: every discrete combination (at most :data:`MAX_ENUMERATE`), refined by gradient with
successive halving.

Which parameters it searches: without ranges (``FitSettings.ranges``, ``--range``), every discrete
parameter that is not fixed, and more than :data:`MAX_ENUMERATE` combinations are refused. Given ranges
for some, only those (``ranged_only``: :class:`~ipm.optim.problem.Problem` holds the others at the
start's values, the preset's, and the search says so in one info line), so that ``--range floors=4:10
--range windows=2:6`` searches those two without fixing each of the building's other discrete parameters.
"""

from __future__ import annotations

import itertools
import logging
import math

import numpy as np

from ipm.errors import InputError
from ipm.optim.discrete import Refine, Space, best_pose, halving, halving_rungs, outlined
from ipm.optim.evaluator import BudgetExhausted, Evaluator
from ipm.optim.strategies import STRATEGIES

log = logging.getLogger(__name__)

MAX_ENUMERATE = 64
# combinations refined alike to the end of the search, then polished alike (run_fit's two leaders): a
# candidate that wins the first rung by a hair no longer gets twice the refinement of the runner-up. The
# ClearGrasp mug's handle on and off were 0.247 and 0.257 apart after the first rung; the one that got
# the rest went on to the polish far ahead, and which one that was flipped with the CPU's kernels
# (photo IoU 0.966 or 0.912: results/perturbation.md)
FINALISTS = 2
# share of the budget that refines the best starts (warm_start) before the combinations are compared: they
# then start from a shape and a pose fitted to the target rather than the generator's defaults in the pose
# grid's first pose, so that the first rung of the halving (a few steps each) compares the discrete values,
# not how far each got from the defaults. Without it, two of six random gears of the plug-in tutorial
# (docs/examples/gear.toml, 36 tooth counts) lost their count: a long gear started edge-on, where every count
# stayed at a loss of 0.15 (0.004 with the right count and pose)
WARM = 0.15
WARM_STARTS = 3  # the best starts of the pose grid refined in the warm-up, the best kept


def check(searched) -> None:
    """Before a fit starts (:class:`~ipm.optim.problem.Problem`): :class:`InputError` if the searched discrete
    parameters (their possibly narrowed ranges) have more than :data:`MAX_ENUMERATE` combinations."""
    n = math.prod(int(p.hi) - int(p.lo) + 1 for p in searched)
    if n > MAX_ENUMERATE:
        raise InputError(f"--discrete enumerate: expected at most {MAX_ENUMERATE} combinations, got "
                         f"{n} combinations of {', '.join(p.name for p in searched)}; narrow them with --range "
                         "or --fix, or use memetic or nlopt")


def warm_start(ev: Evaluator, space: Space, refine: Refine, steps: int) -> tuple:
    """The best of the first :data:`WARM_STARTS` starts after ``steps`` refinement steps shared among them:
    ``(x, discrete)``. The pose grid ranks its poses with the generator's default shape, so its best pose need
    not suit the target's (a long gear ranked edge-on like a flat one); refined, the right one wins. Where the
    outline was fitted first (part labels or depth: :func:`ipm.optim.pose.outline_first`), that is the warm-up:
    the best start as it is."""
    if space.outline is not None:  # outline_first refined the start already, without the part labels, which
        return space.starts[0]     # would pull the outline towards the start's counts here
    chosen = space.starts[:WARM_STARTS]
    share = max(1, steps // len(chosen))
    ev.phase = "enumerate:warm"
    refined = [(*refine(x, d, share), d) for x, d in chosen]
    x, _, d = min(refined, key=lambda r: r[1])
    return x, d


@STRATEGIES.register("enumerate")
def enumerate_discrete(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator, settings=None,
                       steps0: int | None = None) -> None:
    """All discrete combinations, refined from the best start with successive halving."""
    check(space.discrete)
    given, fixed = getattr(settings, "ranges", None) or {}, getattr(settings, "fix", None) or {}
    held = {k: v for k, v in space.fixed_discrete.items() if k not in fixed}
    if given and held:
        log.info("enumerate searches the discrete parameters given ranges (%s); the other %d stay at the start's "
                 "values (%s)", ", ".join(p.name for p in space.discrete), len(held),
                 ", ".join(f"{k}={v}" for k, v in held.items()))
    ranges = [range(int(p.lo), int(p.hi) + 1) for p in space.discrete]
    combos = [dict(zip((p.name for p in space.discrete), c)) for c in itertools.product(*ranges)]
    try:
        x0, _ = warm_start(ev, space, refine, int(WARM * ev.remaining))
        ev.phase = "enumerate:poses"
        alive = []
        for c in combos:
            d = {**space.fixed_discrete, **c}
            alive.append((outlined(space, best_pose(ev, space, x0, d), d), d))
    except BudgetExhausted:
        return
    # successive halving spends about steps0 * len(combos) per round, over log2(len) + 1 rounds
    steps = steps0 or max(5, ev.remaining // (len(combos) * halving_rungs(len(combos))))
    ev.phase = "enumerate:halving"
    try:
        refined = halving(alive, refine, steps, keep=FINALISTS)
        final = sorted(refined, key=lambda a: a[2])[:FINALISTS]
        for i, (x, d, _) in enumerate(final):  # the finalists share what is left
            refine(x, d, ev.remaining // (len(final) - i))
    except BudgetExhausted:
        return


enumerate_discrete.check = check  # called by Problem before any evaluation or file
enumerate_discrete.ranged_only = True  # given ranges for some discrete parameters, Problem searches only those
