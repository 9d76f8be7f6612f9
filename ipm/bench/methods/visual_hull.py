"""Bench method ``visual-hull``: space carving (Laurentini's visual hull) meshed by marching cubes.

A voxel is kept if it projects inside every mask; ``resolution`` voxels per side over [-1.2, 1.2]^3
(default 96). No optimization: ``evaluations`` is 0.
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec
import numpy as np
import torch

from ipm.bench.methods import Prediction, Task, method
from ipm.bench.views import carve
from ipm.errors import MethodFailed
from ipm.types import TriMesh

EXTENT = 1.2


class VisualHullSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    resolution: Annotated[int, msgspec.Meta(ge=8, le=512)] = 96   # voxels per side


def hull_mesh(task: Task, resolution: int) -> tuple[TriMesh, int]:
    """The visual hull of the task's masks on ``resolution``³ voxels, meshed: (mesh, kept voxels)."""
    from skimage.measure import marching_cubes

    ax = np.linspace(-EXTENT, EXTENT, resolution)
    keep = carve(task.masks, task.cameras, torch.as_tensor(ax))
    occ = keep.cpu().numpy().astype(np.float32)
    if occ.sum() == 0:
        raise MethodFailed("visual hull is empty: the masks do not agree on any voxel")
    occ = np.pad(occ, 1)
    h = ax[1] - ax[0]
    verts, faces, _, _ = marching_cubes(occ, 0.5, spacing=(h, h, h))
    verts = verts - h + ax[0]
    mesh = TriMesh(torch.as_tensor(verts, dtype=torch.float64), torch.as_tensor(faces.astype(np.int64)))
    return mesh, int(keep.sum())


@method("visual-hull", VisualHullSettings)
def visual_hull(task: Task, s: VisualHullSettings, budget: int, seed: int) -> Prediction:
    """Space carving of the masks (module docstring)."""
    t0 = time.perf_counter()
    mesh, voxels = hull_mesh(task, s.resolution)
    return Prediction(mesh, 0, time.perf_counter() - t0, {"voxels": voxels})
