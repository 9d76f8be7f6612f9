"""A fit from start to end: settings, initialization, the search, the polish and the tie rule.

The parts live in their own modules: the search vector's layout (:mod:`ipm.optim.encoding`), the targets
(:mod:`ipm.optim.targets`), the problem and its objective (:mod:`ipm.optim.problem`), the starting poses
(:mod:`ipm.optim.pose`), the discrete search strategies (:mod:`ipm.optim.strategies`), gradient refinement
(:mod:`ipm.optim.gradient`) and the tie rule (:mod:`ipm.optim.ties`). This module runs them in order;
the names below that other modules define are re-exported for callers of ``ipm.optim.fit``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import torch

from ipm.optim import discrete as D
from ipm.optim import gradient as G
from ipm.optim import phases
from ipm.optim.encoding import DIST, ELEV, FOV, LOG2S_RANGE, T_RANGE, YAW_RANGE
from ipm.optim.evaluator import BudgetExhausted, Evaluator
from ipm.optim.parsimony import applies, nested, simpler_winner
from ipm.optim.phases import OUTLINE, OUTLINE_SHARE, OUTLINE_STEPS, SEARCH
from ipm.optim.pose import (
    initial_starts,
    learned_starts,
    pose_grid,
    preset_starts,
    spread_starts,
    variant_starts,
    yaw_free,
    yaw_turns,
)
from ipm.optim.problem import Problem
from ipm.optim.settings import CAMERA_MODES, MASK_LR, MESH_LR, FitSettings, InitMode
from ipm.optim.shapes import POLISH_SIGMA_FACTOR
from ipm.optim.strategies import STRATEGIES
from ipm.optim.targets import MaskTarget, MeshTarget
from ipm.optim.ties import TIE_SHARE, break_ties
from ipm.types import FitResult

__all__ = [
    "CAMERA_MODES", "DIST", "ELEV", "FOV", "LOG2S_RANGE", "MASK_LR", "MESH_LR", "POLISH_SIGMA_FACTOR",
    "T_RANGE", "TIE_SHARE", "YAW_RANGE", "FitSettings", "MaskTarget", "MeshTarget", "Problem", "break_ties",
    "fit_lr", "hard_scores", "initial_starts", "pose_grid", "preset_starts", "run_fit", "spread_starts",
    "yaw_free",
]

def outline_first(prob: Problem, ev: Evaluator, space: D.Space, settings: FitSettings) -> None:
    """Before a discrete search judged by part labels or depth: the first start refined on the outline
    (silhouette and depth, without part labels; L-BFGS, whose steps follow the gradient's size, so that
    sizes the outline does not see stay where they are) for :data:`OUTLINE_SHARE` of the budget, and
    ``space.outline``, which refits the outline of a candidate with other discrete values
    (:func:`ipm.optim.discrete.outlined`) for :data:`OUTLINE_STEPS` of it.

    Why: part labels tell counts (floors, windows) apart that leave the outline alone (sizes per count,
    :meth:`Problem.carry`), but only once the outline is in place; refined from the start with them, the
    sizes bend towards the start's counts (panel5 from 5 floors: 5 and 9 floors won over the true 7).
    Depth shows a handle the silhouette hides, but only on a body already in place, where the pose grid
    can turn the handle towards where the depth wants it. Adam's steps have the same size whatever the
    gradient's, so under it the window sizes, which the outline barely sees, drifted (1.5 -> 2.9 m)."""
    starts = space.starts
    # at most all but one of the evaluations left: the fit's own objective must judge at least one point
    # after the start's losses are forgotten (a budget the pose grid nearly used up skips the outline)
    steps = min(max(1, int(settings.budget * OUTLINE_SHARE)), ev.remaining - 1)
    if steps < 1:
        return
    try:
        with ev.running(OUTLINE, label="outline"):
            xo, _ = G.refine(ev, starts[0][0], starts[0][1], steps, "lbfgs", mask=prob.search_mask)
    except BudgetExhausted:
        xo = starts[0][0]
    ev.forget_best()  # the start's losses came before the outline was in place
    space.starts[0] = (xo, starts[0][1])

    def outline(x: torch.Tensor, d: dict) -> torch.Tensor:
        with ev.running(OUTLINE):
            if ev.remaining <= 0:
                raise BudgetExhausted
            steps = min(max(5, int(settings.budget * OUTLINE_STEPS)), ev.remaining)
            return G.refine(ev, x, d, steps, "lbfgs", mask=prob.search_mask)[0]

    space.outline = outline


def learned_proposals(gen, target: MaskTarget | MeshTarget, settings: FitSettings) -> list:
    """The proposals of the generator's network for the target's masks (:mod:`ipm.proposals`; every view read on
    its own, their outputs fused: :meth:`~ipm.proposals.Proposer.propose_views`), where :func:`init_mode` asks for
    them (:func:`check_proposals`); none otherwise."""
    proposer = check_proposals(gen, target, settings)
    return [] if proposer is None else proposer.propose_views(target.masks, target.cameras)


def fit_problem(gen, target: MaskTarget | MeshTarget, settings: FitSettings) -> tuple[Problem, list]:
    """The fit's problem and the learned proposals it starts from (:func:`learned_proposals`): sizes per count are
    held for the most probable proposal's counts (``Problem(reference=...)``), so that it is fitted as the network
    proposed it, not squeezed into the sizes the start's counts allow."""
    proposals = learned_proposals(gen, target, settings)
    return Problem(gen, target, settings, reference=proposals[0].values if proposals else None), proposals


def check_proposals(gen, target, settings: FitSettings):
    """The proposer a fit with ``settings`` uses (None for ``init = "presets"`` and for ``"both"`` without weights
    or with a mesh target), its weights read and checked: ``InputError`` for ``"learned"`` with a mesh target or
    without weights, and for a weights file that is not one or was trained for other parameters. Called before a
    run folder is made (:func:`ipm.fitting.fit`) and by the fit itself."""
    from ipm.errors import InputError
    from ipm.proposals import load_proposer

    init = init_mode(gen, settings)
    if init == "presets":
        if settings.proposals is not None:
            raise InputError(f"proposals: applies with init learned or both, got init presets ({gen.name}'s default) "
                             f"and {settings.proposals!r}")
        return None
    if not isinstance(target, MaskTarget):
        if init == "learned":
            raise InputError("init learned: expected masks, a photo or a mask set (the proposals read a mask), got a "
                             "mesh target")
        return None
    proposer = load_proposer(gen, settings.proposals)
    if proposer is None and init == "learned":
        raise InputError(f"init learned: expected proposal weights for {gen.name}, got none; train them with ipm "
                         f"train-proposals {gen.name} -o W.npz and pass --proposals W.npz")
    return proposer


def init_mode(gen, settings: FitSettings) -> str:
    """Where a fit starts (``presets``, ``learned`` or ``both``): ``settings.init`` if given, else the generator's
    ``init`` (``presets`` where it names none)."""
    from typing import get_args

    from ipm.errors import InputError

    init = settings.init or getattr(gen, "init", None) or "presets"
    if init not in get_args(InitMode):
        raise InputError(f"{gen.name}: init: expected one of {', '.join(get_args(InitMode))} as the generator's "
                         f"default start, got {init!r}")
    return init


def fit_lr(gen, target: MaskTarget | MeshTarget, settings: FitSettings) -> float:
    """The Adam step: ``settings.lr`` if given, else the generator's ``mask_lr`` for silhouettes and
    :data:`MESH_LR` for mesh targets."""
    if settings.lr is not None:
        return float(settings.lr)
    if not isinstance(target, MaskTarget):
        return MESH_LR
    return float(getattr(gen, "mask_lr", None) or MASK_LR)


def part_ratio(gen, settings: FitSettings) -> float:
    """The parsimony rule's share (:func:`ipm.optim.parsimony.simpler_winner`): ``settings.part_ratio`` if given,
    else the generator's ``part_ratio``, else 1 (no rule)."""
    if settings.part_ratio is not None:
        return float(settings.part_ratio)
    return float(getattr(gen, "part_ratio", None) or 1.0)


def run_fit(gen, target: MaskTarget | MeshTarget, settings: FitSettings, *, sink: Callable[[dict], None] | None = None,
            replay=(), progress: Callable[[Evaluator], None] | None = None) -> tuple[FitResult, Problem, dict]:
    """Search, then polish; returns (FitResult, the problem, the best point ``{"x", "discrete"}``)."""
    import nlopt

    prob, proposals = fit_problem(gen, target, settings)
    rng = np.random.default_rng(settings.seed)
    torch.manual_seed(settings.seed)
    nlopt.srand(settings.seed)  # GN_CRS2_LM, GN_ESCH and GN_ISRES are stochastic

    ev = Evaluator(prob.objective, settings.budget, sink=sink, replay=replay, progress=progress)
    starts, presets, variants, free_yaw, start_info = _starts(prob, ev, settings, proposals)
    searched = {p.name for p in prob.searched}

    def pose_search(x: torch.Tensor, d: dict) -> torch.Tensor:
        # the start looked the same from every yaw, so its poses say nothing about where, say, a
        # handle switched on by the search should point: rank the pose grid again with it, or, where
        # the outline was fitted first (outline_first), turn the fitted shape on the spot
        if space.outline is not None:
            d0 = space.starts[0][1]
            return yaw_turns(prob, ev, prob.repose(x, d0, d), d, pivot=prob.frame(d0)[0])
        graded = pose_grid(prob, ev, d, x, keep=1)
        return graded[0][1] if graded else x

    space = D.Space(prob.m, np.asarray(prob.coarse, dtype=np.int64), list(prob.searched), starts,
                    fixed_discrete={k: v for k, v in prob.d0.items() if k not in searched},
                    presets=[(x, prob.clamp_discrete({**prob.d0, **{k: v for k, v in d.items() if k in searched}}))
                             for x, d in presets], variants=variants,
                    pose_search=pose_search if free_yaw and not prob.cam_fit else None)

    lr = fit_lr(gen, target, settings)

    search_lr = lr
    own = settings.strategy()
    if getattr(own, "lr", None) is not None:  # a strategy's own step for its refinements (memetic's lr)
        search_lr = float(own.lr)

    def refine(x, d, steps):
        if ev.remaining <= 0:
            raise BudgetExhausted
        return G.refine(ev, x, d, min(steps, ev.remaining), settings.local, search_lr, mask=prob.search_mask)

    if isinstance(target, MaskTarget) and (target.parts is not None or target.depth is not None) and space.discrete:
        outline_first(prob, ev, space, settings)
    polish = int(settings.budget * settings.polish)
    # the tie rule's evaluations (one per searched discrete value, and one more per part it adds that is a
    # part of the mesh: ties.owned_parameters) are kept from the polish; those it does not need go back to
    # the winner
    n_tie = (len(prob.searched) + sum(1 for p in prob.searched if p.adds in getattr(gen, "parts", ()))
             if settings.ties and isinstance(target, MaskTarget) else 0)
    # with nothing discrete to search, every strategy is the multistart of "none"
    strategy = STRATEGIES[settings.discrete if space.discrete else "none"]
    with ev.running(SEARCH, until=max(ev.count + 1, settings.budget - polish)):
        strategy(ev, space, refine, rng, settings)
    # Polish: the two best discrete candidates share what is left (close competitors are often only
    # separated after longer refinement), then the best of all gets the rest. Silhouettes of meshes are
    # polished at a finer blur: the leaders are re-evaluated at it by their refinement.
    leaders = ev.leaders(2) if space.discrete else ev.leaders(1)
    # the parsimony rule's evaluation (the winner's shape without the parts the other leader lacks) is kept too,
    # where one leader has fewer parts than the other and nothing else different
    n_end = n_tie + (len(leaders) == 2 and applies(prob, part_ratio(gen, settings))
                     and nested(prob, leaders[0].discrete, leaders[1].discrete))
    finer = (isinstance(target, MaskTarget) and prob.shape.polish_sigma != 1.0
             and settings.budget - n_end - ev.count > 0)
    polishing = phases.polish(prob.shape.polish_sigma) if finer else SEARCH
    if finer:
        ev.forget_best()
    with ev.running(polishing, until=settings.budget - n_end):
        for i, lead in enumerate(leaders):
            if ev.remaining <= 0:
                break
            ev.phase = f"polish:{i}"
            share = ev.remaining // (len(leaders) - i)
            try:
                G.refine(ev, lead.x, lead.discrete, share, settings.local, lr / 2, mask=prob.pose_mask)
            except BudgetExhausted:
                break
    with ev.running(polishing):
        result, prob, best = _finish(prob, ev, gen, starts, settings, n_tie, lr)
    return dataclasses.replace(result, start=start_info), prob, best


def _starts(prob: Problem, ev: Evaluator, settings: FitSettings, proposals: list
            ) -> tuple[list, list, list, bool, dict]:
    """Where the search starts: (starts, presets, start variants (with nothing discrete to search:
    :func:`variant_starts`), whether the yaw is free, what result.json says of it), from the
    pose grid and the presets, the learned ``proposals`` (:func:`learned_proposals`), or both
    (:func:`init_mode`)."""
    init = init_mode(prob.gen, settings)
    info: dict = {"init": init if proposals else "presets"}
    if proposals:
        # the counts the search holds sizes per count for (Problem.carry): every x of the trajectory depends on them
        info["reference"] = dict(prob.ref)
        info["proposals"] = [{"discrete": {k: v for k, v in p.values.items() if k in prob.d0},
                              "probability": round(p.probability, 4), "yaw_deg": round(p.yaw_deg, 1)}
                             for p in proposals]
    try:
        # presets are ranked for strategies that seed a population with them (memetic)
        rank = bool(getattr(STRATEGIES[settings.discrete], "uses_presets", False)) and bool(prob.searched)
        if proposals and init == "learned":
            starts, presets, free_yaw = learned_starts(prob, ev, proposals)
        else:
            starts, presets, free_yaw = initial_starts(prob, ev, rank=rank, proposals=proposals)
        # the multistart of "none" refines them beside its best starts
        variants = [] if prob.searched else variant_starts(prob, ev, starts[0][0])
    except BudgetExhausted:
        starts, free_yaw, variants = [(prob.x0(), dict(prob.d0))], False, []
        presets = preset_starts(prob, starts[0][0])
    return starts, presets, variants, free_yaw, info


def _finish(prob: Problem, ev: Evaluator, gen, starts, settings: FitSettings, n_tie: int, lr: float
            ) -> tuple[FitResult, Problem, dict]:
    """The tie rule and the final refinement of the winner with what is left of the budget."""
    winner, dropped = simpler_winner(prob, ev, part_ratio(gen, settings))
    x, d, loss = winner.x, winner.discrete, winner.loss
    tied: tuple[str, ...] = ()
    if x is None:  # a budget too small for a single evaluation of the search
        x, d = starts[0][0], dict(prob.d0)
    elif n_tie:
        x, d, loss, tied = break_ties(prob, ev, winner)
    if ev.remaining > 0 and math.isfinite(loss):
        ev.phase = "polish:final"
        xr, lf = G.refine(ev, x, d, ev.remaining, settings.local, lr / 2, mask=prob.pose_mask)
        if lf < loss:
            x, loss = xr, lf
    best = {"x": x, "discrete": d}
    result = FitResult(generator=gen.name, params=prob.values(x, d), loss=float(loss), evaluations=ev.count,
                       wall_time_s=ev.elapsed_s, tied=tied, dropped=dropped)
    return result, prob, best


def hard_scores(prob: Problem, best: dict) -> dict:
    """Exact per-view mask IoUs of the final shape (hard rasterizer) against the target masks."""
    from ipm.metrics import mask_iou
    from ipm.render.raster import rasterize_mesh

    if not isinstance(prob.target, MaskTarget):
        return {}
    mesh = prob.mesh_world(best["x"].to(torch.float64), best["discrete"]).detach()
    out = []
    for cam, tgt in zip(prob.cameras(best["x"].to(torch.float64)), prob.target.masks):
        mask = rasterize_mesh(mesh, cam).mask.cpu().numpy()
        out.append(mask_iou(mask, tgt.cpu().numpy() > 0.5))
    return {"iou_per_view": out, "iou_mean": float(np.mean(out))}
