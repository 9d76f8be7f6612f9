"""Is a weak cell the search's fault or the views'? One diagnostic per target.

For each named target of a bench experiment (default ``experiments/table_coverage.toml``) this runs:

1. the K-view fit (``--views``, default 1; the experiment's ``ipm`` method, its budget, seed 0): ``x1``;
2. a reference fit (``--against METHOD:VIEWS``, default the 8-view ``ipm-bound``): ``x8``, posed in the same
   world as ``x1`` (every fit places the shape in the world of the protocol's cameras);
3. ``x8`` scored by the K-view fit's own objective (its :class:`~ipm.optim.problem.Problem` at its final
   blur, held for ``x8``'s counts: :meth:`~ipm.optim.problem.Problem.adopt`), then refined on that objective
   alone (Adam, ``--steps``): ``x8r``; ``x1`` refined as long on its own objective, ``x1r``, is the control (the
   fit's own answer given the same extra steps).

(The table names them after their view counts: ``x4``, ``x2``, ``x2r`` for ``--views 4 --against ipm:2``.) Each is
scored as the bench scores a K-view cell (at K = 1 scaled about the input camera's eye; held-out IoU over the 16
held-out views). If the input-view loss of ``x8`` is *higher* than that of ``x1`` while its held-out IoU is far
higher, the K-view objective prefers the wrong shape: no search on it can land, only a prior (or more views) can.
If ``x8`` has a lower loss than ``x1``, or ``x8r`` than ``x1r``, the search did not find it. With fewer views in the
reference (``--views 4 --against ipm:2``) it asks why a fit from more views ends worse than one from fewer. The
table ends with the targets' mean held-out IoU of ``x1``, of ``x8`` and of the lower-loss of ``x1r`` and ``x8r``:
where a search that found the best point of the fit's own objective known here would end.

Usage: ``python -m benchmarks.ambiguity [--experiment TOML] [--views K] [--against METHOD:VIEWS] [--steps N]
[--budget N] [-o OUT.md] TARGET ...`` (``make bench-ambiguity`` runs every tune building and vessel of
results/table_coverage, ``make bench-ambiguity-validation`` every validation vessel and building of
results/coverage_validation; ``make bench-ambiguity-views`` the tune vessels at four views against two and the tune
buildings at two against four).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from ipm.files import write_text


def _score(exp_path: str, target: str, mesh, seed: int, views: int = 1) -> float:
    """Held-out IoU of a mesh posed for the input views, as a cell of ``views`` views is scored (at K = 1 scaled about
    the input camera's eye, :func:`ipm.bench.protocol.align_scale`; as it stands from more views)."""
    from ipm.bench import harness as H
    from ipm.bench.config import load_experiment
    from ipm.bench.protocol import align_scale, render_masks, scale_about
    from ipm.metrics import mask_iou

    exp = load_experiment(exp_path)
    eye = H._input_cameras(exp, 1)[0].eye
    if views == 1:
        mesh = scale_about(mesh, eye, align_scale(mesh, H.load_target(exp_path, target).mesh, eye, seed=seed).scale)
    pm = render_masks(mesh, H._heldout_cameras(exp))
    tm = H.target_masks(exp_path, target, None)
    return float(np.mean([mask_iou(a, b) for a, b in zip(pm, tm)]))


def _fit(exp_path: str, target: str, method: str, views: int, seed: int, budget: int | None = None):
    """run_fit as the bench's ``ipm`` method runs it (``budget``: another than the experiment's) ->
    (result, problem, best point, seconds)."""
    from ipm.bench import harness as H
    from ipm.bench.config import load_experiment
    from ipm.bench.methods import METHODS
    from ipm.bench.views import fit_views
    from ipm.optim.fit import FitSettings, MaskTarget, run_fit

    exp = load_experiment(exp_path)
    spec = exp.method(method)
    s = METHODS[spec.method].parse(spec.method, spec.settings_for(exp.target(target)))
    masks = H.target_masks(exp_path, target, views)
    cams = H._input_cameras(exp, views)
    size = s.max_size if s.max_size is not None else max(masks.shape[1:])
    m, c = fit_views(masks, cams, size, torch.float32)
    t0 = time.perf_counter()
    budget = budget or spec.budget_or(exp.budget)
    res, prob, best = run_fit(s.generator, MaskTarget(m, c), FitSettings(budget=budget, seed=seed, **s.fit))
    return res, prob, best, time.perf_counter() - t0


def _final(prob):
    """The phase a fit of ``prob`` ends in (:func:`ipm.optim.fit.run_fit`'s polish): the shape's polish blur, finer
    than the search's for meshes. The fit's result is polished at it; scored at the search's blur instead, a polished
    point looks worse than it is (the teapot's K = 1 fit: 0.0633 against its own 0.0294)."""
    from ipm.optim import phases

    sigma = prob.shape.polish_sigma
    return phases.polish(sigma) if sigma != 1.0 else phases.SEARCH


def _loss(prob, x: torch.Tensor, d: dict) -> tuple[float, float]:
    loss, _, extras = prob.objective(x.to(prob.dtype), d, False, _final(prob))
    return float(loss), float(extras["iou"][0])


def _refine(prob, x: torch.Tensor, d: dict, steps: int, lr: float) -> torch.Tensor:
    """The fit's own projected Adam (cosine schedule, the pose free) on the problem's objective at its final blur
    (:func:`_final`); the best point it visits, so never worse than ``x``."""
    from ipm.optim.evaluator import Evaluator
    from ipm.optim.gradient import adam

    ev = Evaluator(prob.objective, steps)
    with ev.running(_final(prob)):
        return adam(ev, x, d, steps, lr, mask=prob.pose_mask)[0]


def diagnose(exp_path: str, target: str, steps: int, lr: float, seed: int = 0, budget: int | None = None,
             views: int = 1, against: tuple[str, int] = ("ipm-bound", 8)) -> dict:
    from ipm.optim.problem import Problem

    r1, p1, b1, t1 = _fit(exp_path, target, "ipm", views, seed, budget)
    r8, p8, b8, t8 = _fit(exp_path, target, against[0], against[1], seed)
    x1, d1 = b1["x"], b1["discrete"]
    # the 8-view point in the terms of the K = 1 objective: the same problem, but with its sizes per count held for
    # the 8-view answer's counts (Problem.carry: held for the K = 1 fit's, counts too far from those are squeezed)
    d8 = b8["discrete"]
    q1 = Problem(p1.gen, p1.target, p1.s, dtype=p1.dtype, reference=d8)
    x8 = q1.adopt(p8, b8["x"], d8).to(b1["x"].dtype)
    x8r = _refine(q1, x8, d8, steps, lr)
    x1r = _refine(p1, x1, d1, steps, lr)
    row = {"target": target, "discrete_1": d1, "discrete_8": d8, "seconds": round(t1 + t8, 1)}
    for name, prob, x, d in (("x1", p1, x1, d1), ("x1r", p1, x1r, d1), ("x8", q1, x8, d8), ("x8r", q1, x8r, d8)):
        loss, iou = _loss(prob, x, d)
        mesh = prob.mesh_world(x.to(torch.float64), d).detach()
        row[name] = {"loss": loss, "input_iou": iou, "heldout_iou": _score(exp_path, target, mesh, seed, views)}
    return row


def _table(rows: list[dict], steps: int, lr: float, exp_path: str, budget: int | None = None, views: int = 1,
           against: tuple[str, int] = ("ipm-bound", 8)) -> str:
    k, r = views, against[1]
    kv = "K = 1" if k == 1 else f"K = {k}"
    ref = f"the {r}-view fit" + ("" if against[0] == "ipm-bound" else f" (method {against[0]})")
    title = "Single-view ambiguity" if k == 1 else f"{k} views against {r}"
    k1 = f"; the {kv} fit at {budget} evaluations" if budget else ""
    where = "the single-view objective" if k == 1 else f"the {k}-view objective"
    out = [f"# {title} ({exp_path}, seed 0; x{r} and x{k} refined {steps} Adam steps at lr {lr}{k1})", "",
           f"{kv} objective (soft-IoU loss, the fit's final blur, its priors) and hard input-view IoU, with the",
           f"held-out IoU as a {kv} cell is scored. x{k}: the {kv} fit; x{r}: {ref}; x{r}r: x{r} refined on",
           f"the {kv} objective alone; x{k}r: x{k} refined as long (the control). `search missed` when x{r} has a",
           f"lower {kv} loss than x{k}, or x{r}r than x{k}r: a better point of the fit's own objective exists, which",
           f"the search did not find; `prefers wrong` when neither has: near the {r}-view answer {where} is higher.",
           "", f"| target | x{k} loss | x{k} input IoU | x{k} held-out | x{k}r loss | x{k}r held-out | x{r} loss | "
           f"x{r} input IoU | x{r} held-out | x{r}r loss | x{r}r held-out | verdict |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        a, ar, b, c = row["x1"], row["x1r"], row["x8"], row["x8r"]
        # x8r is a point of the K-view objective's basin around the reference answer, x1r of the fit's own
        wrong = b["loss"] >= a["loss"] and c["loss"] >= ar["loss"]
        verdict = "prefers wrong" if wrong else "search missed"
        out.append(f"| {row['target']} | {a['loss']:.4f} | {a['input_iou']:.3f} | {a['heldout_iou']:.3f} | "
                   f"{ar['loss']:.4f} | {ar['heldout_iou']:.3f} | {b['loss']:.4f} | {b['input_iou']:.3f} | "
                   f"{b['heldout_iou']:.3f} | {c['loss']:.4f} | {c['heldout_iou']:.3f} | {verdict} |")
    out += ["", _summary(rows, k, r, kv)]
    out += ["", f"Discrete values (x{k} / x{r}):", ""]
    out += [f"- {row['target']}: {row['discrete_1']} / {row['discrete_8']}" for row in rows]
    return "\n".join(out) + "\n"


def _summary(rows: list[dict], k: int, r: int, kv: str) -> str:
    """The mean held-out IoU over the targets of the fit, of the reference and of the lower-loss of x{k}r and x{r}r:
    the best point of the fit's own objective the diagnostic knows, where a search that found it would end."""
    own = statistics.fmean(row["x1"]["heldout_iou"] for row in rows)
    known = statistics.fmean(min((row["x1r"], row["x8r"]), key=lambda p: p["loss"])["heldout_iou"] for row in rows)
    ref = statistics.fmean(row["x8"]["heldout_iou"] for row in rows)
    return (f"Mean held-out IoU over the {len(rows)} targets: x{k} {own:.3f}; at the lower-loss point of x{k}r and "
            f"x{r}r, the best point of the {kv} objective known here (where a search that found it would end) "
            f"{known:.3f}; x{r} {ref:.3f}.")


def _against(text: str) -> tuple[str, int]:
    method, _, views = text.rpartition(":")
    if not method or not views.isdigit() or int(views) < 1:
        raise argparse.ArgumentTypeError(f"expected METHOD:VIEWS (e.g. ipm-bound:8, ipm:2), got {text!r}")
    return method, int(views)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.ambiguity", description=__doc__.split("\n")[0])
    ap.add_argument("targets", nargs="+")
    ap.add_argument("--experiment", default="experiments/table_coverage.toml")
    ap.add_argument("--views", type=int, default=1, help="the diagnosed fit's view count (method ipm)")
    ap.add_argument("--against", type=_against, default=("ipm-bound", 8), help="the reference fit, METHOD:VIEWS")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--lr", type=float, default=0.003)
    ap.add_argument("--budget", type=int, default=None, help="the diagnosed fit's budget (default: the experiment's)")
    ap.add_argument("-o", "--out", default="results/ambiguity.md")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for t in a.targets:
        rows.append(diagnose(a.experiment, t, a.steps, a.lr, budget=a.budget, views=a.views, against=a.against))
        r = rows[-1]
        print(f"{t}: x{a.views} {r['x1']}  x{a.views}r {r['x1r']}  x{a.against[1]} {r['x8']}  x{a.against[1]}r "
              f"{r['x8r']}", flush=True)
    write_text(Path(a.out), _table(rows, a.steps, a.lr, a.experiment, a.budget, a.views, a.against))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
