"""One candidate tree of a structure search: its parameters refined by gradient, its score, and the regions
of the target it misses or covers too much (where the edits put new parts).

- **Refinement**: Adam on every continuous parameter of the tree (raw values, clamped to their bounds after
  each step) against the fit loss of mesh fits of SDF trees (:mod:`ipm.losses.sdf`): the mean |SDF| at the
  target's surface points plus the occupancy cross-entropy at its volume points. One step is one
  evaluation (the tree at every sample, forward and backward), counted against the search's budget.
  Masks: the same cross-entropy between the tree's silhouette at each ray (the minimum of its distance
  along the ray) and the ray's pixel, every ray counted once (:func:`ray_loss`).
- **Score**: ``1 - IoU`` of the tree's occupancy with the target's on the sample grid (masks: of its
  silhouettes with the masks, over every ray, each counted once as in the fit), plus the description length
  ``node_cost`` per node: a node must buy ``node_cost`` of IoU to stay.
- **Residual**: grid cells inside the target and outside the tree (missing; masks: only on the rays the
  tree misses, :func:`missed_cells`) and the reverse (extra), split into connected regions, largest first,
  each with its bounding box.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ipm.losses.sdf import occupancy_loss, sdf_surface_loss
from ipm.optim.adam import Adam
from ipm.optim.structure.program import count_nodes
from ipm.optim.structure.samples import Samples

OCCUPANCY_WEIGHT = 0.1   # as mesh fits of SDF trees (ipm.optim.problem)
SHARPNESS = 50.0
CLOSER = 6               # points between a ray's best sample's neighbours where its least distance is sought


class Budget:
    """Counted evaluations; ``take()`` is False once ``limit`` is reached."""

    def __init__(self, limit: int, used: int = 0):
        self.limit, self.used = int(limit), int(used)

    @property
    def left(self) -> int:
        """Evaluations still allowed (0 once the limit is reached)."""
        return max(self.limit - self.used, 0)

    def take(self) -> bool:
        """Count one evaluation and return True, or return False without counting once the limit is reached."""
        if self.used >= self.limit:
            return False
        self.used += 1
        return True


@dataclass(frozen=True)
class Region:
    """A connected region of grid cells: ``cells`` many, bounding box ``lo``..``hi`` (cell faces), and its
    core ``core_lo``..``core_hi``: a box of cells nearly all inside the region (:func:`core_box`), the part
    to fit first where the region is several parts joined (a chair's seat, back and legs)."""

    cells: int
    lo: np.ndarray
    hi: np.ndarray
    core_lo: np.ndarray
    core_hi: np.ndarray

    @property
    def center(self) -> np.ndarray:
        """Center ``(3,)`` of the region's bounding box."""
        return 0.5 * (self.lo + self.hi)

    @property
    def extent(self) -> np.ndarray:
        """Side lengths ``(3,)`` of the region's bounding box."""
        return self.hi - self.lo

    @property
    def center_core(self) -> np.ndarray:
        """Center ``(3,)`` of the region's core box."""
        return 0.5 * (self.core_lo + self.core_hi)


CORE_FILL = 0.9   # share of a slab's cells inside the region for the core box to grow over it


def core_box(region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A large box of cells inside ``region`` (X, Y, Z) bool: grown from the cell deepest inside (the
    largest distance to the outside; the first such cell in index order) one slab at a time, over the face
    whose next slab is most inside (ties: the larger slab, then the first face), while that slab is at
    least :data:`CORE_FILL` inside. Returns cell index bounds ``lo`` (inclusive), ``hi`` (exclusive)."""
    from scipy.ndimage import distance_transform_edt

    depth = distance_transform_edt(np.pad(region, 1))[1:-1, 1:-1, 1:-1]
    c = np.unravel_index(int(np.argmax(depth)), region.shape)
    lo, hi = np.array(c), np.array(c) + 1
    shape = np.array(region.shape)
    while True:
        best = None
        for axis in range(3):
            for side in (0, 1):
                if (side == 0 and lo[axis] == 0) or (side == 1 and hi[axis] == shape[axis]):
                    continue
                a, b = lo.copy(), hi.copy()
                if side == 0:
                    a[axis], b[axis] = lo[axis] - 1, lo[axis]
                else:
                    a[axis], b[axis] = hi[axis], hi[axis] + 1
                slab = region[a[0]:b[0], a[1]:b[1], a[2]:b[2]]
                key = (float(slab.mean()), slab.size)
                if key[0] >= CORE_FILL and (best is None or key > best[0]):
                    best = (key, axis, side)
        if best is None:
            return lo, hi
        _, axis, side = best
        if side == 0:
            lo[axis] -= 1
        else:
            hi[axis] += 1


def compile_tree(d: dict):
    """The SDF tree of a nested JSON node ``d`` (``InputError`` if it is not a valid tree)."""
    from ipm.sdf.tree import tree_from_json

    return tree_from_json({"tree": d})


def fit_loss(f: torch.Tensor | None, g: torch.Tensor, inside: torch.Tensor) -> torch.Tensor:
    """The refinement's loss from the tree's values at the surface points ``f`` (None: masks) and at the
    volume points ``g``."""
    occ = occupancy_loss(g, inside, SHARPNESS)
    return occ if f is None else sdf_surface_loss(f) + OCCUPANCY_WEIGHT * occ


def silhouettes(tree, theta: torch.Tensor | None, samples: Samples) -> torch.Tensor:
    """The tree's silhouette value (R,) at every ray of a mask target: its least distance along the ray,
    found among the ray's samples and then among :data:`CLOSER` points evenly between the best sample's two
    neighbours. The search is not differentiated: the least value's gradient is its point's alone, so only
    that point, one per ray, is evaluated again with ``theta``'s graph (a third of the time of the
    minimum over every sample differentiated)."""
    rays = samples.rays
    R, P, _ = rays.shape
    rows = torch.arange(R, device=rays.device)
    with torch.no_grad():
        best = tree.sdf(theta, rays.reshape(-1, 3)).reshape(R, P).argmin(1)
        a, b = rays[rows, (best - 1).clamp_min(0)], rays[rows, (best + 1).clamp_max(P - 1)]
        u = torch.arange(1, CLOSER + 1, dtype=rays.dtype, device=rays.device) / (CLOSER + 1)
        near = torch.cat([rays[rows, best][:, None], a[:, None] + u[:, None] * (b - a)[:, None]], 1)
        d = tree.sdf(theta, near.reshape(-1, 3)).reshape(R, CLOSER + 1)
        if theta is None or not theta.requires_grad:
            return d.amin(1)
        point = near[rows, d.argmin(1)]
    return tree.sdf(theta, point)


def ray_loss(sil: torch.Tensor, samples: Samples) -> torch.Tensor:
    """The mean cross-entropy of silhouette values ``sil`` (R,) with the rays' pixels. Every ray counts once,
    not by its area: a fine ray at an outline weighs as much as a coarse one inside, so the outlines, where
    a fit is decided, weigh more than their area (measured on the armchair from 4 views:
    ``results/structure_masks.md``)."""
    return torch.nn.functional.binary_cross_entropy_with_logits(-SHARPNESS * sil, samples.ray_hit.to(sil.dtype))


def objective(tree, theta: torch.Tensor, samples: Samples) -> torch.Tensor:
    """The refinement's loss of ``tree`` at parameters ``theta`` (module docstring)."""
    if samples.rays is not None:
        return ray_loss(silhouettes(tree, theta, samples), samples)
    f = None if samples.surface is None else tree.sdf(theta, samples.surface)
    return fit_loss(f, tree.sdf(theta, samples.volume), samples.inside)


def refine(d: dict, samples: Samples, steps: int, lr: float, budget: Budget,
           after_step: Callable[[], None] | None = None) -> tuple[dict, float]:
    """``d`` with its parameters refined by up to ``steps`` Adam steps (fewer when the budget runs out);
    returns the refined tree and its last loss."""
    tree = compile_tree(d)
    if tree.n_params == 0 or steps <= 0:
        return d, float("nan")
    dt, dev = samples.volume.dtype, samples.volume.device
    theta = tree.theta(dt, dev).requires_grad_(True)
    lo = torch.tensor([float(p.lo) for p in tree.spec.continuous], dtype=dt, device=dev)
    hi = torch.tensor([float(p.hi) for p in tree.spec.continuous], dtype=dt, device=dev)
    opt = Adam([theta], lr=lr)
    loss = float("nan")
    for _ in range(steps):
        if not budget.take():
            break
        value = objective(tree, theta, samples)
        opt.zero_grad()
        value.backward()
        if not bool(torch.isfinite(theta.grad).all()):
            theta.grad = torch.nan_to_num(theta.grad, nan=0.0, posinf=0.0, neginf=0.0)
        opt.step()
        with torch.no_grad():
            theta.copy_(torch.maximum(torch.minimum(theta, hi), lo))
        loss = float(value.detach())
        if after_step is not None:
            after_step()
    from ipm.sdf.tree import tree_to_json

    # float32 steps may land a rounding error outside a bound: clamp again in float64
    lo64 = torch.tensor([float(p.lo) for p in tree.spec.continuous], dtype=torch.float64)
    hi64 = torch.tensor([float(p.hi) for p in tree.spec.continuous], dtype=torch.float64)
    final = torch.maximum(torch.minimum(theta.detach().cpu().double(), hi64), lo64)
    return tree_to_json(tree.with_theta(final))["tree"], loss


@torch.no_grad()
def occupancy(d: dict, samples: Samples) -> torch.Tensor:
    """The tree's occupancy (n³,) bool on the sample grid."""
    tree = compile_tree(d)
    return tree.sdf(None, samples.grid) < 0


def iou(occ: torch.Tensor, samples: Samples) -> float:
    """IoU of the occupancy ``occ`` with the target's on the sample grid (1.0 when both are empty)."""
    t = samples.grid_inside
    union = int((occ | t).sum())
    return float(int((occ & t).sum()) / union) if union else 1.0


def score(d: dict, samples: Samples, node_cost: float) -> tuple[float, float, torch.Tensor]:
    """``(score, IoU, occupancy on the grid)`` of tree ``d`` (module docstring)."""
    occ = occupancy(d, samples)
    if samples.rays is not None:
        with torch.no_grad():
            seen = silhouettes(compile_tree(d), None, samples) < 0
        union = int((seen | samples.ray_hit).sum())
        q = float(int((seen & samples.ray_hit).sum()) / union) if union else 1.0
    else:
        q = iou(occ, samples)
    return (1.0 - q) + node_cost * count_nodes(d), q, occ


MARGIN = 1.5   # cells: residual cells this close to the other shape are its outline's error, not a part


def missed_cells(d: dict, samples: Samples) -> torch.Tensor:
    """Grid cells (n³,) bool that a ray the tree ``d`` misses passes through (its pixel object, the tree's
    silhouette there not): where a missing part of a mask target may lie. Visual-hull cells off every such
    ray are explained by the tree in every view, however far they are from it (the hull of a chair holds
    the space between its legs)."""
    from scipy.ndimage import binary_dilation

    with torch.no_grad():
        missed = samples.ray_hit & (silhouettes(compile_tree(d), None, samples) >= 0)
    pts = samples.rays[missed].reshape(-1, 3).double().cpu().numpy()
    shape = np.asarray(samples.shape)
    idx = np.floor((pts - samples.lo) / samples.cell).astype(np.int64)
    idx = idx[((idx >= 0) & (idx < shape)).all(1)]
    grid = np.zeros(samples.shape, dtype=bool)
    grid[tuple(idx.T)] = True
    # a ray's samples are up to two cells apart: a cell's neighbours close the gaps
    return torch.as_tensor(binary_dilation(grid).ravel(), device=samples.grid.device)


def residual(occ: torch.Tensor, samples: Samples,
             along: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Grid cells (n³,) bool that the tree misses (inside the target, more than :data:`MARGIN` cells from the
    tree's inside, and within ``along`` (n³,) bool if given: :func:`missed_cells`) and that it covers too
    much (inside the tree, more than the margin from the target's inside): a tree whose outline is off by a
    cell leaves a thin shell of errors around it, which would otherwise join every region into one."""
    from scipy.ndimage import distance_transform_edt

    tree = occ.cpu().numpy().reshape(samples.shape)
    target = samples.grid_inside.cpu().numpy().reshape(samples.shape)
    far_tree = distance_transform_edt(np.pad(~tree, 1, constant_values=True))[1:-1, 1:-1, 1:-1] > MARGIN
    far_target = distance_transform_edt(np.pad(~target, 1, constant_values=True))[1:-1, 1:-1, 1:-1] > MARGIN
    missing = torch.as_tensor((target & far_tree).ravel(), device=occ.device)
    if along is not None:
        missing &= along
    extra = torch.as_tensor((tree & far_target).ravel(), device=occ.device)
    return missing, extra


def regions(cells: torch.Tensor, samples: Samples, min_cells: int, k: int) -> list[Region]:
    """The ``k`` largest connected regions (6-connected) of grid cells ``cells`` (n³,) bool with at least
    ``min_cells`` cells, largest first (ties: by position, so the order is deterministic)."""
    from scipy import ndimage

    grid = cells.cpu().numpy().reshape(samples.shape)
    labels, n = ndimage.label(grid)
    if n == 0:
        return []
    sizes = np.bincount(labels.ravel())[1:]
    order = sorted(range(n), key=lambda i: (-sizes[i], i))
    slices = ndimage.find_objects(labels)
    out = []
    h = samples.cell
    for i in order[:k]:
        if sizes[i] < min_cells:
            break
        sl = slices[i]
        start = np.array([s.start for s in sl])
        clo, chi = core_box(labels[sl] == i + 1)
        out.append(Region(int(sizes[i]), samples.lo + h * start, samples.lo + h * np.array([s.stop for s in sl]),
                          samples.lo + h * (start + clo), samples.lo + h * (start + chi)))
    return out


__all__ = ["Budget", "Region", "compile_tree", "core_box", "fit_loss", "iou", "missed_cells", "objective",
           "occupancy", "ray_loss", "refine", "regions", "residual", "score", "silhouettes"]
