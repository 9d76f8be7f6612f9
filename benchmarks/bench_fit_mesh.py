"""Fits to a mesh by Chamfer: time, evaluations and F-scores; the Chamfer loss itself.

Cases (issue #5): the dishes generator fitted to the real mug scan ``ocrtoc_mug.ply``
(../shared/data/real, Z up, normalized as in DESIGN.md), 4,000 surface samples on each side:
- from the ``mug`` preset, no discrete search (the handle is known);
- from the generator's defaults (no handle), memetic search over ``has_handle``.

F-scores use exact point-to-surface distances (10,000 samples each way), in the target's frame where
the fit placed the result ("as fitted"), and after renormalizing the result by its own bounding box
as the bench scores predictions ("renormalized"; a few percent of shift or scale alone costs about
0.2 at tau = 0.02). Target: F >= 0.8 at 0.02 and >= 0.98 at 0.05 as fitted.

``chamfer.md`` times one loss with its gradient between two sets of 4,000 points: nearest neighbours
from a k-d tree (what the fits use) against the minimum over all pairs (``torch.cdist``), the same
value and gradient.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from benchmarks.common import timings, write_results

ROOT = Path(__file__).resolve().parents[1]
MUG = (ROOT / ".." / "shared" / "data" / "real" / "vessels" / "ocrtoc_mug.ply").resolve()


def _case(name: str, target, budget: int, **settings) -> dict:
    from ipm.generators import get_generator
    from ipm.metrics import fscore
    from ipm.optim.fit import FitSettings, run_fit

    t0 = time.perf_counter()
    res, prob, best = run_fit(get_generator("dishes"), target, FitSettings(budget=budget, seed=0, **settings))
    wall = time.perf_counter() - t0
    fit = prob.mesh_world(best["x"].double(), best["discrete"]).detach()
    f = {(tau, norm): fscore(fit, target.mesh, tau, normalize=norm) for tau in (0.02, 0.05) for norm in (False, True)}
    return {"case": name, "settings": str(settings), "budget": budget, "evaluations": res.evaluations,
            "seconds": round(wall, 1), "has_handle": best["discrete"].get("has_handle"),
            "F@0.02": round(f[0.02, False], 3), "F@0.05": round(f[0.05, False], 3),
            "F@0.02 renormalized": round(f[0.02, True], 3), "F@0.05 renormalized": round(f[0.05, True], 3),
            "ok": f[0.02, False] >= 0.8 and f[0.05, False] >= 0.98}


def _chamfer_rows() -> list[dict]:
    from ipm.losses import chamfer_loss

    g = torch.Generator().manual_seed(0)
    a = torch.randn(4000, 3, generator=g, requires_grad=True)
    b = torch.randn(4000, 3, generator=g)

    def brute(x, y):
        d = torch.cdist(x, y) ** 2
        return d.min(1).values.mean() + d.min(0).values.mean()

    rows = []
    for name, fn in (("k-d tree nearest neighbours", chamfer_loss), ("all pairs (cdist)", brute)):
        def step(fn=fn):
            torch.autograd.grad(fn(a, b), a)
        med, best = timings(step, repeat=7)
        rows.append({"case": f"Chamfer 4000 x 4000, value + gradient: {name}", "median ms": round(1000 * med, 1),
                     "best ms": round(1000 * best, 1)})
    return rows


def run(out_dir: Path) -> list[dict]:
    from ipm.io.fit_targets import TargetFiles, load_target

    torch.set_num_threads(2)
    rows = []
    if MUG.is_file():
        target, _ = load_target(TargetFiles(target_mesh=str(MUG), up="z"))
        rows.append(_case("real mug scan, mug preset", target, 1500, preset="mug", discrete="none"))
        rows.append(_case("real mug scan, defaults", target, 3000, discrete="memetic"))
    notes = __doc__.split("\n\n", 1)[1].strip()
    write_results(out_dir, "fit_mesh", "Fits to a mesh by Chamfer", rows, notes=notes)
    write_results(out_dir, "chamfer", "The Chamfer loss: nearest neighbours by k-d tree or over all pairs",
                  _chamfer_rows(), notes=notes.split("\n\n")[-1])
    return rows
