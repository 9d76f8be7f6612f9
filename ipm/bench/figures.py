"""Contact sheets for a bench: per target, the target and every method's result from one held-out view."""

from __future__ import annotations

from pathlib import Path

from ipm.bench.config import Experiment
from ipm.bench.harness import load_target, mesh_path

SHEET_VIEW = 1  # held-out view 1: azimuth 33.75°, elevation 40° (never an input view)


def sheet_cells(exp: Experiment, rows: list[dict], target: str) -> list[dict]:
    """One finished row per (method, views) of ``target``: the lowest seed, in the experiment's order."""
    ok = {r["key"]: r for r in rows if r.get("status") == "ok" and r["target"] == target}
    chosen = []
    for cell in exp.cells():
        if cell.target != target or cell.key not in ok:
            continue
        if any(c["method"] == cell.method and c["views"] == cell.views for c in chosen):
            continue
        chosen.append(ok[cell.key])
    return chosen


def write_contact_sheets(exp_path: str | Path, exp: Experiment, rows: list[dict], out_dir: str | Path,
                         *, size: int = 192, warn=None) -> list[Path]:
    """Write ``sheet_<target>.png`` for every target with at least one stored prediction; returns the
    sheets there are afterwards.

    Predictions are stored under ``meshes/`` (not committed). When some of a target's are missing (a
    bench resumed in a fresh clone), an existing sheet is kept rather than redrawn without them, and
    ``warn`` (a callable taking one line) is told.
    """
    import numpy as np
    import torch
    import trimesh

    from ipm.render.camera import heldout_views
    from ipm.render.preview import render_preview, save_png
    from ipm.types import TriMesh
    from ipm.viz.sheet import contact_sheet

    cam = heldout_views(size, exp.distance)[SHEET_VIEW]
    out = []
    for t in exp.targets:
        chosen = sheet_cells(exp, rows, t.name)
        cells = [r for r in chosen if mesh_path(out_dir, r["key"]).is_file()]
        path = Path(out_dir) / f"sheet_{t.name}.png"
        if len(cells) < len(chosen) and path.is_file():
            if warn is not None:
                warn(f"{path.name}: kept; {len(chosen) - len(cells)} of {len(chosen)} predictions are not in "
                     f"{Path(out_dir) / 'meshes'} (FRESH=1 recomputes them)")
            out.append(path)
            continue
        if not cells:
            continue
        target = load_target(str(Path(exp_path).resolve()), t.name).mesh
        target = TriMesh(target.verts, target.faces)  # one grey like the predictions, not colored by part
        pictures, labels = [render_preview(target, cam, size=size)], [f"{t.name} (target)"]
        for r in cells:
            tm = trimesh.load(mesh_path(out_dir, r["key"]), force="mesh", process=False)
            mesh = TriMesh(torch.as_tensor(tm.vertices, dtype=torch.float64), torch.as_tensor(tm.faces))
            pictures.append(render_preview(mesh, cam, size=size))
            labels.append(f"{r['method']} K={r['views']} IoU {r.get('heldout_iou', float('nan')):.2f}")
        sheet = contact_sheet(pictures, cols=min(len(pictures), 6), labels=labels)
        out.append(save_png(path, np.asarray(sheet)))
    return out
