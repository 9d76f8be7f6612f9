"""The parsimony rule: a part that the input views show stays only where it buys a clear fit, so that a
handle does not stand in for an outline the generator's body of revolution cannot make."""

from __future__ import annotations

import logging

from ipm.optim.evaluator import Best, BudgetExhausted, Evaluator
from ipm.optim.problem import Problem
from ipm.optim.targets import MaskTarget

log = logging.getLogger(__name__)


def simpler(prob: Problem, ev: Evaluator, ratio: float) -> list[dict]:
    """The discrete combinations of the evaluator's best points (``best_by_discrete``) that the parsimony rule
    weighs against the winner (``ev.best``): those that differ from it only in values that add parts
    (:attr:`ipm.params.Param.adds`), each lower. None where ``ratio`` is 1 or the target is not silhouettes."""
    winner = ev.best
    if ratio >= 1.0 or winner.x is None or not isinstance(prob.target, MaskTarget):
        return []
    return [dict(b.discrete) for b in ev.best_by_discrete.values() if fewer_parts(prob, b.discrete, winner.discrete)]


def fewer_parts(prob: Problem, d: dict, than: dict) -> bool:
    """Whether discrete values ``d`` differ from ``than`` only in values that add parts
    (:attr:`ipm.params.Param.adds`), each lower."""
    adds = {p.name for p in prob.gen.spec.discrete if p.adds}
    diff = [k for k in than if d.get(k) != than[k]]
    return set(d) == set(than) and bool(diff) and all(k in adds and d[k] < than[k] for k in diff)


def nested(prob: Problem, a: dict, b: dict) -> bool:
    """Whether one of the discrete combinations ``a`` and ``b`` has :func:`fewer_parts` than the other."""
    return fewer_parts(prob, a, b) or fewer_parts(prob, b, a)


def simpler_winner(prob: Problem, ev: Evaluator, ratio: float) -> tuple[Best, tuple[str, ...]]:
    """The fit's winner (``ev.best``), or a point with fewer parts where the winner's parts buy too little:
    (that point, the names of the values it has lower than the winner).

    For each combination of :func:`simpler` (after the polish: the other polished leader, at the polish's
    blur), the best fit without the parts is the better of its own best point and the winner's shape with
    the parts taken off where they are (:meth:`Problem.repose`; one evaluation each: a small part's body is
    better fitted in the winner's search than in a combination that got less of it). It is taken where the
    winner's loss is above ``ratio`` times its loss: the parts did not bring the loss below that share of the
    best fit without them. Among several, the lowest loss (then the fewest parts). ``ratio`` 1 keeps the
    winner (the lower loss wins). Silhouette targets only: ``ratio`` was measured on silhouettes
    (:attr:`ipm.generators.base.Generator.part_ratio`), and a mesh target shows every part as it is."""
    winner = ev.best
    combos = simpler(prob, ev, ratio)
    key = lambda d: tuple(sorted(d.items()))  # noqa: E731 (the evaluator's key of a combination)
    for d in combos:
        try:
            ev.phase = "parsimony"
            ev(prob.repose(winner.x, winner.discrete, d), d, grad=False)
        except BudgetExhausted:
            break
    adds = [p.name for p in prob.gen.spec.discrete if p.adds]
    picks = []
    for d in combos:
        cand = ev.best_by_discrete[key(d)]
        if winner.loss > ratio * cand.loss:
            picks.append((cand.loss, sum(d[k] for k in adds), cand))
    if not picks:
        return winner, ()
    loss, _, cand = min(picks, key=lambda e: e[:2])
    fewer = tuple(k for k in winner.discrete if cand.discrete[k] != winner.discrete[k])
    log.info("parsimony: %s -> %s: the parts bring the loss to %.6g against %.6g without them (over %.2f of it)",
             {k: winner.discrete[k] for k in fewer}, {k: cand.discrete[k] for k in fewer}, winner.loss, loss, ratio)
    return cand, fewer
