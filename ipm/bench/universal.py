"""The universal representations of issue #7 as bench methods: ``bsp`` and ``perturb``.

Both are mesh converters (:mod:`ipm.convert`), not silhouette fitters, so from K masks they convert the
visual hull of those masks (:func:`ipm.bench.methods.visual_hull`, ``resolution`` voxels a side):

``bsp``
    BSP-Net's two stages fitted per shape to the hull's occupancy (:func:`ipm.convert.bsp.fit_bsp`;
    settings ``planes`` (32), ``convexes`` (8), ``steps`` (300)); the prediction is the exact polytope.
``perturb``
    A base quadric plus perturbation functions (:func:`ipm.convert.perturb.convert_perturb`; settings
    ``max_functions`` (300), ``tolerance`` (0.01)), meshed by marching cubes.

They see exactly the masks the other methods see, so they can be no better than the visual hull of the
same views up to smoothing; what they add is a compact, editable representation (``info`` reports its
size). No image is rendered: ``evaluations`` is 0 and the conversion's own work is in ``info``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from ipm.bench import baselines as B  # attributes used at call time (baselines imports this registry)
from ipm.bench.methods import Prediction, Task, method, visual_hull


@dataclass(frozen=True)
class BspSettings:
    """Settings of ``bsp`` (module docstring)."""

    resolution: int = 96      # visual-hull voxels per side
    planes: int = 32
    convexes: int = 8
    steps: int = 300          # Adam steps of each stage

    def check(self, name: str) -> None:
        B._in_range(name, "resolution", self.resolution, 8, 256)
        B._in_range(name, "planes", self.planes, 1, 4096)
        B._in_range(name, "convexes", self.convexes, 1, 1024)
        B._in_range(name, "steps", self.steps, 1, 100_000)


@dataclass(frozen=True)
class PerturbSettings:
    """Settings of ``perturb`` (module docstring)."""

    resolution: int = 96      # visual-hull voxels per side
    max_functions: int = 300
    tolerance: float = 0.01   # mean vertex deviation, share of the bounding-box diagonal

    def check(self, name: str) -> None:
        B._in_range(name, "resolution", self.resolution, 8, 256)
        B._in_range(name, "max_functions", self.max_functions, 1, 100_000)
        B._in_range(name, "tolerance", self.tolerance, 1e-6, 1.0)


def _hull(task: Task, resolution: int):
    return visual_hull(task, {"resolution": resolution}, 0, 0).mesh


@method("bsp")
def bsp_method(task: Task, settings: dict, budget: int, seed: int) -> Prediction:
    """BSP conversion of the visual hull of the input masks (module docstring)."""
    from ipm.convert.bsp import fit_bsp

    s = B._settings(BspSettings, "bsp", settings)
    B._check_task("bsp", task, budget)
    t0 = time.perf_counter()
    conv = fit_bsp(_hull(task, s.resolution), planes=s.planes, convexes=s.convexes, steps=s.steps, seed=seed)
    mesh = conv.generator.to_mesh(conv.values)
    return Prediction(mesh, 0, time.perf_counter() - t0,
                      {"convexes": conv.stats["convexes"], "planes": conv.stats["planes"],
                       "parameters": int(conv.stats["parameters"])})


@method("perturb")
def perturb_method(task: Task, settings: dict, budget: int, seed: int) -> Prediction:
    """Perturbation-function conversion of the visual hull of the input masks (module docstring)."""
    from ipm.convert.perturb import convert_perturb

    s = B._settings(PerturbSettings, "perturb", settings)
    B._check_task("perturb", task, budget)
    t0 = time.perf_counter()
    conv = convert_perturb(_hull(task, s.resolution), max_functions=s.max_functions, tolerance=s.tolerance,
                           seed=seed)
    mesh = conv.generator.to_mesh(conv.values)
    return Prediction(mesh, 0, time.perf_counter() - t0,
                      {"functions": conv.stats["functions"], "parameters": conv.stats["parameters"],
                       "mean_deviation_rel": conv.stats.get("mean_deviation_rel")})
