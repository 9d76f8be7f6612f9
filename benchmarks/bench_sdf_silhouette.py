"""The universal generator's silhouette fits at mesh speed (issue #30): evaluations per second and final IoU.

Side by side in one process, on one thread, the README's fit ``ipm fit mug --masks M --discrete none --budget
300`` (the ``mug`` SDF tree preset; ``ipm.fit("mug", masks=M, discrete="none", budget=300, seed=0)``) with its
silhouettes through the differentiable iso-surface mesh (``sdf_silhouette="mesh"``, the default:
:mod:`ipm.render.sdf_mesh_silhouette`) and sphere-traced (``"trace"``, the reference:
:mod:`ipm.render.sdf_silhouette`), and the ``dishes`` mesh generator's fit to the same mask
(``ipm fit dishes --preset mug --masks M --discrete none --budget 300``). Masks, one view at 128^2:
``ipm render ../shared/data/real/vessels/ocrtoc_mug.ply --up z --views 1 --size 128`` (the README's example
scan), four more real mugs and cups of ``../shared/data/real`` rendered the same way (up axes as
``experiments/table1.toml`` reads them), and ``ipm render mug --views 1 --size 128`` (the preset itself).
Each fit runs ``REPEATS`` times, the
cases interleaved; the table gives medians, and the median of each repeat's ratio of a case's rate to the dishes
fit's next to it (the load of a shared machine changes from minute to minute). "evals/s" counts the fit's
evaluations over the time of its last one (the trajectory's ``t``: the search and polish), "evals/s, whole
call" over the whole ``ipm.fit`` call (reading the masks, writing the run folder: meshes at resolution 128,
overlays, the loss plot). Final IoU: the exact mask IoU of the result (marching cubes at 128 for the SDF tree,
the hard rasterizer) against the target mask. The last rows compare the two silhouettes of the tree fit over
the targets: the mean final IoU of each and of the difference (iso-surface mesh less sphere tracing), over the
real scans and over all targets.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.bench_render import _loadavg
from benchmarks.common import write_results

ROOT = Path(__file__).resolve().parents[1]
VESSELS = (ROOT / ".." / "shared" / "data" / "real" / "vessels").resolve()
SCAN = VESSELS / "ocrtoc_mug.ply"
# the README's scan first, then the other real mugs and cups: (label, file, up axis)
SCANS = (("real mug scan (README)", "ocrtoc_mug.ply", "z"), ("real mug (probcomp)", "probcomp_mug.obj", "z"),
         ("real mug (low-poly)", "bullet_mug.obj", "z"), ("real cup (dinnerware)", "bullet_dinnerware_cup.obj", "z"),
         ("real tea-set cup", "polyhaven_teaset_cup_small.obj", "y"))
REPEATS = 3
BUDGET = 300
COMMAND = "IPM_THREADS=1 python -m benchmarks.bench_sdf_silhouette"
DISHES = "dishes, mug preset (mesh generator)"
CASES = {  # name -> (generator, settings beyond the README's)
    "mug tree, iso-surface mesh (new default)": ("mug", {"sdf_silhouette": "mesh"}),
    "mug tree, sphere-traced (reference)": ("mug", {"sdf_silhouette": "trace"}),
    DISHES: ("dishes", {"preset": "mug"}),
}


def _render(args: list[str], out: Path) -> Path:
    """``ipm render ARGS --views 1 --size 128`` into ``out`` (masks and cameras.json)."""
    from ipm.cli import main

    try:
        main(["render", *args, "--views", "1", "--size", "128", "--no-previews", "-q", "-o", str(out)])
    except SystemExit as e:
        if e.code:
            raise RuntimeError(f"ipm render exited {e.code}") from None
    return out


def _fit(gen: str, masks: Path, run: Path, settings: dict) -> dict:
    """One fit: evaluations, the two rates and the final IoU."""
    import ipm

    t0 = time.perf_counter()
    res = ipm.fit(gen, masks=str(masks), run_dir=str(run), discrete="none", budget=BUDGET, seed=0, **settings)
    wall = time.perf_counter() - t0
    last = json.loads((run / "trajectory.jsonl").read_text().splitlines()[-1])
    return {"evals": res.evaluations, "loop": res.evaluations / float(last["t"]), "call": res.evaluations / wall,
            "iou": res.scores["iou_mean"]}


def _summary(rows: list[dict]) -> list[dict]:
    """Rows of the mean final IoU of the tree fit's two silhouettes and of their difference per target (mesh less
    trace), over the real scans and over every target."""
    mesh, trace = (next(iter(CASES)), list(CASES)[1])
    iou = {(r["target"], r["case"]): r["final IoU (median)"] for r in rows}
    groups = {"mean over the real scans": [t for t, c in iou if c == mesh and t.startswith("real")],
              "mean over every target": [t for t, c in iou if c == mesh]}
    out = []
    for label, ts in groups.items():
        if not ts:
            continue
        m = statistics.mean(iou[t, mesh] for t in ts)
        tr = statistics.mean(iou[t, trace] for t in ts)
        worst = min(iou[t, mesh] - iou[t, trace] for t in ts)
        out.append({"target": f"{label} ({len(ts)})", "case": "mesh less trace", "evaluations": "",
                    "evals/s (median)": "", "evals/s each": "", "rate / dishes' (median)": "",
                    "evals/s, whole call": "", "final IoU (median)": round(m - tr, 4),
                    "final IoU each": f"mesh {m:.4f}, trace {tr:.4f}, least {worst:+.4f}"})
    return out


def run(out_dir: Path) -> list[dict]:
    """Write ``sdf_silhouette.md`` / ``.json`` under ``out_dir``; returns the rows."""
    torch.set_num_threads(1)
    load_before = _loadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        targets = {f"{label}, 1 view": _render([str(VESSELS / name), "--up", up], tmp / f"scan{i}")
                   for i, (label, name, up) in enumerate(SCANS) if (VESSELS / name).is_file()}
        targets["mug preset, 1 view"] = _render(["mug"], tmp / "preset")
        for target, masks in targets.items():
            runs: dict[str, list[dict]] = {name: [] for name in CASES}
            for rep in range(REPEATS):
                for i, (name, (gen, settings)) in enumerate(CASES.items()):
                    runs[name].append(_fit(gen, masks, tmp / f"run{len(rows)}_{rep}_{i}", settings))
            base = runs[DISHES]
            for name, rs in runs.items():
                ratio = statistics.median(r["loop"] / b["loop"] for r, b in zip(rs, base))
                rows.append({"target": target, "case": name, "evaluations": rs[0]["evals"],
                             "evals/s (median)": round(statistics.median(r["loop"] for r in rs), 1),
                             "evals/s each": " / ".join(f"{r['loop']:.1f}" for r in rs),
                             "rate / dishes' (median)": round(ratio, 2),
                             "evals/s, whole call": round(statistics.median(r["call"] for r in rs), 1),
                             "final IoU (median)": round(statistics.median(r["iou"] for r in rs), 4),
                             "final IoU each": " / ".join(f"{r['iou']:.4f}" for r in rs)})
    rows += _summary(rows)
    notes = (__doc__.split("\n\n", 1)[1].strip() + f"\n\nCommand: `{COMMAND}` (torch threads: "
             f"{torch.get_num_threads()}). Load average (1 min) before / after: {load_before} / {_loadavg()} "
             "(a shared 2-core machine: the rates of one run are comparable with each other, less so with "
             "other runs).")
    write_results(out_dir, "sdf_silhouette", "SDF tree silhouette fits: iso-surface mesh, sphere tracing, dishes",
                  rows, notes)
    return rows


if __name__ == "__main__":
    run(ROOT / "results" / "perf")
