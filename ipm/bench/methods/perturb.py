"""Bench method ``perturb``: a base quadric plus perturbation functions fitted to the masks' visual hull
(:func:`ipm.convert.perturb.convert_perturb`), meshed by marching cubes. One of the universal
representations of issue #7; how converter methods see the task: :mod:`ipm.bench.methods._hull`.
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec

from ipm.bench.methods import Prediction, Task, method
from ipm.bench.methods._hull import hull_input

NAME = "perturb"


class PerturbSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Settings of ``perturb``."""

    resolution: Annotated[int, msgspec.Meta(ge=8, le=256)] = 96       # visual-hull voxels per side
    max_functions: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 300
    tolerance: Annotated[float, msgspec.Meta(ge=1e-6, le=1.0)] = 0.01  # mean deviation, share of the diagonal


@method(NAME, PerturbSettings)
def perturb(task: Task, s: PerturbSettings, budget: int, seed: int) -> Prediction:
    """Perturbation-function conversion of the visual hull of the input masks (module docstring)."""
    from ipm.convert.perturb import convert_perturb

    t0 = time.perf_counter()
    hull = hull_input(NAME, task, budget, s.resolution)
    conv = convert_perturb(hull, max_functions=s.max_functions, tolerance=s.tolerance, seed=seed)
    mesh = conv.generator.to_mesh(conv.values)
    return Prediction(mesh, 0, time.perf_counter() - t0,
                      {"functions": conv.stats["functions"], "parameters": conv.stats["parameters"],
                       "mean_deviation_rel": conv.stats.get("mean_deviation_rel")})
