"""Bench methods: one registry; a method turns input masks (and cameras) into a predicted mesh.

A method is ``run(task: Task, settings: dict, budget: int, seed: int) -> Prediction``. New methods
register themselves with ``@method("name")``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ipm.types import Camera, TriMesh

METHODS: dict[str, Callable] = {}


def method(name: str):
    def deco(fn):
        if name in METHODS:
            raise ValueError(f"bench method {name!r} is registered twice")
        METHODS[name] = fn
        return fn
    return deco


@dataclass
class Task:
    """What a method sees: K input masks ``(K, H, W)`` bool and their cameras."""

    masks: np.ndarray
    cameras: list[Camera]


@dataclass
class Prediction:
    mesh: TriMesh
    evaluations: int = 0
    wall_time_s: float = 0.0
    info: dict = field(default_factory=dict)


@method("ipm")
def ipm_fit(task: Task, settings: dict, budget: int, seed: int) -> Prediction:
    """Fit a generator (``generator``; optional ``preset``, ``discrete``, ``camera``, ``lr``, ...; any
    :class:`~ipm.optim.fit.FitSettings` field). ``max_size``: box-filter the masks to at most this many
    pixels a side first, as the baselines do (:func:`ipm.bench.baselines.fit_views`; default: full size)."""
    from ipm.generators import get_generator
    from ipm.optim.fit import FitSettings, MaskTarget, run_fit

    s = dict(settings)
    gen = get_generator(s.pop("generator"))
    max_size = s.pop("max_size", None)
    if max_size is not None:
        from ipm.bench.baselines import fit_views

        masks, cams = fit_views(task.masks, task.cameras, int(max_size), torch.float32)
    else:
        masks = torch.as_tensor(task.masks, dtype=torch.float32)
        cams = [c.to(torch.float32) for c in task.cameras]
    t0 = time.perf_counter()
    res, prob, best = run_fit(gen, MaskTarget(masks, cams), FitSettings(budget=budget, seed=seed, **s))
    mesh = prob.mesh_world(best["x"].to(torch.float64), best["discrete"]).detach()
    return Prediction(TriMesh(mesh.verts.double(), mesh.faces), res.evaluations, time.perf_counter() - t0,
                      {"params": res.params, "discrete": best["discrete"], "loss": res.loss})


@method("visual-hull")
def visual_hull(task: Task, settings: dict, budget: int, seed: int) -> Prediction:
    """Space carving: a voxel is kept if it projects inside every mask (Laurentini's visual hull),
    meshed by marching cubes. ``resolution`` voxels per side over [-1.2, 1.2]^3 (default 96)."""
    from skimage.measure import marching_cubes

    from ipm.render.camera import project

    t0 = time.perf_counter()
    n = int(settings.get("resolution", 96))
    ax = np.linspace(-1.2, 1.2, n)
    grid = torch.as_tensor(np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3))
    keep = torch.ones(len(grid), dtype=torch.bool)
    for mask, cam in zip(task.masks, task.cameras):
        xy, depth = project(grid, cam.to(torch.float64))
        px = torch.floor(xy[:, 0]).long()
        py = torch.floor(xy[:, 1]).long()
        H, W = mask.shape
        inside = (px >= 0) & (px < W) & (py >= 0) & (py < H) & (depth > 0)
        m = torch.as_tensor(mask)
        hit = torch.zeros_like(keep)
        hit[inside] = m[py[inside], px[inside]]
        keep &= hit
    occ = keep.reshape(n, n, n).numpy().astype(np.float32)
    if occ.sum() == 0:
        raise ValueError("visual hull is empty: the masks do not agree on any voxel")
    occ = np.pad(occ, 1)
    h = ax[1] - ax[0]
    verts, faces, _, _ = marching_cubes(occ, 0.5, spacing=(h, h, h))
    verts = verts - h + ax[0]
    return Prediction(TriMesh(torch.as_tensor(verts, dtype=torch.float64), torch.as_tensor(faces.astype(np.int64))),
                      0, time.perf_counter() - t0, {"voxels": int(keep.sum())})


from ipm.bench import baselines as _baselines  # noqa: E402,F401  (registers sdf-grid and mesh-deform)
from ipm.bench import universal as _universal  # noqa: E402,F401  (registers bsp and perturb)


def check_settings(name: str, settings: dict) -> None:
    """Interim check (replaced by the methods package): the method must exist."""
    from ipm.errors import InputError

    if name not in METHODS:
        raise InputError(f"unknown method {name!r}; known: {', '.join(sorted(METHODS))}")
