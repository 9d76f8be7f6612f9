"""Bench method ``bsp``: BSP-Net's two stages fitted per shape to the occupancy of the masks' visual
hull (:func:`ipm.convert.bsp.fit_bsp`); the prediction is the exact polytope. One of the universal
representations of issue #7; how converter methods see the task: :mod:`ipm.bench.methods._hull`.
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec

from ipm.bench.methods import Prediction, Task, method
from ipm.bench.methods._hull import hull_input

NAME = "bsp"


class BspSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of ``bsp``."""

    resolution: Annotated[int, msgspec.Meta(ge=8, le=256)] = 96       # visual-hull voxels per side
    planes: Annotated[int, msgspec.Meta(ge=1, le=4096)] = 32
    convexes: Annotated[int, msgspec.Meta(ge=1, le=1024)] = 8
    steps: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 300       # Adam steps of each stage


@method(NAME, BspSettings)
def bsp(task: Task, s: BspSettings, budget: int, seed: int) -> Prediction:
    """BSP conversion of the visual hull of the input masks (module docstring)."""
    from ipm.convert.bsp import fit_bsp

    t0 = time.perf_counter()
    hull = hull_input(NAME, task, budget, s.resolution)
    conv = fit_bsp(hull, planes=s.planes, convexes=s.convexes, steps=s.steps, seed=seed)
    mesh = conv.generator.to_mesh(conv.values)
    return Prediction(mesh, 0, time.perf_counter() - t0,
                      {"convexes": conv.stats["convexes"], "planes": conv.stats["planes"],
                       "parameters": int(conv.stats["parameters"])})
