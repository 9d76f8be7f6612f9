"""``nlopt``: a derivative-free global algorithm of nlopt (GN_CRS2_LM, GN_ESCH or GN_ISRES) over the
generator's normalized parameters with discrete coordinates rounded; each evaluation is refined briefly by
gradient steps. Settings: :class:`NloptSettings` (``FitSettings.search["nlopt"]``), registered with the
strategy."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from msgspec import Meta

from ipm.errors import InputError
from ipm.optim.discrete import NLOPT_GLOBAL, NloptAlgorithm, Refine, Space, from_genome, genome
from ipm.optim.evaluator import BudgetExhausted, Evaluator
from ipm.optim.nlopt_run import minimize
from ipm.optim.strategies import STRATEGIES


@dataclass(frozen=True)
class NloptSettings:
    """The nlopt search's settings (``FitSettings.search["nlopt"]``)."""

    algorithm: NloptAlgorithm = "GN_CRS2_LM"
    refine_steps: Annotated[int, Meta(ge=1, extra={"noun": "a number of steps"})] = 10
    population: Annotated[int, Meta(ge=0, extra={"noun": "a population"})] = 0  # 0: nlopt's default



@STRATEGIES.register("nlopt")
def nlopt_global(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator, settings=None) -> None:
    """nlopt's global derivative-free search; every point is rounded and briefly refined. An exception
    raised by the refinement propagates (:func:`ipm.optim.nlopt_run.minimize`)."""
    import nlopt

    settings = NloptSettings() if settings is None else settings.strategy("nlopt")
    if settings.algorithm not in NLOPT_GLOBAL:
        raise InputError(f"nlopt algorithm: expected one of {', '.join(NLOPT_GLOBAL)}, got {settings.algorithm!r}")
    pose0 = space.starts[0][0]
    dim = len(space.gen) + len(space.discrete)
    if dim == 0:
        return
    opt = nlopt.opt(getattr(nlopt, settings.algorithm), dim)
    opt.set_lower_bounds([0.0] * dim)
    opt.set_upper_bounds([1.0] * dim)
    if settings.population:
        opt.set_population(settings.population)
    opt.set_maxeval(10**9)
    ev.phase = f"nlopt:{settings.algorithm}"

    def f(z, grad):
        x, d = from_genome(space, np.array(z), pose0)  # a copy: nlopt's array is read-only
        _, loss = refine(x, d, settings.refine_steps)
        if ev.remaining <= 0:
            raise BudgetExhausted
        return loss if math.isfinite(loss) else 1e6

    minimize(opt, f, genome(space, *space.starts[0]), settings.algorithm)


nlopt_global.settings = NloptSettings
