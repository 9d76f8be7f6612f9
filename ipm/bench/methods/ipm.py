"""Bench method ``ipm``: fit a procedural generator to the masks (:func:`ipm.optim.fit.run_fit`).

Settings: ``generator`` (required: a generator name, a tree preset or a tree file), ``preset`` (one of
that generator's presets), ``max_size`` (box-filter the masks to at most this many pixels a side
first, as the baselines do: :func:`ipm.bench.views.fit_views`; default: full size) and any field of
:class:`~ipm.optim.fit.FitSettings` except ``budget`` and ``seed`` (the bench's own).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import torch

from ipm.bench.methods import Prediction, Task, method
from ipm.errors import InputError
from ipm.types import TriMesh

NAME = "ipm"
MAX_SIZE = (8, 4096)


@dataclass(frozen=True)
class IpmSettings:
    generator: object          # the Generator instance
    max_size: int | None
    fit: dict                  # FitSettings fields (preset included)


def _fit_fields() -> list[str]:
    from ipm.optim.fit import FitSettings

    return [f.name for f in fields(FitSettings) if f.name not in ("budget", "seed")]


def parse_settings(name: str, settings: dict) -> IpmSettings:
    """Check and split the ``ipm`` settings; :class:`InputError` names the key and what is allowed."""
    from ipm.generators import get_generator
    from ipm.optim.fit import FitSettings

    fit_fields = _fit_fields()
    known = {"generator", "max_size", *fit_fields}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise InputError(f"{name}: unknown setting(s) {', '.join(map(repr, unknown))}; expected some of: "
                         f"{', '.join(sorted(known))}")
    if "generator" not in settings:
        raise InputError(f"{name}: setting generator: expected a generator name, got none")
    g = settings["generator"]
    if not isinstance(g, str):
        raise InputError(f"{name}: setting generator: expected a generator name, got {g!r}")
    try:
        gen = get_generator(g)
    except InputError as e:
        raise InputError(f"{name}: setting generator: {e}") from None
    preset = settings.get("preset")
    if preset is not None and preset not in gen.presets:
        raise InputError(f"{name}: setting preset: expected one of {', '.join(sorted(gen.presets)) or '(none)'} "
                         f"(presets of {g}), got {preset!r}")
    max_size = settings.get("max_size")
    if max_size is not None and (isinstance(max_size, bool) or not isinstance(max_size, int)
                                 or not MAX_SIZE[0] <= max_size <= MAX_SIZE[1]):
        raise InputError(f"{name}: setting max_size: expected an integer in [{MAX_SIZE[0]}, {MAX_SIZE[1]}], "
                         f"got {max_size!r}")
    fit = {k: v for k, v in settings.items() if k not in ("generator", "max_size")}
    try:  # types and ranges as declared by FitSettings (msgspec), the registries' names
        FitSettings(budget=1, seed=0, **fit).check()
    except (TypeError, ValueError) as e:
        raise InputError(f"{name}: setting {e}") from None
    return IpmSettings(gen, max_size, fit)


@method(NAME, parse_settings)
def ipm_fit(task: Task, s: IpmSettings, budget: int, seed: int) -> Prediction:
    """Fit a generator to the masks (module docstring)."""
    from ipm.optim.fit import FitSettings, MaskTarget, run_fit

    if s.max_size is not None:
        from ipm.bench.views import fit_views

        masks, cams = fit_views(task.masks, task.cameras, s.max_size, torch.float32)
    else:
        masks = torch.as_tensor(task.masks, dtype=torch.float32)
        cams = [c.to(torch.float32) for c in task.cameras]
    t0 = time.perf_counter()
    res, prob, best = run_fit(s.generator, MaskTarget(masks, cams), FitSettings(budget=budget, seed=seed, **s.fit))
    mesh = prob.mesh_world(best["x"].to(torch.float64), best["discrete"]).detach()
    return Prediction(TriMesh(mesh.verts.double(), mesh.faces), res.evaluations, time.perf_counter() - t0,
                      {"params": res.params, "discrete": best["discrete"], "loss": res.loss})
