"""Mesh -> BSP (:mod:`ipm.generators.bsp`): BSP-Net's two stages (Chen et al., CVPR 2020, sec. 3.2) as a
per-shape optimization, no network.

1. Samples: points uniform in the padded bounding box (and a tenth in the whole domain box) plus points
   near the surface, labelled inside or outside by the generalized winding number (robust for scans).
2. Initialization (what the network's encoder/decoder would predict; per shape, the surface tells us):
   the planes are the tangent planes of ``p`` clusters of surface samples (k-means in the space of
   tangent planes, so every face of a polyhedron gets a plane); the selection is a greedy cover of the
   inside samples with maximal convex cells of those planes (:func:`initial_selection`), then single
   entries are flipped while that lowers the number of misclassified samples (step 4's search); ``W = 1``.
3. Stage 1 (continuous): Adam on planes, ``T`` and ``W`` (projected to [0, 1]) with the relaxed field;
   loss = binary cross-entropy of ``sigmoid(-f / s)`` against the labels (the paper's reconstruction
   loss on occupancies, with a sharpening ``s``), plus ``T (1 - T)`` and ``W (1 - W)`` penalties that
   grow over the stage and drive the relaxed values to 0 or 1 (the paper keeps ``T`` in [0, 1] and
   ``W`` near 1 by penalties too).
4. Stage 2 (discrete): ``T`` is binarized and fixed. The paper thresholds at 0.01 because under its
   sum-of-ReLU relaxation a small ``T`` barely contributes; under ours ``T`` scales the slope of a
   plane pushed out by ``R (1 - T) / T``, which is out of reach for ``T < 1/3`` and halfway at 0.5, so we
   threshold at 0.5 (convexes with ``W < 0.5`` are dropped). Single entries are then flipped, the least
   certain first, while that lowers the number of misclassified samples under the hard field (the
   relaxation rarely ends exactly binary). Adam then moves the planes under the hard field (max over a
   convex's planes, min over convexes), with the paper's overlap penalty: the sum over convexes of the
   soft inside-ness beyond one, at each sample (weight ``overlap``).
5. Compaction (our addition, so a shape gets as few convexes as it needs): convexes are removed
   greedily, smallest first, while the share of misclassified samples grows by at most ``prune_tol``;
   stage 2 runs briefly again.
6. Export: the exact polytope mesh (no marching cubes), with the numbers of convexes and planes used.

Every stage keeps the best binary state seen, counted in misclassified samples: on simple solids the
settled initial guess is often already exact, and the relaxation (whose smooth maximum and minimum
shift surfaces by up to ``tau log k``) can end worse than it started. Near-duplicate initial planes are
parked outside the domain for the same reason.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from ipm.convert import CONVERTERS
from ipm.convert.common import (
    Conversion,
    Progress,
    Target,
    check_positive,
    check_positive_int,
    farthest_points,
    occupancy_samples,
    prepare,
    surface_with_normals,
)
from ipm.generators.bsp import (
    BspGenerator,
    convex_fields,
    hard_field,
    plane_names,
    polytope_mesh,
    relaxed_field,
)
from ipm.optim.adam import geometric, minimize

log = logging.getLogger(__name__)


def _bce(f: torch.Tensor, occ: torch.Tensor, s: float) -> torch.Tensor:
    return torch.nn.functional.binary_cross_entropy_with_logits(-f / s, occ)


def _full_mask(sel: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.vstack([sel, np.ones((6, sel.shape[1]), bool)]))


@torch.no_grad()
def _errors(planes: torch.Tensor, sel: np.ndarray, X: torch.Tensor, occ: torch.Tensor, extent: float) -> int:
    """Misclassified samples under the hard field of selection ``sel (p, c)`` bool."""
    if not sel.any():
        return int(occ.sum())
    f = hard_field(planes, _full_mask(sel[:, sel.any(0)]), X, extent)
    return int(((f < 0) != occ.bool()).sum())


def _keep_best(best: tuple, planes: torch.Tensor, sel: np.ndarray, X: torch.Tensor, occ: torch.Tensor,
               extent: float, what: str) -> tuple:
    """``(errors, planes, sel)``: the new state if it misclassifies no more samples than ``best``."""
    e = _errors(planes, sel, X, occ, extent)
    log.debug("bsp: %s -> %d errors (best so far %d)", what, e, best[0])
    return (e, planes, sel) if e <= best[0] else best


def kmeans(points: np.ndarray, k: int, rng: np.random.Generator, iters: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means (scipy's ``kmeans2``) from a farthest-point start: ``(centers (k, d), labels (N,))``.
    An empty cluster keeps its start (the caller gives it a plane out of the way)."""
    import warnings

    from scipy.cluster.vq import kmeans2

    start = points[farthest_points(points, k, rng)].copy()
    with warnings.catch_warnings():  # "one of the clusters is empty": expected when k exceeds the faces
        warnings.simplefilter("ignore", UserWarning)
        return kmeans2(points, start, iter=iters, minit="matrix", missing="warn")


def initial_planes(target: Target, p: int, rng: np.random.Generator, weight: float = 1.0) -> np.ndarray:
    """``(p, 4)`` planes (unit normal, offset): k-means (farthest-point start) of surface samples in the
    space of their tangent planes ``(n, weight * n . x)``, each cluster's plane the mean normal and the
    median offset. Samples on one face share one point of that space, so every distinct face of a
    polyhedron gets its own cluster as soon as ``p`` is at least the number of face planes (clustering
    positions instead splits big faces and merges small ones with their neighbours)."""
    pts, normals = surface_with_normals(target, max(40 * p, 4000), rng)
    offsets = (pts * normals).sum(1)
    _, lab = kmeans(np.hstack([normals, weight * offsets[:, None]]), p, rng)
    out = np.zeros((p, 4))
    for j in range(p):
        m = lab == j
        if not m.any():                  # an empty cluster: a plane out of the way
            out[j] = [0.0, 1.0, 0.0, 1.0]
            continue
        n = normals[m].mean(0)
        n /= max(np.linalg.norm(n), 1e-12)
        out[j] = [*n, float(np.median(pts[m] @ n))]
    return out


def merge_duplicates(planes: np.ndarray, extent: float, tol: float = 1e-3) -> np.ndarray:
    """``planes (p, 4)`` with near-duplicates (normals and offsets within ``tol``) parked out of the domain
    (normal +Y, offset ``2 extent``: every point keeps it). k-means gives a big face several clusters; two
    copies of one plane would otherwise split its convexes and, in the relaxed stage, sharpen the
    smooth maximum's bias ``tau log k``."""
    out = planes.copy()
    for i in range(1, len(out)):
        d = np.abs(out[:i] - out[i]).max(1)
        if (d <= tol).any():
            out[i] = [0.0, 1.0, 0.0, 2.0 * extent]
    return out


def initial_selection(planes: np.ndarray, pts: np.ndarray, labels: np.ndarray, c: int, rng: np.random.Generator,
                      tries: int = 8, slack: float = 0.02) -> np.ndarray:
    """Binary selection ``(p, c)`` to start from, by greedy cover with maximal convex cells.

    For a seed (an inside sample not yet covered), the cell of the seed is the intersection of every
    plane that keeps it; planes are then dropped one at a time, the one that lets the cell take in the
    most inside samples first, as long as each drop takes in at most ``slack`` outside samples per inside
    one (a maximal convex part inside the shape). Of ``tries`` seeds the cell covering the most new inside
    samples becomes the next convex, ``c`` times. For a polyhedron whose face planes are all among
    ``planes`` this finds its convex parts directly; the network of the paper predicts this, per shape
    the samples stand in for it."""
    n = planes[:, :3] / np.maximum(np.linalg.norm(planes[:, :3], axis=1, keepdims=True), 1e-12)
    S = (pts @ n.T - planes[:, 3]) <= 0                          # (N, p): sample on the kept side
    y = np.asarray(labels, bool)
    uncovered = y.copy()
    sel = np.zeros((len(planes), c), bool)
    for j in range(c):
        cand = np.flatnonzero(uncovered)
        if len(cand) == 0:
            break
        best = (-1, None, None)
        for seed in rng.choice(cand, size=min(tries, len(cand)), replace=False):
            K = S[seed].copy()
            cnt = (~S[:, K]).sum(1)
            while K.any():
                idx = np.flatnonzero(K)
                M = (cnt == 1)[:, None] & ~S[:, idx]             # samples a drop would take in
                gain = (M & y[:, None]).sum(0)
                cost = (M & ~y[:, None]).sum(0)
                ok = (gain > 0) & (cost <= slack * gain)
                if not ok.any():
                    break
                i = idx[np.argmax(np.where(ok, gain, -1))]
                K[i] = False
                cnt -= ~S[:, i]
            cov = cnt == 0
            new = int((cov & uncovered).sum())
            if new > best[0]:
                best = (new, K, cov)
        if best[0] <= 0:
            break
        sel[:, j] = best[1]
        uncovered &= ~best[2]
    return sel


def _stage1(P: torch.Tensor, T: torch.Tensor, W: torch.Tensor, X: torch.Tensor, occ: torch.Tensor,
            g: BspGenerator, steps: int, batch: int, lr: float, binarize: float, gen: torch.Generator,
            tick) -> None:
    """Adam on the planes, ``T`` and ``W`` (in place) under the relaxed field."""

    def loss_fn(k: int) -> torch.Tensor:
        idx = torch.randint(len(X), (batch,), generator=gen)
        t = k / max(steps - 1, 1)
        s = geometric(0.05, 0.005, k, steps)
        f = relaxed_field(P, T, W, X[idx], g.extent, g.relax, geometric(g.temperature, 0.1 * g.temperature, k, steps))
        ramp = binarize * max(0.0, 2.0 * t - 0.5)        # off for the first quarter, then growing
        return _bce(f, occ[idx], s) + ramp * ((T * (1 - T)).mean() + (W * (1 - W)).mean())

    def project(k: int, loss: torch.Tensor) -> None:
        with torch.no_grad():
            T.clamp_(0.0, 1.0)
            W.clamp_(0.0, 1.0)
        tick()

    minimize([P, T, W], loss_fn, steps, lr, after_step=project)


def _stage2(planes: torch.Tensor, sel: np.ndarray, X: torch.Tensor, occ: torch.Tensor, extent: float,
            steps: int, batch: int, lr: float, s0: float, s1: float, overlap: float, gen: torch.Generator,
            tick=None) -> torch.Tensor:
    """Adam on the planes under the hard field with selection ``sel (p, c)`` bool, plus the overlap
    penalty ``overlap * mean(relu(sum_j sigmoid(-g_j / s) - 1))``; returns the planes."""
    keep = sel.any(0)
    if steps <= 0 or not keep.any():
        return planes
    mask = _full_mask(sel[:, keep])
    P = planes.clone().requires_grad_(True)

    def loss_fn(k: int) -> torch.Tensor:
        idx = torch.randint(len(X), (batch,), generator=gen)
        s = geometric(s0, s1, k, steps)
        G = convex_fields(P, mask, X[idx], extent)                  # (batch, c)
        loss = _bce(G.amin(-1), occ[idx], s)
        if overlap > 0 and G.shape[1] > 1:
            loss = loss + overlap * torch.relu(torch.sigmoid(-G / s).sum(-1) - 1.0).mean()
        return loss

    minimize([P], loss_fn, steps, lr, schedule=lambda k: geometric(lr, lr / 20, k, steps),
             after_step=None if tick is None else lambda k, loss: tick())
    return P.detach()


def _plane_table(planes: torch.Tensor, X: torch.Tensor, extent: float) -> np.ndarray:
    """Signed distances ``(N, p + 1)`` of the samples to the planes and to the box (``|x|_inf - extent``)."""
    with torch.no_grad():
        a = planes[:, :3] / torch.sqrt((planes[:, :3] ** 2).sum(1, keepdim=True) + 1e-12)
        D = torch.cat([X @ a.T - planes[:, 3], (X.abs() - extent).amax(1, keepdim=True)], 1)
    return D.numpy()


def search_selection(planes: torch.Tensor, T: np.ndarray, X: torch.Tensor, occ: torch.Tensor, extent: float,
                     start: np.ndarray, passes: int = 3) -> np.ndarray:
    """Binary selection from ``start (p, c)`` bool: flip single entries, the least certain under the
    relaxed ``T (p, c)`` first, while that lowers the number of misclassified samples (hard field)."""
    D = _plane_table(planes, X, extent)
    box = D[:, -1]
    lab = occ.numpy() > 0.5
    p, c = T.shape
    sel = start.copy()
    inf = np.full(len(D), np.inf, dtype=D.dtype)

    def column(s):
        idx = np.flatnonzero(s)
        return np.maximum(D[:, idx].max(1), box) if len(idx) else inf

    G = np.stack([column(sel[:, j]) for j in range(c)], 1)
    err = int(((G.min(1) < 0) != lab).sum())
    order = np.argsort(np.abs(T - 0.5), axis=None)
    for _ in range(passes):
        improved = False
        for flat in order:
            i, j = divmod(int(flat), c)
            trial = sel[:, j].copy()
            trial[i] = not trial[i]
            gj = column(trial)
            rest = np.delete(G, j, axis=1).min(1) if c > 1 else inf
            e = int(((np.minimum(rest, gj) < 0) != lab).sum())
            if e < err:
                sel[:, j], G[:, j], err, improved = trial, gj, e, True
        if not improved:
            break
    return sel


def prune(planes: torch.Tensor, sel: np.ndarray, X: torch.Tensor, occ: torch.Tensor, extent: float,
          tol: int) -> np.ndarray:
    """Greedy removal of convexes (smallest first) while the number of misclassified samples stays within
    ``tol`` of the starting one. (Planes are not removed: a plane without a face costs nothing in the
    polytope, while dropping one whose effect is below the sampling density lets a convex run out to
    the domain box where no sample watches.)"""
    sel = sel.copy()
    base = _errors(planes, sel, X, occ, extent)
    D = _plane_table(planes, X, extent)
    while True:
        live = [j for j in range(sel.shape[1]) if sel[:, j].any()]
        if len(live) <= 1:
            break
        size = {j: int((np.maximum(D[:, np.flatnonzero(sel[:, j])].max(1), D[:, -1]) < 0).sum()) for j in live}
        removed = False
        for j in sorted(live, key=size.get):
            trial = sel.copy()
            trial[:, j] = False
            if _errors(planes, trial, X, occ, extent) <= base + tol:
                sel, removed = trial, True
                log.debug("bsp: removed convex %d", j)
                break
        if not removed:
            break
    return sel


@CONVERTERS.register("bsp")
def fit_bsp(mesh, *, planes: int = 16, convexes: int = 4, steps: int = 300, relaxed_steps: int | None = None,
            seed: int = 0, samples: int = 30_000, batch: int = 4096, lr: float = 0.01, prune_tol: float = 1e-4,
            overlap: float = 0.01, binarize: float = 1.0, extent: float = 1.5,
            progress: Progress | None = None) -> Conversion:
    """Fit a BSP of ``planes`` planes and ``convexes`` convexes to ``mesh`` (TriMesh, trimesh or (V, F)).

    steps: Adam steps of each stage (plus a quarter for the final refinement); relaxed_steps: steps of
    stage 1 if not ``steps`` (0 skips the relaxation: the settled initial guess goes to stage 2);
    samples: occupancy samples (half uniform, half near the surface); batch: samples per step; prune_tol: share of the
    samples a removal may misclassify; overlap: weight of the stage-2 overlap penalty; binarize: final
    weight of the stage-1 ``T (1 - T)`` penalty. The mesh is normalized first (bounding-box center at
    the origin, farthest vertex at distance 1); the result lives in that frame (``data["frame"]`` says how).

    Returns a :class:`~ipm.convert.common.Conversion` whose generator is a stage-2 (binary)
    :class:`BspGenerator`; ``stats`` holds ``convexes`` and ``planes`` (those the polytope uses),
    ``sample_accuracy``, ``iou_3d`` (polytope against the input in the normalized frame, 64^3
    winding-number grid) and ``seconds``.
    """
    p = check_positive_int("planes", planes)
    c = check_positive_int("convexes", convexes)
    steps = check_positive_int("steps", steps)
    s1 = check_positive_int("relaxed_steps", relaxed_steps, 0) if relaxed_steps is not None else steps
    samples = check_positive_int("samples", samples, 100)
    batch = check_positive_int("batch", batch)
    check_positive("lr", lr)
    t0 = time.perf_counter()
    target = prepare(mesh)
    rng = np.random.default_rng(seed)
    gen_t = torch.Generator().manual_seed(seed)
    pts, labels = _occupancy(target, samples, extent, rng)
    X = torch.as_tensor(pts, dtype=torch.float32)
    occ = torch.as_tensor(labels, dtype=torch.float32)
    batch = min(batch, len(X))
    total = s1 + steps + steps // 4
    done = [0]

    def tick():
        done[0] += 1
        if progress is not None and (done[0] % 10 == 0 or done[0] == total):
            progress(done[0], total, {"stage": "stage 1" if done[0] <= s1 else "stage 2"})

    g = BspGenerator(p, c, extent=extent)
    planes0, T0, best = _settled_guess(target, p, c, pts, labels, X, occ, extent, rng)
    P = torch.as_tensor(planes0, dtype=torch.float32).requires_grad_(True)
    T = torch.as_tensor(T0, dtype=torch.float32).requires_grad_(True)
    W = torch.ones(c, dtype=torch.float32, requires_grad=True)
    _stage1(P, T, W, X, occ, g, s1, batch, lr, binarize, gen_t, tick)

    Tn, Wn = T.detach().numpy(), W.detach().numpy()
    start = (Tn >= 0.5) & (Wn >= 0.5)[None, :]
    sel = search_selection(P.detach(), Tn, X, occ, g.extent, start)
    # every stage keeps the best binary state seen (by misclassified samples): the relaxation may end
    # worse than it started, and Adam on a sharpened cross-entropy does not count errors
    best = _keep_best(best, P.detach(), sel, X, occ, extent, "stage 1")
    planes_t = _stage2(best[1], best[2], X, occ, extent, steps, batch, lr, 0.01, 0.002, overlap, gen_t, tick)
    best = _keep_best(best, planes_t, best[2], X, occ, extent, "stage 2")
    tol = int(prune_tol * len(X))
    sel = prune(best[1], best[2], X, occ, extent, tol)
    best = (_errors(best[1], sel, X, occ, extent), best[1], sel)
    planes_t = _stage2(best[1], sel, X, occ, extent, steps // 4, batch, lr / 2, 0.004, 0.001, overlap, gen_t, tick)
    _, planes_t, sel = _keep_best(best, planes_t, sel, X, occ, extent, "refinement")
    if progress is not None:
        progress(total, total, {"stage": "export"})
    return _bsp_conversion(planes_t, sel, g, target, X, occ, seed=seed, steps=steps, t0=t0)


def _occupancy(target, samples: int, extent: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Occupancy samples (n, 3) float64 and their inside labels (n,): half of ``samples`` near the surface,
    the rest uniform over the target's box, of which a tenth of ``samples`` over the whole domain box
    ``[-extent, extent]^3`` (a convex may reach anywhere in it, and only samples can tell it not to)."""
    n_far = samples // 10
    pts, labels = occupancy_samples(target, samples // 2 - n_far, samples - samples // 2, rng)
    far, far_in = occupancy_samples(target, n_far, 0, rng, box=(np.full(3, -extent), np.full(3, extent)))
    return np.vstack([pts, far]), np.concatenate([labels, far_in])


def _settled_guess(target, p: int, c: int, pts: np.ndarray, labels: np.ndarray, X: torch.Tensor,
                   occ: torch.Tensor, extent: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The initial guess settled by :func:`search_selection`: ``p`` planes (p, 4) float64 from the target,
    their soft selection (p, c) float64 (0 or 1) into ``c`` convexes, and the best binary state so far,
    (misclassified samples of ``X``, planes (p, 4) float32, selection (p, c) bool)."""
    planes0 = merge_duplicates(initial_planes(target, p, rng), extent)
    sub = rng.choice(len(pts), size=min(len(pts), 12_000), replace=False)
    T0 = initial_selection(planes0, pts[sub], labels[sub], c, rng).astype(np.float64)
    P0 = torch.as_tensor(planes0, dtype=torch.float32)
    log.debug("bsp: initial guess %d errors", _errors(P0, T0 >= 0.5, X, occ, extent))
    T0 = search_selection(P0, T0, X, occ, extent, T0 >= 0.5).astype(np.float64)
    best = (_errors(P0, T0 >= 0.5, X, occ, extent), P0, T0 >= 0.5)
    log.debug("bsp: settled guess %d errors of %d samples", best[0], len(X))
    return planes0, T0, best


def _bsp_conversion(planes_t: torch.Tensor, sel: np.ndarray, g: BspGenerator, target, X: torch.Tensor,
                    occ: torch.Tensor, *, seed: int, steps: int, t0: float) -> Conversion:
    """The fitted planes (p, 4) and selection (p, c) bool as a stage-2 :class:`BspGenerator` with its file
    and stats (:func:`fit_bsp`), unit normals written (the field depends on their direction only)."""
    from ipm.metrics import iou_3d

    p, c = g.n_planes, g.n_convexes
    planes_np = planes_t.double().numpy()
    # unit normals in the file: the field only depends on the direction
    norm = np.linalg.norm(planes_np[:, :3], axis=1, keepdims=True)
    planes_np = np.hstack([planes_np[:, :3] / np.maximum(norm, 1e-12), planes_np[:, 3:]])
    poly = polytope_mesh(planes_np, sel, g.extent)
    values = dict(zip(plane_names(p), planes_np.reshape(-1).tolist()))
    out = BspGenerator(p, c, sel, values, extent=g.extent, relax=g.relax, temperature=g.temperature)
    acc = 1.0 - _errors(planes_t, sel, X, occ, g.extent) / len(X)
    stats = {"convexes": len(poly.convexes), "planes": len(poly.planes), "planes_total": p,
             "convexes_total": c, "parameters": 4 * p, "sample_accuracy": acc, "faces": poly.mesh.n_faces}
    # in the target's frame (the conversion keeps it): no second normalization, which would let a missing
    # thin part rescale the whole shape
    stats["iou_3d"] = iou_3d(poly.mesh, target.mesh(), normalize=False) if poly.mesh.n_faces else 0.0
    stats["seconds"] = time.perf_counter() - t0
    vals = out.spec.defaults()
    data = out.to_json(vals, conversion={"method": "bsp", "seed": seed, "steps": steps, **stats},
                       frame={"center": target.center.tolist(), "scale": target.scale})
    log.info("bsp: %d convexes, %d planes, IoU %.4f in %.1f s", stats["convexes"], stats["planes"],
             stats["iou_3d"], stats["seconds"])
    return Conversion(out, vals, data, stats)
