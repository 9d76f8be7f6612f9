"""Discrete (and global) search strategies, one module each, registered by name in :data:`STRATEGIES`.

A strategy is a function ``(ev, space, refine, rng, settings) -> None`` that spends the evaluator's budget
(:class:`~ipm.optim.discrete.Space`, :data:`~ipm.optim.discrete.Refine`; ``settings`` is the fit's
:class:`~ipm.optim.fit.FitSettings`, or None for the defaults), registered with
``@STRATEGIES.register("name")``. Adding one is one new module in this package; ``FitSettings`` and
``ipm fit --discrete`` accept its name from then on. The best point is what the evaluator saw. A strategy
with limits on the searched parameters gives the function a ``check(searched_params)`` attribute, which
:class:`~ipm.optim.problem.Problem` calls before anything is evaluated or written.
"""

from __future__ import annotations

from ipm.registry import Registry

STRATEGIES = Registry("discrete search strategy", packages=["ipm.optim.strategies"])
