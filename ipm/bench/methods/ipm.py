"""Bench method ``ipm``: fit a procedural generator to the masks (:func:`ipm.optim.fit.run_fit`).

Settings: ``generator`` (required: a generator name, a tree preset or a tree file), ``preset`` (one of
that generator's presets), ``max_size`` (box-filter the masks to at most this many pixels a side
first, as the baselines do: :func:`ipm.bench.views.fit_views`; default: full size), ``cues`` (what the
fit is given besides the masks: ``"depth"``, ``"parts"`` or ``"parts:NAME"`` for NAME among the
generator's parts, :func:`ipm.bench.methods.parse_cues`; mesh generators only; default none) and any
field of :class:`~ipm.optim.fit.FitSettings` except ``budget`` and ``seed`` (the bench's own), the cue
weights ``depth_weight`` and ``parts_weight`` among them.

The cues the task carries go into the fit's :class:`~ipm.optim.targets.MaskTarget` (reduced with the
masks under ``max_size``: :func:`ipm.bench.views.fit_cues`).

Besides the mesh, a row gets the fit's discrete values, its final loss and ``evals_to_final``: the evaluations
the fit needed to first come within :data:`NEAR_FINAL` of its final mask IoU on the input views
(:func:`evaluations_to_final`; how soon a start lands, issue #29).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import torch

from ipm.bench.methods import NO_CUES, Cues, Prediction, Task, method, parse_cues
from ipm.errors import InputError
from ipm.types import TriMesh

NAME = "ipm"
MAX_SIZE = (8, 4096)
NEAR_FINAL = 0.01  # of mask IoU (evaluations_to_final)


@dataclass(frozen=True)
class IpmSettings:
    generator: object          # the Generator instance
    max_size: int | None
    fit: dict                  # FitSettings fields (preset included)
    cues: Cues = NO_CUES       # what the harness renders besides the masks (read by Method.cues)


def _fit_fields() -> list[str]:
    from ipm.optim.fit import FitSettings

    return [f.name for f in fields(FitSettings) if f.name not in ("budget", "seed")]


def parse_settings(name: str, settings: dict) -> IpmSettings:
    """Check and split the ``ipm`` settings; :class:`InputError` names the key and what is allowed."""
    from ipm.generators import get_generator
    from ipm.optim.fit import FitSettings

    fit_fields = _fit_fields()
    known = {"generator", "max_size", "cues", *fit_fields}
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
    from ipm.optim.shapes import SHAPES

    cues = NO_CUES
    if "cues" in settings:
        if not SHAPES.get(gen.kind).has_faces:
            raise InputError(f"{name}: setting cues: expected none for the SDF generator {g} (depth and part "
                             f"labels are compared on a mesh generator's faces), got {settings['cues']!r}")
        parts = tuple(gen.parts) or gen.to_mesh(gen.values(preset)).group_names
        cues = parse_cues(name, settings["cues"], parts)
    fit = {k: v for k, v in settings.items() if k not in ("generator", "max_size", "cues")}
    try:  # types and ranges as declared by FitSettings (msgspec), the registries' names
        FitSettings(budget=1, seed=0, **fit).check()
    except (TypeError, ValueError) as e:
        raise InputError(f"{name}: setting {e}") from None
    return IpmSettings(gen, max_size, fit, cues)


@method(NAME, parse_settings)
def ipm_fit(task: Task, s: IpmSettings, budget: int, seed: int) -> Prediction:
    """Fit a generator to the masks and the cues of the task (module docstring)."""
    from ipm.bench.views import fit_cues, fit_views
    from ipm.optim.fit import FitSettings, MaskTarget, run_fit

    size = s.max_size if s.max_size is not None else max(task.masks.shape[1:])
    masks, cams = fit_views(task.masks, task.cameras, size, torch.float32)
    depth, parts = fit_cues(task.depth, task.parts, size, torch.float32)
    target = MaskTarget(masks, cams, depth=depth, parts=parts, part_names=task.part_names if parts is not None else ())
    t0 = time.perf_counter()
    records: list[dict] = []
    res, prob, best = run_fit(s.generator, target, FitSettings(budget=budget, seed=seed, **s.fit), sink=records.append)
    mesh = prob.mesh_world(best["x"].to(torch.float64), best["discrete"]).detach()
    return Prediction(TriMesh(mesh.verts.double(), mesh.faces), res.evaluations, time.perf_counter() - t0,
                      {"params": res.params, "discrete": best["discrete"], "loss": res.loss,
                       "evals_to_final": evaluations_to_final(records, best["x"], best["discrete"])})


def evaluations_to_final(records: list[dict], x: torch.Tensor, discrete: dict, near: float = NEAR_FINAL
                         ) -> int | None:
    """How many evaluations a fit took to first reach a mask IoU (the mean over the input views, as each record's
    ``iou`` gives it) within ``near`` of the final point's. records: the fit's evaluation records in order (the
    evaluator's sink); x (m,), discrete: the final point, which is one of them (the last record at it gives
    the final IoU). None where the records carry no IoU or do not hold the final point."""
    xs = [float(v) for v in x.detach().to(torch.float64).tolist()]
    d = {k: int(v) for k, v in discrete.items()}
    final = [r for r in records if r.get("iou") and r["x"] == xs and r["discrete"] == d]
    if not final:
        return None
    goal = sum(final[-1]["iou"]) / len(final[-1]["iou"]) - near
    return next(r["i"] + 1 for r in records if r.get("iou") and sum(r["iou"]) / len(r["iou"]) >= goal)
