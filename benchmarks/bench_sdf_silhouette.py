"""The universal generator's silhouette fits at mesh speed (issue #30): evaluations per second and final IoU.

Side by side in one process, on one thread, the README's fit ``ipm fit mug --masks M --discrete none --budget
300`` (the ``mug`` SDF tree preset; ``ipm.fit("mug", masks=M, discrete="none", budget=300, seed=0)``) with its
silhouettes through the differentiable iso-surface mesh (``sdf_silhouette="mesh"``, the default:
:mod:`ipm.render.sdf_mesh_silhouette`) and sphere-traced (``"trace"``, the reference:
:mod:`ipm.render.sdf_silhouette`), and the ``dishes`` mesh generator's fit to the same mask
(``ipm fit dishes --preset mug --masks M --discrete none --budget 300``). Masks, one view at 128^2:
``ipm render ../shared/data/real/vessels/ocrtoc_mug.ply --up z --views 1 --size 128`` (the README's example
scan) and ``ipm render mug --views 1 --size 128`` (the preset itself). Each fit runs ``REPEATS`` times, the
cases interleaved; the table gives medians, and the median of each repeat's ratio of a case's rate to the dishes
fit's next to it (the load of a shared machine changes from minute to minute). "evals/s" counts the fit's
evaluations over the time of its last one (the trajectory's ``t``: the search and polish), "evals/s, whole
call" over the whole ``ipm.fit`` call (reading the masks, writing the run folder: meshes at resolution 128,
overlays, the loss plot). Final IoU: the exact mask IoU of the result (marching cubes at 128 for the SDF tree,
the hard rasterizer) against the target mask.
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
SCAN = (ROOT / ".." / "shared" / "data" / "real" / "vessels" / "ocrtoc_mug.ply").resolve()
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


def run(out_dir: Path) -> list[dict]:
    """Write ``sdf_silhouette.md`` / ``.json`` under ``out_dir``; returns the rows."""
    torch.set_num_threads(1)
    load_before = _loadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        targets = {"mug preset, 1 view": _render(["mug"], tmp / "preset")}
        if SCAN.is_file():
            targets = {"real mug scan (README), 1 view": _render([str(SCAN), "--up", "z"], tmp / "scan"), **targets}
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
    notes = (__doc__.split("\n\n", 1)[1].strip() + f"\n\nCommand: `{COMMAND}` (torch threads: "
             f"{torch.get_num_threads()}). Load average (1 min) before / after: {load_before} / {_loadavg()} "
             "(a shared 2-core machine: the rates of one run are comparable with each other, less so with "
             "other runs).")
    write_results(out_dir, "sdf_silhouette", "SDF tree silhouette fits: iso-surface mesh, sphere tracing, dishes",
                  rows, notes)
    return rows


if __name__ == "__main__":
    run(ROOT / "results" / "perf")
