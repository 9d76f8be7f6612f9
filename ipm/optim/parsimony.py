"""The parsimony rule: in a fit to one silhouette alone, a part that the view shows stays only where it buys
a clear fit, so that a handle does not stand in for an outline the generator's body of revolution cannot make.

One view cannot tell such a stand-in from a part; two or more can (the stand-in then shows where the object has
nothing). On the tune split's vessels (experiments/table1.toml, 500 evaluations, dishes ``part_ratio`` 0.5)
the rule at every K dropped the sugar bowl's real handle from four views (held-out IoU 0.934 -> 0.920) and the
teapot's real knob from the eight views of its bound (0.961 -> 0.948; the knob lowers the loss by a quarter
only, the rest of the loss being elsewhere); it raised the bowl's bound by 0.008 (0.959 -> 0.967) and moved no other
fit from two or more views by more than 0.001."""

from __future__ import annotations

import logging

from ipm.optim.evaluator import Best, BudgetExhausted, Evaluator
from ipm.optim.problem import Problem

log = logging.getLogger(__name__)


def simpler(prob: Problem, ev: Evaluator, ratio: float) -> list[dict]:
    """The discrete combinations of the evaluator's best points (``best_by_discrete``) that the parsimony rule
    weighs against the winner (``ev.best``): those that differ from it only in values that add parts
    (:attr:`ipm.params.Param.adds`), each lower. None where the rule does not apply (:func:`applies`)."""
    winner = ev.best
    if not applies(prob, ratio) or winner.x is None:
        return []
    return [dict(b.discrete) for b in ev.best_by_discrete.values() if fewer_parts(prob, b.discrete, winner.discrete)]


def applies(prob: Problem, ratio: float) -> bool:
    """Whether the rule applies: ``ratio`` below 1, and one silhouette alone (:attr:`Problem.one_view`, and no
    part labels or image either: where they are given, they say where a part is; the rule was measured without)."""
    return ratio < 1.0 and prob.one_view and not prob.target.cues


def fewer_parts(prob: Problem, d: dict, than: dict) -> bool:
    """Whether discrete values ``d`` differ from ``than`` only in values that add parts
    (:attr:`ipm.params.Param.adds`), each lower."""
    adds = _switches(prob)
    diff = [k for k in than if d.get(k) != than[k]]
    return set(d) == set(than) and bool(diff) and all(k in adds and d[k] < than[k] for k in diff)


def _switches(prob: Problem) -> list[str]:
    """The discrete parameters whose values add parts (:attr:`ipm.params.Param.adds`)."""
    return [p.name for p in prob.gen.spec.discrete if p.adds]


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
    winner (the lower loss wins), and so does a fit the rule does not apply to (:func:`applies`: one silhouette
    alone; ``ratio`` was measured there, :attr:`ipm.generators.base.Generator.part_ratio`)."""
    winner = ev.best
    combos = simpler(prob, ev, ratio)
    for d in combos:
        try:
            ev.phase = "parsimony"
            ev(prob.repose(winner.x, winner.discrete, d), d, grad=False)
        except BudgetExhausted:
            break
    adds = _switches(prob)
    picks = []
    for d in combos:
        cand = ev.best_of(d)
        if winner.loss > ratio * cand.loss:
            picks.append((cand.loss, sum(d[k] for k in adds), cand))
    if not picks:
        return winner, ()
    loss, _, cand = min(picks, key=lambda e: e[:2])
    fewer = tuple(k for k in winner.discrete if cand.discrete[k] != winner.discrete[k])
    log.info("parsimony: %s -> %s: the parts bring the loss to %.6g against %.6g without them (over %.2f of it)",
             {k: winner.discrete[k] for k in fewer}, {k: cand.discrete[k] for k in fewer}, winner.loss, loss, ratio)
    return cand, fewer
