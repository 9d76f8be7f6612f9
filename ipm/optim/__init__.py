"""Optimizers and the fit, one job per module; everything works on a normalized vector ``x`` in [0, 1]^m
(generator parameters, then pose, then camera) plus a dict of discrete values.

- :mod:`~ipm.optim.encoding`: the layout of ``x`` (pure functions between named dicts, vectors and
  normalized vectors)
- :mod:`~ipm.optim.targets`, :mod:`~ipm.optim.problem`: what is matched, and the objective
- :mod:`~ipm.optim.evaluator`: counted, recorded, replayable evaluations under one budget
- :mod:`~ipm.optim.pose`: starting poses; :mod:`~ipm.optim.ties`: the tie rule
- :mod:`~ipm.optim.gradient`: continuous refinement (Adam, nlopt LD_*), run through
  :mod:`~ipm.optim.nlopt_run` like every nlopt search
- :mod:`~ipm.optim.discrete` and :mod:`~ipm.optim.strategies`: discrete search (a registry: one module per
  strategy)
- :mod:`~ipm.optim.fit`: the fit from start to end (``run_fit``, ``FitSettings``)
"""
