"""Structure search from masks (issue #30): the code of a base commit (32² silhouette rays a view) against the
working tree's (fine rays near the masks' outlines), side by side on the real armchair (Y up) and side table
(Z up).

Each target is normalized into DESIGN.md's unit sphere and rendered by the exact rasterizer in the protocol's
K = 4 input views at 256 px (``ipm.render.camera.input_views``); ``ipm.fitting.fit_structure`` searches a tree
from that mask set at the default budget, seed 0; the tree's mesh is scored against the target in the 16
held-out views (``heldout_views(256)``), as ``ipm.showcase.structure_showcase`` scores the mesh search. Every
search runs in its own process, one torch thread, on the package of the base commit (``git archive``) or of
this tree, the two alternating (old, new, old, new, ...) so that the machine's load falls on both alike; the
search is deterministic, so repeats differ only in seconds.

Usage: ``python -m benchmarks.structure_masks [OUT_DIR] [--base COMMIT] [--repeat 2,1] [--budget B]``; writes
``OUT_DIR/structure_masks.md`` and ``.json`` (default ``results/``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
TARGETS = (("armchair", "furniture/kaolin_armchair.obj", "y"), ("side table", "furniture/trimesh_side_table.obj", "z"))
BASE = "84ed15d"          # the last commit with 32² rays only
VIEWS, SIZE = 4, 256


def target_masks(rel: str, up: str, folder: Path):
    """The normalized mesh of ``rel`` and its mask set in the protocol's input views, written to ``folder``."""
    from ipm import data
    from ipm.io.masks import save_mask_set
    from ipm.io.meshes import load_mesh
    from ipm.render.camera import input_views
    from ipm.render.raster import rasterize_mesh

    mesh = load_mesh(data.path(rel), up=up, normalize=True)
    cams = input_views(VIEWS, SIZE)
    save_mask_set(folder, [rasterize_mesh(mesh, c).mask for c in cams], cams)
    return mesh


def search_once(masks: str, rel: str, up: str, budget: int) -> dict:
    """One search from ``masks`` by the ``ipm`` on the path; its held-out IoU against the mesh ``rel``, nodes,
    evaluations and seconds (the search's own wall time)."""
    from ipm import data
    from ipm.bench.protocol import render_masks
    from ipm.fitting import fit_structure
    from ipm.io.meshes import load_mesh
    from ipm.metrics import mask_iou
    from ipm.render.camera import heldout_views

    torch.set_num_threads(1)
    torch.manual_seed(0)
    res = fit_structure(masks=masks, budget=budget, seed=0)
    cams = heldout_views(SIZE)
    mesh = load_mesh(data.path(rel), up=up, normalize=True)
    iou = float(np.mean([mask_iou(a, b) for a, b in zip(render_masks(res.mesh(), cams), render_masks(mesh, cams))]))
    import ipm

    return {"heldout_iou": round(iou, 4), "fit_iou": round(res.scores["fit_iou"], 4), "nodes": res.scores["nodes"],
            "evaluations": res.evaluations, "seconds": res.wall_time_s, "ipm": str(Path(ipm.__file__).parent)}


def run(code: Path, masks: Path, rel: str, up: str, budget: int) -> dict:
    """:func:`search_once` in a new process whose ``ipm`` is the package under ``code``."""
    env = {**os.environ, "IPM_THREADS": "1", "PYTHONPATH": str(code), "IPM_DATA": str(_data_root())}
    call = (f"import json, sys; sys.path.append({str(ROOT)!r}); from benchmarks.structure_masks import "
            f"search_once; print(json.dumps(search_once({str(masks)!r}, {rel!r}, {up!r}, {budget})))")
    p = subprocess.run([sys.executable, "-c", call], cwd=code, env=env, capture_output=True, text=True, check=False)
    if p.returncode:
        raise RuntimeError(p.stderr[-2000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


def _data_root() -> Path:
    from ipm import data

    return data.root()


def main(argv: list[str] | None = None) -> None:
    """Run the comparison (module docstring) and write its table."""
    from benchmarks import common
    from ipm.optim.structure import StructureSettings

    p = argparse.ArgumentParser()
    p.add_argument("out", nargs="?", default="results")
    p.add_argument("--base", default=BASE)
    p.add_argument("--repeat", default="2,1", help="alternations per target, comma separated")
    p.add_argument("--budget", type=int, default=StructureSettings().budget)
    p.add_argument("--only", default=None, help="one target by name")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    common.COMMAND = "IPM_THREADS=1 python -m benchmarks.structure_masks " + " ".join(argv or sys.argv[1:])
    load0 = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        tar = subprocess.run(["git", "archive", a.base, "ipm"], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(old)], input=tar, check=True)
        codes = {f"{a.base}: 32² rays": old, f"{common.commit()}: 32², 64² at outlines": ROOT}
        for (name, rel, up), repeat in zip(TARGETS, map(int, a.repeat.split(","))):
            if (a.only and a.only != name) or not repeat:
                continue
            target_masks(rel, up, Path(tmp) / name)
            runs: dict[str, list[dict]] = {c: [] for c in codes}
            for _ in range(repeat):
                for label, code in codes.items():
                    r = run(code, Path(tmp) / name, rel, up, a.budget)
                    r["load"] = os.getloadavg()[0]
                    runs[label].append(r)
                    print(name, label, r, f"load {os.getloadavg()[0]:.2f}", file=sys.stderr, flush=True)
            for label, rs in runs.items():
                secs = [r["seconds"] for r in rs]
                rows.append({"target": name, "code": label, **{k: rs[0][k] for k in ("heldout_iou", "fit_iou", "nodes",
                             "evaluations")}, "seconds (median)": round(statistics.median(secs), 1),
                             "seconds (each)": " ".join(f"{s:.1f}" for s in secs),
                             "load": " ".join(f"{r['load']:.1f}" for r in rs)})
    notes = (f"K = {VIEWS} protocol input views at {SIZE} px (exact rasterizer, mesh in the unit sphere); held-out "
             f"IoU over the 16 held-out views; budget {a.budget}, seed 0, one torch thread; the two codes alternated "
             f"({a.repeat} times per target), one process a search; seconds: the search wall time; load: the 1-minute "
             f"load average after each search (at the start {load0[0]:.2f}).")
    common.write_results(Path(a.out), "structure_masks", "Structure search from masks: 32² rays against fine rays at "
                         "the outlines", rows, notes)


if __name__ == "__main__":
    main()
