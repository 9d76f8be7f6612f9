"""The phases of a fit, as immutable values: what each one evaluates.

A :class:`Phase` says which loss terms it leaves out (by name, :mod:`ipm.optim.terms`), the blur of its
silhouettes relative to the fit's, and whether its evaluations are candidates for the result (another
objective's losses are not comparable with the fit's). :func:`ipm.optim.fit.run_fit` runs them in order,
each within its share of the budget (:meth:`ipm.optim.evaluator.Evaluator.running`):

1. ``init`` (:data:`SEARCH`): the pose grid, the presets ranked;
2. ``outline`` (:data:`OUTLINE`; where the target has part labels or depth and discrete values are searched):
   the start refined without part labels, and each candidate's outline refit before the labels judge it;
3. the search strategy (:data:`SEARCH`), up to the budget less the polish's share;
4. ``polish`` (the shape adapter's polish blur: finer for meshes, whose thin parts come out too thin at a
   wide blur): the two best discrete candidates alike, then the tie rule and the winner.

Budget shares: :data:`OUTLINE_SHARE`, :data:`OUTLINE_STEPS`, ``FitSettings.polish``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

OUTLINE_SHARE = 0.15  # of the budget: the outline's refinement before a search with part labels or depth
OUTLINE_STEPS = 0.02  # of the budget: the outline's refit of a candidate with other discrete values


@dataclass(frozen=True)
class Phase:
    """What a phase evaluates: ``without`` (loss terms left out, by name), ``sigma`` (the silhouettes' blur
    relative to the fit's), ``keep_best`` (whether its evaluations are candidates for the result)."""

    name: str
    sigma: float = 1.0
    without: frozenset[str] = field(default_factory=frozenset)
    keep_best: bool = True


SEARCH = Phase("search")
# the outline: silhouette (and depth) without part labels, which only tell counts apart once the outline is
# in place; its losses lack the labels, so they are not candidates for the result
OUTLINE = Phase("outline", without=frozenset({"parts"}), keep_best=False)


def polish(sigma: float) -> Phase:
    """The polish at the shape adapter's polish blur (:attr:`ipm.optim.shapes.Shape.polish_sigma`)."""
    return Phase("polish", sigma=sigma)
