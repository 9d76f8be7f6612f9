"""Bench method ``proposal``: a proposal network's best guess, scored with no refinement (issue #29's baseline).

The network (:mod:`ipm.proposals`: the weights shipped for ``generator``, or ``weights``) reads every input
mask, its outputs fused over the views (:meth:`~ipm.proposals.Proposer.propose_views`); its most probable
proposal is posed at its own yaw, with the scale and translation that match its silhouettes' areas
and centroids to the masks' (:func:`ipm.optim.pose.looks`, two evaluations; the cell's budget
allows ``budget // 2`` looks in a row, :func:`ipm.optim.pose.placed`, each from where the last left the guess:
one look leaves the shape off by the perspective it was first seen at, results/proposal_ablation.md), and nothing
else: no parameter of the guess changes, no gradient step, no search. What the table shows beside ``ipm`` is how
much of a fit the first guess already is.

Settings: ``generator`` (required), ``weights`` (a weights file; default the shipped ones), ``max_size`` (as the
``ipm`` method's).
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec
import torch

from ipm.bench.methods import Prediction, Task, method
from ipm.errors import InputError, MethodFailed
from ipm.types import TriMesh


class ProposalSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    generator: str
    weights: str | None = None
    max_size: Annotated[int, msgspec.Meta(ge=8, le=4096)] | None = None


@method("proposal", ProposalSettings)
def proposal(task: Task, s: ProposalSettings, budget: int, seed: int) -> Prediction:
    """The network's most probable proposal, posed by one look (module docstring)."""
    from ipm.bench.views import fit_views
    from ipm.generators import get_generator
    from ipm.optim.evaluator import Evaluator
    from ipm.optim.fit import FitSettings, MaskTarget, Problem
    from ipm.optim.pose import placed, proposed
    from ipm.proposals import load_proposer

    gen = get_generator(s.generator)
    proposer = load_proposer(gen, s.weights)
    if proposer is None:
        raise InputError(f"proposal: expected proposal weights for {s.generator} (ipm list proposals), got none")
    size = s.max_size if s.max_size is not None else max(task.masks.shape[1:])
    masks, cams = fit_views(task.masks, task.cameras, size, torch.float32)
    t0 = time.perf_counter()
    props = proposer.propose_views(masks, cams, k=1)
    if not props:
        raise MethodFailed("proposal: the network proposed nothing")
    rounds = max(1, budget // 2)
    prob = Problem(gen, MaskTarget(masks, cams), FitSettings(budget=2 * rounds, seed=seed, init="presets"),
                   reference=props[0].values)
    ev = Evaluator(prob.objective, 2 * rounds)
    x, d = proposed(prob, props, prob.x0())[0]
    x = placed(prob, ev, x, d, rounds)
    mesh = prob.mesh_world(x.to(torch.float64), d).detach()
    return Prediction(TriMesh(mesh.verts.double(), mesh.faces), ev.count, time.perf_counter() - t0,
                      {"params": prob.values(x, d), "discrete": d, "probability": round(props[0].probability, 4)})
