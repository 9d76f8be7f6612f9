"""The bench grid: targets x methods x views x seeds, one JSON row per finished cell.

Rows are appended to ``rows.jsonl`` as soon as a cell finishes, so an interrupted bench resumes where it
stopped (``resume=True`` skips the cells already in the file). Cells run inline (one worker), in local
worker processes, or on a Dask distributed cluster (``scheduler`` address); all three run the same
function, :func:`run_cell`.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from ipm.bench.config import Cell, Experiment, load_experiment
from ipm.types import TriMesh

log = logging.getLogger(__name__)
ROWS = "rows.jsonl"


@lru_cache(maxsize=16)
def _target_mesh(exp_path: str, name: str) -> tuple[TriMesh, dict | None, str | None]:
    """The normalized target mesh, and for generator samples their parameters and generator name."""
    from ipm.metrics import normalize_vertices

    exp = load_experiment(exp_path)
    t = exp.target(name)
    truth, gen_name = None, None
    if t.mesh is not None:
        from ipm.io.meshes import load_mesh

        path = Path(t.mesh)
        path = path if path.is_absolute() else exp.root / path
        m = load_mesh(path, up=t.up, normalize=False)  # ValueError names a missing or unreadable file
        V, F = m.verts.numpy(), m.faces.numpy()
    else:
        from ipm.generators import get_generator

        gen = get_generator(t.generator)
        values = gen.values(t.preset, t.params)
        if t.random:
            values = gen.spec.validate({**values, **gen.spec.random(np.random.default_rng(t.seed)), **t.params})
        m = gen.to_mesh(values)
        V, F = m.verts.detach().double().numpy(), m.faces.numpy()
        truth, gen_name = values, gen.name
    return TriMesh(torch.as_tensor(normalize_vertices(V)), torch.as_tensor(F)), truth, gen_name


def _masks(mesh: TriMesh, cams) -> np.ndarray:
    from ipm.render.raster import rasterize_mesh

    return np.stack([rasterize_mesh(mesh, c).mask.cpu().numpy().astype(bool) for c in cams])


def param_error(pred: dict, truth: dict, gen_name: str) -> dict:
    """Mean absolute error of continuous parameters in normalized [0, 1] units, discrete accuracy."""
    from ipm.generators import get_generator

    spec = get_generator(gen_name).spec
    cont = [abs(float(pred[p.name]) - float(truth[p.name])) / max(p.hi - p.lo, 1e-12) for p in spec.continuous]
    disc = [int(pred[p.name]) == int(truth[p.name]) for p in spec.discrete]
    return {"param_error": float(np.mean(cont)) if cont else 0.0,
            "discrete_accuracy": float(np.mean(disc)) if disc else 1.0}


def mesh_path(out_dir: str | Path, key: str) -> Path:
    """Where a cell's predicted mesh (normalized as the protocol scores it) is kept: ``meshes/<key>.ply``."""
    return Path(out_dir) / "meshes" / (key.replace("|", "__") + ".ply")


def run_cell(exp_path: str, cell: Cell, out_dir: str | None = None) -> dict:
    """Run one cell and score it (DESIGN.md's protocol). Safe to call in a fresh process.

    The prediction is normalized like the target (bounding-box center at the origin, longest side 2)
    before every score, held-out silhouettes included; with ``out_dir`` it is also written to
    :func:`mesh_path` (for the contact sheets).
    """
    from ipm.bench.methods import METHODS, Task
    from ipm.io.export import export_mesh
    from ipm.io.meshes import normalize_mesh
    from ipm.metrics import mask_iou, shape_scores
    from ipm.render.camera import heldout_views, input_views

    torch.set_num_threads(1 if os.environ.get("IPM_BENCH_WORKER") else torch.get_num_threads())
    exp = load_experiment(exp_path)
    spec = exp.method(cell.method)
    target, truth, gen_name = _target_mesh(str(exp_path), cell.target)
    cams = input_views(cell.views, exp.size)
    task = Task(_masks(target, cams), cams)
    t0 = time.perf_counter()
    row = {"target": cell.target, "method": cell.method, "views": cell.views, "seed": cell.seed, "key": cell.key}
    try:
        pred = METHODS[spec.method](task, dict(spec.settings), exp.budget, cell.seed)
    except ValueError as e:
        row.update(status="failed", error=str(e), wall_time_s=round(time.perf_counter() - t0, 3))
        return row
    try:
        pred_mesh = normalize_mesh(pred.mesh)
    except ValueError as e:
        row.update(status="failed", error=f"prediction: {e}", wall_time_s=round(time.perf_counter() - t0, 3))
        return row
    if out_dir is not None:
        export_mesh(TriMesh(pred_mesh.verts.double(), pred_mesh.faces), mesh_path(out_dir, cell.key), sidecar=False)
    held = heldout_views(exp.heldout_size)
    p_masks, t_masks = _masks(pred_mesh, held), _masks(target, held)
    row["heldout_iou"] = float(np.mean([mask_iou(a, b) for a, b in zip(p_masks, t_masks)]))
    s = shape_scores(pred_mesh, target, n=exp.samples, seed=cell.seed, resolution=exp.iou_resolution)
    row.update(s.to_json())
    row.update(status="ok", evaluations=pred.evaluations, wall_time_s=round(pred.wall_time_s, 3))
    if truth is not None and "params" in pred.info and spec.settings.get("generator") == gen_name:
        row.update(param_error(pred.info["params"], truth, gen_name))
    return row


def read_rows(out_dir: Path) -> list[dict]:
    path = Path(out_dir) / ROWS
    if not path.is_file():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a torn last line from an interrupted run
    return rows


def run_experiment(exp_path: str | Path, out_dir: str | Path, *, workers: int = 1, scheduler: str | None = None,
                   resume: bool = False, dry_run: bool = False,
                   progress: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """Run every cell not yet in ``out_dir/rows.jsonl``; return all rows (old and new)."""
    exp_path = str(Path(exp_path).resolve())
    exp: Experiment = load_experiment(exp_path)
    out = Path(out_dir)
    done = read_rows(out)
    if done and not resume and not dry_run:
        raise ValueError(f"{out / ROWS} already has {len(done)} rows; pass --resume to continue it, "
                         "or choose another output folder")
    finished = {r["key"] for r in done}
    todo = [c for c in exp.cells() if c.key not in finished]
    if dry_run:
        return [{"key": c.key, "status": "todo"} for c in todo]
    out.mkdir(parents=True, exist_ok=True)
    rows = list(done)
    if done:  # drop a torn last line before appending
        (out / ROWS).write_text("".join(json.dumps(r) + "\n" for r in done))
    with open(out / ROWS, "a", buffering=1) as f:
        def keep(row: dict) -> None:
            f.write(json.dumps(row) + "\n")
            f.flush()
            rows.append(row)
            if progress is not None:
                progress(row, len(rows) - len(done), len(todo))

        for row in _execute(exp_path, todo, workers, scheduler, str(out.resolve())):
            keep(row)
    return rows


def _execute(exp_path: str, cells: list[Cell], workers: int, scheduler: str | None, out_dir: str):
    if scheduler is not None:
        from dask.distributed import Client, as_completed

        with Client(scheduler) as client:
            futures = [client.submit(run_cell, exp_path, c, out_dir, pure=False) for c in cells]
            for fut in as_completed(futures):
                yield fut.result()
        return
    if workers <= 1:
        for c in cells:
            yield run_cell(exp_path, c, out_dir)
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed

    os.environ["IPM_BENCH_WORKER"] = "1"
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(run_cell, exp_path, c, out_dir) for c in cells]
        for fut in as_completed(futures):
            yield fut.result()
