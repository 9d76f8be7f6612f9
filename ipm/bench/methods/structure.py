"""Bench method ``structure``: a tree of the universal generator's nodes searched from the masks (issue #34).

No fixed tree: the structure search (:mod:`ipm.optim.structure`, as ``ipm fit --structure search --masks``)
grows, replaces and removes primitives and cuts until the silhouettes of K >= 2 views agree, refining every
tree's parameters by Adam; the best tree is meshed by marching cubes as ``ipm generate tree.json`` meshes it.
What it is for: objects no fixed generator covers (chairs, tables, stools, sofas), where the ``chair`` and
``table`` trees fit only their own topology.

Its budget counts the search's own evaluations (an Adam step or a score of one tree over the views' silhouette
rays: :class:`~ipm.optim.structure.StructureSettings`), not renders of the views: give the method its own
``budget`` in the experiment (the CLI's default is 16000) and compare wall times. One view is refused: the
search needs two to place a part in depth.

Settings: any field of :class:`~ipm.optim.structure.StructureSettings` except ``budget`` and ``seed`` (the
bench's own), for example ``edits`` (leave out ``smooth`` for hard booleans) or ``rays``; ``resolution``: the
marching-cubes grid of the scored mesh (default that of ``ipm generate``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import torch

from ipm.bench.methods import Prediction, Task, method
from ipm.bench.views import check_task
from ipm.errors import InputError, MethodFailed
from ipm.types import TriMesh

RESOLUTION = (16, 512)


@dataclass(frozen=True)
class StructureMethodSettings:
    search: dict        # StructureSettings fields other than budget and seed
    resolution: int     # marching cubes of the found tree


def parse_settings(name: str, settings: dict) -> StructureMethodSettings:
    """Check the settings (``InputError`` names the key and what is allowed) by building the search's own
    settings from them (:meth:`~ipm.optim.structure.StructureSettings.check`)."""
    from ipm.fitting import STRUCTURE_RESOLUTION
    from ipm.optim.structure import StructureSettings

    own = [f.name for f in fields(StructureSettings) if f.name not in ("budget", "seed")]
    unknown = sorted(set(settings) - {*own, "resolution"})
    if unknown:
        raise InputError(f"{name}: unknown setting(s) {', '.join(map(repr, unknown))}; expected some of: "
                         f"{', '.join(sorted([*own, 'resolution']))}")
    search = {k: tuple(v) if isinstance(v, list) else v for k, v in settings.items() if k != "resolution"}
    try:
        StructureSettings(**search).check()
    except (InputError, TypeError) as e:
        raise InputError(f"{name}: {e}") from None
    res = settings.get("resolution", STRUCTURE_RESOLUTION)
    if isinstance(res, bool) or not isinstance(res, int) or not RESOLUTION[0] <= res <= RESOLUTION[1]:
        raise InputError(f"{name}: setting resolution: expected an integer in [{RESOLUTION[0]}, {RESOLUTION[1]}], "
                         f"got {res!r}")
    return StructureMethodSettings(search, res)


@method("structure", parse_settings)
def structure_search(task: Task, s: StructureMethodSettings, budget: int, seed: int) -> Prediction:
    """The searched tree of the masks, meshed (module docstring)."""
    from ipm.generators.sdftree import SdfTreeGenerator
    from ipm.optim.structure import StructureSettings, count_nodes, mask_samples, search
    from ipm.optim.structure.program import structure
    from ipm.sdf.tree import tree_from_json

    check_task("structure", task.masks, task.cameras, budget)
    if len(task.cameras) < 2:
        raise MethodFailed("structure: the search needs masks of at least 2 views to place parts in depth, got 1")
    cfg = StructureSettings(**s.search, budget=budget, seed=seed)
    t0 = time.perf_counter()
    samples = mask_samples(task.masks, task.cameras, volume=cfg.volume, grid=cfg.grid, seed=cfg.seed,
                           rays=cfg.rays, fine_rays=cfg.fine_rays).to(dtype=torch.float32)  # as ipm fit searches
    res = search(samples, cfg)
    gen = SdfTreeGenerator(tree_from_json({"tree": res.tree}))
    shape = gen.to_mesh(gen.spec.defaults(), resolution=s.resolution)
    mesh = TriMesh(shape.verts.detach().double(), shape.faces)
    return Prediction(mesh, res.evaluations, time.perf_counter() - t0,
                      {"structure": structure(res.tree), "nodes": count_nodes(res.tree), "fit_iou": res.iou,
                       "rounds": res.rounds, "stopped": res.stopped})
