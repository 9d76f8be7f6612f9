"""What every discrete (and global) search works on, and the settings of the built-in ones.

Every strategy (:mod:`ipm.optim.strategies`, registered by name in
:data:`~ipm.optim.strategies.STRATEGIES`) receives a :class:`Space` (the normalized continuous vector's
size, which coordinates belong to the generator and which to the pose/camera, the discrete parameters,
and ranked starting points) and a ``refine(x, discrete, steps) -> (x, loss)`` callable (gradient
refinement that spends evaluations). Genomes, the vectors that the genetic and nlopt searches work on,
are the generator's coordinates of ``x`` followed by the discrete genes of :mod:`ipm.optim.encoding`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Literal, get_args

import numpy as np
import torch
from msgspec import Meta

from ipm.optim.encoding import decode_discrete, encode_discrete
from ipm.optim.evaluator import Evaluator
from ipm.params import Param

# refine(x, discrete, steps) -> (x, loss); raises BudgetExhausted when no evaluation is left.
Refine = Callable[[torch.Tensor, dict, int], tuple[torch.Tensor, float]]


@dataclass
class Space:
    """What a search works on.

    m: length of the normalized continuous vector; gen: indices of the generator's coordinates (the
    rest is pose and camera); discrete: the searched discrete parameters; starts: (x, discrete)
    starting poses, best first; presets: the generator's presets posed like the best start; variants: with nothing
    discrete to search, the generator's start variants, each posed (:func:`ipm.optim.pose.variant_starts`), which the
    multistart of ``none`` refines beside the starts.
    """

    m: int
    gen: np.ndarray
    discrete: list[Param]
    starts: list[tuple[torch.Tensor, dict]]
    fixed_discrete: dict = field(default_factory=dict)
    presets: list[tuple[torch.Tensor, dict]] = field(default_factory=list)
    variants: list[tuple[torch.Tensor, dict]] = field(default_factory=list)
    # (x, discrete) -> x posed anew for these discrete values; set when the starts' poses cannot tell
    pose_search: Callable[[torch.Tensor, dict], torch.Tensor] | None = None
    # (x, discrete) -> x with the outline refit for these discrete values, before part labels judge
    # them (see outlined); set when part labels are fitted
    outline: Callable[[torch.Tensor, dict], torch.Tensor] | None = None

    def encode(self, d: dict) -> np.ndarray:
        """Discrete values -> genes ``(k,)`` in [0, 1]."""
        return encode_discrete(self.discrete, d)

    def decode(self, z: np.ndarray) -> dict:
        """Genes ``(k,)`` -> discrete values (the fixed ones included)."""
        return decode_discrete(self.discrete, z, self.fixed_discrete)


# Types of the built-in searches' settings (each strategy's settings class lives in its module and is
# registered with it: ``strategy.settings``; msgspec checks the values, FitSettings.check)
Probability = Annotated[float, Meta(ge=0, le=1, extra={"noun": "a probability"})]
LearningRate = Annotated[float, Meta(gt=0, le=1, extra={"noun": "a learning rate"})]
NloptAlgorithm = Literal["GN_CRS2_LM", "GN_ESCH", "GN_ISRES"]
NLOPT_GLOBAL: tuple[str, ...] = get_args(NloptAlgorithm)


def best_pose(ev: Evaluator, space: Space, x: torch.Tensor, d: dict) -> torch.Tensor:
    """``x`` in its own pose or that (and camera) of the kept start that suits discrete values ``d`` best.

    The pose grid was ranked with the starting discrete values; another count (of floors, boxes) can
    prefer another of the kept poses, so each is tried once (one evaluation, no gradient), as is ``x``'s
    own pose: a preset comes matched to the target by :func:`ipm.optim.pose.rank_presets` (the public
    building_2 from ``block_stair``: soft-IoU loss 0.40 after 12 steps from a kept start's pose, 0.086
    from its own). Where the starts' poses were all alike for the starting values
    (``space.pose_search``), the pose grid is ranked again for ``d`` instead."""
    if space.pose_search is not None and d != space.starts[0][1]:
        return space.pose_search(x, d)
    if len(space.starts) < 2:
        return x
    gen = torch.as_tensor(space.gen)
    pose = torch.ones(len(x), dtype=torch.bool)
    pose[gen] = False
    best, best_x = math.inf, x
    # x's own pose first (a preset's, matched to the target by rank_presets), then the kept starts'
    for cand in [x] + [xs.clone().index_put_((gen,), x[gen]) for xs, _ in space.starts]:
        if cand is not x and torch.equal(cand[pose], x[pose]):
            continue  # that pose is x's own, tried already
        loss, _ = ev(cand, d, grad=False)
        if loss < best:
            best, best_x = loss, cand
    return best_x


def outlined(space: Space, x: torch.Tensor, d: dict) -> torch.Tensor:
    """``x`` made ready for discrete values ``d`` it was not refined with: where part labels are fitted, a
    short refinement of the outline alone (``space.outline``), since the labels only tell counts apart
    once the outline is in place; else ``x`` itself."""
    return x if space.outline is None else space.outline(x, d)


def genome(space: Space, x: torch.Tensor, d: dict) -> np.ndarray:
    """``(x (m,), discrete)`` -> genome ``(len(space.gen) + k,)`` in [0, 1]."""
    return np.concatenate([x.numpy()[space.gen], space.encode(d)])


def from_genome(space: Space, g: np.ndarray, pose_from: torch.Tensor) -> tuple[torch.Tensor, dict]:
    """Genome -> ``(x (m,), discrete)``, the pose (and camera) taken from ``pose_from (m,)``."""
    x = pose_from.clone()
    x[torch.as_tensor(space.gen)] = torch.as_tensor(g[: len(space.gen)], dtype=torch.float64)
    return x, space.decode(g[len(space.gen):])


def halving_rungs(n: int) -> int:
    """How many rungs :func:`halving` runs for ``n`` candidates: ceil(log2 n) + 1."""
    return math.ceil(math.log2(n)) + 1 if n > 1 else 1


def halving(first: list[tuple[torch.Tensor, dict]], refine: Refine, steps: int,
            keep: int = 1) -> list[tuple[torch.Tensor, dict, float]]:
    """Successive halving (Jamieson and Talwalkar, AISTATS 2016): every candidate is refined ``steps``
    steps, then the better half (by loss) twice as many, and so on until ``keep`` or fewer are left,
    which are refined once more at their rung's steps; each rung costs about the same. Returns every
    candidate ``(x, discrete, loss)`` in the order given, with its latest refinement (the dropped ones
    keep theirs). :class:`~ipm.optim.evaluator.BudgetExhausted` from ``refine`` is passed on."""
    pop = [(x, d, math.inf) for x, d in first]
    alive = list(range(len(pop)))
    k = steps
    while alive:
        for i in alive:
            x, d, _ = pop[i]
            xr, loss = refine(x, d, k)
            pop[i] = (xr, d, loss)
        if len(alive) <= keep:
            break
        alive = sorted(alive, key=lambda i: pop[i][2])[: max(keep, len(alive) // 2)]
        k *= 2
    return pop
