"""Where a fit starts: a coarse grid over the pose (and camera), scale and translation set from the masks'
areas and centroids, the best few poses kept; and the generator's presets posed like the best."""

from __future__ import annotations

import math

import numpy as np
import torch

from ipm.optim.encoding import T_RANGE
from ipm.optim.evaluator import Evaluator
from ipm.optim.problem import Problem, centroids, rot_y
from ipm.optim.targets import MaskTarget
from ipm.types import Camera

YAWS = (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0)
# turns of a fitted shape when a switch adds a part that breaks its symmetry (yaw_turns): finer than the
# grid, since a part's cues are narrow (a mug handle pointing at the camera, under depth: the loss 0.08
# at the true azimuth, 0.41 and 0.43 at 30 degrees either side, 0.28 with the handle behind the body)
TURNS = tuple(15.0 * k for k in range(24))
# the largest share of a fit's budget that the start variants' pose grids may take (variant_starts)
VARIANT_SHARE = 0.1
# camera fit: (elevation, distance, FOV) of the grid
CAMERA_GRID = tuple((e, 3.2, f) for e in (5.0, 25.0, 45.0) for f in (25.0, 40.0, 60.0))


def proposed(prob: Problem, proposals: list, x_pose: torch.Tensor) -> list[tuple[torch.Tensor, dict]]:
    """Learned proposals (:class:`ipm.proposals.Proposal`) as ``(x, discrete)``, each posed like ``x_pose`` but
    turned to its own yaw (where the pose is searched); values the fit holds (``--fix``, discrete parameters it
    does not search) stay at the start's, searched ones within their ranges."""
    from ipm.optim.encoding import encode_yaw

    searched = {p.name for p in prob.searched}
    start = prob.gen.values(prob.s.preset, prob.s.fix)
    out = []
    for p in proposals:
        vals = {**start, **{k: v for k, v in p.values.items() if k not in prob.s.fix}}
        th, dd = prob.gen.split(vals, torch.float64)
        dd = prob.clamp_discrete({k: (v if k in searched else prob.d0[k]) for k, v in dd.items()})
        th = prob.carry(th, dd, inverse=True)
        x = torch.cat([prob.encode_params(th), x_pose[prob.n:].double()])
        if prob.s.pose:
            x[prob.n + 3] = encode_yaw(p.yaw_deg)
        out.append((x.clamp(0, 1), dd))
    return out


def initial_starts(prob: Problem, ev: Evaluator, keep: int = 4, rank: bool = False, proposals: list = ()):
    """Rank poses on a grid (yaw; with ``camera="fit"`` also elevation and FOV), scale and translation set
    from mask areas and centroids. Returns (the best ``keep`` starts, the presets posed like the best
    (with ``rank``, best first: :func:`rank_presets`), whether the grid left the yaw undetermined: see
    :func:`yaw_free`). Learned ``proposals`` (``init = "both"``) join the presets before them, each posed at its
    own yaw; with ``rank`` they are ranked with them, so that one takes a preset's place only where it looks
    better."""
    d = dict(prob.d0)
    graded = pose_grid(prob, ev, d, keep=keep)
    starts = [(e[1], d) for e in graded] or [(prob.x0(), d)]
    presets = proposed(prob, proposals, starts[0][0]) + preset_starts(prob, starts[0][0])
    return (starts, rank_presets(prob, ev, presets, learned=len(proposals)) if rank else presets,
            yaw_free(graded))


def variant_starts(prob: Problem, ev: Evaluator, x_best: torch.Tensor) -> list[tuple[torch.Tensor, dict]]:
    """What a fit with nothing discrete to search refines beside its best starts (the multistart of ``none``, which
    otherwise refines one shape, the starting one, in its best poses): the generator's start variants
    (:attr:`Generator.start_variants`, the fit's fixed values winning), for silhouette targets: posed like ``x_best``
    and, where the pose is searched, each by its own pose grid (:func:`pose_grid`, phase ``init:variants``; a
    fitted camera the best start's).
    Refined, not ranked: their poses' looks do not tell them (on a stool seen from one view the chair tree's backless
    variant looks worse than its chair, loss 0.608 against 0.469, and refines far better, 0.19 against 0.29). Mesh
    targets: none (their fits are left as they were). Nor where their pose grids (two evaluations a yaw) would take
    more than :data:`VARIANT_SHARE` of the budget: the dishes' two variants took 32 of the 60 evaluations of
    ``make bench-small``'s mug fit, whose held-out IoU fell from 0.936 to 0.879."""
    if not isinstance(prob.target, MaskTarget):
        return []
    variants = [(x, dict(prob.d0)) for x, _ in preset_starts(prob, x_best, others=False)]
    if not variants or not prob.s.pose:
        return variants
    if 2 * len(YAWS) * len(variants) > VARIANT_SHARE * prob.s.budget:
        return []  # their pose grids would take too much of a small budget from the starts
    cam = prob.decode(x_best.detach().double())[4]  # a fitted camera stays the best start's
    cam = None if cam is None else tuple(float(v) for v in cam)
    out = []
    for x, d in variants:
        ev.phase = "init:variants"
        graded = pose_grid(prob, ev, d, x, keep=1, camera=cam)
        out.append((graded[0][1] if graded else x, d))
    return out


def learned_starts(prob: Problem, ev: Evaluator, proposals: list, keep: int = 4):
    """``init = "learned"``: :func:`initial_starts` with the network's proposals in place of the start and the
    presets: the pose grid runs on the most probable proposal's values; the others, posed like its best pose at
    their own yaws, are looked at (:func:`looks`, where the pose is searched) and come best first as the presets."""
    ev.phase = "init:learned"
    first = proposed(prob, proposals[:1], prob.x0())[0]
    graded = pose_grid(prob, ev, first[1], first[0], keep=keep)
    starts = [(e[1], first[1]) for e in graded] or [first]
    rest = proposed(prob, proposals[1:], starts[0][0])
    ev.phase = "init:learned"
    scored = looks(prob, ev, rest) if rest and isinstance(prob.target, MaskTarget) and prob.s.pose else []
    presets = [(x, rest[i][1]) for _, i, x in sorted(scored, key=lambda e: (e[0], e[1]))] or rest
    return starts, presets, yaw_free(graded)


def rank_presets(prob: Problem, ev: Evaluator, presets: list[tuple[torch.Tensor, dict]], learned: int = 0
                 ) -> list[tuple[torch.Tensor, dict]]:
    """``presets`` (x, discrete) best first by one cheap look each: rendered where the best start is, then
    rescaled and moved so that their silhouettes' areas and centroids match the target's (one more
    evaluation), the better of the two kept. A search that seeds its population with presets then
    takes the ones that look like the target rather than the first few by name (a synthetic bottle
    fitted from the ``mug`` preset: ``bottle`` first, loss 0.064, the others 0.24 to 0.68; alphabetically
    the population of 8 never reached ``pitcher``, ``plate`` or ``vase``). Silhouette targets only; the
    order is kept for others and when the budget ends. The first ``learned`` entries are learned proposals
    (their looks are recorded as phase ``init:learned``)."""
    from ipm.optim.evaluator import BudgetExhausted

    if not isinstance(prob.target, MaskTarget) or not prob.s.pose or len(presets) < 2:
        return presets
    try:
        labels = ["init:learned"] * learned + ["init:presets"] * (len(presets) - learned)
        scored = looks(prob, ev, presets, labels=labels)
    except BudgetExhausted:
        return presets
    return [(x, presets[i][1]) for _, i, x in sorted(scored, key=lambda e: (e[0], e[1]))]


def placed(prob: Problem, ev: Evaluator, x: torch.Tensor, d: dict, rounds: int = 1) -> torch.Tensor:
    """``x (m,)`` (discrete values ``d``) scaled and moved by ``rounds`` :func:`looks` in a row, each from where the
    last left it (one look places a shape by how it looked where it stood, so a shape first seen far off stays off:
    results/proposal_ablation.md); its parameters unchanged. Two evaluations a round."""
    for _ in range(rounds):
        _, _, x = looks(prob, ev, [(x, d)])[0]
    return x


def looks(prob: Problem, ev: Evaluator, entries: list[tuple[torch.Tensor, dict]], labels: list[str] | None = None
          ) -> list[tuple[float, int, torch.Tensor]]:
    """One cheap look at each of ``entries`` (x, discrete): its loss where it stands, and, rescaled and moved so
    that its silhouettes' areas and centroids match the target's, once more; ``(loss, index, x)`` of the better
    of the two, in the entries' order; each entry's evaluations recorded under its ``labels`` entry (default: the
    evaluator's phase as it is). Raises ``BudgetExhausted`` when the budget ends."""
    from ipm.optim.encoding import encode_log2_scale, encode_translation

    tgt = prob.target.masks.sum((-2, -1))
    scored = []
    for i, (x, d) in enumerate(entries):
        if labels is not None:
            ev.phase = labels[i]
        loss, _ = ev(x, d, grad=False)
        area, cen = ev.last.get("area"), ev.last.get("centroid")
        best = (loss, i, x)
        if area is not None and min(area) > 0 and cen is not None:
            _, t, _, scale, _ = prob.decode(x.detach().double())
            k = float(np.sqrt(float(tgt.mean()) / max(float(np.mean(area)), 1e-9)))
            dt = translation_from_centroids(prob.cameras(x), cen, centroids(prob.target.masks))
            xp = x.detach().double().clone()
            xp[prob.n:prob.n + 3] = encode_translation(t + torch.tensor(dt, dtype=torch.float64))
            xp[prob.n + 4] = encode_log2_scale(torch.log2(scale * k))
            xp = xp.clamp(0, 1)
            lp, _ = ev(xp, d, grad=False)
            if lp < loss:
                best = (lp, i, xp)
        scored.append(best)
    return scored

def pose_grid(prob: Problem, ev: Evaluator, d: dict, x: torch.Tensor | None = None, keep: int = 4,
              camera: tuple[float, float, float] | None = None) -> list[tuple]:
    """The best ``keep`` poses of the shape with discrete values ``d`` and the generator coordinates of
    ``x`` (default: the start), best first, as :func:`spread_starts` entries ``(loss, x, yaw, camera)``; where the
    camera is fitted, under every camera of the grid, or only under ``camera`` (elevation, distance, FOV) if given."""
    ev.phase = ev.phase if x is not None else "init"
    theta = None if x is None else prob.decode(x.detach().double())[0]
    yaws = list(YAWS) if prob.s.pose else [0.0]
    cams = [None]
    if prob.cam_fit and camera is not None:
        cams = [camera]
    elif prob.cam_fit:
        # with known intrinsics the FOV coordinate is unused, with a known ground the elevation's: one
        # value of each is enough
        ground = prob.target.ground_elevation
        cams = [c for c in CAMERA_GRID if (not prob.target.known_intrinsics or c[2] == CAMERA_GRID[0][2])
                and (ground is None or c[0] == CAMERA_GRID[0][0])]
        if ground is not None:
            cams = [(ground, d, f) for _, d, f in cams]
    scored = []
    for cam in cams:
        for yaw in yaws:
            if ev.remaining <= 1:
                break
            xp = prob.x0(yaw=yaw, camera=cam, theta=theta, **prob.mesh_start(d))
            if isinstance(prob.target, MaskTarget) and prob.s.pose:
                loss, _ = ev(xp, d, grad=False)
                area, cen = ev.last.get("area"), ev.last.get("centroid")
                tgt = prob.target.masks.sum((-2, -1))
                if area is not None and min(area) > 0:
                    s = float(np.clip(np.sqrt(float(tgt.mean()) / max(float(np.mean(area)), 1e-9)), 0.26, 3.9))
                    t = (0.0, 0.0, 0.0)
                    if cen is not None:
                        cams_x = prob.cameras(xp)
                        # scaling about the canonical center moves the rendered centroid by a factor s
                        # relative to the image center of the object; the offset is small, so ignore it
                        t = translation_from_centroids(cams_x, cen, centroids(prob.target.masks))
                    xp = prob.x0(yaw=yaw, scale=s, t=t, camera=cam, theta=theta)
            loss, _ = ev(xp, d, grad=False)
            scored.append((loss, xp, yaw, cam))
    return spread_starts(scored, keep)


def yaw_turns(prob: Problem, ev: Evaluator, x: torch.Tensor, d: dict, pivot: torch.Tensor) -> torch.Tensor:
    """``x (m,)`` turned about the vertical line through ``pivot`` (3,), a point of the generator's frame
    (the axis of a body of revolution), by the best of :data:`TURNS` (one evaluation each, no gradient);
    sizes, scale and the pivot's place in the world are kept. Where the outline is in place (a mug's
    body) and a switch adds a part that breaks the symmetry (its handle), the turn points the part where
    the cues want it. (Turning about the frame's center instead moves the body: the frame of a mug
    with its handle is centered between the two.)"""
    from ipm.optim.encoding import encode_translation, encode_yaw

    x = x.detach().double()
    _, t, yaw, scale, _ = prob.decode(x)
    c, size = prob.frame(d)
    arm = (scale * 2.0 / size) * (pivot.double() - c)  # the pivot relative to the frame's center, scaled
    best, best_x = math.inf, x
    for turn in TURNS:
        y2 = (float(yaw) + turn + 180.0) % 360.0 - 180.0
        # _to_world: p -> scale (p - c) 2 / size @ R^T + t; keep the pivot's world point
        t2 = t + arm @ rot_y(yaw).T - arm @ rot_y(torch.tensor(y2, dtype=torch.float64)).T
        xp = x.clone()
        xp[prob.n:prob.n + 3] = encode_translation(t2)
        xp[prob.n + 3] = encode_yaw(y2)
        loss, _ = ev(xp.clamp(0, 1), d, grad=False)
        if loss < best:
            best, best_x = loss, xp.clamp(0, 1)
    return best_x


def yaw_free(graded: list[tuple], tol: float = 1e-3) -> bool:
    """Whether a pose grid's entries (:func:`pose_grid`) leave the yaw undetermined: three or more poses
    tied with the best, as for a body of revolution (a mug started without its handle)."""
    return len(graded) >= 3 and all(abs(e[0] - graded[0][0]) <= tol * max(abs(graded[0][0]), 1e-12)
                                    for e in graded[:3])


def spread_starts(scored: list[tuple], keep: int, tol: float = 1e-3) -> list[tuple]:
    """The ``keep`` best of ``(loss, x, yaw, camera)`` entries (more if more tie with the best), best
    first; among equal losses (within ``tol``, relative), the yaw farthest from those already kept
    comes first.

    A shape that looks the same from every yaw (a body of revolution: a mug started without its
    handle) leaves the pose to be decided by other discrete values; the kept poses, which
    :func:`ipm.optim.discrete.best_pose` tries for those, should then cover the circle rather than be
    the first few of the grid."""
    rest = sorted(scored, key=lambda e: e[0])
    out: list[tuple] = []
    if rest:  # every pose tied with the best is kept: the grid's spacing is then the search's
        keep = max(keep, sum(e[0] <= rest[0][0] + tol * max(abs(rest[0][0]), 1e-12) for e in rest))

    def gap(e) -> float:
        same = [abs((e[2] - o[2] + 180.0) % 360.0 - 180.0) for o in out if o[3] == e[3]]
        return min(same, default=360.0)

    while rest and len(out) < keep:
        lo = rest[0][0]
        tied = [i for i, e in enumerate(rest) if e[0] <= lo + tol * max(abs(lo), 1e-12)]
        pick = max(tied, key=lambda i: gap(rest[i]))  # max keeps the first of equal gaps: the grid order
        out.append(rest.pop(pick))
    return out


def preset_starts(prob: Problem, x_best: torch.Tensor, others: bool = True) -> list[tuple[torch.Tensor, dict]]:
    """The generator's presets (other than the starting one; with ``others``), then its start variants of the
    starting preset or defaults (:attr:`Generator.start_variants`; the fit's fixed values win), as (x, discrete),
    posed like ``x_best``."""
    names = sorted(prob.gen.presets) if others else []
    overrides = [(name, dict(prob.s.fix)) for name in names if name != prob.s.preset]
    overrides += [(prob.s.preset, {**variant, **prob.s.fix}) for variant in prob.gen.start_variants
                  if any(k not in prob.s.fix for k in variant)]
    out = []
    for name, over in overrides:
        vals = prob.gen.values(name, over)
        th, dd = prob.gen.split(vals, torch.float64)
        th = prob.carry(th, dd, inverse=True)  # the search holds sizes per count for its reference counts
        out.append((torch.cat([prob.encode_params(th), x_best[prob.n:]]), dict(dd)))
    return out


def translation_from_centroids(cams: list[Camera], rendered: list, target: list) -> list[float]:
    """World translation (3,) moving rendered mask centroids onto the target's, by least squares over
    views (one view constrains the two directions parallel to its image plane)."""
    from ipm.render.camera import camera_frame

    rows, rhs = [], []
    for cam, (rx, ry), (tx, ty) in zip(cams, rendered, target):
        frame = camera_frame(cam.to(torch.float64)).numpy()  # rows: right, up, backward
        dist = float((cam.eye - cam.target).double().norm())
        px = dist * 2.0 * math.tan(math.radians(float(cam.fov_deg)) / 2.0) / cam.height  # world size of a pixel
        rows += [frame[0] / px, -frame[1] / px]
        rhs += [tx - rx, ty - ry]
    t, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return [float(np.clip(v, -T_RANGE, T_RANGE)) for v in t]
